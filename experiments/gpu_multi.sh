#!/usr/bin/env bash
# The 2-GPU scaling check on an nvidia-h200-x2 machine: experiments/multi_gpu.py (the seed axis sharded over a
# "seeds" mesh, each device running its seeds under shard_map) against one GPU at the same per-GPU batch.
#   MULTI_T=200 bash experiments/gpu_multi.sh
set -uo pipefail
source experiments/gpu_env.sh
nvidia-smi --query-gpu=name --format=csv,noheader
timeout ${MULTI_T:-200} python3 experiments/multi_gpu.py --task handover --envs 8192 --unroll 10 --calls 5 \
  --updates-per-call 8 --out "$OUT/multi-handover.json" 2>&1 | grep -v -i warp | tail -4
timeout ${MULTI_T:-200} python3 experiments/multi_gpu.py --task fetchq --envs 8192 --calls 5 --updates-per-call 16 \
  --out "$OUT/multi-fetchq.json" 2>&1 | grep -v -i warp | tail -4
