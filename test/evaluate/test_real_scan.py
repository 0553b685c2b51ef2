"""A real scan's reader, levelling, tile labels and view rule, on a frame written by the test."""
from __future__ import annotations

import math

import numpy as np
import pytest

from landing_zone.errors import ConfigError
from landing_zone.tools.evaluate.real_scan import (assess_scan, depression_deg, label_tiles,
                                                   level_scan, markdown_scan, read_scan,
                                                   steep_counts)

HEIGHT = 1.5  # the synthetic sensor's height above its ground [m]
TILT = 3.0    # its ground plane's tilt in the sensor's frame [deg]


def _rot_y(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def write_frame(tmp_path):
    """A ground vehicle's frame in the KITTI layout: concrete and grass ahead (-x) of the
    sensor, a 0.6 m object on the ground 8 m ahead, rows without a return, instance ids in
    the labels' upper bits; the whole frame tilted by TILT about y."""
    gx, gy = np.meshgrid(np.arange(-20.0, -5.0, 0.1), np.arange(-10.0, 10.0, 0.1))
    ground = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, -HEIGHT)])
    ground_cls = np.where(ground[:, 1] < 0, 23, 3)  # concrete right of the track, grass left
    ox, oy, oz = np.meshgrid(np.linspace(-8.4, -7.6, 8), np.linspace(-0.4, 0.4, 8),
                             np.linspace(0.3, 0.7, 5))
    obj = np.column_stack([ox.ravel(), oy.ravel(), oz.ravel() - HEIGHT])
    pts = np.concatenate([ground, obj, np.zeros((50, 3))]) @ _rot_y(TILT).T
    cls = np.concatenate([ground_cls, np.full(len(obj), 9), np.zeros(50, int)])
    raw = np.column_stack([pts, np.ones(len(pts))]).astype(np.float32)
    labels = (cls.astype(np.uint32) | (np.uint32(7) << np.uint32(16)))
    raw.tofile(tmp_path / 'f.bin')
    labels.tofile(tmp_path / 'f.label')
    return tmp_path / 'f.bin', tmp_path / 'f.label', len(ground), len(obj)


def test_read_level_and_label_a_frame(tmp_path):
    b, lab, n_ground, n_obj = write_frame(tmp_path)
    xyz, cls = read_scan(b, lab)
    assert len(xyz) == n_ground + n_obj  # the rows without a return are dropped
    assert set(np.unique(cls).tolist()) == {3, 9, 23}  # instance ids masked off
    pts, origin, info = level_scan(xyz, cls)
    assert info['height'] == pytest.approx(HEIGHT, abs=1e-6)
    assert info['tilt_deg'] == pytest.approx(TILT, abs=1e-6)
    np.testing.assert_allclose(origin, [0, 0, HEIGHT], atol=1e-6)
    np.testing.assert_allclose(pts[cls != 9, 2], 0.0, atol=1e-6)
    tiles = label_tiles(pts, cls)
    # the object's 320 returns fall on four tiles, 80 each, all 0.3-0.7 m above the ground
    obstacle = sorted(k for k, t in tiles.items() if t['label'] == 'obstacle')
    assert obstacle == [(-9, -1), (-9, 0), (-8, -1), (-8, 0)]
    assert [tiles[k]['structure_in_band'] for k in obstacle] == [80] * 4
    assert tiles[(-15, -5)]['label'] == 'clear:concrete'
    assert tiles[(-15, 4)]['label'] == 'clear:grass'
    # rays from 1.5 m onto the ground 1.5 m away come down at 45 degrees
    assert depression_deg(np.array([[-1.5, 0.0, 0.0]]), origin)[0] == pytest.approx(45.0)
    steep = steep_counts(pts, depression_deg(pts, origin), angles=(5.0, 20.0))
    # 5.1-6 m ahead: 14-16.4 degrees, steeper than 5 and not than 20
    assert steep[(-6, 2)][0] == tiles[(-6, 2)]['returns'] and steep[(-6, 2)][1] == 0
    with pytest.raises(ConfigError, match='too few'):
        level_scan(xyz[:10], cls[:10])


def test_a_frame_through_the_assessor(tmp_path):
    from test_assessor import make_model

    b, lab, _, _ = write_frame(tmp_path)
    doc = assess_scan(b, lab, model=make_model(tmp_path / 'm.safetensors'))
    assert doc['level']['sensor_height'] == pytest.approx(HEIGHT, abs=1e-4)
    assert doc['center'] == [-10.0, 0.0] and len(doc['tiles']) == 400
    assert doc['judged'] + doc['unknown'] == 400
    assert sum(s['tiles'] for s in doc['by_label'].values()) == 400
    assert doc['must_hold']['obstacle_tiles'] >= 1
    # seen from 1.5 m, no tile past 5 m holds a return from a ray 20 degrees steep
    rule = {r['depression_deg']: r for r in doc['view_rule']['angles']}
    assert rule[20.0]['still_judged'] == 0 and rule[20.0]['would_be_unknown'] == doc['judged']
    # and the assessor applies that rule (tiles.min_ray_depression_deg): the network still
    # reads the tiles, but none is judged
    assert doc['judged'] == 0 and any(t['p_net'] is not None for t in doc['tiles'])
    assert rule[5.0]['still_judged'] >= rule[10.0]['still_judged']
    # with the rule off the same frame is judged, and the table says what 20 degrees would take
    off = assess_scan(b, lab, model=tmp_path / 'm.safetensors', grazing_rule=False)
    rule_off = {r['depression_deg']: r for r in off['view_rule']['angles']}
    assert off['judged'] > 0 and rule_off[20.0]['would_be_unknown'] == off['judged']
    text = markdown_scan(doc)
    assert '| clear:concrete |' in text and '(must be 0)' in text
    with pytest.raises(ConfigError, match='not float32'):
        (tmp_path / 'bad.bin').write_bytes(b'123')
        read_scan(tmp_path / 'bad.bin')
