"""OpenSfM reconstruction.json + tracks.csv + ground_control_points.json (the real Berlin
example), the documented projection as reference, import -> adjust -> export, errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from lidarcat.survey import adjust_survey
from lidarcat.errors import FormatError
from lidarcat.interop.block import block_from_survey, reprojection_residuals_px, write_survey
from lidarcat.interop.opensfm import read_opensfm, read_opensfm_gcp, write_opensfm

D = Path(__file__).parents[1] / "data" / "interop" / "opensfm"
REC = D / "berlin_reconstruction_example.json"
TRACKS = D / "berlin_tracks_example.csv"


def _opensfm_residuals_px(rec_path: Path, tracks_path: Path) -> dict[tuple[str, str], np.ndarray]:
    """OpenSfM's projected minus observed image point, in pixels (normalised x max(w, h)),
    written from doc/source/geometry.rst (perspective and brown)."""
    rec = json.loads(rec_path.read_text())[0]
    out: dict[tuple[str, str], np.ndarray] = {}
    for line in tracks_path.read_text().splitlines()[1:]:
        f = line.split("\t")
        im, tr = f[0], f[1]
        if im not in rec["shots"] or tr not in rec["points"]:
            continue
        sh = rec["shots"][im]
        cam = rec["cameras"][sh["camera"]]
        p = Rotation.from_rotvec(sh["rotation"]).as_matrix() @ np.array(rec["points"][tr]["coordinates"]) \
            + sh["translation"]
        x, y = p[0] / p[2], p[1] / p[2]
        r2 = x * x + y * y
        if cam["projection_type"] == "perspective":
            proj = cam["focal"] * (1 + cam["k1"] * r2 + cam["k2"] * r2 * r2) * np.array([x, y])
        else:
            rad = 1 + cam["k1"] * r2 + cam["k2"] * r2**2 + cam["k3"] * r2**3
            xd = x * rad + 2 * cam["p1"] * x * y + cam["p2"] * (r2 + 2 * x * x)
            yd = y * rad + cam["p1"] * (r2 + 2 * y * y) + 2 * cam["p2"] * x * y
            proj = np.array([cam["focal_x"] * xd + cam["c_x"], cam["focal_y"] * yd + cam["c_y"]])
        out.setdefault((im, tr), (proj - [float(f[3]), float(f[4])]) * max(cam["width"], cam["height"]))
    return out


def _mine(block) -> dict[tuple[str, str], np.ndarray]:
    return {(a, b): v for a, b, v in zip(block.obs_photo.tolist(), block.obs_point.tolist(),
                                         reprojection_residuals_px(block))}


def test_read_berlin():
    b = read_opensfm(REC, TRACKS)
    assert sorted(b.photo_ids.tolist()) == ["01.jpg", "02.jpg", "03.jpg"]
    assert len(b.point_ids) == 1430
    cam = next(iter(b.cameras.values()))
    assert (cam.columns_px, cam.rows_px) == (3264, 2448)
    assert cam.focal_length_mm == pytest.approx(0.8696658484855359 * 3264 * 0.001, rel=1e-15)
    assert b.height_system == "ellipsoidal" and "+lat_0=52.51896296296295" in b.crs


def test_model_reprojects_as_opensfm():
    ref = _opensfm_residuals_px(REC, TRACKS)
    mine = _mine(read_opensfm(REC, TRACKS))
    assert set(mine) == set(ref) and len(ref) == 3082
    assert max(np.abs(mine[k] - ref[k]).max() for k in ref) < 1e-6
    assert 0.5 < np.sqrt(np.mean(np.array(list(ref.values())) ** 2)) < 5.0


def test_import_adjust_export_same_residuals(tmp_path):
    write_survey(read_opensfm(REC, TRACKS), tmp_path / "s", control_sd_m=0.05)
    # the round trip is the subject, not blunder detection: data snooping ('report' keeps every
    # observation, so the adjusted block is the same) and the covariance blocks are not checked here
    res, out = adjust_survey(tmp_path / "s", outdir=tmp_path / "adj", snooping="off", precision="none")
    assert res.success
    adjusted = block_from_survey(tmp_path / "s", out)
    assert adjusted.source_models  # the perspective k1, k2 model survives the survey folder
    write_opensfm(adjusted, tmp_path / "exp")
    ref = _opensfm_residuals_px(tmp_path / "exp" / "reconstruction.json", tmp_path / "exp" / "tracks.csv")
    mine = _mine(adjusted)
    assert set(ref) == set(mine)
    assert max(np.abs(mine[k] - ref[k]).max() for k in ref) < 1e-6
    cam = json.loads((tmp_path / "exp" / "reconstruction.json").read_text())[0]["cameras"]
    assert next(iter(cam.values()))["projection_type"] == "perspective"


def test_ground_control_points_json():
    b = read_opensfm(REC, TRACKS)
    g = read_opensfm_gcp(D / "berlin_ground_control_points.json", b)
    assert g.point.tolist() == ["gcp0", "gcp1", "gcp3"]
    assert np.isnan(g.enh_m[1]).all()  # GCP '1' has no world position
    assert len(g.obs_point) == 5
    # OpenSfM's topocentric_from_lla, written out: ECEF difference rotated to ENU at reference_lla
    lat0, lon0 = np.radians([52.51896296296295, 13.400376851851851])
    ecef = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x0 = np.array(ecef.transform(13.400376851851851, 52.51896296296295, 0.0))
    x1 = np.array(ecef.transform(13.400703631118825, 52.51926834404209, 14.946108041331172))
    enu = np.array([[-np.sin(lon0), np.cos(lon0), 0],
                    [-np.sin(lat0) * np.cos(lon0), -np.sin(lat0) * np.sin(lon0), np.cos(lat0)],
                    [np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)]]) @ (x1 - x0)
    np.testing.assert_allclose(g.enh_m[0], enu, rtol=0, atol=1e-6)
    # normalised (-0.015689, -0.0625362) on 02.jpg -> pixel centre origin
    np.testing.assert_allclose(g.obs_px[0], [-0.015689 * 3264 + 3263 / 2, -0.0625362 * 3264 + 2447 / 2], atol=1e-9)


@pytest.mark.parametrize("edit,expect", [
    (lambda r: r[0]["cameras"][next(iter(r[0]["cameras"]))].update(projection_type="spherical"),
     "field 'projection_type': camera 'v2 apple iphone4,1 3264 2448 perspective 0.9722': projection 'spherical' is not "
     "supported (supported: perspective, brown, fisheye, fisheye_opencv)"),
    (lambda r: r[0]["cameras"][next(iter(r[0]["cameras"]))].update(projection_type="fisheye", focal=0.19, k1=0.0, k2=0.0),
     "camera 'v2 apple iphone4,1 3264 2448 perspective 0.9722': field 'fx': the image corner (-0.5, -0.5) px lies "
     "beyond 180 deg from the optical axis"),
    (lambda r: r[0]["shots"]["03.jpg"].update(rotation=[1.0, "a", 0.0]),
     "field 'rotation': 'a' is not a finite number (03.jpg)"),
    (lambda r: r[0]["shots"]["01.jpg"].update(translation=[1.0, 2.0]),
     "field 'translation': expected a list of 3 numbers (01.jpg)"),
    (lambda r: r[0]["shots"]["01.jpg"].update(camera="nope"),
     "field 'camera': shot '01.jpg': camera 'nope' is not defined"),
])
def test_located_errors(tmp_path, edit, expect):
    rec = json.loads(REC.read_text())
    edit(rec)
    p = tmp_path / "r.json"
    p.write_text(json.dumps(rec, indent=4))
    with pytest.raises(FormatError) as ei:
        read_opensfm(p, TRACKS)
    msg = str(ei.value)
    assert msg.startswith(f"{p}:") and expect in msg


def test_invalid_json_and_tracks(tmp_path):
    p = tmp_path / "r.json"
    p.write_text('[{"cameras": {}\n "shots": {}}]')
    with pytest.raises(FormatError, match=r"r.json:2: invalid JSON: Expecting ',' delimiter"):
        read_opensfm(p)
    t = shutil.copy(TRACKS, tmp_path / "tracks.csv")
    lines = Path(t).read_text().splitlines()
    lines[2] = lines[2].replace("\t-0.150952\t", "\tx\t")
    Path(t).write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError, match=r"tracks.csv:3: field 'x': 'x' is not a number"):
        read_opensfm(REC, t)


def test_dataset_config(tmp_path):
    from lidarcat.interop.opensfm import gcp_sd_from_config, read_opensfm_config

    cfg = read_opensfm_config(D / "berlin_config.yaml")
    assert cfg == {"processes": 8, "depthmap_min_consistent_views": 2, "depthmap_save_debug_files": False,
                   "feature_process_size": 1024, "bundle_use_gcp": True}
    assert gcp_sd_from_config(cfg, 0.05) == (0.05, 0.05, 0.05)
    assert gcp_sd_from_config({"gcp_horizontal_sd": 0.02, "gcp_vertical_sd": 0.1}, 0.05) == (0.02, 0.02, 0.1)
    p = tmp_path / "config.yaml"
    p.write_text("processes: 8\nbundle_use_gcp yes\n")
    with pytest.raises(FormatError, match=r"config.yaml:2: 'bundle_use_gcp yes' is no 'key: value' line"):
        read_opensfm_config(p)
    p.write_text("processes: 8\n# again\nprocesses: 4\n")
    with pytest.raises(FormatError, match=r"config.yaml:3: field 'processes': given twice \(also line 1\)"):
        read_opensfm_config(p)


def test_truncated_tracks_no_measurements(tmp_path):
    """Fuzz case 958: a tracks.csv cut after the first shot measures no point on two shots: a located
    error naming the next step (the survey would have image_points.csv without measurement columns)."""
    lines = TRACKS.read_text().splitlines()
    first = lines[1].split("\t")[0]
    t = tmp_path / "tracks.csv"
    t.write_text("\n".join(ln for ln in lines if ln.split("\t")[0] in (first, lines[0])) + "\n")
    points = json.loads(REC.read_text())[0]["points"]   # parsed once (it was parsed again for every line)
    n = sum(1 for ln in lines[1:] if ln.split("\t")[0] == first and ln.split("\t")[1] in points)
    with pytest.raises(FormatError) as ei:
        read_opensfm(REC, t)
    assert str(ei.value) == (f"{t}: no measurements: no point of {REC.name} is measured on two of its shots "
                             f"({n} usable measurement(s) of 1430 points; is the file truncated?); write "
                             f"tracks.csv again with OpenSfM, or remove it to import the orientations only")
