#!/usr/bin/env bash
# The shipped model's fine-tune recipe with edge scenes (experiments/
# 2026-12-03_obstacles_at_the_edge) on a lent GPU machine (16 cores + one NVIDIA GPU, Python 3.12 with torch, numba,
# numpy, scipy, scikit-learn, typer; no internet): its training data made on all cores, then one
# fine-tune per RUN on the GPU. Each RUN is NAME:SEED[:FAMILIES]; FAMILIES (comma separated)
# adds a set of 1,200 synth3 scenes of those obstacle families to that run's training data.
# Tuned weights (the training's guarded calibration) go to $OUT/NAME.safetensors; `calibrate
# --like` and `fit-ood` run afterwards on the CPU, on the same data made there (same seeds).
#   usage: scripts/gpu_finetune.sh RUN [RUN ...]      e.g. B0:0:hoop A0:0
# trimesh and embreex travel as wheels in .whl/ (ignored by git), fetched here once with
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
#       --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
#       -d .whl trimesh==5.2.0 embreex==4.4.0.post1
# Measured on an H200 machine (2026-12-04): the data (9,600 scenes with one extra set) 280 s;
# a run 190-225 s, of it 32-34 s of training (about 6,000 samples/s) and the rest the voxel
# cache on 15 processes. Two runs fit one 10-minute call; a third does not.
set -euo pipefail
[ $# -ge 1 ] || { echo "usage: $0 NAME:SEED[:FAMILIES] ..." >&2; exit 2; }
out=${OUT:-/tmp/out}; data=${DATA:-/tmp/finetune_data}; mkdir -p "$out" "$data"
source "$(dirname "$0")/gpu_env.sh"  # wheels, paths, step and sim
sim --families frame,mesh --scenes 1200 --seed 1 --out "$data/thin_train"
sim --scenes 1200 --seed 0 --out "$data/synth3_some"
sim --edge 1 --scenes 2400 --seed 8 --out "$data/edge15_train"
sim --scenes 3600 --seed 2 --out "$data/synth3_more"
for run in "$@"; do
    IFS=: read -r name seed families <<< "$run"
    extra=()
    if [ -n "${families:-}" ]; then
        set_dir="$data/extra_${families//,/_}"
        sim --families "$families" --scenes 1200 --seed 9 --out "$set_dir"
        extra=(--data "$set_dir")
    fi
    step $lz train --init models/landing_zone.safetensors --data "$data/edge15_train" \
        --data "$data/thin_train" --data "$data/synth3_some" --data "$data/synth3_more" \
        "${extra[@]}" --out "$out/$name.safetensors" --lr 0.001 --epochs 4 \
        --augment-copies 6 --cache-voxels 3 --workers 15 --device cuda --seed "$seed"
    rm -f "$out/$name.train.safetensors"
done
