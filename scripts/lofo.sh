#!/usr/bin/env bash
# Leave one family out: one model per held-out train family of obstacles and per vegetation
# family, the final model on everything, then the LOFO table (experiments/2026-12-03_one_family_at_a_time):
# WORKDIR/lofo.{md,json}, and the per-scene scores in WORKDIR/lofo_scores.json (what
# scripts/pass_breakdown.py reads).
# Resumable at any point: a finished model is skipped, an interrupted one resumes from its
# training state (--resume), and the dataset commands skip finished shards.
#   usage: scripts/lofo.sh [WORKDIR]          (default runs/lofo; data in data/synth3*)
# Budget knobs (environment): EPOCHS, COPIES, CACHE, MAX_SAMPLES (the LOFO models) and
# FINAL_EPOCHS, FINAL_COPIES, FINAL_CACHE (the final model); MAX_SCENES, FINAL_MAX_SCENES (an
# even subset of the scenes, to bound memory: about 16 bytes per return); WORKERS; SEED (of
# the final and fold models' initialisation, split and augmentation: another seed gives
# another ensemble member with its own fold models, the same folds).
# FOLDS=K (K >= 2) leaves out groups instead: K models, each without about 1/K of the
# obstacle and vegetation families (landing_zone.tools.evaluate.lofo.family_folds, seeded by
# FOLD_SEED): K models instead of 19, pessimistic figures (each model saw fewer families).
# FINAL=FILE takes FILE as the final model instead of training one (the shipped model, say).
# TRAIN_DATA may name several directories (space-separated): with FOLDS=K all are trained on
# (calibrate and the per-family fleet read the first).
# TUNE_DATA="DIR..." (with FOLDS=K and FINAL) judges a fine-tuned model by fold models of its
# own recipe: each fold model is fine-tuned (`train --init`, the same hold-outs) on TUNE_DATA
# with TUNE_ARGS (default: the shipped recipe's --lr 0.001 --epochs 4 --augment-copies 6
# --cache-voxels 3), and carries FINAL's calibration (scripts/lofo_calibrated.py) when judged.
# ENSEMBLE=1 (with FOLDS=K) also trains, for every pair of groups, a model without both, and
# builds the ensemble of the K fold models (`landing-zone ensemble`: every family was seen by
# K - 1 of them) beside its leave-groups-out stand-ins: for group g, the fold model g and the
# pair models without g, K members none of which saw g. The ensemble is calibrated on those
# (`landing-zone calibrate`), which carry that calibration to be judged
# (experiments/2026-12-02_subset_ensemble_and_cosine).
# FOLDS=each leaves out one family at a time along the same path (one model per train family of
# obstacles and per vegetation family, 19 on synth3, trained one after the other, named
# lofo_AXIS_FAMILY): the yardstick of issue 15 for a recipe FOLDS=0 cannot train (TUNE_DATA).
# ONLY="AXIS:FAMILY..." (with FOLDS=each) trains and judges those families alone (a session's
# share of the 19, say); the others' finished models are left as they are.
# EVAL_ARGS: more options of the final `landing-zone evaluate` ("--guard": every model judged
# with the guard, as the assessor judges).
# FOLDS=0 (the default) trains one model per family side by side (`landing-zone train-fleet
# --lofo`): FLEET_WORKERS at once (default one per core), as processes here or, with ENGINE=ray,
# as Ray tasks (ADDRESS names a cluster; then WORKDIR and the data must be paths every worker
# mounts).
set -euo pipefail
work=${1:-runs/lofo}
lz=${LZ:-.venv/bin/landing-zone}
read -ra train_dirs <<< "${TRAIN_DATA:-data/synth3}"
train_data=${train_dirs[0]}  # what calibrate fits on (one directory)
data_args=()
for d in "${train_dirs[@]}"; do data_args+=(--data "$d"); done
read -ra tune_dirs <<< "${TUNE_DATA:-}"
tune_args=()
for d in "${tune_dirs[@]}"; do tune_args+=(--data "$d"); done
read -ra tune_opts <<< "${TUNE_ARGS:---lr 0.001 --epochs 4 --augment-copies 6 --cache-voxels 3}"
test_data=${TEST_DATA:-data/synth3_test}
epochs=${EPOCHS:-3}; copies=${COPIES:-4}; cache=${CACHE:-2}; max_samples=${MAX_SAMPLES:-0}
max_scenes=${MAX_SCENES:-0}
workers=${WORKERS:-2}
folds=${FOLDS:-0}; fold_seed=${FOLD_SEED:-0}; seed=${SEED:-0}
if [ -n "${ONLY:-}" ] && [ "$folds" != each ]; then
    echo "lofo: ONLY needs FOLDS=each" >&2
    exit 2
