"""Evaluating: a model on a dataset split (evaluate), on recorded flights with their ground
truth (evaluate-flights), and a site-adapted model against the one it started from
(site-check)."""
from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import typer

from landing_zone.tools.cli.options import (ADDRESS_HELP, ENGINE_HELP, POINTS_HELP, POSE_HELP,
                                            Engine)

app = typer.Typer()


class Split(str, Enum):
    test = 'test'
    train = 'train'


@app.command(help='ROC / AUC, calibration (ECE) and timing on a dataset split, for the CNN and '
                  'with --baselines the paper\'s baselines; the table like the paper\'s Table '
                  'II on stdout.\n\n'
                  'Examples:\n\n  landing-zone evaluate --data data/synth2 --model '
                  'model.safetensors --out-dir eval\n\n'
                  '  landing-zone evaluate --data data/synth2 --baselines --json results.json'
                  '\n\n  landing-zone evaluate --data data/synth2 --model a.safetensors --model '
                  'b.safetensors --baselines\n\n'
                  '  landing-zone evaluate --data data/synth3 --by-family --model '
                  'final.safetensors --model lofo_log.safetensors --json lofo.json')
def evaluate(
    data: Annotated[Path, typer.Option(help='Dataset directory.')],
    model: Annotated[Optional[list[Path]], typer.Option(
        help='Model file; repeat for more CNNs in one table; default the shipped one.')] = None,
    baselines: Annotated[bool, typer.Option(help='Also evaluate the baselines.')] = False,
    json_path: Annotated[Optional[Path], typer.Option(
        '--json', help='Write RESULTS.json here.')] = None,
    out_dir: Annotated[Optional[Path], typer.Option(
        help='Write table.md, ROC and reliability plots and the look inside here.')] = None,
    split: Annotated[Split, typer.Option(help='Dataset split.')] = Split.test,
    workers: Annotated[int, typer.Option(help='Voxelizing processes.')] = 0,
    fit_scenes: Annotated[int, typer.Option(
        help='Train scenes the baselines are fitted on.')] = 2000,
    max_scenes: Annotated[int, typer.Option(
        help='Evaluate an even subset of this many scenes (0: all).')] = 0,
    seed: Annotated[int, typer.Option(help='Seed of the baselines.')] = 0,
    by_family: Annotated[bool, typer.Option(
        help='synth3: the figures per obstacle, vegetation, terrain and sensor family, and '
             'the leave-one-family-out table (each family judged by a --model that never '
             'saw it).')] = False,
    scores: Annotated[Optional[Path], typer.Option(
        help='Write every scene\'s score by every method here (JSON: scene indices, labels, '
             'scores per method), for breakdowns by scene parameters.')] = None,
    guard: Annotated[bool, typer.Option(
        help='Judge every CNN as the assessor does: P(safe) capped where the guard finds '
             'opaque structure above the tile\'s ground plane (rows named "... + guard").')
    ] = False,
) -> None:
    from landing_zone.tools.evaluate.roc import evaluate as run_evaluate

    res = run_evaluate(data, model, baselines=baselines, json_path=json_path, out_dir=out_dir,
                       split=split.value, workers=workers, fit_scenes=fit_scenes,
                       max_scenes=max_scenes, seed=seed, by_family=by_family,
                       scores_path=scores, guard=guard)
    print(res['table'], end='')


@app.command(name='evaluate-flights',
             help='Replay recorded flights, each with its ground truth beside it '
                  '(SITE.labels.json for SITE.mcap, as simulate-flight writes it), with the map '
                  'fixed on the labelled site, and score it per flight and pooled. Tiles: AUC, '
                  'ECE, obstacle tiles at P(safe) >= 0.5 and >= 0.9, safe tiles at >= 0.9, the '
                  'share unjudged. Footprints: clear footprints accepted at the site limits, '
                  'footprints over an obstacle accepted, and the clear footprints accepted at '
                  '0, 1 and 5 footprints over an obstacle along the least tile P(safe). The '
                  'flights run in parallel, here or on a Ray cluster, with the same '
                  'figures.\n\n'
                  'Examples:\n\n  landing-zone evaluate-flights a.mcap b.mcap --json '
                  'flights.json\n\n'
                  '  landing-zone evaluate-flights flights/*.mcap --engine ray\n\n'
                  '  landing-zone evaluate-flights /shared/flights/*.mcap --engine ray '
                  '--address ray://head:10001 --model /shared/models/m.safetensors')
