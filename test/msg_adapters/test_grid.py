"""Assessment -> output messages, identical for rclpy and rosbags (same CDR content)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from landing_zone.assessor import Assessment
from landing_zone.config import SiteConfig
from landing_zone.judging.ground import slope_deg
from landing_zone.judging.sites import GroundGrids, evaluate_candidates
from msg_adapters import jazzy_typestore as typestore
from landing_zone.judging.sites import LandingSite
from msg_adapters import MessageTypes
from msg_adapters import grid as g
from msg_adapters.pointcloud import cloud_to_structured

STAMP = 1_700_000_123_456_789_000


def hand_made() -> Assessment:
    """3 x 2 tiles from tile (-1, 4): p = 1, 0, 0.5 / NaN, 0.994, 0.006 along x then y."""
    origin, shape = (-1, 4), (3, 2)
    gx, gy = np.meshgrid(np.arange(3), np.arange(2), indexing='ij')
    index = np.column_stack([gx.ravel(), gy.ravel()]) + origin
    p = np.array([[1.0, np.nan], [0.0, 0.994], [0.5, 0.006]], np.float32)
    gz = np.array([[0.1, np.nan], [0.2, 0.3], [0.4, 0.5]])
    conf = np.array([[0.9, 0.0], [0.8, 0.7], [0.6, 0.5]], np.float32)
    tilt = np.radians(10.0)
    sites = [LandingSite(x=0.5, y=4.5, z=0.2, p_safe=0.9, confidence=0.8, index=(0, 4),
                         slope_deg=10.0, normal=(-np.sin(tilt), 0.0, np.cos(tilt))),
             LandingSite(x=1.5, y=5.5, z=float('nan'), p_safe=0.7, confidence=0.5,
                         index=(1, 5))]
    # tile (0, 0) (the one at x -0.5) rises 12 degrees towards +x, the others are level
    grad = np.zeros((3, 2, 2))
    grad[0, 0, 0] = np.tan(np.radians(12.0))
    grad[0, 1] = np.nan
    clearance = np.array([[2.0, np.nan], [2.0, 2.0], [2.0, 2.0]], np.float32)
    cand = evaluate_candidates(p, conf, origin, SiteConfig(footprint_radius=0.5, min_p_safe=0.5),
                               1.0, GroundGrids(gz, grad, clearance))
    return Assessment(frame_id='map', tile_size=1.0, origin=origin, shape=shape, index=index,
                      centers=(index + 0.5) * 1.0, ground_z=gz.ravel(), p_safe=p.ravel(),
                      confidence=conf.ravel(), observed_fraction=np.full(6, 0.5, np.float32),
                      n_returns=np.full(6, 100), sites=sites, stamp=STAMP / 1e9,
                      slope_deg=slope_deg(grad).ravel(),
                      roughness=np.array([0.01, np.nan, 0.02, 0.01, 0.03, 0.01], np.float32),
                      clearance=clearance.ravel(), grad=grad.reshape(-1, 2), candidates=cand)


def both(fn, *args):
    """The message built for rclpy and for rosbags, and their CDR serializations."""
    from rclpy.serialization import serialize_message

    a = hand_made()
    m_rclpy = fn(a, STAMP, *args, types='rclpy')
    m_bags = fn(a, STAMP, *args, types=MessageTypes.rosbags())
    return m_rclpy, m_bags, normalized(serialize_message(m_rclpy), m_bags.__msgtype__), \
        bytes(typestore().serialize_cdr(m_bags, m_bags.__msgtype__))


def normalized(cdr, msgtype):
    """CDR bytes with the alignment padding zeroed (rclpy leaves whatever was in memory)."""
    ts = typestore()
    return bytes(ts.serialize_cdr(ts.deserialize_cdr(bytes(cdr), msgtype), msgtype))


def test_grid_values_follow_the_contract():
    v = g.grid_values(hand_made())
    assert v.dtype == np.int8
    assert v.tolist() == [[0, -1], [100, 1], [50, 99]]


def test_occupancy_grid_layout_and_identical_bytes():
    m, mb, c1, c2 = both(g.safety_grid)
    assert c1 == c2
    assert m.info.width == 3 and m.info.height == 2 and m.info.resolution == 1.0
    assert (m.info.origin.position.x, m.info.origin.position.y) == (-1.0, 4.0)
    assert m.info.origin.position.z == pytest.approx(0.3)  # median ground
    # row-major, x fastest: data[j * width + i] is tile (origin + i, origin + j)
    assert list(m.data) == [0, 100, 50, -1, 1, 99]
    assert m.header.frame_id == 'map'
    assert m.header.stamp.sec == STAMP // 10**9 and m.header.stamp.nanosec == STAMP % 10**9
    assert mb.data.tolist() == [0, 100, 50, -1, 1, 99]


def test_safety_cloud_has_one_point_per_grounded_tile():
    m, mb, c1, c2 = both(g.safety_cloud)
    assert c1 == c2
    arr = cloud_to_structured(m)
    # the contract's fields, then the ground's
    assert arr.dtype.names == ('x', 'y', 'z', 'p_safe', 'confidence', 'slope_deg', 'roughness',
                               'clearance')
    assert all(arr.dtype[n] == np.float32 for n in arr.dtype.names)
    assert len(arr) == 5  # the tile without ground is left out
    a = hand_made()
    have = np.isfinite(a.ground_z)
    np.testing.assert_allclose(arr['x'], a.centers[have, 0])
    np.testing.assert_allclose(arr['z'], a.ground_z[have], rtol=1e-6)
    np.testing.assert_allclose(arr['p_safe'], a.p_safe[have])
    np.testing.assert_allclose(arr['confidence'], a.confidence[have])
    np.testing.assert_allclose(arr['slope_deg'], [12.0, 0.0, 0.0, 0.0, 0.0], atol=1e-4)
    np.testing.assert_allclose(arr['clearance'], a.clearance[have])
    np.testing.assert_array_equal(cloud_to_structured(mb), arr)


def test_landing_sites_best_first():
    m, _, c1, c2 = both(g.landing_site_poses)
    assert c1 == c2
    xyz = [(p.position.x, p.position.y, p.position.z) for p in m.poses]
    assert xyz == [(0.5, 4.5, pytest.approx(0.2)), (1.5, 5.5, 0.0)]
    # the first site's pose turns the vertical onto its ground normal; the second is level
    q = m.poses[0].orientation
    rot = Rotation.from_quat([q.x, q.y, q.z, q.w])
    np.testing.assert_allclose(rot.apply([0.0, 0.0, 1.0]), hand_made().sites[0].normal,
                               atol=1e-9)
    assert np.degrees(rot.magnitude()) == pytest.approx(10.0)
    assert m.poses[1].orientation.w == 1.0


def test_markers_colour_tiles_and_mark_sites():
    m, _, c1, c2 = both(g.markers, 1.5)
    assert c1 == c2
    kinds = [(mk.ns, mk.type, mk.action) for mk in m.markers]
    assert kinds[:4] == [('', 0, 3), ('tiles', 6, 0), ('landing_sites', 3, 0),
                         ('landing_sites', 3, 0)]
    # the rejected candidates' reasons as text: the steep tile, the two near-certain obstacles
    # (the unknown one is left out)
    texts = {(mk.pose.position.x, mk.pose.position.y): mk.text for mk in m.markers[4:]
             if mk.ns == 'rejected' and mk.type == 9}
    assert texts == {(-0.5, 4.5): 'slope 12.0 deg', (0.5, 4.5): 'obstacle',
                     (1.5, 5.5): 'obstacle'}
    tiles = m.markers[1]
    assert len(tiles.points) == len(tiles.colors) == 5
    # p = 1 green, p = 0 red, p = 0.5 yellow (tiles x-major, the one without ground left out)
    rgb = [(c.r, c.g, c.b) for c in tiles.colors]
    assert rgb[0] == (0.0, 1.0, 0.0) and rgb[1] == (1.0, 0.0, 0.0) and rgb[3] == (1.0, 1.0, 0.0)
    assert m.markers[2].scale.x == 3.0
    colors = g.tile_colors(np.array([np.nan, 0.25]))
    assert tuple(colors[0]) == (0.5, 0.5, 0.5, 0.6)
    np.testing.assert_allclose(colors[1], [1.0, 0.5, 0.0, 0.8])


def test_diagnostics_and_levels():
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.serialization import serialize_message

    values = {'clouds integrated': '12', 'map memory [MB]': '26.5'}
    m = g.diagnostics(values, STAMP, level='WARN', message='dropping clouds')
    mb = g.diagnostics(values, STAMP, level='WARN', message='dropping clouds',
                       types=MessageTypes.rosbags())
    assert normalized(serialize_message(m), mb.__msgtype__) == \
        bytes(typestore().serialize_cdr(mb, mb.__msgtype__))
    st = m.status[0]
    assert st.level == DiagnosticStatus.WARN and mb.status[0].level == 1
    assert {kv.key: kv.value for kv in st.values} == values
    with pytest.raises(ValueError, match='level'):
        g.diagnostics({}, STAMP, level='FINE')


def test_build_fills_rosbags_defaults():
    t = MessageTypes.rosbags()
    mk = g.build(t, 'visualization_msgs/msg/Marker', ns='x')
    assert mk.ns == 'x' and mk.texture.data.size == 0 and mk.points == [] and mk.id == 0
    typestore().serialize_cdr(mk, 'visualization_msgs/msg/Marker')
    with pytest.raises(TypeError, match='no field'):
        g.build(t, 'std_msgs/msg/ColorRGBA', alpha=1.0)


def test_landing_sites_cloud_has_every_site_in_the_poses_order_with_identical_bytes():
    m, mb, c1, c2 = both(g.landing_sites_cloud)
    assert c1 == c2
    sites = cloud_to_structured(m)
    assert sites.dtype.names == ('x', 'y', 'z', 'p_safe', 'slope_deg', 'step', 'clearance')
    assert all(sites.dtype[n] == np.float32 for n in sites.dtype.names)
    poses = g.landing_site_poses(hand_made(), STAMP).poses
    assert [(p.position.x, p.position.y) for p in poses] == list(zip(sites['x'], sites['y']))
    np.testing.assert_allclose(sites['p_safe'], [0.9, 0.7])
    np.testing.assert_allclose(sites['slope_deg'], [10.0, np.nan], equal_nan=True)
    assert np.isnan(sites['z'][1])  # no ground under the second: NaN, as the report's null
    assert m.header.frame_id == 'map' and m.width == 2
    assert 'landing_sites_cloud' in g.OUTPUT_TYPES
