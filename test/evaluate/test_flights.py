"""evaluate-flights: the labelled site is scored, and the footprints where the robot acts."""
from __future__ import annotations

import numpy as np
import pytest

from landing_zone.judging.sites import (CLEARANCE, OBSTACLE, SLOPE, UNKNOWN,
                                        evaluate_candidates)
from landing_zone.tools.evaluate.flights import (_figures, _site_figures, flight_groups,
                                                 grouped_figures, markdown_flights,
                                                 pooled_figures)
from landing_zone.tools.evaluate.footprints import (footprint_figures, footprint_truth,
                                                    operating_curve)
from landing_zone.io.labels import tile_truth


def test_footprint_figures_count_each_case_once():
    # one footprint per cell: (truth, reasons, least tile P(safe))
    cells = [(1, 0, 0.95),                  # clear, accepted
             (1, OBSTACLE, 0.6),            # clear, judged doubtful
             (1, SLOPE, 0.9),               # clear, left out for its slope only: not counted
             (1, SLOPE | OBSTACLE, 0.5),    # clear, doubtful as well as steep: counted
             (1, UNKNOWN, np.nan),          # clear, an unknown tile under it: counted
             (1, 0, 0.85),                  # clear, accepted, tied with an obstacle below
             (0, 0, 0.85),                  # over an obstacle, accepted
             (0, OBSTACLE, 0.7),            # over an obstacle, rejected
             (0, CLEARANCE, 0.99),          # over an obstacle, rejected for clearance
             (-1, 0, 0.99)]                 # not scored (a tile under it unlabelled)
    truth = np.array([[c[0] for c in cells]], np.int8)
    reasons = np.array([[c[1] for c in cells]], np.uint8)
    p = np.array([[c[2] for c in cells]])
    f = footprint_figures(reasons, p, truth)
    assert f['clear_footprints'] == 5 and f['clear_footprints_geometry'] == 1
    assert f['clear_accepted'] == 2 and f['clear_accepted_share'] == pytest.approx(2 / 5)
    assert f['obstacle_footprints'] == 3 and f['obstacle_accepted'] == 1
    np.testing.assert_array_equal(np.sort(f['_cp']), [0.6, 0.85, 0.95])
    np.testing.assert_array_equal(np.sort(f['_op']), [0.7, 0.85])
    curve = f['operating_curve']
    # none over an obstacle: above 0.85, and the clear footprint tied at 0.85 is not accepted
    assert curve['0'] == {'threshold': 0.95, 'clear_accepted': 1, 'share': pytest.approx(0.2)}
    # one: above 0.7, both footprints at 0.85 accepted
    assert curve['1'] == {'threshold': 0.85, 'clear_accepted': 2, 'share': pytest.approx(0.4)}
    # five: every footprint a threshold decides
    assert curve['5'] == {'threshold': 0.6, 'clear_accepted': 3, 'share': pytest.approx(0.6)}


def test_operating_curve_without_footprints():
    assert operating_curve(np.zeros(0), np.zeros(0), 0)['0'] == {
        'threshold': None, 'clear_accepted': 0, 'share': None}
    # every clear footprint below the obstacle: nothing can be accepted at 0
    assert operating_curve(np.array([0.3]), np.array([0.9]), 4)['0'] == {
        'threshold': None, 'clear_accepted': 0, 'share': 0.0}


def test_footprints_of_hand_made_tiles_and_labels():
    """Tiles and labels made by hand, through the real candidates and footprint truth."""
    nx, ny = 7, 3
    p = np.full((nx, ny), 0.95)
    p[5, 0] = 0.92          # the obstacle's tile, passed at the shipped 0.9
    p[1, 2] = 0.5           # a false alarm on clear ground
    conf = np.ones_like(p)
    cand = evaluate_candidates(p, conf, (0, 0), tile_size=1.0)
    gx, gy = np.meshgrid(np.arange(nx), np.arange(ny), indexing='ij')
    centers = np.column_stack([gx.ravel(), gy.ravel()]) + 0.5
    labels = {'tile_size': 1.0, 'tiles': [{'x': float(x), 'y': float(y),
                                           'safe': (x, y) != (5.5, 0.5)} for x, y in centers]}
    truth = footprint_truth(tile_truth(centers, 1.0, labels).reshape(nx, ny), 1.5, 1.0)
    # 3 x 3 footprints: only those centred on the middle row, i = 1..5, lie inside the grid;
    # one reaching past it is over the obstacle all the same when its labelled tiles say so
    assert truth.tolist() == [[-1, -1, -1]] + [[-1, 1, -1]] * 3 + [[0, 0, -1]] * 3
    f = footprint_figures(cand.reasons, cand.p_safe, truth)
    assert (f['clear_footprints'], f['clear_accepted']) == (3, 1)  # i = 3 (i = 1, 2 hold 0.5)
    # the two inside the grid are accepted; the four reaching past it are unknown
    assert (f['obstacle_footprints'], f['obstacle_accepted']) == (6, 2)
    assert f['operating_curve']['0'] == {'threshold': 0.95, 'clear_accepted': 1,
                                         'share': pytest.approx(1 / 3)}
    assert f['operating_curve']['5']['clear_accepted'] == 3


def _flight(name, p, y, reasons, fp, ft, labelled):
    f = {'bag': name, **_figures(np.array(p), np.array(y), labelled),
         **_site_figures(np.zeros(0), np.zeros(0, np.int8), 0, 0),
         **footprint_figures(np.array([reasons], np.uint8), np.array([fp]),
                             np.array([ft], np.int8))}
    f['_p'], f['_y'] = np.array(p, np.float32), np.array(y, np.int8)
    f['_fp'], f['_fy'] = np.zeros(0, np.float32), np.zeros(0, np.int8)
    return f


