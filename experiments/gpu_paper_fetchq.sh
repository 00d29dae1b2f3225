#!/usr/bin/env bash
# fetchq on the device machine: the paper's tables for METHODS x MIXES (3 seeds each, experiments/paper.py),
# then for the Co-GAIL uniform run a video and the HTML report. Results (not checkpoints) go to $OUT.
#   METHODS=cogail,ma_gail MIXES=uniform EVERY=3 REPORT=1 bash experiments/gpu_paper_fetchq.sh
# docs/results/paper/paper.json is read first, so several calls add to the same tables.
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/pk && ln -sfn "$PWD/envs" /tmp/pk/cogail_envs
export PYTHONPATH=$PWD/src:/tmp/pk:/tmp/site PYTHONUNBUFFERED=1 COGAIL_DATA=/tmp/data
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT" /tmp/paper
nvidia-smi --query-gpu=name --format=csv,noheader
[ -f docs/results/paper/paper.json ] && [ ! -f /tmp/paper/paper.json ] && cp docs/results/paper/paper.json /tmp/paper/paper.json
copy_out() {  # the device tool brings back few files: one archive of tables, JSON, figures (no checkpoints)
  (cd /tmp/paper && tar czf "$OUT/paper.tgz" --exclude='checkpoints' --exclude='tb' --exclude='*.gif' \
     --exclude='corrupt_checkpoints' *.md *.json *.png runs 2>/dev/null)
}
trap copy_out EXIT
start=$(date +%s.%N)
timeout ${PAPER_T:-420} python3 experiments/paper.py --tasks fetchq --methods ${METHODS:-cogail} \
  --mixes ${MIXES:-uniform} --eval-every ${EVERY:-1} --out /tmp/paper 2>&1 | grep -v -i warp | grep -v "^|" | tail -20
echo "WALL paper.py: $(python3 -c "print(round($(date +%s.%N)-$start,1))") s"
R=/tmp/paper/runs/fetchq-cogail-uniform
if [ -n "${REPORT:-}" ] && [ -f $R/results.json ]; then
  cat $R/speed.json; echo
  python3 -m cogail_jax.cli video --task fetchq --run $R --num 4 --out $R/rollouts.gif 2>&1 | tail -2
  python3 -m cogail_jax.cli report --run $R --out "$OUT/report-fetchq-gpu.html" 2>&1 | tail -2
fi
