"""COLMAP text models: the real kapture/maupertuis model, pycolmap as the reference projector,
import -> adjust -> export, thesis round trip, located errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from lidarcat.survey import adjust_survey
from lidarcat.errors import FormatError
from lidarcat.interop.block import block_from_survey, reprojection_residuals_mm, write_survey
from lidarcat.interop.colmap import read_colmap, write_colmap
from lidarcat.survey.folder import Survey

pycolmap = pytest.importorskip("pycolmap")

DATA = Path(__file__).parents[1] / "data" / "interop" / "colmap" / "kapture_maupertuis"
THESIS_ADJ = Path(__file__).parents[1] / "data" / "report"


def _normalised_copy(src: Path, dst: Path) -> Path:
    """The model with its printed (6-digit, norm 1 +- 4e-7) quaternions normalised, so that
    COLMAP's Eigen formula yields a rotation (COLMAP itself does not normalise on reading)."""
    shutil.copytree(src, dst)
    lines = (src / "images.txt").read_text().splitlines()
    out, k = [], 0
    for line in lines:
        if line.startswith("#"):
            out.append(line)
            continue
        if k % 2 == 0:
            f = line.split()
            q = np.array(f[1:5], dtype=float)
            q /= np.linalg.norm(q)
            f[1:5] = [repr(float(v)) for v in q]
            line = " ".join(f)
        out.append(line)
        k += 1
    (dst / "images.txt").write_text("\n".join(out) + "\n")
    return dst


def _pycolmap_residuals(path: Path) -> dict[tuple[str, str], np.ndarray]:
    """COLMAP's projected minus observed pixel of every triangulated 2D point (first per point)."""
    rec = pycolmap.Reconstruction(str(path))
    out: dict[tuple[str, str], np.ndarray] = {}
    for img in rec.images.values():
        for p in img.points2D:
            if p.has_point3D():
                key = (img.name, str(p.point3D_id))
                if key not in out:
                    out[key] = np.asarray(img.project_point(rec.points3D[p.point3D_id].xyz)) - np.asarray(p.xy)
    return out


def _lidarcat_residuals_px(block) -> dict[tuple[str, str], np.ndarray]:
    r = reprojection_residuals_mm(block)
    out = {}
    for ph, pt, v in zip(block.obs_photo.tolist(), block.obs_point.tolist(), r):
        cam = block.cameras[block.photo_camera[block.photo_index()[ph]]]
        out[(ph, pt)] = v / [cam.pixel_size_x_mm, -cam.pixel_size_y_mm]  # y up (mm) -> y down (px)
    return out


def test_read_maupertuis_counts_and_camera():
    b = read_colmap(DATA)
    text = (DATA / "images.txt").read_text().splitlines()
    data = [ln for ln in text if not ln.startswith("#")]
    triangulated = sum(int((np.array(ln.split(), dtype=float).reshape(-1, 3)[:, 2] >= 0).sum())
                       for ln in data[1::2])
    assert triangulated == 3355
    assert sorted(b.photo_ids.tolist()) == ["00.jpg", "01.jpg", "02.jpg", "03.jpg"]
    assert len(b.point_ids) == 1039
    # 5 points are measured twice on the same image: the first measurement is kept
    assert len(b.obs_photo) == 3350
    cam = b.cameras["1"]
    assert cam.focal_length_mm == pytest.approx(1847.53 * 0.001, abs=1e-12)
    assert (cam.columns_px, cam.rows_px) == (1919, 1079)
    # cx = 959.5 = W/2: the principal point is at the image centre
    assert cam.principal_point_x_mm == pytest.approx(0.0, abs=1e-15)
    assert cam.principal_point_y_mm == pytest.approx(0.0, abs=1e-15)


def test_model_reprojects_as_colmap(tmp_path):
    ref = _pycolmap_residuals(_normalised_copy(DATA, tmp_path / "norm"))
    mine = _lidarcat_residuals_px(read_colmap(DATA))
    assert set(mine) == set(ref)
    diff = np.array([mine[k] - ref[k] for k in ref])
    assert np.abs(diff).max() < 1e-6
    rms = float(np.sqrt(np.mean(np.array(list(ref.values())) ** 2)))
    assert 0.1 < rms < 1.0  # a real model: sub-pixel, not zero


def test_unnormalised_quaternions_are_what_colmap_reads():
    """COLMAP applies Eigen's formula to the printed quaternion; at norm 1 + 3.9e-7 that moves
    the projections by up to ~1e-3 px, which lidarcat's (orthonormal) rotations cannot follow."""
    ref = _pycolmap_residuals(DATA)
    mine = _lidarcat_residuals_px(read_colmap(DATA))
    diff = np.array([mine[k] - ref[k] for k in ref])
    assert 1e-4 < np.abs(diff).max() < 1e-2


