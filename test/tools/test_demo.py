"""The demo: the terminal tile map, and the whole run on the default site."""
from __future__ import annotations

import json
import re
import shlex
from io import StringIO

import numpy as np
import pytest
from rich.console import Console

from landing_zone.tools.demo import BANDS, replay_command, run_demo, tile_map
from landing_zone.errors import ModelError
from test_assessor import make_model
from test_grid import hand_made
from test_labels import labels_for


def test_tile_map_marks_obstacles_and_unknown_tiles():
    a = hand_made()
    centers = [tuple(c) for c in a.centers.tolist()]
    text = tile_map(a, labels_for(a, {centers[2], centers[1]})).plain
    rows = text.splitlines()
    # north up: the first row is y = 5.5 (j = 1), the second y = 4.5 (j = 0); p along x:
    # NaN, 0.994, 0.006 / 1.0, 0.0, 0.5; the obstacles' tiles carry X as second glyph
    assert rows[0].startswith('    5.5 ') and rows[1].startswith('    4.5 ')
    assert rows[0][8:14] == '?X..##' and rows[1][8:14] == '..#X--'
    assert text.count('??') == 1  # the legend's; the unknown tile shows X (truth) instead
    plain = tile_map(a).plain.splitlines()
    assert plain[0][8:14] == '??..##' and plain[1][8:14] == '..##--'


@pytest.mark.parametrize('p, glyph', [(1.0, '.'), (0.9, '.'), (0.89, '-'), (0.5, '-'),
                                      (0.49, '+'), (0.1, '+'), (0.09, '#'), (0.0, '#')])
def test_each_p_safe_band_has_its_glyph(p, glyph):
    from dataclasses import replace

    a = hand_made()
    a = replace(a, p_safe=np.full_like(a.p_safe, p))
    assert tile_map(a).plain.splitlines()[0][8:14] == glyph * 6


def test_piped_tile_map_keeps_the_bands_without_colour():
    a = hand_made()
    out = StringIO()
    Console(file=out, force_terminal=False, width=120).print(tile_map(a))
    piped = out.getvalue()
    assert '\x1b[' not in piped  # no colour codes: the glyphs alone carry the bands
    rows = piped.splitlines()
    assert rows[0][8:14] == '??..##' and rows[1][8:14] == '..##--'
    legend = '\n'.join(rows[3:])
    for low, glyph, _ in BANDS:
        assert glyph * 2 in legend
    assert '.. 0.9-1' in legend and '## <0.1' in legend and '?? not judged' in legend
    # on a terminal the same glyphs, coloured
    out = StringIO()
    Console(file=out, force_terminal=True, color_system='truecolor', width=120).print(
        tile_map(a))
    coloured = out.getvalue()
    assert '\x1b[' in coloured
    assert re.sub(r'\x1b\[[0-9;]*m', '', coloured) == piped


def test_missing_model_stops_the_demo_before_simulating(tmp_path, monkeypatch):
    import landing_zone.assessor as mod

    monkeypatch.setattr(mod, 'MODEL_FILENAME', 'surely-not-shipped.safetensors')
    with pytest.raises(ModelError, match='no shipped model'):
        run_demo(tmp_path / 'demo', console=Console(file=open(tmp_path / 'log', 'w')))
    assert not (tmp_path / 'demo' / 'site.mcap').exists()


@pytest.mark.slow
def test_demo_runs_end_to_end(tmp_path):
    model = make_model(tmp_path / 'small.safetensors')
    out = tmp_path / 'demo'
    log = tmp_path / 'log.txt'
    with open(log, 'w') as f:
        res = run_demo(out, seed=0, model=model, console=Console(file=f, width=120))
    text = log.read_text()
    for name in ('site.mcap', 'site.labels.json', 'assessed.mcap', 'report.json', 'map.png'):
        assert (out / name).is_file(), name
    labels = json.loads((out / 'site.labels.json').read_text())
    report = json.loads((out / 'report.json').read_text())
    # the map is fixed on the site: every labelled tile is in the report, most judged
    assert {(t['x'], t['y']) for t in labels['tiles']} == \
        {(t['x'], t['y']) for t in report['tiles']}
    assert res.judged_fraction > 0.8 and res.n_judged == sum(
        t['p_safe'] is not None for t in report['tiles'])
    assert res.auc is not None and 0.0 <= res.auc <= 1.0
    unsafe = sum(not t['safe'] for t in labels['tiles'])
    # the printed map: 20 rows of 20 cells, an X on each unsafe tile
    cells = [line[8:] for line in text.splitlines()
             if re.fullmatch(r'[ 0-9.-]{8}[.+#?X-]{40}', line)]
    assert len(cells) == 20 and sum(c.count('X') for c in cells) == unsafe
    assert 'X second glyph: an obstacle overlaps the tile (truth)' in text
    assert 'AUC of P(safe) against the labels' in text
    assert res.replay.stats['clouds'] > 100 and np.isfinite(res.replay.realtime_factor)


@pytest.mark.slow
def test_the_printed_replay_command_gives_the_demos_tiles(tmp_path):
    from landing_zone.tools.cli import main

    model = make_model(tmp_path / 'small.safetensors')
    out = tmp_path / 'demo dir'  # a space: the command must quote it
    log = StringIO()
    res = run_demo(out, seed=1, model=model, bank=0.0, size=8.0,
                   console=Console(file=log, width=80))
    text = log.getvalue()
    assert res.command == replay_command(out / 'site.mcap', res.center, out, model=model,
                                         labels=out / 'site.labels.json')
    assert res.command in text.splitlines()[-1]  # printed whole on one line
    assert 'fixed on the site: 20 x 20 m centred at (0, 0)' in ' '.join(text.split())
    assert 'follow the sensor by default' in ' '.join(text.split())
    argv = shlex.split(res.command)
    assert argv[:2] == ['landing-zone', 'replay']
    assert argv[argv.index('--center') + 1:argv.index('--center') + 3] == ['0', '0']
    with pytest.raises(SystemExit) as done:
        main(argv[1:])
    assert done.value.code in (0, None)
    demo = json.loads((out / 'report.json').read_text())
    again = json.loads((out / 'replay.json').read_text())
    assert demo['tiles'] == again['tiles'] and demo['landing_sites'] == again['landing_sites']
    assert len(demo['tiles']) == 400 and (out / 'replay.png').is_file()
    # without the center the map follows the sensor: not the demo's tiles
    follow_argv = argv[1:argv.index('--center')]
    follow_argv[follow_argv.index('--report') + 1] = str(tmp_path / 'follow.json')
    with pytest.raises(SystemExit):
        main(follow_argv)
    follow = json.loads((tmp_path / 'follow.json').read_text())
    assert follow['tiles'] != demo['tiles']
