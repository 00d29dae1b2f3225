#!/usr/bin/env bash
# The fetchq GPU session: paper budget x 3 seeds for the uniform, D1 and D2 mixtures, evaluation, benchmark.
# MIXES="uniform D1 D2" (default) picks the mixtures; BENCH=1 adds the benchmark.
# Run on the device machine from the repository root (see BENCHMARKS.md); results are copied to $OUT.
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/pk && ln -sfn "$PWD/envs" /tmp/pk/cogail_envs
export PYTHONPATH=$PWD/src:/tmp/pk:/tmp/site PYTHONUNBUFFERED=1 COGAIL_DATA=/tmp/data
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
nvidia-smi --query-gpu=name --format=csv,noheader
python3 -c "import jax; print('jax', jax.__version__, jax.devices())"
MIXES=${MIXES:-uniform D1 D2}
for mix in $MIXES; do
  start=$(date +%s.%N)
  python3 -m cogail_jax.cli train --config experiments/fetchq_paper.json --mix $mix --seeds 300,400,500 \
    --run /tmp/runs/fetchq-$mix --eval --no-progress 2>&1 | grep -v -i warp | tail -22
  end=$(date +%s.%N)
  echo "WALL fetchq $mix train+eval: $(python3 -c "print(round($end-$start,1))") s"
  cat /tmp/runs/fetchq-$mix/speed.json
  cp /tmp/runs/fetchq-$mix/results.json "$OUT/fetchq-$mix-results.json"
done
for mix in $MIXES; do
  cp /tmp/runs/fetchq-$mix/strategy_distribution.png "$OUT/fetchq-$mix-strategies.png"
done
if [ -d /tmp/runs/fetchq-uniform ]; then
  cp /tmp/runs/fetchq-uniform/results.md "$OUT/fetchq-uniform-results.md"
  cp /tmp/runs/fetchq-uniform/latent_map.png "$OUT/fetchq-uniform-latent.png"
fi
if [ -n "${BENCH:-}" ]; then timeout 150 python3 -m cogail_jax.bench fetchq "$OUT/bench-fetchq.json" 2>&1 | tail -12; fi
