#!/usr/bin/env bash
# Does a vegetation prior help a held-out vegetation family? (experiments/
# 2026-12-04_meadow_prior): the shipped architecture trained from scratch without one vegetation family, with
# 1,200 scenes of synth3's own vegetation (arm A) or of the meadow prior (arm B) beside synth3_b,
# on a lent GPU machine (16 cores + one NVIDIA GPU, Python 3.12 with torch, numba, numpy, scipy,
# scikit-learn, typer; no internet; trimesh and embreex as wheels in .whl/, fetched as
# scripts/gpu_finetune.sh says). The data is made on all cores with the seeds the 2-core runs
# used, so each model here is the one those runs would make on that machine's arithmetic.
# Each RUN is ARM:FAMILY:SEED; models go to $OUT/ARM_FAMILY_sSEED.safetensors and are judged
# afterwards on the CPU (landing-zone evaluate --data data/synth3_test --by-family).
#   usage: scripts/gpu_vegetation_probe.sh RUN [RUN ...]      e.g. A:shrub:1 B:shrub:1
# Measured on an H200 machine (2026-12-04): the data (7,600 scenes) 223 s; a run 188 s, of it
# 10 s of training (7,400 samples/s) and the rest the voxel cache and validation on 15
# processes: the 2-core CPU makes the same run in about 3 minutes, so this pays only where
# the data is made there. One 10-minute call makes the data and two runs.
set -euo pipefail
[ $# -ge 1 ] || { echo "usage: $0 ARM:FAMILY:SEED ..." >&2; exit 2; }
out=${OUT:-/tmp/out}; data=${DATA:-/tmp/probe_data}; mkdir -p "$out" "$data"
source "$(dirname "$0")/gpu_env.sh"  # wheels, paths, step and sim
sim --scenes 5200 --seed 3 --out "$data/synth3_b"
sim --scenes 1200 --seed 0 --out "$data/synth3_some"
sim --vegetation meadow --scenes 1200 --seed 20 --out "$data/meadow_train"
for run in "$@"; do
    IFS=: read -r arm family seed <<< "$run"
    extra="$data/synth3_some"; [ "$arm" = B ] && extra="$data/meadow_train"
    step $lz train --data "$data/synth3_b" --data "$extra" --hold-out "vegetation:$family" \
        --arch P2-C5-F32-P2-C3-F64-D128 --epochs 3 --augment-copies 4 --cache-voxels 2 \
        --workers 15 --device cuda --seed "$seed" --lr-schedule cosine \
        --out "$out/${arm}_${family}_s${seed}.safetensors"
    rm -f "$out/${arm}_${family}_s${seed}.train.safetensors"
done
