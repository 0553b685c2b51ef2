"""SITE.labels.json: read, write and score in one module (landing_zone.io.labels)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from landing_zone.errors import ConfigError
from landing_zone.io.labels import (labels_center, labels_extent, labels_path_for,
                                    obstacle_footprints, read_labels, score_report,
                                    score_tiles, tile_truth, write_labels)
from test_grid import hand_made


def labels_for(assessment, unsafe):
    return {'frame_id': 'map', 'tile_size': 1.0,
            'tiles': [{'x': float(x), 'y': float(y), 'safe': (float(x), float(y)) not in unsafe}
                      for x, y in assessment.centers]}


def scores(a, labels):
    s = score_tiles(a.centers, a.p_safe, a.tile_size, labels)
    return s.auc, s.judged_fraction, s.judged


def test_scores_rank_judged_tiles_only():
    a = hand_made()  # p: (0,0) 1.0, (0,1) NaN, (1,0) 0.0, (1,1) 0.994, (2,0) 0.5, (2,1) 0.006
    centers = [tuple(c) for c in a.centers.tolist()]
    # the two lowest-p judged tiles unsafe: a perfect ranking
    auc, fraction, n = scores(a, labels_for(a, {centers[2], centers[5]}))
    assert auc == 1.0 and n == 5 and fraction == pytest.approx(5 / 6)
    # the highest-p tile unsafe: ranked above every safe tile, AUC 0
    auc, _, _ = scores(a, labels_for(a, {centers[0]}))
    assert auc == 0.0
    # p = 0.5 unsafe among {1.0, 0.0, 0.994, 0.006} safe: beaten by 2 of 4
    auc, _, _ = scores(a, labels_for(a, {centers[4]}))
    assert auc == pytest.approx(0.5)
    # one class among the judged: undefined
    assert scores(a, labels_for(a, {centers[1]}))[0] is None
    # labels outside the grid do not count as judged
    doc = labels_for(a, set())
    doc['tiles'].append({'x': 100.5, 'y': 0.5, 'safe': False})
    assert scores(a, doc)[1:] == (pytest.approx(5 / 7), 5)


def test_errors_at_the_threshold_and_a_report_scores_as_its_tiles():
    a = hand_made()
    centers = [tuple(c) for c in a.centers.tolist()]
    labels = labels_for(a, {centers[0], centers[2]})  # p 1.0 (judged safe) and 0.0 unsafe
    s = score_tiles(a.centers, a.p_safe, a.tile_size, labels)
    assert (s.unsafe, s.unsafe_judged_safe, s.unknown) == (2, 1, 1)
    assert (s.safe, s.false_alarms) == (3, 1)  # 0.006 judged unsafe
    assert s.safe_edge == 3 and s.false_alarms_edge == 1  # a 3 x 2 grid is all edge
    report = a.to_report({})
    assert score_report(report, labels) == s
    # centres as a report rounds them still meet their tiles
    for t in report['tiles']:
        t['x'] += 1e-7
    assert score_report(report, labels) == s
    with pytest.raises(ConfigError, match='no "tiles" list'):
        score_report({'frame_id': 'map'}, labels)


def test_truth_files_round_trip_and_bad_ones_are_one_line(tmp_path):
    a = hand_made()
    doc = labels_for(a, {tuple(a.centers[1])})
    doc['obstacles'] = [{'kind': 'box', 'x': 1.0, 'y': 2.0, 'z': 0.0, 'yaw': np.pi / 2,
                         'size': [0.4, 0.2, 0.3]}]
    path = labels_path_for(tmp_path / 'site.mcap')
    assert path.name == 'site.labels.json'
    write_labels(path, doc)
    assert read_labels(path) == doc and [p.name for p in tmp_path.iterdir()] == [path.name]
    assert path.read_text().endswith('\n') and json.loads(path.read_text()) == doc
    truth = tile_truth(a.centers, 1.0, doc)
    assert truth.tolist() == [1, 0, 1, 1, 1, 1]
    (fp,) = obstacle_footprints(doc)
    np.testing.assert_allclose(np.sort(fp, axis=0), [[0.9, 1.8], [0.9, 1.8], [1.1, 2.2],
                                                     [1.1, 2.2]], atol=1e-12)
    (tmp_path / 'bad.json').write_text('{"tiles": [{"x": 1}]}')
    with pytest.raises(ConfigError, match='not a labels file'):
        read_labels(tmp_path / 'bad.json')
    with pytest.raises(ConfigError, match='cannot read labels'):
        read_labels(tmp_path / 'none.json')


def test_the_labels_extent_is_the_squares_of_their_tiles():
    doc = {'tile_size': 0.5, 'tiles': [{'x': -1.75, 'y': 2.25, 'safe': True},
                                       {'x': 3.25, 'y': 0.25, 'safe': False},
                                       {'x': 0.25 + 1e-7, 'y': 4.75, 'safe': True}]}
    lo, hi = labels_extent(doc)
    np.testing.assert_allclose(lo, [-2.0, 0.0])
    np.testing.assert_allclose(hi, [3.5, 5.0])
    assert labels_center(doc) == pytest.approx((0.75, 2.5))
    with pytest.raises(ConfigError, match='no tile'):
        labels_center({'tiles': []})
