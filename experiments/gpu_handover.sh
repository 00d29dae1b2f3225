#!/usr/bin/env bash
# HR-Handover on the device machine: env-only throughput, then the paper budget x 3 seeds with evaluation.
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/pk && ln -sfn "$PWD/envs" /tmp/pk/cogail_envs
export PYTHONPATH=$PWD/src:/tmp/pk:/tmp/site PYTHONUNBUFFERED=1 COGAIL_DATA=/tmp/data
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
TASK=${TASK:-handover}
for b in ${BENCH_TASKS:-$TASK}; do
  timeout ${BENCH_T:-150} python3 -m cogail_jax.bench $b "$OUT/bench-$b-env.json" --env-only --sizes ${SIZES:-8192,32768} --steps 100 2>&1 | tail -3
done
start=$(date +%s)
timeout ${TRAIN_T:-400} python3 -m cogail_jax.cli train --config experiments/${TASK}_paper.json --seeds 300,400,500 \
  --run /tmp/runs/$TASK --no-progress 2>&1 | grep -v -i warp | tail -3
echo "WALL $TASK train: $(( $(date +%s) - start )) s"
timeout ${EVAL_T:-200} python3 -m cogail_jax.cli eval --run /tmp/runs/$TASK --every ${EVERY:-3} --no-progress 2>&1 | grep -v -i warp | tail -22
echo "WALL $TASK train+eval: $(( $(date +%s) - start )) s"
cat /tmp/runs/$TASK/speed.json
for f in results.json results.md strategy_distribution.png handover_spots.png latent_map.png; do
  [ -f /tmp/runs/$TASK/$f ] && cp /tmp/runs/$TASK/$f "$OUT/$TASK-$f"
done