fi
if [ "$folds" = each ]; then
    grouped=1
    if [ "${ENSEMBLE:-0}" = 1 ]; then
        echo "lofo: ENSEMBLE=1 needs FOLDS=K (groups), not FOLDS=each" >&2
        exit 2
    fi
elif [[ "$folds" =~ ^[0-9]+$ ]]; then
    grouped=$(( folds > 0 ))
else
    echo "lofo: FOLDS must be a number of groups or 'each', got '$folds'" >&2
    exit 2
fi
if [ ${#tune_args[@]} -gt 0 ] && { [ "$grouped" = 0 ] || [ -z "${FINAL:-}" ]; }; then
    echo "lofo: TUNE_DATA needs FOLDS=K or FOLDS=each, and FINAL (the fine-tuned model whose" \
        "recipe is judged)" >&2
    exit 2
fi
mkdir -p "$work"
# The train families of synth3 (the test families are never trained on: the final model is
# their leave-one-out model) and the vegetation families.
families=$(.venv/bin/python -c 'from landing_zone.tools.sim.families import TRAIN_FAMILIES as f; print(" ".join("obstacle:" + n for n in f))')
vegetation=$(.venv/bin/python -c 'from landing_zone.tools.sim.vegetation import VEGETATION_FAMILIES as f; print(" ".join("vegetation:" + n for n in f))')

run_train() {  # NAME ARGS...: landing-zone train ARGS (resumable), timed, progress filtered
    local name=$1; shift
    /usr/bin/time -f "lofo: $name %e s wall, %U s user" "$lz" train "$@" --workers "$workers" \
        --seed "$seed" --resume 2>&1 | tr '\r' '\n' | grep -E '^(epoch [0-9]+:|wrote|lofo:)'
}

train_one() {  # NAME HOLD-OUT...
    local name=$1; shift
    local out="$work/$name.safetensors"
    [ -f "$out" ] && { echo "lofo: $out done"; return; }
    local holds=()
    for h in "$@"; do holds+=(--hold-out "$h"); done
    run_train "$name" "${data_args[@]}" --out "$out" "${holds[@]}" --epochs "$epochs" \
        --augment-copies "$copies" --cache-voxels "$cache" --max-samples "$max_samples" \
        --max-scenes "$max_scenes"
}

tune_one() {  # NAME INIT HOLD-OUT...: fine-tune INIT as FINAL was, then give it FINAL's calibration
    local name=$1 init=$2; shift 2
    local out="$work/$name.safetensors"
    local holds=()
    for h in "$@"; do holds+=(--hold-out "$h"); done
    [ -f "$out" ] || run_train "$name" --init "$init" "${tune_args[@]}" --out "$out" \
        "${holds[@]}" "${tune_opts[@]}"
    [ -f "$work/${name}_cal.safetensors" ] || .venv/bin/python scripts/lofo_calibrated.py \
        "$work/final.safetensors" "$out" --suffix _cal
}

# the final model first: it is what ships, and it alone already judges the test families
if [ -n "${FINAL:-}" ]; then
    cp -n "$FINAL" "$work/final.safetensors"
else
    (epochs=${FINAL_EPOCHS:-4}; copies=${FINAL_COPIES:-6}; cache=${FINAL_CACHE:-3}
     max_samples=0; max_scenes=${FINAL_MAX_SCENES:-0}
     train_one final)
fi
lofo_models=()
if [ "$grouped" = 1 ]; then
    if [ "$folds" = each ]; then
        # synth3's train families (as family_folds deals them) and the vegetation families
        read -ra groups <<< "$(.venv/bin/python -c 'from landing_zone.tools.sim.synth3 import synth3_train_families as f; print(" ".join("obstacle:" + n for n in f()))') $vegetation"
        if [ -n "${ONLY:-}" ]; then
            read -ra only <<< "$ONLY"
            for spec in "${only[@]}"; do
                [[ " ${groups[*]} " == *" $spec "* ]] || {
                    echo "lofo: ONLY names '$spec', not one of: ${groups[*]}" >&2; exit 2; }
            done
            groups=("${only[@]}")
        fi
    else
        mapfile -t groups < <(.venv/bin/python -c "from landing_zone.tools.evaluate.lofo import family_folds
for g in family_folds($folds, $fold_seed): print(' '.join(g))")
    fi
    for k in "${!groups[@]}"; do
        if [ "$folds" = each ]; then name="lofo_${groups[$k]//:/_}"; else name="fold${k}_of_${folds}"; fi
        # shellcheck disable=SC2086  # a group is a list of specs
        train_one "$name" ${groups[$k]}
        if [ ${#tune_args[@]} -gt 0 ]; then
            # shellcheck disable=SC2086  # a group is a list of specs
            tune_one "${name}_tuned" "$work/$name.safetensors" ${groups[$k]}
            lofo_models+=(--model "$work/${name}_tuned_cal.safetensors")
        else
            lofo_models+=(--model "$work/$name.safetensors")
        fi
    done
    if [ "${ENSEMBLE:-0}" = 1 ]; then
        members=()
        for g in "${!groups[@]}"; do
            members+=(--member "$work/fold${g}_of_${folds}.safetensors")
            stand_in=(--member "$work/fold${g}_of_${folds}.safetensors")
            for h in "${!groups[@]}"; do
                [ "$g" = "$h" ] && continue
                pair="pair$(( g < h ? g : h ))$(( g < h ? h : g ))_of_${folds}"
                # shellcheck disable=SC2086  # groups are lists of specs
                train_one "$pair" ${groups[$g]} ${groups[$h]}
                stand_in+=(--member "$work/$pair.safetensors")
            done
            [ -f "$work/ensemble_without${g}.safetensors" ] || "$lz" ensemble "${stand_in[@]}" \
                --out "$work/ensemble_without${g}.safetensors"
        done
        [ -f "$work/ensemble.safetensors" ] || "$lz" ensemble "${members[@]}" \
            --out "$work/ensemble.safetensors"
        stand_ins=("$work"/ensemble_without[0-9].safetensors)
        if [ ! -f "$work/ensemble_cal.safetensors" ]; then
            fold_args=()
            for f in "${stand_ins[@]}"; do fold_args+=(--fold-model "$f"); done
            "$lz" calibrate --model "$work/ensemble.safetensors" "${fold_args[@]}" \
                --data "$train_data" --workers "$workers" --out "$work/ensemble_cal.safetensors"
            .venv/bin/python scripts/lofo_calibrated.py "$work/ensemble_cal.safetensors" \
                "${stand_ins[@]}" --suffix _cal
        fi
        ens=(--model "$work/ensemble_cal.safetensors")
        for g in "${!groups[@]}"; do ens+=(--model "$work/ensemble_without${g}_cal.safetensors"); done
        "$lz" evaluate --data "$test_data" --by-family "${ens[@]}" --workers "$workers" \
            --json "$work/ensemble_lofo.json" --scores "$work/ensemble_scores.json" \
            | tee "$work/ensemble_lofo.md"
    fi
else
    fleet=(--engine "${ENGINE:-local}")
    [ -n "${ADDRESS:-}" ] && fleet+=(--address "$ADDRESS")
    [ -n "${FLEET_WORKERS:-}" ] && fleet+=(--workers "$FLEET_WORKERS")
    /usr/bin/time -f "lofo: the LOFO models %e s wall, %U s user" "$lz" train-fleet \
        --data "$train_data" --out-dir "$work" --lofo --epochs "$epochs" \
        --augment-copies "$copies" --cache-voxels "$cache" --max-samples "$max_samples" \
        "${fleet[@]}"
    for h in $families $vegetation; do
        lofo_models+=(--model "$work/lofo_${h//:/_}.safetensors")
    done
fi
models=(--model "$work/final.safetensors" "${lofo_models[@]}")
read -ra eval_args <<< "${EVAL_ARGS:-}"
"$lz" evaluate --data "$test_data" --by-family "${models[@]}" --workers "$workers" \
    --json "$work/lofo.json" --scores "$work/lofo_scores.json" "${eval_args[@]}" \
    | tee "$work/lofo.md"
