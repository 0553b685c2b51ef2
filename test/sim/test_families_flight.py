"""Flights and insertions draw from the obstacle families; flights on sloped ground and over
the synth3 vegetation families (real bags written and read back)."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.insert import insert_obstacles
from landing_zone.tools.sim.families import FAMILIES, TEST_BASE, TEST_FAMILIES
from landing_zone.tools.sim.flight import flight_config, simulate_flight
from landing_zone.tools.sim.library import get_model

REPO = Path(__file__).resolve().parents[2]
SMALL = dict(size=8.0, height=5.0, target_density=400.0, angular_resolution=0.25,
             prr=50_000.0)


def _points(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    from landing_zone.io.bags import read_messages
    from msg_adapters.pointcloud import cloud_to_structured
    pts, lab = [], []
    for m in read_messages(bag, ['/lidar/points']):
        a = cloud_to_structured(m.msg)
        pts.append(np.stack([a['x'], a['y'], a['z']], axis=1).astype(float))
        lab.append(a['label'])
    return np.concatenate(pts), np.concatenate(lab)


@pytest.fixture(scope='module')
def family_flight(tmp_path_factory):
    """Four test families on a 10 degree slope, lodged grass, the elliptical scanner."""
    out = tmp_path_factory.mktemp('fam') / 'site.mcap'
    cfg = flight_config('lodged', 'elliptical', kinds=(), families=TEST_FAMILIES,
                        obstacles=4, slope=10.0, slope_azimuth=0.5, seed=2,
                        **{**SMALL, 'prr': 100_000.0})
    result = simulate_flight(cfg, out, threads=1)
    return result, json.loads(result.labels.read_text()), *_points(out)


def test_flight_obstacles_are_test_instances_of_the_families(family_flight):
    result, labels, pts, lab = family_flight
    obs = labels['obstacles']
    assert [o['kind'] for o in obs] == list(TEST_FAMILIES)
    for o in obs:
        fam, _, idx = o['model'].partition('/')
        assert fam == o['kind'] and int(idx) >= TEST_BASE
        m = get_model(o['model'])  # the labels name the mesh exactly
        assert [round(v, 4) for v in m.size] == o['size']
    assert labels['flight']['families'] == list(TEST_FAMILIES)
    assert result.unsafe_tiles >= 4 and (lab == 2).sum() > 100


def test_flight_on_a_slope_over_a_vegetation_family(family_flight):
    _, labels, pts, lab = family_flight
    site = labels['site']
    assert site['slope'] == 10.0 and site['vegetation_family']['family'] == 'lodged'
    ground = pts[lab == 0]
    # The ground returns lie on the plane rising 10 degrees towards azimuth 0.5.
    a = np.c_[ground[:, :2], np.ones(len(ground))]
    coef, *_ = np.linalg.lstsq(a, ground[:, 2], rcond=None)
    assert math.degrees(math.atan(np.hypot(*coef[:2]))) == pytest.approx(10.0, abs=0.5)
    assert math.atan2(coef[1], coef[0]) == pytest.approx(0.5, abs=0.05)
    # Every obstacle stands at least 10 cm out of the ground around it (none sinks uphill).
    for o in labels['obstacles']:
        near = np.hypot(pts[:, 0] - o['x'], pts[:, 1] - o['y']) < 0.4
        obst = pts[near & (lab == 2)]
        plane = coef[0] * obst[:, 0] + coef[1] * obst[:, 1] + coef[2]
        assert (obst[:, 2] - plane).max() > 0.09, o['model']


def test_insert_every_family(family_flight, tmp_path):
    bag = tmp_path / 'in.mcap'
    cfg = flight_config(size=12.0, obstacles=0, grass_density=0.0, **{
        k: v for k, v in SMALL.items() if k != 'size'})
    simulate_flight(cfg, bag, threads=1)
    out = tmp_path / 'out.mcap'
    r = insert_obstacles(bag, out, count=len(FAMILIES), kinds=(), families=tuple(FAMILIES),
                         group='train', seed=1, threads=1)
    names = [o.model.name for o in r.obstacles]
    assert [n.partition('/')[0] for n in names] == list(FAMILIES)
    assert all(int(n.partition('/')[2]) < TEST_BASE for n in names)  # the train instances
    labels = json.loads(r.labels.read_text())
    assert [o['model'] for o in labels['obstacles']] == names
    assert r.altered > 0


def test_kinds_and_families_are_told_apart():
    with pytest.raises(SimulationError, match="'log' is an obstacle family"):
        simulate_flight(flight_config(kinds=('log',)), '/tmp/never.mcap')
    with pytest.raises(SimulationError, match='unknown obstacle family'):
        flight_config(families=('spaceship',)).validate()


def test_cli_families_and_bad_family_is_one_line(tmp_path):
    out = tmp_path / 'c.mcap'
    base = [sys.executable, '-m', 'landing_zone', 'simulate-flight', '--out', str(out),
            '--size', '5', '--obstacles', '2', '--height', '4', '--density', '300']
    run = subprocess.run(base + ['--families', 'log,coil', '--slope', '5',
                                 '--vegetation', 'bare', '--scan-pattern', 'elliptical'],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    labels = json.loads(out.with_name('c.labels.json').read_text())
    assert [o['kind'] for o in labels['obstacles']] == ['log', 'coil']
    assert labels['site']['scan_pattern']['kind'] == 'elliptical'
    bad = subprocess.run(base[:5] + [str(tmp_path / 'b.mcap')] + base[6:]
                         + ['--families', 'spaceship'], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    lines = bad.stderr.strip().splitlines()
    assert bad.returncode == 2 and len(lines) == 1 and 'spaceship' in lines[0]
