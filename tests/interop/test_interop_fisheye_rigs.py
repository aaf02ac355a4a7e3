"""Issue 27: fisheye cameras carried exactly through import and export, and rigs imported and exported.

Truth: pycolmap's own projection (``Camera.img_from_cam``) of the synthetic and of the real T265 models;
the Metashape manual's fisheye formula written out here; the rig poses pycolmap composes.
"""

from __future__ import annotations

import json
import logging
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.errors import FormatError
from lidarcat.interop.block import block_from_survey, reprojection_residuals_px, write_survey
from lidarcat.interop.cameras import ideal_observations, pinhole_camera, project_corner_px, source_rays
from lidarcat.interop.colmap import read_colmap, write_colmap
from lidarcat.interop.colmap_binary import read_colmap_binary
from lidarcat.interop.metashape import read_metashape
from lidarcat.interop.opensfm import read_opensfm, write_opensfm
from lidarcat.interop.rigs import geometry_rig

pycolmap = pytest.importorskip("pycolmap")

D = Path(__file__).parent.parent / "data" / "interop"
T265 = D / "colmap" / "t265_points"
CHUNK = D / "metashape" / "easyidp_wheat_tanashi_chunk.doc.xml"
FRAME = D / "metashape" / "easyidp_wheat_tanashi_frame.doc.xml"

FISHEYES = [
    ("OPENCV_FISHEYE", (450.0, 451.0, 512.0, 384.0, 0.02, -0.01, 0.003, -0.0005)),
    ("RADIAL_FISHEYE", (450.0, 512.0, 384.0, 0.02, -0.01)),
    ("SIMPLE_RADIAL_FISHEYE", (450.0, 512.0, 384.0, 0.02)),
]


def _synthetic(tmp_path, model, params, rigs=1, cams=1):
    o = pycolmap.SyntheticDatasetOptions()
    o.num_rigs, o.num_cameras_per_rig, o.num_frames_per_rig, o.num_points3D = rigs, cams, 3, 60
    o.camera_model_id = getattr(pycolmap.CameraModelId, model)
    o.camera_params = list(params)
    rec = pycolmap.synthesize_dataset(o)
    for sub in ("t", "b"):
        (tmp_path / sub).mkdir()
    rec.write_text(str(tmp_path / "t"))
    rec.write_binary(str(tmp_path / "b"))
    return tmp_path / "t", tmp_path / "b", rec


def _pycolmap_residuals(folder):
    """Largest |pycolmap projection - 2D point| over every observation of a COLMAP model, px."""
    rec = pycolmap.Reconstruction(str(folder))
    worst = 0.0
    for img in rec.images.values():
        cam = rec.cameras[img.camera_id]
        for p2 in img.points2D:
            if p2.has_point3D():
                x = img.cam_from_world() * rec.points3D[p2.point3D_id].xyz
                worst = max(worst, float(np.abs(np.asarray(cam.img_from_cam(x)) - p2.xy).max()))
    return worst, rec


#: COLMAP 3.12's distortion-free fisheyes, written back as the models older COLMAP reads, zeros added
PLAIN_FISHEYES = [
    ("SIMPLE_FISHEYE", (450.0, 512.0, 384.0), "SIMPLE_RADIAL_FISHEYE", [450.0, 512.0, 384.0, 0.0]),
    ("FISHEYE", (450.0, 451.0, 512.0, 384.0), "OPENCV_FISHEYE", [450.0, 451.0, 512.0, 384.0, 0.0, 0.0, 0.0, 0.0]),
]


@pytest.mark.parametrize("model,params,out_model,out_params",
                         [(m, p, m, list(p)) for m, p in FISHEYES] + PLAIN_FISHEYES)
