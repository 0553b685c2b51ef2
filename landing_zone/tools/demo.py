"""``landing-zone demo``: simulate a landing-site flight, assess it with the shipped model.

1. :func:`landing_zone.tools.sim.flight.simulate_flight` writes the default site's flight
   (20 x 20 m of grass patches and obstacles, a bank rising at 12 degrees over its last 5 m in
   x, a lawnmower pass at 8 m) as ``site.mcap`` and its ground truth as ``site.labels.json``.
2. :func:`landing_zone.replay.replay` runs the node's pipeline on it with the map fixed on the
   site (a region of interest centred on it, as the node's ``region_center`` parameter and
   ``replay --center`` fix it), writing ``assessed.mcap`` and ``report.json``;
   :func:`landing_zone.tools.map_png.render_png` draws ``map.png``. The node, ``replay`` and
   ``Assessor()`` follow the sensor by default instead, and so judge other tiles
   (``evaluate-flights`` fixes each map on its labels, as the demo does): the demo says so and
   prints the ``landing-zone replay`` command that gives its figures.
3. The tile map is printed with one glyph per P(safe) band, coloured on a terminal (green safe,
   red unsafe, grey not judged), so piped output keeps the bands; an ``X`` marks the tiles an
   obstacle really overlaps. Then the AUC of the per-tile P(safe) against the labels over the
   tiles that were judged, the fraction judged, and how many candidate footprints were left out
   for each reason (the bank's for slope: ``map.png`` hatches them).
"""
from __future__ import annotations

import math
import os
import shlex
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from rich.console import Console
    from rich.text import Text

    from landing_zone.assessor import Assessment
    from landing_zone.io.labels import LabelScores
    from landing_zone.replay import ReplayResult
    from landing_zone.tools.sim.flight import FlightConfig, FlightResult

__all__ = ['DemoResult', 'tile_map', 'run_demo', 'replay_command', 'DEMO_BANK', 'BANDS']

# Slope of the demo site's bank [deg]: steeper than landing_sites.max_slope_deg's default (8),
# so its footprints are left out for slope.
DEMO_BANK = 12.0
# The tile map's glyph per P(safe) band, safest first: (lowest P(safe) of the band, glyph, a
# P(safe) inside it for the legend's colour). Piped output has no colour, only these.
BANDS = ((0.9, '.', 0.95), (0.5, '-', 0.7), (0.1, '+', 0.3), (0.0, '#', 0.05))
UNKNOWN_GLYPH = '?'
OBSTACLE_GLYPH = 'X'  # the cell's second character on a tile an obstacle really overlaps


@dataclass
class DemoResult:
    """What the demo produced and measured."""

    out_dir: Path
    replay: ReplayResult
    auc: float | None  # of P(safe) against the labels over the judged tiles (None: one class)
    judged_fraction: float  # of the site's labelled tiles
    n_judged: int
    seconds: dict[str, float]
    center: tuple[float, float]  # of the fixed region of interest [m]
    command: str  # the `landing-zone replay` command that gives the same tiles and sites


def _rgb(p: float) -> str:
    """red (0) -> yellow (0.5) -> green (1), as rich's hex colour."""
    r = min(1.0, 2.0 * (1.0 - p))
    g = min(1.0, 2.0 * p)
    return f'#{int(200 * r):02x}{int(190 * g):02x}20'


def _band(p: float) -> str:
    """The glyph of P(safe) ``p``'s band (:data:`BANDS`), compared in float32 as the
    assessment holds it (so a P(safe) of 0.9 is in the band from 0.9)."""
    for low, glyph, _ in BANDS:
        if np.float32(p) >= np.float32(low):
            return glyph
    return BANDS[-1][1]


