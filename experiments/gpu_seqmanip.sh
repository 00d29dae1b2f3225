#!/usr/bin/env bash
# HR-SeqManip on the device machine: env-only throughput (handover and seqmanip), then what `make train
# TASK=seqmanip` runs (experiments/seqmanip_paper.json, 3 seeds, resumable), then evaluation if time is left.
# The run directory (checkpoints included) is packed into $OUT/seqmanip-run.tgz so a later call can resume it:
# unpack it into runs/ on this side and carry it.
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/pk && ln -sfn "$PWD/envs" /tmp/pk/cogail_envs
export PYTHONPATH=$PWD/src:/tmp/pk:/tmp/site PYTHONUNBUFFERED=1 COGAIL_DATA=/tmp/data
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
RUN=${RUN:-runs/seqmanip-cogail-paper}
pack() { tar czf "$OUT/seqmanip-run.tgz" "$RUN" 2>/dev/null; }
trap pack EXIT
for b in ${BENCH_TASKS:-handover seqmanip}; do
  timeout ${BENCH_T:-120} python3 -m cogail_jax.bench $b "$OUT/bench-$b-env.json" --env-only --sizes ${SIZES:-8192} --steps 100 2>&1 | tail -2
done
if [ -n "${FETCHQ_BENCH:-}" ]; then  # fetchq: env-only, Co-GAIL train_step (1, 3 seeds) and brax's PPO, one size
  timeout ${FETCHQ_BENCH_T:-120} python3 -m cogail_jax.bench fetchq "$OUT/bench-fetchq.json" --sizes $FETCHQ_BENCH 2>&1 | tail -6
fi
start=$(date +%s)
resume=""; [ -f "$RUN/config.json" ] && resume=--resume
timeout ${TRAIN_T:-400} python3 -m cogail_jax.cli train --config experiments/seqmanip_paper.json --task seqmanip \
  --seeds 300,400,500 --run "$RUN" $resume 2>&1 | tr '\r' '\n' | grep -v -i warp | grep -v '^ *$' | tail -4
echo "WALL seqmanip train: $(( $(date +%s) - start )) s"
cat "$RUN/speed.json" 2>/dev/null; echo
ls "$RUN/checkpoints" 2>/dev/null | tail -3
if [ -n "${EVAL_T:-}" ]; then
  timeout $EVAL_T python3 -m cogail_jax.cli eval --run "$RUN" --every ${EVERY:-5} --no-progress 2>&1 | grep -v -i warp | tail -12
  echo "WALL seqmanip train+eval: $(( $(date +%s) - start )) s"
fi