def test_pooled_footprints_sum_and_share_one_threshold():
    a = _flight('a.mcap', [0.95, 0.2], [1, 0], [0, 0, OBSTACLE], [0.9, 0.97, 0.5], [1, 0, 1], 2)
    b = _flight('b.mcap', [0.92, 0.93], [1, 1], [0, 0], [0.99, 0.85], [1, 1], 3)
    pooled = pooled_figures([a, b])
    assert pooled['clear_footprints'] == 4 and pooled['clear_accepted'] == 3
    assert pooled['obstacle_footprints'] == 1 and pooled['obstacle_accepted'] == 1
    # one threshold over both flights: above a's 0.97 only b's 0.99 is left
    assert pooled['operating_curve']['0'] == {'threshold': 0.99, 'clear_accepted': 1,
                                              'share': pytest.approx(0.25)}
    assert a['operating_curve']['0']['clear_accepted'] == 0
    assert pooled['safe_passed_0.9'] == pytest.approx(1.0)
    assert pooled['obstacle_passed_0.9'] == 0.0 and pooled['tiles_labelled'] == 5
    table = markdown_flights({'flights': [a, b], 'pooled': pooled})
    assert '| a.mcap | 100.0% | 50.0% (1 of 2) | 1 of 1 | 0.0% (P >= -) |' in table
    assert '| **pooled** | 100.0% | 75.0% (3 of 4) | 1 of 1 | 25.0% (P >= 0.990) |' in table


def test_flights_are_grouped_by_obstacle_family_and_vegetation():
    labels = {'obstacles': [{'kind': 'rock'}, {'kind': 'tire'}, {'kind': 'rock'}],
              'site': {'vegetation': {'preset': 'clumped'}},
              'flight': {'families': [], 'vegetation_family': None}}
    assert flight_groups(labels) == {'obstacles': 'rock,tire', 'vegetation': 'clumped'}
    labels['flight'] = {'families': ['coil'], 'vegetation_family': 'meadow'}
    assert flight_groups(labels) == {'obstacles': 'coil', 'vegetation': 'meadow'}
    assert flight_groups({'tiles': []}) == {'obstacles': 'none', 'vegetation': 'unknown'}

    a = _flight('a.mcap', [0.95, 0.2], [1, 0], [0, 0, OBSTACLE], [0.9, 0.97, 0.5], [1, 0, 1], 2)
    b = _flight('b.mcap', [0.92, 0.93], [1, 1], [0, 0], [0.99, 0.85], [1, 1], 3)
    c = _flight('c.mcap', [0.3, 0.99], [0, 1], [0, 0], [0.2, 0.99], [0, 1], 2)
    for f, obstacles, vegetation in ((a, 'coil', 'meadow'), (b, 'coil', 'forb'),
                                     (c, 'hoop', 'meadow')):
        f.update(obstacles=obstacles, vegetation=vegetation)
    groups = grouped_figures([a, b, c])
    assert set(groups) == {'obstacles', 'vegetation'}
    assert groups['obstacles']['coil'] == {'flights': 2, **pooled_figures([a, b])}
    assert groups['vegetation']['meadow'] == {'flights': 2, **pooled_figures([a, c])}
    assert groups['vegetation']['forb']['clear_footprints'] == b['clear_footprints']
    table = markdown_flights({'flights': [a, b, c], 'pooled': pooled_figures([a, b, c]),
                              'groups': groups})
    assert '| obstacles | flights | AUC |' in table and '| vegetation | flights |' in table
    assert '| coil | 2 | ' in table and '| hoop | 1 | ' in table


@pytest.fixture(scope='module')
def flight(tmp_path_factory):
    from landing_zone.tools.sim.flight import flight_config, simulate_flight
    from test_assessor import make_model

    root = tmp_path_factory.mktemp('flight')
    cfg = flight_config('default', 'line', size=6.0, obstacles=2,
                        kinds=('rock', 'tire', 'cinder_block', 'box'), seed=1)
    return simulate_flight(cfg, root / 'site.mcap').bag, make_model(root / 'm.safetensors')


def test_the_labelled_site_is_scored_and_a_centre_may_be_given(flight):
    from landing_zone.io.labels import labels_center, labels_path_for, read_labels
    from landing_zone.tools.evaluate.flights import evaluate_flights

    bag, model = flight
    labels = read_labels(labels_path_for(bag))
    n = len(labels['tiles'])
    doc = evaluate_flights([bag], workers=1, model=model)
    (f,) = doc['flights']
    # the map is fixed on the labels: every labelled tile the flight covered is judged
    assert f['center'] == list(labels_center(labels)) and f['center_from'] == 'labels'
    assert f['labels_outside_map'] == 0 and 'note' not in f
    assert f['tiles_labelled'] == n == 36 and f['tiles_judged'] == n and f['unjudged'] == 0
    assert f['obstacle_footprints'] >= f['footprints_unsafe']
    assert f['clear_footprints'] + f['clear_footprints_geometry'] >= \
        f['footprints'] - f['footprints_unsafe']
    for k in ('0', '1', '5'):
        assert f['operating_curve'][k]['clear_accepted'] <= f['clear_footprints']
    # a centre given away from the site: its tiles are outside the map, and the table says so
    far = evaluate_flights([bag], workers=1, model=model, center=(60.0, 0.0))
    (g,) = far['flights']
    assert g['center'] == [60.0, 0.0] and g['center_from'] == 'given'
    assert g['labels_outside_map'] == n and g['tiles_judged'] == 0 and g['unjudged'] == 1.0
    assert f'{n} of {n} labelled tiles lie outside' in g['note']
    assert 'lie outside the 20 m x 20 m map' in markdown_flights(far)