def tile_map(assessment: Assessment, labels: dict[str, Any] | None = None) -> Text:
    """The tiles as two-character cells, north (+y) up, with axis ticks and a legend.

    A cell is its P(safe) band's glyph twice (:data:`BANDS`; ``??``: not judged), the second
    replaced by ``X`` where the labels say an obstacle overlaps the tile; on a terminal it is
    also coloured by P(safe). Without colour (piped, CI logs) the glyphs still show the bands.
    """
    from rich.text import Text

    from landing_zone.io.labels import tile_truth

    truth = (tile_truth(assessment.centers, assessment.tile_size, labels) if labels
             else np.full(len(assessment), -1))
    nx, ny = assessment.shape
    ts = assessment.tile_size
    text = Text()
    for j in range(ny - 1, -1, -1):
        y = (assessment.origin[1] + j + 0.5) * ts
        text.append(f'{y:7.1f} ' if j % 5 == 0 or j == ny - 1 else ' ' * 8, style='dim')
        for i in range(nx):
            k = i * ny + j
            p = float(assessment.p_safe[k])
            glyph = UNKNOWN_GLYPH if math.isnan(p) else _band(p)
            cell = glyph + (OBSTACLE_GLYPH if truth[k] == 0 else glyph)
            text.append(cell, style=_UNKNOWN_STYLE if math.isnan(p) else _style(p))
        text.append('\n')
    axis = [' '] * (2 * nx)
    for i in range(0, nx, 5):
        label = f'{(assessment.origin[0] + i + 0.5) * ts:.1f}'
        for c, ch in enumerate(label):
            if 2 * i + c < len(axis):
                axis[2 * i + c] = ch
    text.append(' ' * 8 + ''.join(axis) + '   x [m]\n', style='dim')
    text.append(' ' * 8 + 'P(safe) ')
    bounds = [1.0] + [low for low, _, _ in BANDS[:-1]]
    for (low, glyph, inside), high in zip(BANDS, bounds):
        text.append(glyph * 2, style=_style(inside))
        text.append(f' {low:g}-{high:g}  ' if low > 0 else f' <{high:g}\n')
    text.append(' ' * 8)
    text.append(UNKNOWN_GLYPH * 2, style=_UNKNOWN_STYLE)
    text.append(' not judged  ')
    text.append(' ' + OBSTACLE_GLYPH, style='bold')
    text.append(' second glyph: an obstacle overlaps the tile (truth)\n')
    return text


_UNKNOWN_STYLE = 'white on grey23'


def _style(p: float) -> str:
    return f'bold black on {_rgb(p)}'


def replay_command(bag: str | os.PathLike[str], center: tuple[float, float],
                   out_dir: str | os.PathLike[str], model: str | os.PathLike[str] | None = None,
                   labels: str | os.PathLike[str] | None = None) -> str:
    """The ``landing-zone replay`` command that judges ``bag`` on the region the demo fixed.

    Its outputs go beside the demo's (``replay.mcap``, ``replay.json``, ``replay.png``), so
    the two can be compared; ``model`` None is the shipped model, the CLI's default too.
    """
    out = Path(out_dir)
    args = ['landing-zone', 'replay', str(bag), '--out', str(out / 'replay.mcap'),
            '--report', str(out / 'replay.json'), '--png', str(out / 'replay.png')]
    if labels is not None:
        args += ['--labels', str(labels)]
    if model is not None:
        args += ['--model', str(model)]
    args += ['--center'] + [_number(c) for c in center]
    return shlex.join(args)


def _number(v: float) -> str:
    """``v`` written short, but so that it reads back as the same float."""
    short = f'{v:g}'
    return short if float(short) == v else repr(float(v))


def run_demo(out_dir: str | os.PathLike[str] = 'lz_demo', seed: int = 0,
             model: str | os.PathLike[str] | None = None,
             console: Console | None = None, families: tuple[str, ...] = (),
             bank: float = DEMO_BANK, size: float | None = None) -> DemoResult:
    """Simulate, replay, print; see the module docstring.

    Args:
        out_dir: where site.mcap, site.labels.json, assessed.mcap, report.json, map.png go.
        seed: the simulator's seed (same seed, same site and flight).
        model: model file; default the shipped model.
        console: where to print (default a new rich Console).
        families: obstacle families (:mod:`landing_zone.tools.sim.families`) whose test instances
            join the site's obstacles, one more obstacle each (default: the library's six).
        bank: slope of the bank over the site's last 5 m in x [deg]; 0: none.
        size: edge of the square site [m]; default the simulator's (20 m, the map's extent).

    Raises:
        ModelError: no model (none shipped and none given).
        SimulationError, BagError: the simulation or the replay failed.
    """
    from rich.console import Console

    from landing_zone.assessor import default_model_path
    from landing_zone.replay import replay
    from landing_zone.io.labels import read_labels, score_tiles
    from landing_zone.tools.map_png import render_png
    from landing_zone.tools.sim.flight import simulate_flight

    console = console or Console(highlight=False)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    model_path = Path(model) if model is not None else default_model_path()  # fail early
    seconds: dict[str, float] = {}
    # 1. the site's flight and its ground truth, simulated; the site's centre
    t0 = time.perf_counter()
    with console.status('simulating the flight ...'):
        flight = simulate_flight(_flight_config(seed, bank, size, families), out / 'site.mcap',
                                 overwrite=True)
    seconds['simulate'] = time.perf_counter() - t0
    labels = read_labels(flight.labels)
    lo, hi = np.asarray(labels['site']['lo']), np.asarray(labels['site']['hi'])
    cx, cy = (float(c) for c in (lo + hi) / 2)
    _print_flight(console, flight)
    # 2. the flight replayed with the map fixed on the site, the map drawn, the tiles scored
    t0 = time.perf_counter()
    res = replay(flight.bag, out / 'assessed.mcap', out / 'report.json', model=model_path,
                 center=(cx, cy))
    a = res.assessment
    render_png(a, res.top_view, out / 'map.png', labels=labels,
               title=f'Demo site, map fixed on it (centre ({_number(cx)}, {_number(cy)})): '
                     f'{int(a.known.sum())} of {len(a)} tiles judged, {len(a.sites)} landing '
                     'site(s)')
    seconds['replay'] = time.perf_counter() - t0
    scores = score_tiles(a.centers, a.p_safe, a.tile_size, labels)
    command = replay_command(flight.bag, (cx, cy), out, model=model, labels=flight.labels)
    # 3. the tile map and the figures, then why the map is fixed and how replay fixes it
    _print_assessment(console, res, labels, scores, model_path, (cx, cy))
    _print_sites(console, a)
    _print_outputs(console, out, command)
    return DemoResult(out, res, scores.auc, scores.judged_fraction, scores.judged, seconds,
                      (cx, cy), command)


