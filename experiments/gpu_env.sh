# Sourced by the experiments/gpu_*.sh scripts on the device machine: installs the carried wheels (.whl/, from
# ../shared/tools/gpu-wheels.sh) once per machine, under a lock so scripts started side by side do not race,
# and sets the paths. Demonstrations carried in data/ are copied into the cache, never over a newer file.
( flock 9; [ -f /tmp/site/.ok ] || { python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir \
    --upgrade --target /tmp/site .whl/*.whl && touch /tmp/site/.ok; } ) 9>/tmp/site.lock
[ -f /tmp/site/.ok ] || { echo "wheel install failed"; exit 1; }
mkdir -p /tmp/pk /tmp/data && ln -sfn "$PWD/envs" /tmp/pk/cogail_envs
export PYTHONPATH=$PWD/src:/tmp/pk:/tmp/site PYTHONUNBUFFERED=1 COGAIL_DATA=/tmp/data
[ -d data ] && cp -n data/*.hdf5 /tmp/data/ 2>/dev/null
OUT=${OUT:-/tmp/out}; mkdir -p "$OUT"
true
