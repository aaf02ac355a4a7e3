"""Trajectories (SBET, CSV) and the system calibration from LAS points + trajectory by GPS time."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.errors import LidarFormatError, ProductError
from lidarcat.lidar import PointCloud, write_points
from lidarcat.lidar.trajectory import (
    Trajectory,
    aviation_to_map,
    map_to_aviation,
    match_time_base,
    read_sbet,
    read_trajectory,
    write_sbet,
)
from lidarcat.production.lidarcalib import _ins, georeference, pulses_from_points
from lidarcat.stages.lidar import system_calibration
from lidarcat.synthetic.strips import synthetic_strips

OFFSET = np.array([680000.0, 7480000.0, 0.0])   # SIRGAS 2000 / UTM 23S, near Itaocara
CRS = "EPSG:31983"
WEEK = 2000


def test_aviation_angles_to_the_map_frame_match_the_ned_rotation():
    from scipy.spatial.transform import Rotation

    yaw, pitch, roll = 0.7, 0.1, -0.2
    ned = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    swap, flip = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]]), np.diag([1.0, -1.0, -1.0])
    ours = _ins(aviation_to_map([roll], [pitch], [yaw]))[0]
    np.testing.assert_allclose(ours, swap @ ned @ flip, atol=1e-15)
    r, p, h = map_to_aviation(aviation_to_map([roll], [pitch], [yaw]))
    np.testing.assert_allclose([r[0], p[0], h[0]], [roll, pitch, yaw], atol=1e-15)


@pytest.fixture(scope="module")
def strips():
    return synthetic_strips(1, spacing_m=3.0)


def _traj(s) -> Trajectory:
    t = s.trajectory
    return Trajectory(t.time_s, t.position_m + OFFSET, t.attitude_rad, crs=CRS)


def test_sbet_round_trip_through_wgs84(tmp_path, strips):
    tr = _traj(strips)
    path = write_sbet(tmp_path / "sbet.out", tr)
    assert path.stat().st_size == len(tr) * 17 * 8
    back = read_sbet(path, CRS)
    np.testing.assert_allclose(back.position_m, tr.position_m, atol=1e-6)
    da = np.angle(np.exp(1j * (back.attitude_rad - tr.attitude_rad)))
    assert np.abs(da).max() < 1e-8
    # the heading in the file is true, not grid: at E 680 km in zone 23S the meridian convergence is ~0.5 deg
    rec = np.fromfile(path, dtype="<f8").reshape(-1, 17)
    grid = map_to_aviation(tr.attitude_rad)[2]
    conv = np.degrees(np.angle(np.exp(1j * (rec[:, 9] - grid))))
    assert 0.3 < np.abs(conv).min() and np.abs(conv).max() < 0.8


def test_sbet_of_a_wrong_size_is_refused(tmp_path):
    p = tmp_path / "bad.out"
    p.write_bytes(b"\0" * 140)
    with pytest.raises(LidarFormatError, match=r"bad.out: 140 bytes is not a whole number of 136-byte SBET"):
        read_sbet(p, CRS)


def test_csv_trajectory_and_times_outside(tmp_path):
    p = tmp_path / "traj.csv"
    p.write_text("time,E,N,H,roll_deg,pitch_deg,heading_deg\n"
                 "10,0,0,600,0,0,90\n11,60,0,600,1,2,90\n12,120,0,600,0,0,90\n", encoding="utf-8")
    tr = read_trajectory(p)
    pos, att = tr.at(np.array([10.5, 12.0]))
    np.testing.assert_allclose(pos, [[30, 0, 600], [120, 0, 600]])
    # heading 90 (east, clockwise from north) is k = 0; pitch nose-up 1 deg is p = -1 deg
    np.testing.assert_allclose(np.degrees(att[0]), [0.5, -1.0, 0.0], atol=1e-12)
    # a time rounded 1e-10 s past the last record (adjusted standard time -> week seconds) takes its pose
    pos, _ = tr.at(np.array([12.0 + 1e-10, 10.0 - 1e-10]))
    np.testing.assert_allclose(pos, [[120, 0, 600], [0, 0, 600]], atol=1e-12)
    with pytest.raises(ProductError, match=r"point 1: GPS time 12.000002 s is outside the trajectory"):
        tr.at(np.array([12.0 + 2e-6]))
    with pytest.raises(ProductError, match=r"point 2: GPS time 12.500000 s is outside the trajectory .*traj.csv"):
        tr.at(np.array([11.0, 12.5]))
    p.write_text("time,E,N,H,roll_deg,pitch_deg,heading_deg\n10,0,0,600,0,0,90\n10,1,0,600,0,0,90\n",
                 encoding="utf-8")
    with pytest.raises(ProductError, match=r"record 2: time 10.000000 s does not increase"):
        read_trajectory(p)


def test_week_seconds_from_adjusted_standard_time(strips):
    tr = strips.trajectory
    adj = WEEK * 604800 + strips.gps_time_s[:100] - 1e9
    t, note = match_time_base(adj, tr)
    np.testing.assert_allclose(t, strips.gps_time_s[:100], atol=1e-6)
    assert "adjusted standard" in note


def test_pulses_rebuilt_from_points_and_trajectory_are_exact(strips):
    raw = georeference(strips.pulses)
    g, a = strips.trajectory.at(strips.gps_time_s)
    p, along = pulses_from_points(raw, g, a, strips.pulses.strip)
    np.testing.assert_allclose(p.range_m, strips.pulses.range_m, atol=1e-9)
    np.testing.assert_allclose(p.scan_rad, strips.pulses.scan_rad, atol=1e-12)
    assert np.abs(along).max() < 1e-12


def _write_survey(tmp: Path, s, *, csv_traj: bool = False) -> tuple[Path, Path, Path]:
    raw = georeference(s.pulses) + OFFSET
    adj = WEEK * 604800 + s.gps_time_s - 1e9          # LAS adjusted standard GPS time
    las = tmp / "strips.las"
    write_points(las, PointCloud(raw, {"gps_time": adj, "point_source_id": s.pulses.strip + 1}, crs=CRS))
    tr = _traj(s)
    if csv_traj:
        traj = tmp / "traj.csv"
        r, p, h = map_to_aviation(tr.attitude_rad)
        rows = ["time,E,N,H,roll_deg,pitch_deg,heading_deg"] + [
            ",".join(repr(float(v)) for v in (t, e, n, z, a, b, c)) for t, (e, n, z), a, b, c in
            zip(tr.time_s, tr.position_m, np.degrees(r), np.degrees(p), np.degrees(h))]
        traj.write_text("\n".join(rows) + "\n", encoding="utf-8")
    else:
        traj = write_sbet(tmp / "sbet.out", tr)
    ctrl = tmp / "runway.csv"
    c = s.control_m + OFFSET
    ctrl.write_text("id,E,N,H\n" + "".join(f"r{i},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in enumerate(c)),
                    encoding="utf-8")
    return las, traj, ctrl


@pytest.mark.parametrize("csv_traj", [False, True])
def test_calibration_from_las_and_trajectory_recovers_the_truth(tmp_path, strips, csv_traj):
    las, traj, ctrl = _write_survey(tmp_path, strips, csv_traj=csv_traj)
    rep = system_calibration([las], traj, tmp_path / "calib.json", control=ctrl, stride=2)
    assert json.loads((tmp_path / "calib.json").read_text())["flight_lines"] == [1, 2, 3, 4]
    assert "adjusted standard" in rep["time_base"]
    est, sd = rep["calibration"]["parameters"], rep["calibration"]["sd"]
    for name, true in vars(strips.truth).items():
        assert abs(est[name] - true) < 3 * sd[name], (name, est[name], true, sd[name])
    # the 1 mm LAS quantisation is the only along-track angle left
    assert rep["along_track_rms_deg"] < 1e-3


def test_calibration_cli_and_missing_gps_time(tmp_path, strips):
    from lidarcat.cli.main import cli

    las, traj, ctrl = _write_survey(tmp_path, strips)
    res = CliRunner().invoke(cli, ["lidar", "calibrate", str(las), "--trajectory", str(traj), "--control",
                                   str(ctrl), "--stride", "4", "-o", str(tmp_path / "c.json"), "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.output)
    assert abs(rep["parameters_deg"]["roll_deg"] - 0.05) < 3 * rep["sd_deg"]["roll_deg"]
    bare = tmp_path / "bare.las"
    write_points(bare, PointCloud(georeference(strips.pulses)[:100] + OFFSET, {}, crs=CRS))
    with pytest.raises(ProductError, match=r"bare.las: the points carry no gps_time"):
        system_calibration([bare], traj, tmp_path / "x.json")
    assert not (tmp_path / "x.json").exists()
    assert math.isfinite(rep["calibration"]["sigma0"])
