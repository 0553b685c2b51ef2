"""The demo: the terminal tile map, and the whole run on the default site."""
from __future__ import annotations

import json

import numpy as np
import pytest
from rich.console import Console

from landing_zone.tools.demo import run_demo, tile_map
from landing_zone.errors import ModelError
from test_assessor import make_model
from test_grid import hand_made
from test_labels import labels_for


def test_tile_map_marks_obstacles_and_unknown_tiles():
    a = hand_made()
    centers = [tuple(c) for c in a.centers.tolist()]
    text = tile_map(a, labels_for(a, {centers[2], centers[1]})).plain
    rows = text.splitlines()
    # north up: the first row is y = 5.5 (j = 1), the second y = 4.5 (j = 0)
    assert rows[0].startswith('    5.5 ') and rows[1].startswith('    4.5 ')
    assert rows[0][8:14] == 'XX    ' and rows[1][8:14] == '  XX  '
    assert text.count('··') == 1  # the legend's; the unknown tile shows XX (truth) instead
    plain = tile_map(a).plain.splitlines()
    assert plain[0][8:10] == '··'


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
    assert text.count('XX') == unsafe + 1  # each unsafe tile, and the legend
    assert 'AUC of P(safe) against the labels' in text
    assert res.replay.stats['clouds'] > 100 and np.isfinite(res.replay.realtime_factor)