def evaluate_flights(
    bags: Annotated[list[Path], typer.Argument(
        help='Flight bags (.mcap, .db3 or directory; ROS 1 .bag), each with BAG.labels.json.')],
    engine: Annotated[Engine, typer.Option(help=ENGINE_HELP)] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=ADDRESS_HELP)] = None,
    json_path: Annotated[Optional[Path], typer.Option(
        '--json', help='Write the figures (per flight and pooled) here.')] = None,
    model: Annotated[Optional[Path], typer.Option(
        help='Model file; default the shipped one.')] = None,
    workers: Annotated[Optional[int], typer.Option(
        help='Processes, or the CPUs of a local Ray cluster; default one per core.', min=1)
    ] = None,
    points_topic: Annotated[str, typer.Option(help=POINTS_HELP)] = '/lidar/points',
    pose_topic: Annotated[str, typer.Option(help=POSE_HELP)] = '/lidar/pose',
    center: Annotated[Optional[tuple[float, float]], typer.Option(
        metavar='X Y', help="Centre of every flight's region of interest; default: the "
                            "centre of its labels' extent (the labelled site is scored).")] = None,
) -> None:
    from landing_zone.tools.evaluate.flights import evaluate_flights as run_flights
    from landing_zone.tools.evaluate.flights import markdown_flights

    doc = run_flights(bags, engine=engine.value, address=address, workers=workers,
                      model=model, points_topic=points_topic, pose_topic=pose_topic,
                      json_path=json_path, center=center)
    print(markdown_flights(doc), end='')
    print(f'{len(doc["flights"])} flight(s) in {doc["seconds"]:.1f} s on {doc["engine"]} '
          f'({doc["workers"]} worker(s)): {doc["flights_per_s"]} flights/s'
          + (f'; wrote {json_path}' if json_path is not None else ''))


@app.command(name='site-check',
             help='Did adapting a model to a site cut its false alarms on the held-out '
                  'vegetation (a hybrid set\'s test split, a replayed flight with obstacles) '
                  'without passing more obstacles of the families no model trained on (synth3\'s '
                  'test families, from evaluate --by-family --json of both models)? One line '
                  'per figure, the verdict last; exit status 1 when the check fails.\n\n'
                  'Example (experiments/reproduce/site_adaptation.sh runs it end to end):\n\n'
                  '  landing-zone site-check --initial-model models/landing_zone.safetensors '
                  '--adapted-model runs/site/site.safetensors --hybrid runs/site/hybrid '
                  '--labels runs/site/site_13.labels.json --initial-report '
                  'runs/site/report_landing_zone.json --adapted-report runs/site/report_site.json '
                  '--families runs/site/families_site.json')
def site_check(
    initial_model: Annotated[Path, typer.Option(help='The model before adaptation.')],
    adapted_model: Annotated[Path, typer.Option(help='The adapted model.')],
    hybrid: Annotated[Path, typer.Option(
        help='The hybrid set (landing-zone simulate --dataset hybrid); its test split is '
             'judged.')],
    labels: Annotated[Path, typer.Option(help='SITE.labels.json of the replayed flight.')],
    initial_report: Annotated[Path, typer.Option(
        help='REPORT.json of the flight replayed with the initial model.')],
    adapted_report: Annotated[Path, typer.Option(
        help='REPORT.json of the flight replayed with the adapted model.')],
    families: Annotated[Optional[Path], typer.Option(
        help='evaluate --by-family --json of both models, the initial first; without it the '
             'check cannot hold.')] = None,
) -> None:
    from landing_zone.tools.evaluate.site_check import site_check as run_check

    res = run_check(initial_model, adapted_model, hybrid, labels, initial_report,
                    adapted_report, families)
    print('\n'.join(res.lines))
    if not res.holds:
        raise typer.Exit(1)
