"""The anchored calibration of a fine-tuned model: never more lenient on reference obstacles."""
import numpy as np
import pytest

from landing_zone.errors import ConfigError
from landing_zone.tools.learn.anchored_calibration import anchored_offset, passes

T, B = 0.7, -0.9


def reference(seed=0, n=200):
    rng = np.random.default_rng(seed)
    y = np.arange(n) % 2  # half obstacles (0), half safe (1)
    z = np.where(y == 1, rng.normal(3.0, 1.0, n), rng.normal(-3.0, 1.5, n))
    return z, y


def test_the_initial_net_itself_keeps_its_offset():
    z, y = reference()
    b, report = anchored_offset(z, z, y, T, B)
    assert b == B and report['offset'] == B


def test_a_net_more_lenient_on_obstacles_passes_no_more_after_the_anchoring():
    z, y = reference()
    new = np.where(y == 0, z + 3.0, z)  # every obstacle 3 logits safer
    b, report = anchored_offset(new, z, y, T, B)
    assert b < B
    for t in (0.5, 0.9):
        assert passes(new[y == 0], T, b, t) <= passes(z[y == 0], T, B, t)
    assert report['groups'][0]['passed']['0.5']['anchored'] \
        <= report['groups'][0]['passed']['0.5']['initial']


def test_the_offset_is_never_raised():
    z, y = reference()
    b, _ = anchored_offset(z - 2.0, z, y, T, B)  # stricter everywhere
    assert b == B


def test_a_few_obstacles_judged_surely_safe_are_enough_to_lower_it():
    z, y = reference()
    new = z.copy()
    worst = np.flatnonzero(y == 0)[np.argsort(z[y == 0])[-3:]]
    new[worst] = 10.0  # three obstacles now surely safe
    b, _ = anchored_offset(new, z, y, T, B)
    assert b < B
    for t in (0.5, 0.9):
        assert passes(new[y == 0], T, b, t) <= passes(z[y == 0], T, B, t)


def test_the_anchor_holds_in_every_group():
    z, y = reference()
    g = (np.arange(z.size) // 2) % 2  # obstacles of both groups
    new = np.where((y == 0) & (g == 1), z + 3.0, z)  # only group 1 more lenient
    b, report = anchored_offset(new, z, y, T, B, groups=g)
    assert b < B
    assert [e['group'] for e in report['groups']] == [0, 1]
    for e, sel in zip(report['groups'], (g == 0, g == 1)):
        assert e['passed']['0.5']['anchored'] <= e['passed']['0.5']['initial']
        assert e['passed']['0.9']['anchored'] <= e['passed']['0.9']['initial']
    assert report['groups'][1]['passed']['0.5']['unanchored'] \
        > report['groups'][1]['passed']['0.5']['initial']
    # pooled, the group the new net judges as before would have hidden it
    assert anchored_offset(new, z, y, T, B)[0] >= b
    # each group's own limit: group 0 asks for nothing, group 1 set the offset
    assert report['groups'][0]['offset_limit'] == B
    assert report['groups'][1]['offset_limit'] == b
    assert anchored_offset(new[g == 1], z[g == 1], y[g == 1], T, B)[0] == b


def test_bad_input_is_refused():
    z, y = reference()
    with pytest.raises(ConfigError, match='one of each'):
        anchored_offset(z[:-1], z, y, T, B)
    with pytest.raises(ConfigError, match='finite'):
        anchored_offset(np.full(z.size, np.nan), z, y, T, B)
    with pytest.raises(ConfigError, match='thresholds'):
        anchored_offset(z, z, y, T, B, thresholds=(1.0,))
