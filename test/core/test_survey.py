"""Survey input: LAS / LAZ files written with laspy here, read back and replayed.

The files are real (laspy writes them, LAZ through lazrs), made in the test from a simulated
straight flight line over flat ground at georeferenced coordinates (UTM-sized numbers), so the
test fetches nothing.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

laspy = pytest.importorskip('laspy')

from landing_zone.errors import BagError  # noqa: E402
from landing_zone.io.survey import read_survey  # noqa: E402

E0, N0, Z0 = 512_345.0, 4_101_234.0, 100.0  # the ground's georeferenced position [m]
HEIGHT, SPEED = 60.0, 40.0  # flight height above the ground [m], speed [m/s]


def flight_line(seconds: float = 1.0, lines_hz: float = 1000.0, pulses: int = 600,
                sparse_from: float = 30.0, seed: int = 0):
    """Returns of a cross-track scanner flying +x at SPEED, HEIGHT above flat ground.

    Returns (xyz (N, 3) georeferenced, gps_time, scan_angle [deg], sensor (N, 3)); beyond
    ``sparse_from`` m along the track only 3 % of the returns are kept.
    """
    rng = np.random.default_rng(seed)
    t_line = np.arange(0.0, seconds, 1.0 / lines_hz)
    angle = np.linspace(-20.0, 20.0, pulses)
    t = (t_line[:, None] + np.linspace(0, 1.0 / lines_hz, pulses, endpoint=False)[None, :])
    t = t.ravel() + 300_000.0
    th = np.tile(angle, len(t_line))
    sx = E0 + SPEED * (t - 300_000.0)
    sensor = np.column_stack([sx, np.full_like(sx, N0), np.full_like(sx, Z0 + HEIGHT)])
    # positive angles to the right of +x: towards -y
    xyz = np.column_stack([sx, N0 - HEIGHT * np.tan(np.radians(th)),
                           Z0 + rng.normal(0.0, 0.01, len(t))])
    keep = (sx - E0 < sparse_from) | (rng.random(len(t)) < 0.03)
    return xyz[keep], t[keep], th[keep], sensor[keep]


def write_las(path, xyz, t, angle):
    header = laspy.LasHeader(point_format=3, version='1.2')
    header.offsets = np.floor(xyz.min(axis=0))
    header.scales = np.array([0.001, 0.001, 0.001])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.gps_time = t
    las.scan_angle_rank = np.round(angle).astype(np.int8)
    las.point_source_id = np.full(len(t), 7, np.uint16)
    las.write(str(path))


@pytest.fixture(scope='module')
def survey_file(tmp_path_factory):
    xyz, t, angle, sensor = flight_line()
    path = tmp_path_factory.mktemp('survey') / 'line.laz'
    write_las(path, xyz, t, angle)
    return path, xyz, t, sensor


def test_a_laz_file_reads_back_in_float64_with_its_origins_derived(survey_file):
    path, xyz, t, sensor = survey_file
    notes = []
    s = read_survey(path, log=notes.append)
    assert len(s.points) == len(xyz)
    # local + origin is the georeferenced position, to the file's millimetres
    back = s.points + s.origin
    order = np.argsort(t, kind='stable')
    np.testing.assert_allclose(back, xyz[order], atol=1.5e-3)
    assert s.origin[0] % 100 == 0 and s.origin[1] % 100 == 0  # whole tiles, georeferenced
    assert np.abs(s.points[:, :2]).max() < 200  # small numbers before anything is float32
    # the sensor's track from GPS time and (whole-degree) scan angles: within a metre
    est = np.column_stack([np.interp(t[order], s.traj_times, s.traj_xyz[:, k])
                           for k in range(3)]) + s.origin
    assert np.abs(est - sensor[order]).max() < 1.0
    assert any('derived from GPS time and scan angle' in n for n in notes)
    assert s.metres_per_unit == 1.0 and any('metres assumed' in n for n in s.notes)


def test_a_csv_trajectory_is_used_as_given(survey_file, tmp_path):
    path, xyz, t, sensor = survey_file
    ts = np.linspace(t.min(), t.max(), 30)
    traj = np.column_stack([ts, E0 + SPEED * (ts - 300_000.0), np.full(30, N0),
                            np.full(30, Z0 + HEIGHT)])
    csv = tmp_path / 'traj.csv'
    csv.write_text('t,x,y,z\n' + '\n'.join(','.join(f'{v:.4f}' for v in r) for r in traj))
    s = read_survey(path, trajectory=csv)
    np.testing.assert_allclose(s.traj_xyz + s.origin, traj[:, 1:], atol=1e-6)
    assert s.trajectory_source == 'traj.csv'
    bad = tmp_path / 'bad.csv'
    bad.write_text('t,x,y,z\n1,2,three,4\n')
    with pytest.raises(BagError, match='not numbers'):
        read_survey(path, trajectory=bad)


def test_replay_of_a_survey_judges_dense_ground_and_leaves_sparse_unknown(survey_file,
                                                                          tmp_path):
    path, xyz, *_ = survey_file
    report = tmp_path / 'r.json'
    # a fixed region in the file's coordinates: 20 m from 20 to 40 m along the track
    proc = subprocess.run([sys.executable, '-m', 'landing_zone', 'replay', str(path), '--out',
                           str(tmp_path / 'a.mcap'), '--report', str(report), '--center',
                           str(E0 + 30.0), str(N0)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert 'derived from GPS time and scan angle' in proc.stdout
    doc = json.loads(report.read_text())
    o = np.array(doc['survey']['origin'])
    assert doc['survey']['returns'] == len(xyz)
    tiles = doc['tiles']
    # tiles at their georeferenced position: local + origin
    east = np.array([tt['x'] for tt in tiles]) + o[0]
    north = np.array([tt['y'] for tt in tiles]) + o[1]
    assert east.min() == pytest.approx(E0 + 20.5) and east.max() == pytest.approx(E0 + 39.5)
    judged = np.array([tt['p_safe'] is not None for tt in tiles])
    dense = (east < E0 + 29) & (np.abs(north - N0) < 8)
    sparse = east > E0 + 31
    assert judged[dense].mean() > 0.9
    assert not judged[sparse].any()  # 3 % of the returns: too sparse to judge
    ground = np.array([tt['ground_z'] if tt['ground_z'] is not None else np.nan
                       for tt in tiles]) + o[2]
    assert np.nanmax(np.abs(ground[dense] - Z0)) < 0.05
    slope = np.array([tt['slope_deg'] for tt in np.array(tiles)[dense]], float)
    assert np.nanmax(slope) < 1.0


def test_a_bad_survey_file_exits_with_one_line(tmp_path):
    bad = tmp_path / 'broken.laz'
    bad.write_bytes(b'LASF' + b'\0' * 50)
    proc = subprocess.run([sys.executable, '-m', 'landing_zone', 'replay', str(bad), '--out',
                           str(tmp_path / 'a.mcap'), '--report', str(tmp_path / 'r.json')],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(lines) == 1 and 'cannot read survey' in lines[0], lines
    assert 'Traceback' not in proc.stderr


AUTZEN = Path(__file__).resolve().parent / 'data' / 'autzen_trim.laz'


def test_the_real_autzen_sample_replays_at_its_georeferenced_position():
    # a real airborne survey: one flight line, feet, no trajectory (derived)
    s = read_survey(AUTZEN)
    assert s.metres_per_unit == pytest.approx(0.3048)
    assert len(s.points) == 110_000
    ground = np.median(s.points[:, 2])
    v = np.diff(s.traj_xyz[:, :2], axis=0) / np.diff(s.traj_times)[:, None]
    # a survey aircraft: hundreds of metres up, tens of metres per second
    assert 300 < s.traj_xyz[0, 2] - ground < 1000
    assert 30 < np.median(np.hypot(v[:, 0], v[:, 1])) < 100
    from landing_zone.replay import replay

    centre = (636_581.0, 849_212.0)  # in the file's feet
    res = replay(AUTZEN, center=centre, progress=False)
    a = res.assessment
    geo = res.survey['origin'][0] + a.centers[:, 0] / 0.3048
    assert geo.min() < centre[0] < geo.max()
    # about two returns per square metre: far too sparse for the network, every tile unknown
    assert len(a) == 400 and not a.known.any() and not a.sites


def test_an_sbet_trajectory_is_projected_into_the_files_crs(tmp_path):
    pyproj = pytest.importorskip('pyproj')
    xyz, t, angle, _ = flight_line(seconds=0.05, lines_hz=200.0, pulses=50)
    header = laspy.LasHeader(point_format=3, version='1.4')
    header.add_crs(pyproj.CRS.from_epsg(32633))  # UTM 33N: E0, N0 lie in it
    header.offsets = np.floor(xyz.min(axis=0))
    header.scales = np.array([0.001, 0.001, 0.001])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.gps_time = t
    path = tmp_path / 'utm.las'
    las.write(str(path))
    # the true track as an SBET: 17 float64 per record, latitude / longitude in radians
    ts = np.linspace(t.min(), t.max(), 12)
    east = E0 + SPEED * (ts - 300_000.0)
    to_geo = pyproj.Transformer.from_crs('EPSG:32633', 'EPSG:4979', always_xy=True)
    lon, lat, alt = to_geo.transform(east, np.full(12, N0), np.full(12, Z0 + HEIGHT))
    rec = np.zeros((12, 17))
    rec[:, 0], rec[:, 1], rec[:, 2], rec[:, 3] = ts, np.radians(lat), np.radians(lon), alt
    sbet = tmp_path / 'track.sbet'
    rec.astype('<f8').tofile(sbet)
    s = read_survey(path, trajectory=sbet)
    want = np.column_stack([east, np.full(12, N0), np.full(12, Z0 + HEIGHT)])
    np.testing.assert_allclose(s.traj_xyz + s.origin, want, atol=0.01)
    (tmp_path / 'short.sbet').write_bytes(b'\0' * 100)
    with pytest.raises(BagError, match='not an SBET'):
        read_survey(path, trajectory=tmp_path / 'short.sbet')
