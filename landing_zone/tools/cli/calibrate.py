"""Fitting what a trained model carries beside its weights: its calibration on families it
never saw (calibrate), one model of several members (ensemble) and its out-of-distribution
reference (fit-ood). The fitting (torch, scikit-learn: the `[learn]` extra) is imported by each
command."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

app = typer.Typer()


@app.command(help='Fit a model\'s calibration on families it never saw: the logits of '
                  'leave-groups-out models (train --hold-out, one per group of families) on the '
                  'train scenes of the '
                  'families each held out, pooled; P(safe) = sigmoid(logit / T + b) fitted by '
                  'maximum likelihood and written into OUT (the weights unchanged). A model '
                  'fine-tuned from a calibrated one (train --init) has no fold models: --like '
                  'INITIAL carries the initial model\'s out-of-family correction over to it, '
                  'both nets fitted in family on the train scenes of --data (families both '
                  'trained on, instances neither saw).\n\n'
                  'Examples:\n\n  landing-zone calibrate --model runs/lofo/final.safetensors '
                  '--fold-model runs/lofo/fold0_of_4.safetensors --fold-model '
                  'runs/lofo/fold1_of_4.safetensors --data data/synth3 --out '
                  'models/landing_zone.safetensors\n\n'
                  '  landing-zone calibrate --model tuned.safetensors --like '
                  'models/landing_zone.safetensors --data data/synth3_fresh --out '
                  'tuned_cal.safetensors')
def calibrate(
    model: Annotated[Path, typer.Option(help='The model to calibrate.')],
    data: Annotated[Path, typer.Option(
        help='synth3 directory: the one the fold models were trained on; with --like, fresh '
             'scenes of families both models trained on.')],
    out: Annotated[Path, typer.Option(help='Model file to write (may be --model).')],
    fold_model: Annotated[Optional[list[Path]], typer.Option(
        help='A model trained with --hold-out; repeat for each fold.')] = None,
    like: Annotated[Optional[Path], typer.Option(
        help='The calibrated model --model was fine-tuned from (instead of --fold-model).')]
    = None,
    scenes: Annotated[int, typer.Option(
        help='At most this many scenes per fold model (with --like: in all).')] = 2000,
    offset: Annotated[bool, typer.Option(
        help='Fit an offset b beside the temperature (else b = 0; not with --like).')] = True,
    seed: Annotated[int, typer.Option(help='Which scenes.')] = 0,
    workers: Annotated[int, typer.Option(help='Voxelizing processes.')] = 0,
) -> None:
    from landing_zone.errors import ConfigError
    from landing_zone.tools.learn.recalibrate import calibrate as run_calibrate, calibrate_like

    if (like is None) == (not fold_model):
        raise ConfigError('give either --fold-model (one per fold) or --like INITIAL')
    if like is not None:
        if not offset:
            raise ConfigError('--like carries T and b over; --no-offset does not apply')
        s = calibrate_like(model, like, data, out, scenes=scenes, seed=seed, workers=workers,
                           progress=True)
        print(f'wrote {out}: T {s["temperature"]:.3f}, offset {s["offset"]:+.3f}, carried over '
              f'from {like} (in family on {s["n"]} scenes, {s["n_unsafe"]} unsafe: this model '
              f'T {s["in_family"]["model"]["temperature"]:.3f} b '
              f'{s["in_family"]["model"]["offset"]:+.3f}, the initial T '
              f'{s["in_family"]["initial"]["temperature"]:.3f} b '
              f'{s["in_family"]["initial"]["offset"]:+.3f})')
        return
    s = run_calibrate(model, fold_model or [], data, out, per_model=scenes, seed=seed,
                      offset=offset, workers=workers, progress=True)
    print(f'wrote {out}: T {s["temperature"]:.3f}, offset {s["offset"]:+.3f} fitted on {s["n"]} '
          f'out-of-family scenes ({s["n_unsafe"]} unsafe); there ECE '
          f'{s["out_of_family_ece"]["previous"]:.3f} -> {s["out_of_family_ece"]["fitted"]:.3f}, '
          f'obstacle scenes at P(safe) >= 0.5 '
          f'{100 * s["out_of_family_unsafe_ge_0.5"]["previous"]:.1f}% -> '
          f'{100 * s["out_of_family_unsafe_ge_0.5"]["fitted"]:.1f}%')


@app.command(help='One model file from trained members of one architecture: the mean of their '
                  'logits, judged as one net (landing_zone.judging.ensemble). Its metadata lists '
                  'the members and, as what it held out, the families no member trained on. '
                  'Calibrate it afterwards (calibrate, with ensembles of members that never saw '
                  'the families as --fold-model).\n\n'
                  'Example:\n\n  landing-zone ensemble --member runs/e/final.safetensors '
                  '--member runs/e/fold0_of_4.safetensors --member '
                  'runs/e/fold1_of_4.safetensors --out runs/e/ensemble.safetensors')
def ensemble(
    member: Annotated[list[Path], typer.Option(help='A member model; repeat for each.')],
    out: Annotated[Path, typer.Option(help='Ensemble model file to write.')],
) -> None:
    from landing_zone.tools.learn.ensembles import assemble

    meta = assemble(member, out)
    held = meta['training']['hold_out']
    print(f'wrote {out}: {meta["ensemble"]["members"]} members of {meta["model"]["spec"]}, '
          f'T {meta["temperature"]:.3f}, offset {meta["calibration_offset"]:+.3f}; no member '
          f'trained on: {", ".join(held) if held else "(none)"}')


@app.command(name='fit-ood',
             help='Fit the out-of-distribution reference of a model: the penultimate features '
                  'of tiles from the train split of its data, and the threshold (a quantile of '
                  'held-out scenes\' k-NN distance) past which a tile the model calls safe '
                  'becomes unknown. Write it as NAME.ood.safetensors beside NAME.safetensors '
                  'for the assessor to find it. Same seed, same bytes.\n\n'
                  'Example:\n\n'
                  '  landing-zone simulate --dataset synth2 --split train --scenes 1200 '
                  '--seed 1 --out data/s2ref\n\n'
                  '  landing-zone fit-ood --model models/landing_zone.safetensors --data '
                  'data/s2ref --out models/landing_zone.ood.safetensors --scenes 1200')
def fit_ood(
    model: Annotated[Path, typer.Option(help='Model file (.safetensors).')],
    data: Annotated[list[Path], typer.Option(
        help='Dataset directory; repeat for more (their train splits are pooled).')],
    out: Annotated[Path, typer.Option(help='Reference file (NAME.ood.safetensors).')],
    scenes: Annotated[int, typer.Option(
        help='Scenes to read, reference and held-out together.')] = 1000,
    held_out: Annotated[float, typer.Option(
        help='Share of the scenes that set the threshold, not in the reference.')] = 0.25,
    views: Annotated[int, typer.Option(help='Voxelizations of each scene at seeded yaws.')] = 3,
    seed: Annotated[int, typer.Option(help='Seed of the scene draw and the yaws.')] = 0,
    k: Annotated[int, typer.Option(help='The neighbour whose distance is the score.')] = 10,
    quantile: Annotated[float, typer.Option(
        help='Quantile [%] of the held-out distances taken as the threshold.')] = 99.5,
    quiet: Annotated[bool, typer.Option(help='No progress bar.')] = False,
) -> None:
    from landing_zone.tools.learn.ood_fit import fit_ood as run_fit

    res = run_fit(model, data, out, scenes=scenes, held_out=held_out, views=views, seed=seed,
                  k=k, quantile=quantile, progress=not quiet)
    ref = res.reference
    print(f'wrote {res.path}: {res.reference_tiles} reference tiles of {ref.dim} features '
          f'({res.path.stat().st_size / 1e6:.1f} MB), k {ref.k}, threshold {ref.threshold:.4f} '
          f'(the {ref.quantile:g}th percentile of {res.held_out_tiles} held-out tiles; '
          f'{res.held_out_past:.1%} of them past it), from {res.scenes} scenes in '
          f'{res.seconds:.0f} s')