def _flight_config(seed: int, bank: float, size: float | None, families: tuple[str, ...]
                   ) -> FlightConfig:
    """The demo site's flight: the simulator's default site with ``seed``, ``bank``, ``size``
    (None: the default's) and, for each of ``families``, one obstacle more."""
    from landing_zone.tools.sim.flight import FlightConfig

    cfg = FlightConfig(seed=seed, bank=bank)
    if size is not None:
        cfg = replace(cfg, size=size)
    if families:
        # The library's kinds and then the families, one obstacle each of the families
        # more than the default's six.
        cfg = replace(cfg, families=tuple(families),
                      obstacles=cfg.obstacles + len(families))
    return cfg


def _print_flight(console: Console, flight: FlightResult) -> None:
    """One line on what the simulation wrote."""
    console.print(f'simulated {flight.clouds} clouds, {flight.points:,} returns over '
                  f'{flight.duration:.1f} s of flight ({flight.passes} passes at '
                  f'{flight.speed:.1f} m/s, {flight.density:.0f} returns/m^2); '
                  f'{flight.unsafe_tiles} of {flight.tiles} tiles unsafe -> {flight.bag}')


def _print_assessment(console: Console, res: ReplayResult, labels: dict[str, Any],
                      scores: LabelScores, model_path: Path, center: tuple[float, float]
                      ) -> None:
    """The tile map, how fast the replay ran, and how well the judged tiles score."""
    a = res.assessment
    cx, cy = center
    nx, ny = a.shape
    console.print(f'\nP(safe) per {a.tile_size:g} m tile ({a.frame_id} frame), model '
                  f'{model_path.name},\nover a region fixed on the site: '
                  f'{nx * a.tile_size:g} x {ny * a.tile_size:g} m centred at '
                  f'({_number(cx)}, {_number(cy)}) (why: see the end)')
    console.print(tile_map(a, labels), soft_wrap=True)  # wide maps stay maps when piped
    console.print(f'replayed at {res.realtime_factor:.1f}x real time '
                  f'({res.timings["loop"]:.1f} s for {res.bag_seconds:.1f} s of flight, '
                  f'{res.assessments} assessments, {res.timings["assess"]:.1f} s of them '
                  'assessing)')
    auc, fraction, n = scores.auc, scores.judged_fraction, scores.judged
    console.print(f'judged {n} of {len(labels["tiles"])} tiles ({100 * fraction:.0f} %); '
                  + (f'AUC of P(safe) against the labels over them: {auc:.3f}'
                     if auc is not None else 'AUC undefined (one class among the judged)'))


def _print_sites(console: Console, a: Assessment) -> None:
    """The best landing site (or that there is none), and why candidate footprints were left
    out."""
    if a.sites:
        best = a.sites[0]
        console.print(f'best landing site: ({best.x:.1f}, {best.y:.1f}) with P(footprint '
                      f'safe) {best.p_safe:.2f} (r = {a.footprint_radius:g} m), '
                      f'{len(a.sites)} candidate(s)')
    else:
        console.print('no landing site: no footprint within the limits')
    if a.candidates is not None:
        from landing_zone.judging.sites import REASONS

        counts = {why: int(((a.candidates.reasons >> k) & 1).sum())
                  for k, why in enumerate(REASONS)}
        console.print('candidate footprints left out, by reason (one may have several): '
                      + ', '.join(f'{why} {n}' for why, n in counts.items())
                      + f' of {a.candidates.reasons.size} (map.png hatches slope, step and '
                      'clearance)')


def _print_outputs(console: Console, out: Path, command: str) -> None:
    """The files written; why the demo fixes the map, and the replay command that does too."""
    console.print(f'wrote {out / "report.json"}, {out / "map.png"}, {out / "assessed.mcap"}')
    console.print('\nThe demo fixes the map on the site, as `evaluate-flights` does. The node, '
                  '`landing-zone replay` and `Assessor()` follow the sensor by default instead, '
                  'judging a window around it: other tiles, another best site. The same '
                  'tiles and sites from replay (on the node: the parameter region_center):')
    # soft_wrap: the command stays on one line, to be copied whole
    console.print(f'  {command}', soft_wrap=True, markup=False)
