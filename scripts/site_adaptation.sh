#!/usr/bin/env bash
# The README's site-adaptation figures, end to end (about 12 minutes on 2 CPU cores):
# clear flights over vegetation the shipped model never trained on (stand-ins for a user's
# recordings) -> a hybrid set (obstacles inserted by ray alteration) -> fine-tuning with some
# synth2 rehearsed -> the shipped and the fine-tuned model on the hybrid test split, on synth2's
# test split (when data/synth2 exists) and on a further flight with obstacles neither saw.
#   usage: scripts/site_adaptation.sh [WORKDIR] [VEGETATION]   (defaults: runs/site, mixed)
set -euo pipefail
work=${1:-runs/site}; veg=${2:-mixed}
lz=${LZ:-.venv/bin/landing-zone}; py=${PY:-.venv/bin/python}
shipped=models/landing_zone.safetensors
mkdir -p "$work"
for s in 11 14 15 12; do
    [ -f "$work/clear_$s.mcap" ] || "$lz" simulate-flight --out "$work/clear_$s.mcap" \
        --vegetation "$veg" --obstacles 0 --seed "$s"
done
[ -f "$work/site_13.mcap" ] || "$lz" simulate-flight --out "$work/site_13.mcap" \
    --vegetation "$veg" --seed 13
"$lz" simulate --dataset hybrid --from "$work/clear_11.mcap" --from "$work/clear_14.mcap" \
    --from "$work/clear_15.mcap" --test-from "$work/clear_12.mcap" --out "$work/hybrid" \
    --seed 0 --quiet
"$lz" simulate --dataset synth2 --split train --scenes 1200 --out "$work/synth2_some" \
    --seed 0 --quiet
"$lz" train --init "$shipped" --data "$work/hybrid" --data "$work/synth2_some" \
    --out "$work/site.safetensors" --lr 0.001 --epochs 4 --augment-copies 6 \
    --cache-voxels 3 --workers 2 2>&1 | tr '\r' '\n' | grep -E '^(epoch [0-9]+:|wrote)'
"$lz" evaluate --data "$work/hybrid" --model "$shipped" --model "$work/site.safetensors"
if [ -d data/synth2 ]; then
    "$lz" evaluate --data data/synth2 --model "$shipped" --model "$work/site.safetensors"
fi
for m in "$shipped" "$work/site.safetensors"; do
    name=$(basename "$m" .safetensors)
    "$lz" replay "$work/site_13.mcap" --out "$work/assessed_$name.mcap" \
        --report "$work/report_$name.json" --center 0 0 --model "$m" > /dev/null
    "$py" scripts/score_report.py "$work/report_$name.json" "$work/site_13.labels.json"
done
