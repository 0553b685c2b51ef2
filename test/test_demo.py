"""The demo: label scores, the terminal tile map, and the whole run on the default site."""
from __future__ import annotations

import json

import numpy as np
import pytest
from rich.console import Console

from landing_zone.demo import label_scores, run_demo, tile_map
from landing_zone.errors import ModelError
from test_assessor import make_model
from test_grid import hand_made


def labels_for(assessment, unsafe):
    return {'frame_id': 'map', 'tile_size': 1.0,
            'tiles': [{'x': float(x), 'y': float(y), 'safe': (float(x), float(y)) not in unsafe}
                      for x, y in assessment.centers]}


def test_label_scores_rank_judged_tiles_only():
    a = hand_made()  # p: (0,0) 1.0, (0,1) NaN, (1,0) 0.0, (1,1) 0.994, (2,0) 0.5, (2,1) 0.006
    centers = [tuple(c) for c in a.centers.tolist()]
    # the two lowest-p judged tiles unsafe: a perfect ranking
    auc, fraction, n = label_scores(a, labels_for(a, {centers[2], centers[5]}))
    assert auc == 1.0 and n == 5 and fraction == pytest.approx(5 / 6)
    # the highest-p tile unsafe: ranked above every safe tile, AUC 0
    auc, _, _ = label_scores(a, labels_for(a, {centers[0]}))
    assert auc == 0.0
    # p = 0.5 unsafe among {1.0, 0.0, 0.994, 0.006} safe: beaten by 2 of 4
    auc, _, _ = label_scores(a, labels_for(a, {centers[4]}))
    assert auc == pytest.approx(0.5)
    # one class among the judged: undefined
    assert label_scores(a, labels_for(a, {centers[1]}))[0] is None
    # labels outside the grid do not count as judged
    doc = labels_for(a, set())
    doc['tiles'].append({'x': 100.5, 'y': 0.5, 'safe': False})
    assert label_scores(a, doc)[1:] == (pytest.approx(5 / 7), 5)


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
