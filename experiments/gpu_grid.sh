#!/usr/bin/env bash
# Several paper runs side by side on the device machine (experiments/paper.py, 3 seeds each), each job its own
# process and results folder; small runs (64 envs per seed) leave a GPU mostly idle, so several share one.
#   JOBS="0|handover|cogail,bc_single|uniform 1|fetchq|ma_gail|uniform,D1,D2" T=480 bash experiments/gpu_grid.sh
# A job is GPU|task|methods|mixes[|overrides] (overrides: FIELD=VALUE joined by '+'). Each writes /tmp/grid/<task>-<methods>-<mixes>/paper.json; everything but
# checkpoints comes back in $OUT/grid.tgz. Merge here with
#   python experiments/paper.py --out docs/results/paper --merge DIR...
# Runs resume, so calling again with the same JOBS on a warm machine finishes what a time limit cut. Keep T
# about 100 s under the device call's limit: demonstrations, wheel install and packing come on top of it.
set -uo pipefail
source experiments/gpu_env.sh
mkdir -p /tmp/grid
export XLA_PYTHON_CLIENT_MEM_FRACTION=${MEM:-0.15}
pack() { (cd /tmp/grid && tar czf "$OUT/grid.tgz" --exclude='checkpoints' --exclude='corrupt_checkpoints' \
           --exclude='*.gif' . 2>/dev/null); }
trap pack EXIT
# demonstrations first, one process, so side-by-side jobs never write the same cache file
python3 - "$JOBS" <<'PY'
import sys
import cogail_envs
from cogail_jax import data
for job in sys.argv[1].split():
    fields = job.split("|")
    _, task, _, mixes = fields[:4]
    sets = dict(kv.split("=", 1) for kv in fields[4].split("+")) if len(fields) > 4 and fields[4] else {}
    env = cogail_envs.make_env(task)
    for mix in (mixes.split(",") if task == "fetchq" else ["uniform"]):
        data.ensure_default_demos(env, "train", mix, num=int(sets.get("num_demos", 0)),
                                  states=float(sets.get("demo_reset", 0)) > 0)
        data.ensure_default_demos(env, "heldout", mix)
PY
start=$(date +%s)
for job in $JOBS; do
  IFS='|' read -r gpu task methods mixes sets <<< "$job"
  name=$task-${methods//,/-}-${mixes//,/-}
  setargs=()
  if [ -n "${sets:-}" ]; then  # optional 5th field: config overrides joined by '+', e.g. bc_code_noise=0.3+lambda_r=5
    IFS='+' read -ra kv <<< "$sets"
    for x in "${kv[@]}"; do setargs+=(--set "$x"); done
    name=$name-${sets//[=+]/_}
  fi
  CUDA_VISIBLE_DEVICES=$gpu timeout ${T:-480} python3 experiments/paper.py --tasks $task --methods $methods \
    --mixes $mixes --eval-every ${EVERY:-3} ${EXTRA:-} "${setargs[@]}" --out /tmp/grid/$name > /tmp/grid/$name.log 2>&1 &
done
wait
echo "WALL grid: $(( $(date +%s) - start )) s"
for f in /tmp/grid/*.log; do echo "== $f"; grep -v -i warp "$f" | grep -E "replay|Error|error|Traceback" | tail -8; done
