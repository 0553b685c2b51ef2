# Sourced by the scripts that run on a lent GPU machine (gpu_finetune.sh,
# gpu_vegetation_probe.sh): installs the wheels that travel in .whl/ (trimesh and embreex, fetched
# as scripts/gpu_finetune.sh says), points Python at them and at this checkout, and defines
#   step CMD...   run a command, keep its summary lines, say how long it took;
#   sim ARGS...   a synth3 train split made on every core (landing-zone simulate ARGS).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 NUMBA_CACHE_DIR=/tmp/numba
lz="python3 -m landing_zone"
step() {
    local t0; t0=$(date +%s)
    "$@" 2>&1 | tr '\r' '\n' | grep -E '^(synth3:|epoch [0-9]+:|train:|wrote)' || true
    echo "[$(( $(date +%s) - t0 )) s] $*"
}
sim() { step $lz simulate --dataset synth3 --split train --workers "$(nproc)" --quiet "$@"; }