def test_import_adjust_export_same_residuals(tmp_path):
    b = read_colmap(DATA)
    write_survey(b, tmp_path / "s", control_sd_m=0.01)
    res, out = adjust_survey(tmp_path / "s", outdir=tmp_path / "adj")
    assert res.success
    adjusted = block_from_survey(tmp_path / "s", out)
    write_colmap(adjusted, tmp_path / "export")
    ref = _pycolmap_residuals(tmp_path / "export")
    cam = adjusted.cameras["1"]
    lidarcat_px = {(str(res.problem.photo_ids[i]), str(res.problem.point_ids[j])):
                   v / [cam.pixel_size_x_mm, -cam.pixel_size_y_mm]
                   for i, j, v in zip(res.problem.photo_index, res.problem.point_index, res.residuals_mm)}
    assert set(lidarcat_px) == set(ref)
    assert max(np.abs(lidarcat_px[k] - ref[k]).max() for k in ref) < 1e-6


def test_thesis_round_trip(tmp_path):
    survey = Survey.load()
    blk = block_from_survey(survey, THESIS_ADJ)
    write_colmap(blk, tmp_path / "m")
    back = read_colmap(tmp_path / "m", pixel_size_mm=survey.cameras["dcs14n"].pixel_size_x_mm)
    order = [back.photo_index()[p] for p in blk.photo_ids.tolist()]
    assert np.abs(back.eo[order, 3:] - blk.eo[:, 3:]).max() < 1e-9          # rad
    assert np.abs(back.eo[order, :3] - blk.eo[:, :3]).max() < 1e-8          # m, at 7.2e6 m
    pos = {p: i for i, p in enumerate(back.point_ids.tolist())}
    idx = [pos[p] for p in blk.point_ids.tolist()]
    np.testing.assert_allclose(back.points_m[idx], blk.points_m, rtol=0, atol=1e-9)
    # the thesis camera has distortion: exported as FULL_OPENCV fitted to lidarcat's correction
    # polynomial (issue 25), the measured pixels go out, and the corrected photo coordinates come
    # back through COLMAP's model to within the fit's largest misfit (same focal length)
    from lidarcat.interop.lens import export_camera

    cam = survey.cameras["dcs14n"]
    fit = export_camera(cam)
    assert fit["how"] == "fitted" and 0 < fit["fit_max_px"] < 0.02
    assert "FULL_OPENCV" in (tmp_path / "m" / "cameras.txt").read_text()
    assert back.cameras["1"].focal_length_mm == pytest.approx(cam.focal_length_mm, rel=1e-12)
    key = {(a, b): v for a, b, v in zip(back.obs_photo.tolist(), back.obs_point.tolist(), back.obs_mm)}
    orig = {(a, b): v for a, b, v in zip(blk.obs_photo.tolist(), blk.obs_point.tolist(), blk.obs_mm)}
    assert set(key) == set(orig)
    assert max(np.abs(key[k] - orig[k]).max() for k in orig) < fit["fit_max_px"] * cam.pixel_size_x_mm


@pytest.mark.parametrize("file,line_no,old,new,expect", [
    ("cameras.txt", 4, "SIMPLE_PINHOLE", "FOV", "cameras.txt:4: field 'MODEL': camera 1: camera model 'FOV' is not "
     "supported (supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, "
     "SIMPLE_RADIAL_FISHEYE, RADIAL_FISHEYE, OPENCV_FISHEYE, SIMPLE_FISHEYE, FISHEYE)"),
    ("cameras.txt", 4, "SIMPLE_PINHOLE", "OPENCV_FISHEYE", "cameras.txt:4: field 'PARAMS': model OPENCV_FISHEYE has 8 "
     "parameters (fx fy cx cy k1 k2 k3 k4), the line has 3"),
    ("cameras.txt", 4, "1847.53", "abc", "cameras.txt:4: field 'f': 'abc' is not a number"),
    ("cameras.txt", 4, " 539.5", "", "cameras.txt:4: field 'PARAMS': model SIMPLE_PINHOLE has 3 parameters (f cx cy), the line has 2"),
    ("images.txt", 5, " 1 03.jpg", " 7 03.jpg", "images.txt:5: field 'CAMERA_ID': camera 7 is not in cameras.txt"),
    ("images.txt", 5, "0.860298", "nan", "images.txt:5: field 'QW': 'nan' is not a finite number"),
    ("points3D.txt", 4, "708 -2.39675", "708 x", "points3D.txt:4: field 'X': 'x' is not a number"),
])
def test_located_errors(tmp_path, file, line_no, old, new, expect):
    d = shutil.copytree(DATA, tmp_path / "m")
    lines = (d / file).read_text().splitlines()
    assert old in lines[line_no - 1]
    lines[line_no - 1] = lines[line_no - 1].replace(old, new, 1)
    (d / file).write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError) as ei:
        read_colmap(d)
    assert expect in str(ei.value)
    assert str(ei.value).startswith(str(d / file))


def test_missing_file_and_no_half_written_survey(tmp_path):
    d = shutil.copytree(DATA, tmp_path / "m")
    (d / "points3D.txt").unlink()
    with pytest.raises(FormatError, match=r"points3D.txt: file not found"):
        read_colmap(d)
    b = read_colmap(DATA)
    write_survey(b, tmp_path / "s")
    with pytest.raises(FormatError, match="already holds a survey.toml"):
        write_survey(b, tmp_path / "s")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m", "s"]  # no temporary folder left
