#!/usr/bin/env bash
# The paper's net (models/paper_C7-F32-P2-C5-F64-P2-D512.safetensors), with the command line
# only: a synth2 dataset and one safety CNN per ARCH, trained on a GPU machine (16 cores + one
# NVIDIA GPU, Python 3.12 with torch/numba/numpy/scipy/sklearn, no internet). What must come
# back goes to $OUT; evaluation runs afterwards on the CPU (landing-zone evaluate), so the device
# time goes to training. trimesh and embreex travel as wheels in .whl/ (ignored by git), fetched
# once where there is internet with
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
#       --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
#       -d .whl trimesh==5.2.0 embreex==4.4.0.post1
#   usage: experiments/reproduce/paper_net.sh SCENES CACHE_COPIES EPOCHS AUG_COPIES ARCH [ARCH ...]
#   the paper's net: experiments/reproduce/paper_net.sh 5000 5 6 10 C7-F32-P2-C5-F64-P2-D512
set -euo pipefail
scenes=$1; copies=$2; epochs=$3; aug=$4; shift 4
out=${OUT:-/tmp/out}; mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 NUMBA_CACHE_DIR=/tmp/numba
nvidia-smi -L || true
python3 -c 'import torch, numba, numpy; print("torch", torch.__version__, "cuda",
    torch.cuda.is_available(), "numba", numba.__version__, "numpy", numpy.__version__)'
t0=$(date +%s)
python3 -m landing_zone simulate --dataset synth2 --out /tmp/synth2 --scenes "$scenes" \
    --workers 16 --seed 0 --quiet 2>&1 | tail -3
echo "dataset: $scenes scenes in $(( $(date +%s) - t0 )) s"
for arch in "$@"; do
    t1=$(date +%s); name=$(echo "$arch" | tr -d '-')
    python3 -m landing_zone train --data /tmp/synth2 --out "$out/$name.safetensors" \
        --arch "$arch" --device cuda --workers 15 --cache-voxels "$copies" --epochs "$epochs" \
        --augment-copies "$aug" 2>&1 | tr '\r' '\n' | grep -E '^(epoch [0-9]+:|wrote)' || true
    echo "$arch: $(( $(date +%s) - t1 )) s"
    rm -f "$out/$name.train.safetensors"
done
