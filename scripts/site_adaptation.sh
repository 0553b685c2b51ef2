#!/usr/bin/env bash
# The README's site-adaptation figures, end to end (about 12 minutes on 2 CPU cores):
# clear flights over vegetation the shipped model never trained on (stand-ins for a user's
# recordings) -> a hybrid set (obstacles inserted by ray alteration) -> fine-tuning with some
# synth3 rehearsed (every train family of obstacles, vegetation, terrain and sensor) -> the
# shipped and the fine-tuned model on the hybrid test split, on the obstacle families neither
# ever trained on (synth3's test families, when TEST_DATA exists: the check that adapting to a
# site's vegetation does not make the model lenient on unfamiliar shapes) and on a further
# flight with obstacles neither saw.
#   usage: scripts/site_adaptation.sh [WORKDIR] [VEGETATION]   (defaults: runs/site, mixed)
# Environment: MODEL (default the shipped one), TEST_DATA (default data/synth3_test).
set -euo pipefail
work=${1:-runs/site}; veg=${2:-mixed}
lz=${LZ:-.venv/bin/landing-zone}; py=${PY:-.venv/bin/python}
shipped=${MODEL:-models/landing_zone.safetensors}; test_data=${TEST_DATA:-data/synth3_test}
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
"$lz" simulate --dataset synth3 --split train --scenes 1200 --out "$work/synth3_some" \
    --seed 0 --quiet
[ -f "$work/site.safetensors" ] || \
"$lz" train --init "$shipped" --data "$work/hybrid" --data "$work/synth3_some" \
    --out "$work/site.safetensors" --lr 0.001 --epochs 4 --augment-copies 6 \
    --cache-voxels 3 --workers 2 2>&1 | tr '\r' '\n' | grep -E '^(epoch [0-9]+:|wrote)'
# train --init refits the temperature on in-distribution validation scenes and drops the
# shipped model's out-of-family calibration; site_cal carries it over (weights unchanged)
"$py" scripts/lofo_calibrated.py "$shipped" "$work/site.safetensors" --suffix _cal
"$lz" evaluate --data "$work/hybrid" --model "$shipped" --model "$work/site.safetensors" \
    --model "$work/site_cal.safetensors"
if [ -d "$test_data" ]; then
    "$lz" evaluate --data "$test_data" --by-family --model "$shipped" \
        --model "$work/site.safetensors" --model "$work/site_cal.safetensors" --workers 2 \
        --json "$work/families.json" \
        > "$work/families.md"
    "$py" - "$work/families.json" <<'PY'
import json, sys
from landing_zone.sim.families import TEST_FAMILIES
rep = json.load(open(sys.argv[1]))['families']['methods']
for name, per in rep.items():
    obs = [per['obstacle'][f] for f in TEST_FAMILIES if f in per['obstacle']]
    n = sum(f['n_unsafe'] for f in obs)
    passed = sum(f['unsafe_ge_0.5'] * f['n_unsafe'] for f in obs)
    sure = sum(f['unsafe_ge_0.9'] * f['n_unsafe'] for f in obs)
    print(f'{name}: obstacle tiles of the test families ({", ".join(TEST_FAMILIES)}) at '
          f'P(safe) >= 0.5: {passed:.0f} of {n} ({100 * passed / max(n, 1):.1f}%), '
          f'>= 0.9: {sure:.0f}')
PY
fi
for m in "$shipped" "$work/site.safetensors" "$work/site_cal.safetensors"; do
    name=$(basename "$m" .safetensors)
    "$lz" replay "$work/site_13.mcap" --out "$work/assessed_$name.mcap" \
        --report "$work/report_$name.json" --center 0 0 --model "$m" > /dev/null
    "$py" scripts/score_report.py "$work/report_$name.json" "$work/site_13.labels.json"
done
