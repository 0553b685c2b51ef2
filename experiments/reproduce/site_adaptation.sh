#!/usr/bin/env bash
# Site adaptation and its check, end to end, with the command line only (about 20 minutes on 2
# CPU cores): clear flights over vegetation the shipped model never trained on (stand-ins for a
# user's recordings) -> a hybrid set (obstacles inserted by ray alteration) -> fine-tuning with
# some synth3 rehearsed (every train family of obstacles, vegetation, terrain and sensor, and
# the frames and wire mesh the shipped model was tuned on; by default under the leniency
# penalty and with the initial model's calibration kept, anchored) and its offset also anchored
# on obstacle scenes the fine-tuning never sees (other frames and wire mesh,
# WORKDIR/anchor_thin)
# -> the initial and the adapted model compared on:
#   - the held-out vegetation: false alarms (safe tiles given P(safe) < 0.5) on the hybrid test
#     split (flight 12) and on a further flight with obstacles neither saw (flight 13);
#   - the obstacle families no model ever trained on (synth3's test families, TEST_DATA):
#     obstacle tiles passed at P(safe) >= 0.5 and >= 0.9.
# The check (`landing-zone site-check`) holds when the adapted model raises fewer false alarms on
# the held-out vegetation and passes no more test-family obstacle tiles at either threshold; the
# last line says, and the exit status is 1 when it fails.
#   usage: experiments/reproduce/site_adaptation.sh [WORKDIR] [VEGETATION]
#          (from the repository root; defaults: runs/site, mixed)
# Environment: LZ (the command, default .venv/bin/landing-zone), MODEL (default the shipped one),
# TEST_DATA (default data/synth3_test: `landing-zone simulate --dataset synth3 --split test --out
# data/synth3_test`), NAME (of the adapted model, default site), FLIGHT_ARGS (more options for
# simulate-flight, e.g. "--scan-pattern rosette"), TRAIN_ARGS (more options for train, e.g.
# "--leniency-penalty 0 --calibration refit" for plain fine-tuning, with ANCHOR_ARGS=), ANCHOR_ARGS
# (default --anchor-data WORKDIR/anchor_thin; empty: the offset holds on the training sources'
# validation obstacles only). Flights and data sets already in WORKDIR are reused; an adapted model
# already there is kept.
set -euo pipefail
# shellcheck disable=SC2086  # FLIGHT_ARGS is a list of options
work=${1:-runs/site}; veg=${2:-mixed}
lz=${LZ:-.venv/bin/landing-zone}
shipped=${MODEL:-models/landing_zone.safetensors}; test_data=${TEST_DATA:-data/synth3_test}
name=${NAME:-site}; adapted="$work/$name.safetensors"
mkdir -p "$work"
for s in 11 14 15 12; do
    [ -f "$work/clear_$s.mcap" ] || "$lz" simulate-flight --out "$work/clear_$s.mcap" \
        --vegetation "$veg" --obstacles 0 --seed "$s" ${FLIGHT_ARGS:-}
done
[ -f "$work/site_13.mcap" ] || "$lz" simulate-flight --out "$work/site_13.mcap" \
    --vegetation "$veg" --seed 13 ${FLIGHT_ARGS:-}
# (simulate resumes a data set cut short and skips a complete one: meta.json is written first)
"$lz" simulate --dataset hybrid --from "$work/clear_11.mcap" --from "$work/clear_14.mcap" \
    --from "$work/clear_15.mcap" --test-from "$work/clear_12.mcap" --out "$work/hybrid" \
    --seed 0 --quiet
"$lz" simulate --dataset synth3 --split train --scenes 1200 --out "$work/synth3_some" \
    --seed 0 --quiet
# rehearsal of the thin open structure the shipped model was fine-tuned on (other instances
# than the anchor set's)
"$lz" simulate --dataset synth3 --families frame,mesh --split train --scenes 600 \
    --out "$work/thin_some" --seed 2 --quiet
# the anchor set: thin open structure (frames, wire mesh), in no training, rehearsal or test set
"$lz" simulate --dataset synth3 --families frame,mesh --split train --scenes 600 \
    --out "$work/anchor_thin" --seed 0 --quiet
anchor_args=${ANCHOR_ARGS---anchor-data $work/anchor_thin}
# shellcheck disable=SC2086  # TRAIN_ARGS and anchor_args are lists of options
[ -f "$adapted" ] || \
"$lz" train --init "$shipped" --data "$work/hybrid" --data "$work/synth3_some" \
    --data "$work/thin_some" --out "$adapted" --lr 0.001 --epochs 4 --augment-copies 6 \
    --cache-voxels 3 --workers 2 \
    $anchor_args ${TRAIN_ARGS:-} 2>&1 | tr '\r' '\n' | grep -E '^(epoch [0-9]+:|wrote|train:)'
"$lz" evaluate --data "$work/hybrid" --model "$shipped" --model "$adapted" \
    --json "$work/hybrid_$name.json"
if [ -d "$test_data" ]; then
    "$lz" evaluate --data "$test_data" --by-family --model "$shipped" --model "$adapted" \
        --workers 2 --json "$work/families_$name.json" > "$work/families_$name.md"
fi
for m in "$shipped" "$adapted"; do
    base=$(basename "$m" .safetensors)
    "$lz" replay "$work/site_13.mcap" --report "$work/report_$base.json" --center 0 0 \
        --model "$m" > /dev/null
done
fam=(); [ -d "$test_data" ] && fam=(--families "$work/families_$name.json")
"$lz" site-check --initial-model "$shipped" --adapted-model "$adapted" \
    --hybrid "$work/hybrid" --labels "$work/site_13.labels.json" \
    --initial-report "$work/report_$(basename "$shipped" .safetensors).json" \
    --adapted-report "$work/report_$name.json" "${fam[@]}"
