"""PoseBuffer: exact at the stored stamps, linear in position, slerp in orientation (checked
against closed forms and scipy), out-of-order insertion, tolerances, 'too old' / 'not yet', and
pruning by age and by count."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from landing_zone.errors import ConfigError, InvalidPoseError
from landing_zone.poses import (
    PoseBuffer,
    PoseLookupError,
    PoseNotYetError,
    PoseTooOldError,
    normalize_quaternion,
    quaternion_to_matrix,
    slerp,
)

S = 1_000_000_000  # ns per s


def yaw(angle):
    return np.array([0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)])


def same_rotation(q0, q1, atol=1e-12):
    """q and -q are the same rotation."""
    return min(np.abs(q0 - q1).max(), np.abs(q0 + q1).max()) <= atol


def test_exact_at_stored_stamps(rng):
    buf = PoseBuffer()
    stamps = np.sort(rng.choice(10 * S, 20, replace=False))
    poses = [(rng.normal(size=3), rng.normal(size=4)) for _ in stamps]
    for stamp, (p, q) in zip(stamps, poses):
        buf.add(int(stamp), p, q)
    for stamp, (p, q) in zip(stamps, poses):
        got_p, got_q = buf.lookup(int(stamp))
        np.testing.assert_array_equal(got_p, p)
        np.testing.assert_array_equal(got_q, normalize_quaternion(q))  # stored normalised


def test_halfway_slerp_between_known_rotations():
    buf = PoseBuffer()
    buf.add(1 * S, [0, 0, 10], yaw(0.0))
    buf.add(2 * S, [4, -2, 12], yaw(math.pi / 2))
    p, q = buf.lookup(S + S // 2)
    np.testing.assert_allclose(p, [2, -1, 11], atol=1e-15)
    np.testing.assert_allclose(q, yaw(math.pi / 4), atol=1e-15)
    # A quarter of the way: the angle interpolates linearly (constant angular velocity).
    _, q = buf.lookup(S + S // 4)
    np.testing.assert_allclose(q, yaw(math.pi / 8), atol=1e-15)
    R, t = buf.lookup_rt(S + S // 2)
    np.testing.assert_allclose(R @ [1, 0, 0], [math.sqrt(0.5), math.sqrt(0.5), 0], atol=1e-15)
    np.testing.assert_allclose(t, [2, -1, 11], atol=1e-15)


def test_slerp_takes_the_short_way():
    # 350 degrees of yaw is -10 degrees: halfway from 0 is -5 degrees, not 175.
    q = slerp(yaw(0.0), yaw(math.radians(350)), 0.5)
    assert same_rotation(q, yaw(math.radians(-5)))


def test_slerp_matches_scipy(rng):
    for _ in range(50):
        r = Rotation.random(2, rng=rng)
        alpha = float(rng.random())
        want = Slerp([0, 1], r)([alpha]).as_quat()[0]
        got = slerp(r[0].as_quat(), r[1].as_quat(), alpha)
        assert same_rotation(got, want, atol=1e-12)
        assert np.linalg.norm(got) == pytest.approx(1.0, abs=1e-15)


def test_slerp_of_nearly_equal_rotations_is_unit_and_between():
    q0 = yaw(0.1)
    q1 = yaw(0.1 + 1e-9)
    q = slerp(q0, q1, 0.5)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
    assert same_rotation(q, yaw(0.1 + 0.5e-9), atol=1e-15)


def test_out_of_order_insertion_equals_in_order(rng):
    stamps = np.arange(10) * S // 10
    poses = [(rng.normal(size=3), normalize_quaternion(rng.normal(size=4))) for _ in stamps]
    ordered, shuffled = PoseBuffer(), PoseBuffer()
    for s, (p, q) in zip(stamps, poses):
        ordered.add(int(s), p, q)
    for i in rng.permutation(len(stamps)):
        shuffled.add(int(stamps[i]), *poses[i])
    assert len(shuffled) == 10 and shuffled.oldest_ns == 0 and shuffled.newest_ns == 9 * S // 10
    for t in rng.integers(0, 9 * S // 10, 100):
        for a, b in zip(ordered.lookup(int(t)), shuffled.lookup(int(t))):
            np.testing.assert_array_equal(a, b)


def test_duplicate_stamp_replaces():
    buf = PoseBuffer()
    buf.add(5, [0, 0, 0], [0, 0, 0, 1])
    buf.add(5, [1, 1, 1], [0, 0, 0, 1])
    assert len(buf) == 1
    np.testing.assert_array_equal(buf.lookup(5)[0], [1, 1, 1])


def test_tolerance_clamps_without_extrapolating():
    buf = PoseBuffer(tolerance_s=0.05)
    buf.add(10 * S, [0, 0, 0], yaw(0))
    buf.add(11 * S, [1, 0, 0], yaw(1))
    np.testing.assert_array_equal(buf.lookup(11 * S + 50_000_000)[0], [1, 0, 0])
    np.testing.assert_array_equal(buf.lookup(10 * S - 50_000_000)[0], [0, 0, 0])


def test_not_yet_and_too_old():
    buf = PoseBuffer(tolerance_s=0.05)
    with pytest.raises(PoseNotYetError, match='no pose received') as err:
        buf.lookup(0)
    assert err.value.reason == 'not_yet'
    buf.add(10 * S, [0, 0, 0], yaw(0))
    buf.add(11 * S, [1, 0, 0], yaw(1))
    with pytest.raises(PoseNotYetError, match='newest pose is 0.051 s older') as err:
        buf.lookup(11 * S + 51_000_000)
    assert isinstance(err.value, InvalidPoseError) and err.value.reason == 'not_yet'
    with pytest.raises(PoseTooOldError, match='too old.*2.000 s newer') as err:
        buf.lookup(8 * S)
    assert isinstance(err.value, PoseLookupError) and err.value.reason == 'too_old'


def test_pruned_by_age_keeps_the_window_interpolable():
    buf = PoseBuffer(max_age_s=1.0, tolerance_s=0.0)
    for i in range(31):  # 10 Hz for 3 s
        buf.add(i * S // 10, [i, 0, 0], yaw(0))
    # The window [2.0 s, 3.0 s] is kept, with the pose at its left end.
    assert buf.oldest_ns == 2 * S and buf.newest_ns == 3 * S
    np.testing.assert_allclose(buf.lookup(2 * S + S // 20)[0], [20.5, 0, 0])
    with pytest.raises(PoseTooOldError):
        buf.lookup(2 * S - 1)
    # An old pose arriving late is dropped at once: it is beyond the window.
    buf.add(S, [-1, 0, 0], yaw(0))
    assert buf.oldest_ns == 2 * S


def test_pruned_by_count():
    buf = PoseBuffer(max_age_s=100.0, max_len=5)
    for i in range(12):
        buf.add(i, [i, 0, 0], yaw(0))
    assert len(buf) == 5 and buf.oldest_ns == 7 and buf.newest_ns == 11


def test_clear():
    buf = PoseBuffer()
    buf.add(1, [0, 0, 0], yaw(0))
    buf.clear()
    assert len(buf) == 0 and buf.newest_ns is None
    with pytest.raises(PoseNotYetError):
        buf.lookup(1)


@pytest.mark.parametrize('position,quaternion,match', [
    ([0, 0, np.nan], [0, 0, 0, 1], 'position is not finite'),
    ([0, 0], [0, 0, 0, 1], 'position must have 3'),
    ([0, 0, 0], [0, 0, 0, 0], 'norm'),
    ([0, 0, 0], [0, 0, np.inf, 1], 'quaternion is not finite'),
    ([0, 0, 0], [0, 0, 1], 'quaternion must have 4'),
])
def test_bad_poses_rejected(position, quaternion, match):
    buf = PoseBuffer()
    with pytest.raises(InvalidPoseError, match=match):
        buf.add(0, position, quaternion)
    assert len(buf) == 0


@pytest.mark.parametrize('kwargs', [dict(max_age_s=0), dict(max_age_s=math.inf),
                                    dict(max_len=1), dict(tolerance_s=-1e-3),
                                    dict(tolerance_s=math.nan)])
def test_bad_parameters(kwargs):
    with pytest.raises(ConfigError):
        PoseBuffer(**kwargs)


def test_quaternion_to_matrix_matches_scipy(rng):
    for q in rng.normal(size=(20, 4)):
        np.testing.assert_allclose(quaternion_to_matrix(q), Rotation.from_quat(q).as_matrix(),
                                   atol=1e-12)