def test_colmap_fisheye_import_export_keeps_pycolmap_projection(tmp_path, model, params, out_model, out_params):
    t, b, rec = _synthetic(tmp_path, model, params)
    blk = read_colmap(t, name="m")
    assert blk.source_models["1"]["kind"] == "fisheye"
    np.testing.assert_array_equal(read_colmap_binary(b, name="m").obs_mm, blk.obs_mm)
    assert len(blk.obs_point) == rec.compute_num_observations()
    # the ideal observations are pycolmap's rays on the image plane: the pinhole residual is rounding
    assert np.abs(reprojection_residuals_px(blk)).max() < 1e-9
    write_colmap(blk, tmp_path / "out")
    line = next(ln for ln in (tmp_path / "out" / "cameras.txt").read_text().splitlines() if ln[:1] == "1")
    assert line.split()[1] == out_model and [float(v) for v in line.split()[4:]] == out_params
    worst, back = _pycolmap_residuals(tmp_path / "out")
    assert worst <= 1e-6
    assert back.cameras[1].params.tolist() == out_params


def test_opensfm_fisheye_round_trip_is_pycolmaps_projection(tmp_path):
    t, _, _ = _synthetic(tmp_path, *FISHEYES[0])
    write_opensfm(read_colmap(t), tmp_path / "osfm")
    cam = json.loads((tmp_path / "osfm" / "reconstruction.json").read_text())[0]["cameras"]["1"]
    assert cam["projection_type"] == "fisheye_opencv" and cam["focal_x"] == 450.0 / 1024
    osfm = read_opensfm(tmp_path / "osfm" / "reconstruction.json")
    assert osfm.source_models["1"]["kind"] == "fisheye"
    write_colmap(osfm, tmp_path / "back")
    worst, back = _pycolmap_residuals(tmp_path / "back")
    assert worst <= 1e-6 and back.cameras[1].params.tolist() == list(FISHEYES[0][1])
    # OpenSfM's one-focal "fisheye" (centred, k1, k2) is RADIAL_FISHEYE
    rec = json.loads((tmp_path / "osfm" / "reconstruction.json").read_text())
    rec[0]["cameras"]["1"] = {"projection_type": "fisheye", "width": 1024, "height": 768, "focal": 0.45,
                              "k1": 0.02, "k2": -0.01}
    (tmp_path / "osfm" / "reconstruction.json").write_text(json.dumps(rec))
    m = read_opensfm(tmp_path / "osfm" / "reconstruction.json").source_models["1"]
    assert (m["fx"], m["cx"], m["cy"], m["dist"]) == (0.45 * 1024, 512.0, 384.0, {"k1": 0.02, "k2": -0.01})


def _metashape_fisheye_manual(xyz, f, cx, cy, b1, b2, k, p, w, h):
    """The Metashape manual's fisheye (Appendix C), written out independently."""
    x0, y0 = xyz[:, 0] / xyz[:, 2], xyz[:, 1] / xyz[:, 2]
    r0 = np.hypot(x0, y0)
    x, y = x0 * np.arctan(r0) / r0, y0 * np.arctan(r0) / r0
    r = np.hypot(x, y)
    rad = 1 + k[0] * r**2 + k[1] * r**4 + k[2] * r**6 + k[3] * r**8
    xd = x * rad + p[0] * (r**2 + 2 * x**2) + 2 * p[1] * x * y
    yd = y * rad + p[1] * (r**2 + 2 * y**2) + 2 * p[0] * x * y
    return np.column_stack([w * 0.5 + cx + xd * f + xd * b1 + yd * b2, h * 0.5 + cy + yd * f])


