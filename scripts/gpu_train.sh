#!/usr/bin/env bash
# Generate a synth2 dataset and train the safety CNN on a lent GPU machine (16 cores + one
# NVIDIA GPU, Python 3.12 with torch/numba/numpy/scipy/sklearn, no internet). trimesh and
# embreex travel as wheels in .whl/ (see docs/TRAINING.md). Everything it writes that must
# come back goes to $OUT.
#   usage: scripts/gpu_train.sh SCENES CACHE_COPIES EPOCHS [ARCH] [EXTRA TRAIN ARGS...]
set -euo pipefail
scenes=${1:-400}; copies=${2:-2}; epochs=${3:-1}; arch=${4:-C7-F32-P2-C5-F64-P2-D512}
shift $(( $# < 4 ? $# : 4 ))
out=${OUT:-/tmp/out}; mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 NUMBA_CACHE_DIR=/tmp/numba
nvidia-smi -L || true
python3 -c 'import torch, numba, numpy, trimesh; print("torch", torch.__version__,
    "cuda", torch.cuda.is_available(), "numba", numba.__version__, "numpy", numpy.__version__)'
t0=$(date +%s)
python3 -m landing_zone.sim simulate --dataset synth2 --out /tmp/synth2 --scenes "$scenes" \
    --workers 16 --seed 0 --quiet 2>&1 | tail -5
t1=$(date +%s); echo "dataset: $scenes scenes in $((t1 - t0)) s"
python3 -m landing_zone train --data /tmp/synth2 --out "$out/model.safetensors" --arch "$arch" \
    --device cuda --workers 15 --cache-voxels "$copies" --epochs "$epochs" "$@" 2>&1 \
    | tr '\r' '\n' | grep -v -E '^(epoch [0-9]+/|voxelizing|loading)' | tail -20
t2=$(date +%s); echo "training: $((t2 - t1)) s"
python3 -m landing_zone evaluate --data /tmp/synth2 --model "$out/model.safetensors" \
    --json "$out/results.json" --workers 15 2>&1 | tr '\r' '\n' | grep -v -E '^(voxelizing|loading)' \
    | tail -15
t3=$(date +%s); echo "evaluation: $((t3 - t2)) s"
rm -f "$out"/*.train.safetensors
