#!/usr/bin/env bash
# Benchmarks on a 2-GPU device machine (nvidia-h200-x2), each on idle GPUs: the MJX tasks' env-only, Co-GAIL
# train_step (1 and 3 seeds) and brax-PPO rows at 8192 envs x 10 steps (one task per GPU, side by side), then
# the 2-GPU scaling check (seed axis sharded) for fetchq and handover. JSON files go to $OUT.
#   bash experiments/gpu_bench.sh
set -uo pipefail
source experiments/gpu_env.sh
nvidia-smi --query-gpu=name --format=csv,noheader
python3 - <<'PY'
import cogail_envs
from cogail_jax import data
for t in ("fetchq", "handover", "seqmanip"):
    data.ensure_default_demos(cogail_envs.make_env(t), "train")
PY
CUDA_VISIBLE_DEVICES=0 timeout ${BENCH_T:-400} python3 -m cogail_jax.bench handover "$OUT/bench-handover.json" \
  --sizes 8192 --unroll 10 > /tmp/bench-handover.log 2>&1 &
CUDA_VISIBLE_DEVICES=1 timeout ${BENCH_T:-400} python3 -m cogail_jax.bench seqmanip "$OUT/bench-seqmanip.json" \
  --sizes 8192 --unroll 10 > /tmp/bench-seqmanip.log 2>&1 &
wait
grep -v -i warp /tmp/bench-handover.log | tail -6; grep -v -i warp /tmp/bench-seqmanip.log | tail -6
timeout ${MULTI_T:-150} python3 experiments/multi_gpu.py --task fetchq --envs 8192 --calls 5 --updates-per-call 16 \
  --out "$OUT/multi-fetchq.json" 2>&1 | grep -v -i warp | tail -3
timeout ${MULTI_T:-150} python3 experiments/multi_gpu.py --task handover --envs 8192 --unroll 10 --calls 5 \
  --updates-per-call 8 --out "$OUT/multi-handover.json" 2>&1 | grep -v -i warp | tail -3
