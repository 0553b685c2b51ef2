"""The flight sets the product is judged on: families kept apart, drawn from the seed alone."""
from __future__ import annotations

import json

import pytest

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.families import FAMILIES
from landing_zone.tools.sim.flight_sets import (DEVELOPMENT_OBSTACLES, HELDOUT_OBSTACLES,
                                                HELDOUT_VEGETATION, SETS, plan, simulate_set)
from landing_zone.tools.sim.flight_settings import SCAN, VEGETATION
from landing_zone.tools.sim.vegetation import SYNTH3_VEGETATION, VEGETATION_FAMILIES


def test_heldout_families_are_apart_from_training():
    assert not set(HELDOUT_OBSTACLES) & set(DEVELOPMENT_OBSTACLES)
    assert set(HELDOUT_OBSTACLES) | set(DEVELOPMENT_OBSTACLES) == set(FAMILIES)
    # synth3's six vegetation families are what the shipped model trained on
    assert not set(HELDOUT_VEGETATION) & set(SYNTH3_VEGETATION)
    assert set(HELDOUT_VEGETATION) <= set(VEGETATION) | set(VEGETATION_FAMILIES)


@pytest.mark.parametrize('which', sorted(SETS))
def test_every_pair_every_scanner_and_the_seed_decides(which):
    families, vegetations = SETS[which]
    flights = plan(which, 5, repeats=2)
    assert len(flights) == 2 * len(families) * len(vegetations)
    pairs = [(f.family, f.vegetation) for f in flights]
    assert set(pairs) == {(a, b) for a in families for b in vegetations}
    for family in families:
        assert {f.scan_pattern for f in flights if f.family == family} == set(SCAN)
    assert len({f.name for f in flights}) == len(flights)
    assert plan(which, 5, repeats=2) == flights
    other = plan(which, 6, repeats=2)
    assert [f.seed for f in other] != [f.seed for f in flights]
    assert all(5.0 <= f.height <= 22.0 and 1500 <= f.density <= 4500 for f in flights)


def test_bad_sets_are_refused_in_one_line(tmp_path):
    with pytest.raises(SimulationError, match='unknown flight set'):
        plan('mine', 0)
    with pytest.raises(SimulationError, match='non-negative'):
        plan('heldout', -1)
    with pytest.raises(SimulationError, match='repeats'):
        plan('heldout', 0, repeats=0)
    (tmp_path / 'flights.json').write_text(json.dumps({'set': 'heldout', 'seed': 1}))
    with pytest.raises(SimulationError, match='holds another flight set'):
        simulate_set('heldout', 2, tmp_path)


def test_a_set_resumes_and_writes_only_what_is_missing(tmp_path, monkeypatch):
    flights = plan('heldout', 3, repeats=1)
    done = []
    # the first flight exists already: only the others are written
    first = tmp_path / f'{flights[0].name}.mcap'
    first.write_bytes(b'x')
    first.with_name(f'{flights[0].name}.labels.json').write_text('{}')

    def fake_run(fn, tasks, **kw):
        for i, t in enumerate(tasks):
            done.append(t['flight']['name'])
            yield i, t['out']
    monkeypatch.setattr('landing_zone.tools.engines.run_tasks', fake_run)
    bags = simulate_set('heldout', 3, tmp_path, repeats=1, workers=1)
    assert [b.name for b in bags] == [f'{f.name}.mcap' for f in flights]
    assert done == [f.name for f in flights[1:]]
    assert json.loads((tmp_path / 'flights.json').read_text())['seed'] == 3


def test_a_planned_flight_is_simulated_with_its_family_and_vegetation(tmp_path):
    from landing_zone.io.labels import read_labels
    from landing_zone.tools.evaluate.flights import flight_groups
    from landing_zone.tools.sim.flight_sets import _simulate_one

    f = plan('heldout', 11, repeats=1)[3]
    bag = _simulate_one({'flight': f.to_json(), 'out': str(tmp_path / 'f.mcap')})
    labels = read_labels(tmp_path / 'f.labels.json')
    assert bag.endswith('f.mcap')
    assert flight_groups(labels) == {'obstacles': f.family, 'vegetation': f.vegetation}
    assert {o['kind'] for o in labels['obstacles']} == {f.family}
    assert labels['flight']['seed'] == f.seed and labels['flight']['slope'] == f.slope