def test_metashape_fisheye_is_the_manuals_formula(tmp_path):
    p = tmp_path / "chunk.xml"
    text = CHUNK.read_text().replace('label="FC550, DJI MFT 15mm F1.7 ASPH (15mm)" type="frame"',
                                     'label="FC550, DJI MFT 15mm F1.7 ASPH (15mm)" type="fisheye"', 1)
    p.write_text(text.replace("<f>4785.3046873759595</f>", "<f>1800.0</f>", 1))
    blk = read_metashape(p, FRAME)
    m = blk.source_models["0"]
    assert m["kind"] == "metashape_fisheye" and m["fx"] == m["fy"] == 1800.0
    rng = np.random.default_rng(1)
    xyz = np.column_stack([rng.uniform(-1.2, 1.2, (200, 2)), np.ones(200)])
    d = m["dist"]
    want = _metashape_fisheye_manual(xyz, 1800.0, m["cx"] - 2304, m["cy"] - 1728, 0.0, 0.0,
                                     [d["k1"], d["k2"], d["k3"], d["k4"]], [d["p1"], d["p2"]], 4608, 3456)
    np.testing.assert_allclose(project_corner_px(xyz, m, "0"), want, atol=1e-9, rtol=0)
    rays = source_rays(want, m, "0")                           # and back: the rays, to 1e-9
    np.testing.assert_allclose(rays, xyz / np.linalg.norm(xyz, axis=1)[:, None], atol=1e-9, rtol=0)
    assert np.isfinite(blk.obs_mm).all() and len(blk.obs_mm) == len(read_metashape(CHUNK, FRAME).obs_mm)
    out = tmp_path / "col"
    write_colmap(blk, out)  # tangential terms: fitted as OPENCV_FISHEYE, the misfit noted
    assert re.search(r"# camera 0: distortion model converted to fisheye \(Kannala-Brandt\) by a least-squares "
                     r"fit over a 41x31 pixel grid, largest misfit [0-9.e-]+ px", (out / "cameras.txt").read_text())


def test_rays_beyond_89_deg_are_skipped_with_count_and_reason(caplog):
    cam, m = pinhole_camera("f", 250.0, 250.0, 512.0, 384.0, 1024, 768, pixel_size_mm=None, model="m", source="s",
                            dist={"k1": 0.01}, kind="fisheye")
    ang = np.radians([10.0, 60.0, 84.0, 95.0, 120.0])
    rays = np.column_stack([np.sin(ang), np.zeros(5), np.cos(ang)])
    px = project_corner_px(rays, m, "f")
    with caplog.at_level(logging.WARNING):
        mm, keep, sd = ideal_observations(px, cam, m, where="cameras.txt:4")
    assert keep.tolist() == [True, True, True, False, False]
    np.testing.assert_allclose(mm[:3, 0], cam.focal_length_mm * np.tan(ang[:3]), rtol=1e-12)
    # the sd of the image-plane point: 0.75 px through d(c tan theta)/d px = c / (cos^2 theta d u/d theta)
    # along the radius, c tan(theta) / (sin(theta) d u/d theta ... ) across it (u = f theta_d(theta))
    f, k1 = 250.0, 0.01
    du = f * (1 + 3 * k1 * ang[:3] ** 2)
    np.testing.assert_allclose(sd[:3, 0], cam.focal_length_mm * 0.75 / (np.cos(ang[:3]) ** 2 * du), rtol=1e-6)
    rho = f * ang[:3] * (1 + k1 * ang[:3] ** 2)                 # the pixel's distance from the centre
    np.testing.assert_allclose(sd[:3, 1], cam.focal_length_mm * 0.75 * np.tan(ang[:3]) / rho, rtol=1e-6)
    assert np.isnan(sd[3:]).all()
    assert ("cameras.txt:4: camera 'f': 2 observation(s) skipped: their rays lie 95-120 deg from the optical axis, "
            "beyond the 85 deg an image-plane (pinhole) observation of lidarcat's bundle can hold") in caplog.text


