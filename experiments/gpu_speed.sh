#!/usr/bin/env bash
# Issue 7's device checks in one call on an nvidia-h200-x2 machine (carry .whl and the train demos of handover
# and fetchq under data/):
#   1. the 2-GPU scaling check (experiments/gpu_multi.sh: handover and fetchq, one seed per GPU against one GPU);
#   2. then brax's PPO beside our env-only rows at 8192 envs, one benchmark per GPU at a time: PEERS lists
#      GPU:task:unroll jobs; the jobs of one GPU run one after another, the GPUs side by side.
#   MULTI_T=150 PEER_T=150 PEERS="0:handover:10 1:fetchq:94 1:seqmanip:10" bash experiments/gpu_speed.sh
set -uo pipefail
source experiments/gpu_env.sh
MULTI_T=${MULTI_T:-150} bash experiments/gpu_multi.sh
peer() {  # GPU task unroll
  CUDA_VISIBLE_DEVICES=$1 timeout ${PEER_T:-150} python3 -m cogail_jax.bench $2 "$OUT/bench-$2.json" --sizes 8192 \
    --unroll $3 --peer-only > /tmp/peer-$2.log 2>&1
  echo "== $2 (GPU $1)"; grep -v -i warp /tmp/peer-$2.log | tail -4
}
for gpu in 0 1; do
  ( for job in ${PEERS:-0:handover:10 1:fetchq:94 1:seqmanip:10}; do
      IFS=: read -r g task unroll <<< "$job"
      [ "$g" = "$gpu" ] && peer $g $task $unroll
    done ) &
done
wait
