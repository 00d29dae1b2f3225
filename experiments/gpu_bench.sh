#!/usr/bin/env bash
# Benchmarks on one idle GPU (nvidia-h200 or -h100-x1), the tasks one after another so no two share the GPU:
# env-only, Co-GAIL train_step (1 and 3 seeds) and brax-PPO rows at 8192 envs x 10 steps. JSON files go to $OUT
# (rewritten after every row, so a task cut by BENCH_T keeps what it finished).
#   BENCH_TASKS="handover seqmanip" BENCH_ARGS="--peer-only" BENCH_T=250 bash experiments/gpu_bench.sh
# The 2-GPU scaling check is experiments/gpu_multi.sh (nvidia-h200-x2).
set -uo pipefail
source experiments/gpu_env.sh
nvidia-smi --query-gpu=name --format=csv,noheader
for t in ${BENCH_TASKS:-handover seqmanip}; do
  timeout ${BENCH_T:-250} python3 -m cogail_jax.bench $t "$OUT/bench-$t.json" --sizes ${BENCH_SIZES:-8192} \
    --unroll 10 ${BENCH_ARGS:-} > /tmp/bench-$t.log 2>&1
  grep -v -i warp /tmp/bench-$t.log | tail -8
done