@pytest.mark.parametrize("params,field,msg", [
    ("180.0 180.0 424.0 400.0 0 0 0 0", "fx",
     "the image corner (-0.5, -0.5) px lies beyond 180 deg from the optical axis"),
    ("284.5 285.5 424.4 393.7 0.0008 0.031 -0.6 0.005", "k3", "the fisheye polynomial folds over at"),
])
def test_fisheye_out_of_range_is_a_located_error(tmp_path, params, field, msg):
    d = shutil.copytree(T265, tmp_path / "m")
    lines = (d / "cameras.txt").read_text().splitlines()
    lines[3] = f"1 OPENCV_FISHEYE 848 800 {params}"
    (d / "cameras.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError) as ei:
        read_colmap(d)
    assert str(ei.value).startswith(f"{d / 'cameras.txt'}:4: camera '1': field '{field}': {msg}")


def test_colmap_rigs_text_binary_survey_and_export(tmp_path):
    t, b, rec = _synthetic(tmp_path, "OPENCV", (1280.0, 1270.0, 512.0, 384.0, 0.05, -0.01, 1e-3, -5e-4), rigs=2, cams=2)
    blk = read_colmap(t)
    assert blk.rigs == read_colmap_binary(b).rigs
    assert [len(r.sensors) for r in blk.rigs.rigs] == [2, 2] and len(blk.rigs.exposures) == 6
    write_survey(blk, tmp_path / "s", control_sd_m=0.01)
    back = block_from_survey(tmp_path / "s")
    assert back.rigs == blk.rigs
    rig = geometry_rig(back, "1")                              # the bundle's form: the pose pycolmap holds
    want = rec.rig(1).sensor_from_rig(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, 2)).matrix()
    np.testing.assert_allclose(rig.rotation[1], want[:, :3], atol=1e-12)
    np.testing.assert_allclose(rig.translation_m[1], want[:, 3], atol=1e-12)
    write_colmap(back, tmp_path / "out")
    out = pycolmap.Reconstruction(str(tmp_path / "out"))
    assert out.num_rigs() == 2 and out.num_frames() == 6
    for img in rec.images.values():
        got = next(i for i in out.images.values() if i.name == img.name)
        np.testing.assert_allclose(got.cam_from_world().matrix(), img.cam_from_world().matrix(), atol=1e-9)
        fr = out.frame(got.frame_id)
        np.testing.assert_allclose(
            (out.rig(fr.rig_id).sensor_from_rig(got.data_id.sensor_id) * fr.rig_from_world
             if got.data_id.sensor_id != out.rig(fr.rig_id).ref_sensor_id else fr.rig_from_world).matrix(),
            img.cam_from_world().matrix(), atol=1e-9)


