#!/usr/bin/env bash
# HR-SeqManip on the device machine: what `make train TASK=seqmanip` runs (experiments/seqmanip_paper.json,
# 3 seeds, evaluation of every checkpoint, figures), timed; results without checkpoints (324 MB each: they hold
# the 3000 MJX env states) go to $OUT/seqmanip.tgz. Calling again on a warm machine resumes the run.
#   METHOD=cogail T=560 bash experiments/gpu_seqmanip.sh
set -uo pipefail
source experiments/gpu_env.sh
METHOD=${METHOD:-cogail}
RUN=/tmp/runs/seqmanip-$METHOD-paper
pack() { (cd /tmp/runs && tar czf "$OUT/seqmanip-$METHOD.tgz" --exclude='checkpoints' --exclude='corrupt_checkpoints' \
           --exclude='*.gif' "seqmanip-$METHOD-paper" 2>/dev/null); }
trap pack EXIT
mkdir -p /tmp/runs; start=$(date +%s)
resume=""; [ -f "$RUN/config.json" ] && resume=--resume
timeout ${T:-560} python3 -m cogail_jax.cli train --config experiments/seqmanip_paper.json --task seqmanip \
  --method $METHOD --seeds 300,400,500 --run "$RUN" --eval $resume 2>&1 | tr '\r' '\n' | grep -v -i warp \
  | grep -v '^ *$' > /tmp/runs/seqmanip-$METHOD.log
tail -25 /tmp/runs/seqmanip-$METHOD.log
echo "WALL seqmanip $METHOD train+eval: $(( $(date +%s) - start )) s"
cat "$RUN/speed.json" 2>/dev/null; echo
