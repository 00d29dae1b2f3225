#!/usr/bin/env bash
# A GPU sweep over fetchq settings (paper budget, 3 seeds each): one line of results per setting.
# Usage (device machine, repository root): bash experiments/sweep_fetchq.sh 'name1|--set a=1 --set b=2' 'name2|...'
set -uo pipefail
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/pk && ln -sfn "$PWD/envs" /tmp/pk/cogail_envs
export PYTHONPATH=$PWD/src:/tmp/pk:/tmp/site PYTHONUNBUFFERED=1 COGAIL_DATA=/tmp/data
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
for spec in "$@"; do
  name=${spec%%|*}; flags=${spec#*|}
  start=$(date +%s)
  python3 -m cogail_jax.cli train --config experiments/fetchq_paper.json --seeds 300,400,500 $flags \
    --run /tmp/runs/$name --eval --no-progress > /tmp/runs-$name.log 2>&1 || { echo "$name FAILED"; tail -5 /tmp/runs-$name.log; continue; }
  cp /tmp/runs/$name/results.json "$OUT/$name.json"
  python3 - "$name" "$(( $(date +%s) - start ))" <<'PY'
import json, sys
r = json.load(open(f"/tmp/runs/{sys.argv[1]}/results.json"))
f = lambda d: f"{100*d['mean']:.1f}+-{100*d['std']:.1f}"
dist = " ".join(f"{100*v:.0f}" for v in r["strategy_distribution"].values())
print(f"{sys.argv[1]:14} replay {f(r['replay_success'])}  interp {f(r['interpolation_success'])}  strategies [{dist}]  {sys.argv[2]}s", flush=True)
PY
done