def test_colmap_frame_of_another_camera_is_a_located_error(tmp_path):
    t, _, _ = _synthetic(tmp_path, "SIMPLE_RADIAL", (1280.0, 512.0, 384.0, 0.05), rigs=2, cams=2)
    lines = (t / "frames.txt").read_text().splitlines()
    no = next(k for k, ln in enumerate(lines) if ln.startswith("1 1 "))
    lines[no] = lines[no].replace(" CAMERA 2 2", " CAMERA 2 7")   # image 7 is of camera 3
    (t / "frames.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError) as ei:
        read_colmap(t)
    assert str(ei.value) == (f"{t / 'frames.txt'}:{no + 1}: field 'DATA_ID': frame 1: image 7 "
                             f"('camera000003_frame000000.png') is of camera 3, not of the rig's sensor camera 2")


def test_opensfm_rigs_round_trip_and_a_size_disagreement(tmp_path):
    t, _, _ = _synthetic(tmp_path, "OPENCV", (1280.0, 1270.0, 512.0, 384.0, 0.05, -0.01, 1e-3, -5e-4), rigs=1, cams=2)
    blk = read_colmap(t)
    write_opensfm(blk, tmp_path / "o")
    rec = json.loads((tmp_path / "o" / "reconstruction.json").read_text())
    assert set(rec[0]["rig_cameras"]) == {"1", "2"} and len(rec[0]["rig_instances"]) == 3
    back = read_opensfm(tmp_path / "o" / "reconstruction.json")
    s1 = blk.rigs.rigs[0].sensor("2").sensor_from_rig
    s2 = back.rigs.rigs[0].sensor("2").sensor_from_rig
    np.testing.assert_allclose(np.abs(s2[:4]), np.abs(s1[:4]), atol=1e-12)
    np.testing.assert_allclose(s2[4:], s1[4:], atol=1e-12)
    assert sorted(sorted(e.photos) for e in back.rigs.exposures) == sorted(sorted(e.photos) for e in blk.rigs.exposures)
    cams = rec[0]["cameras"]
    cams["2"]["width"] = 1000                                     # camera 2 is no longer the size of camera 1
    shot = next(s for s, v in rec[0]["shots"].items() if v["camera"] == "2")
    inst = next(i for i, v in rec[0]["rig_instances"].items() if shot in v["rig_camera_ids"])
    rec[0]["rig_instances"][inst]["rig_camera_ids"][shot] = "1"   # ... and one of its shots is rig camera 1's
    (tmp_path / "o" / "reconstruction.json").write_text(json.dumps(rec))
    with pytest.raises(FormatError, match=re.escape(f"rig instance {inst!r}: shot {shot!r} of rig camera '1' is "
                                                    f"1000 x 768 px (camera '2'), the rig camera's other shots "
                                                    f"1024 x 768 px (camera '1'): the rig's cameras disagree in size")):
        read_opensfm(tmp_path / "o" / "reconstruction.json")


def test_real_t265_fisheye_model_imported_adjusted_exported(tmp_path):
    """kapture's real T265 cameras and poses (tests/data/README.md), pycolmap-projected pixels."""
    s, adj, out = tmp_path / "s", tmp_path / "adj", tmp_path / "out"
    run = CliRunner().invoke
    res = run(cli, ["import", "colmap", str(T265), "-o", str(s), "--control-sd-m", "0.001"])
    assert res.exit_code == 0, res.output
    assert json.loads((s / "source_cameras.json").read_text())["2"]["kind"] == "fisheye"
    # the adjustment starts 5 cm and 0.5 deg away from the poses it has to find again
    lines = (s / "photos.csv").read_text().splitlines()
    head = lines[0].split(",")
    rng = np.random.default_rng(7)
    for k in range(1, len(lines)):
        cells = lines[k].split(",")
        for c in ("X0", "Y0", "Z0"):
            cells[head.index(c)] = repr(float(cells[head.index(c)]) + float(rng.choice([-0.05, 0.05])))
        for c in ("omega_deg", "phi_deg", "kappa_deg"):
            cells[head.index(c)] = repr(float(cells[head.index(c)]) + float(rng.choice([-0.5, 0.5])))
        lines[k] = ",".join(cells)
    (s / "photos.csv").write_text("\n".join(lines) + "\n")
    res = run(cli, ["adjust", str(s), "-o", str(adj)])
    # exact pixels: the variance factor is ~0 and the global test says so (exit 3), the results are written
    assert res.exit_code == 3 and "chi-square test of the variance factor REJECTED" in res.output, res.output
    res = run(cli, ["export", "colmap", str(adj), "--survey", str(s), "-o", str(out)])
    assert res.exit_code == 0, res.output
    src = [ln for ln in (T265 / "cameras.txt").read_text().splitlines() if ln[:1].isdigit()]
    got = [ln for ln in (out / "cameras.txt").read_text().splitlines() if ln[:1].isdigit()]
    assert [ln.split() for ln in got] == [ln.split() for ln in src]      # the same cameras, digit for digit
    worst, rec = _pycolmap_residuals(out)
    assert rec.num_rigs() == 1 and rec.num_frames() == 3
    # pycolmap's projection of the exported (adjusted) model is lidarcat's own, to 1e-6 px
    blk = block_from_survey(s, adj)
    ours = np.abs(reprojection_residuals_px(blk)).max()
    assert worst < 1e-3 and abs(worst - ours) <= 1e-6
    x0 = read_colmap(T265)
    assert np.abs(blk.eo[:, :3] - x0.eo[:, :3]).max() < 1e-6          # exact pixels: the poses come back
    assert np.abs(blk.eo[:, 3:] - x0.eo[:, 3:]).max() < 1e-6
    assert math.isclose(blk.cameras["1"].focal_length_mm, 2.84468)


def test_odm_cameras_json_round_trip_and_import(tmp_path):
    from lidarcat.interop.odm import read_odm_cameras, write_odm_cameras

    t, b, _ = _synthetic(tmp_path, *FISHEYES[0])
    blk = read_colmap(t)
    write_odm_cameras(blk, tmp_path / "cameras.json")
    doc = json.loads((tmp_path / "cameras.json").read_text())
    assert doc["1"]["projection_type"] == "fisheye_opencv" and doc["1"]["k4"] == -0.0005
    back = read_odm_cameras(tmp_path / "cameras.json")
    assert back["1"][1] == {**blk.source_models["1"], "opensfm": "fisheye_opencv"}
    # the CLI: a binary COLMAP folder is read as such; OpenSfM observations made ideal through ODM's cameras
    res = CliRunner().invoke(cli, ["import", "colmap", str(b), "-o", str(tmp_path / "s"), "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.output)
    assert rep["fisheye_cameras"] == ["1"] and rep["observations"] == len(blk.obs_point)
    write_opensfm(blk.with_(source_models={"1": {**blk.source_models["1"], "dist": {}}}), tmp_path / "o")
    plain = read_opensfm(tmp_path / "o" / "reconstruction.json")
    odm = read_opensfm(tmp_path / "o" / "reconstruction.json", cameras=tmp_path / "cameras.json")
    assert plain.source_models["1"]["dist"] == {"k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0}
    assert odm.source_models["1"]["dist"] == blk.source_models["1"]["dist"]
    np.testing.assert_allclose(odm.obs_mm, blk.obs_mm, atol=1e-12, rtol=0)
    doc["1"]["projection_type"] = "dual"
    (tmp_path / "bad.json").write_text(json.dumps(doc, indent=1))
    with pytest.raises(FormatError, match=re.escape(f"{tmp_path / 'bad.json'}:2: field 'projection_type': camera '1': "
                                                    f"projection 'dual' is not supported")):
        read_odm_cameras(tmp_path / "bad.json")


def test_colmap_import_skips_rays_beyond_85_deg_and_says_so(tmp_path, caplog):
    """Two images of a wide fisheye (f 250 px, 1024 x 768; the corners 147 deg from the axis), five points:
    one 95 deg from the first camera's axis (71 deg from the second's) is measured there, and that
    measurement is skipped."""
    from lidarcat.geometry.models import FisheyeCamera

    fish = FisheyeCamera("1", 1024, 768, fx=250.0, fy=250.0, cx=511.5, cy=383.5)
    ang = np.radians([0.0, 30.0, 60.0, 80.0, 95.0])
    pts = np.column_stack([5 * np.sin(ang), np.zeros(5), 5 * np.cos(ang)])
    cams = [np.zeros(3), np.array([0.5, 0.0, -2.0])]          # centres; both look along +Z
    (tmp_path / "m").mkdir()
    m = tmp_path / "m"
    (m / "cameras.txt").write_text("1 SIMPLE_RADIAL_FISHEYE 1024 768 250.0 512.0 384.0 0.0\n")
    lines, tracks = [], {k: [] for k in range(5)}
    for i, c in enumerate(cams, start=1):
        px = fish.project(pts - c) + 0.5
        lines.append(f"{i} 1 0 0 0 {-float(c[0])!r} 0 {-float(c[2])!r} 1 img{i}.png")
        lines.append(" ".join(f"{u!r} {v!r} {k + 1}" for k, (u, v) in enumerate(px.tolist())))
        for k in range(5):
            tracks[k].append((i, k))
    (m / "images.txt").write_text("\n".join(lines) + "\n")
    (m / "points3D.txt").write_text("".join(
        f"{k + 1} {x!r} {y!r} {z!r} 0 0 0 0 " + " ".join(f"{a} {b}" for a, b in tracks[k]) + "\n"
        for k, (x, y, z) in enumerate(pts.tolist())))
    with caplog.at_level(logging.WARNING):
        blk = read_colmap(m)
    assert len(blk.obs_point) == 9 and ("img1.png", "5") not in set(zip(blk.obs_photo, blk.obs_point))
    assert blk.description.endswith("; 1 observation(s) of rays beyond 85 deg from a fisheye's axis skipped")
    assert re.search(r"images\.txt: camera '1': 1 observation\(s\) skipped: their rays lie 95-95 deg from the "
                     r"optical axis", caplog.text)
    assert np.abs(reprojection_residuals_px(blk)).max() < 1e-9
    res = CliRunner().invoke(cli, ["import", "colmap", str(m), "-o", str(tmp_path / "s"), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["skipped"] == "1 observation(s) of rays beyond 85 deg from a fisheye's axis skipped"


def test_bad_fisheye_and_rig_files_are_located_errors(tmp_path):
    # a Metashape fisheye whose corners lie beyond 180 deg
    p = tmp_path / "chunk.xml"
    text = CHUNK.read_text().replace('label="FC550, DJI MFT 15mm F1.7 ASPH (15mm)" type="frame"',
                                     'label="FC550, DJI MFT 15mm F1.7 ASPH (15mm)" type="fisheye"', 1)
    p.write_text(text.replace("<f>4785.3046873759595</f>", "<f>900.0</f>", 1).replace(
        "<k3>0.021610798069009122</k3>", "", 1))
    with pytest.raises(FormatError, match=re.escape(f"{p}:16: camera '0': field 'k2': the fisheye polynomial folds "
                                                    f"over at 107.1 deg from the optical axis (theta_d stops "
                                                    f"increasing at "
                                                    f"1.472 rad) "
                                                    f"before the image corner (0, 3456) px")):
        read_metashape(p, FRAME)
    p.write_text(text.replace("<f>4785.3046873759595</f>", "<f>800.0</f>", 1).replace(
        "<k1>-0.0086161282569410177</k1>", "", 1).replace("<k2>-0.014935050703477608</k2>", "", 1).replace(
        "<k3>0.021610798069009122</k3>", "", 1))
    with pytest.raises(FormatError, match=re.escape(f"{p}:16: camera '0': field 'f': the image corner (0, 3456) px "
                                                    f"lies beyond 180 deg from the optical axis")):
        read_metashape(p, FRAME)
    # a survey's source_cameras.json and rigs.json, edited by hand
    t, _, _ = _synthetic(tmp_path, *FISHEYES[0], rigs=1, cams=2)
    write_survey(read_colmap(t), tmp_path / "s", control_sd_m=0.01)
    src = tmp_path / "s" / "source_cameras.json"
    good = json.loads(src.read_text())
    src.write_text(json.dumps({**good, "1": {**good["1"], "kind": "kannala"}}))
    with pytest.raises(FormatError, match=re.escape(f"{src}: camera '1': kind: 'kannala' is not a camera model kind "
                                                    f"(brown, metashape, fisheye, metashape_fisheye)")):
        block_from_survey(tmp_path / "s")
    src.write_text(json.dumps({**good, "1": {**good["1"], "fx": 150.0, "fy": 150.0, "dist": {}}}))
    with pytest.raises(FormatError, match=re.escape(f"{src}: camera '1': field 'fx': the image corner")):
        block_from_survey(tmp_path / "s")
    src.write_text(json.dumps(good))
    rigs = tmp_path / "s" / "rigs.json"
    doc = json.loads(rigs.read_text())
    doc["rigs"][0]["sensors"][1]["sensor_from_rig"]["q_wxyz"] = [0.1, 0, 0, 0]
    rigs.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=re.escape(f"{rigs}: rig '1': sensor '2': field 'q_wxyz': a quaternion of "
                                                    f"norm 0.1 is no rotation")):
        block_from_survey(tmp_path / "s")
    doc["rigs"][0]["sensors"][1]["sensor_from_rig"] = None
    first = doc["exposures"][0]["photos"]["1"]
    doc["exposures"][1]["photos"]["1"] = first
    rigs.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=re.escape(f"{rigs}: exposure '2': photo {first!r} is also in exposure '1'")):
        block_from_survey(tmp_path / "s")


def test_the_survey_rig_file_holds_the_rig_poses(tmp_path):
    """The rig TOML an import writes for the survey (:mod:`lidarcat.survey.rigs`: sensors are cameras, the
    sensor_from_rig rotation a rotation vector in degrees): read back, the poses pycolmap holds."""
    import tomllib
    from types import SimpleNamespace

    from lidarcat.geometry.rolling import rodrigues
    from lidarcat.interop.rigs import rigs_from_survey, survey_reads_rig_files, survey_rig_file

    t, _, rec = _synthetic(tmp_path, "OPENCV", (1280.0, 1270.0, 512.0, 384.0, 0.05, -0.01, 1e-3, -5e-4), rigs=2, cams=2)
    blk = read_colmap(t)
    text, labels = survey_rig_file(blk.rigs)
    doc = tomllib.loads(text)
    assert doc["1"]["sensors"] == ["1", "2"] and doc["2"]["sensors"] == ["3", "4"]
    want = rec.rig(1).sensor_from_rig(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, 2)).matrix()
    np.testing.assert_allclose(rodrigues(np.radians(doc["1"]["2"]["rotation_deg"]))[0], want[:, :3], atol=1e-12)
    np.testing.assert_allclose(doc["1"]["2"]["translation_m"], want[:, 3], atol=1e-12)
    assert len(labels) == 12 and len(set(labels.values())) == 6
    # and back, as a survey made by hand gives it
    (tmp_path / "rigs.toml").write_text(text)
    cam_of = dict(zip(blk.photo_ids.tolist(), blk.photo_camera.tolist()))
    fake = SimpleNamespace(files={"rigs": tmp_path / "rigs.toml"}, photos=[
        SimpleNamespace(id=p, camera=cam_of[p], rig_exposure=labels.get(p, "")) for p in blk.photo_ids.tolist()])
    back = rigs_from_survey(fake)
    for a, b in zip(back.rigs, blk.rigs.rigs):
        assert [s.camera for s in a.sensors] == [s.camera for s in b.sensors]
        np.testing.assert_allclose(np.abs(a.sensors[1].sensor_from_rig), np.abs(b.sensors[1].sensor_from_rig),
                                   atol=1e-12)
    assert sorted(sorted(e.photos) for e in back.exposures) == sorted(sorted(e.photos) for e in blk.rigs.exposures)
    # a rig OpenSfM leaves without a sensor at its frame, or with an unknown pose, has no such file
    assert survey_rig_file(blk.rigs.__class__(blk.rigs.rigs[:1] + (blk.rigs.rigs[1].__class__(
        "x", (blk.rigs.rigs[1].sensors[0], blk.rigs.rigs[1].sensors[1].__class__("4", "4", None))),),
        ())) == "rig 'x': the pose of sensor '4' is unknown"
    if survey_reads_rig_files():  # the survey format with rigs (issue 27's bundle side): a loaded survey
        from lidarcat.survey.folder import Survey

        write_survey(blk, tmp_path / "s", control_sd_m=0.01)
        s = Survey.load(tmp_path / "s")
        assert s.files["rigs"].name == "rigs.toml"
        assert sum(bool(p.rig_exposure) for p in s.photos) == 12


def test_kaptures_own_t265_files_read_as_the_fixture_holds_them():
    """kapture's samples/t265/colmap, byte for byte (``1, 0.95, ...`` with commas, no points): the real
    cameras and poses the T265 fixture is built on."""
    raw, fix = read_colmap(D / "colmap" / "t265_kapture"), read_colmap(T265)
    assert raw.photo_ids.tolist() == fix.photo_ids.tolist() and len(raw.obs_point) == 0
    assert raw.source_models == fix.source_models
    assert raw.source_models["1"] == {"fx": 284.468, "fy": 285.51, "cx": 424.355, "cy": 393.742, "w": 848, "h": 800,
                                      "dist": {"k1": 0.0008, "k2": 0.031, "k3": -0.03, "k4": 0.005}, "kind": "fisheye"}
    np.testing.assert_allclose(raw.eo, fix.eo, atol=1e-12, rtol=0)


def test_a_fisheye_for_a_brown_only_target_is_fitted_or_refused():
    from lidarcat.interop.lens import export_camera

    narrow = pinhole_camera("n", 900.0, 900.0, 512.0, 384.0, 1024, 768, pixel_size_mm=None, model="m", source="s",
                            dist={"k1": 0.01}, kind="fisheye")
    m = export_camera(narrow[0], narrow[1], fisheye=False)
    assert m["kind"] == "brown" and m["how"] == "fitted" and 0 < m["fit_max_px"] < 0.5
    t265 = read_colmap(T265)
    with pytest.raises(FormatError, match=re.escape("camera '1': its fisheye image reaches 122.3 deg from the optical "
                                                    "axis; the target format has Brown (OpenCV) cameras only")):
        export_camera(t265.cameras["1"], t265.source_models["1"], fisheye=False)
