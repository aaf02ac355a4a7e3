"""Interior orientation (thesis eq. 01-07) against Appendix 1, and its inverse."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import ROOT, THESIS_SURVEY, THESIS_TABLES
from lidarcat.geometry.camera import SD_KEYS, Camera
from lidarcat.errors import CameraError, SurveyError
from lidarcat.survey.cameras import load_camera, load_cameras

TOL_PRINTED = 0.0015  # Appendix 1 prints 3 decimals (mm)


def _appendix1():
    with open(THESIS_TABLES / "appendix1_corrections.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    cols = ("C", "L", "dx_ra", "dy_ra", "dx_des", "dy_des", "x_fotc", "y_fotc")
    return rows, {c: np.array([float(r[c]) for r in rows]) for c in cols}


@pytest.fixture(scope="module")
def thesis_camera() -> Camera:
    return load_cameras(THESIS_SURVEY / "camera.toml")["dcs14n"]


@pytest.fixture(scope="module")
def lactec_camera() -> Camera:
    return load_cameras(ROOT / "data" / "cameras" / "lactec_dcs14n_2008.toml")["lactec_dcs14n"]


def _simple(**kw) -> Camera:
    args = dict(focal_length_mm=50.0, principal_point_x_mm=0.0, principal_point_y_mm=0.0,
                k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0, refraction_eps45=0.0,
                pixel_size_x_mm=0.01, pixel_size_y_mm=0.01, columns_px=101, rows_px=51)
    args.update(kw)
    return Camera("t", **args)


# ------------------------------------------------------------------ Appendix 1
def test_thesis_camera_is_table1(thesis_camera):
    c = thesis_camera
    assert (c.focal_length_mm, c.principal_point_x_mm, c.principal_point_y_mm) == (51.902, 0.033, -0.07)
    assert (c.k1, c.k2, c.p1) == (-3.8430896e-05, 1.1695517e-08, -4.2651702e-06)
    assert (c.columns_px, c.rows_px, c.pixel_size_x_mm) == (3000, 4500, 0.0079)
    assert c.sd["sd_focal_length_mm"] == 0.032


def test_appendix1_all_153_rows(thesis_camera):
    rows, t = _appendix1()
    assert len(rows) == 153
    cr = np.column_stack([t["C"], t["L"]])
    d = thesis_camera.distortion_corrections(thesis_camera.pixel_to_fot(cr))
    for k in ("dx_ra", "dy_ra", "dx_des", "dy_des"):
        np.testing.assert_allclose(d[k], t[k], atol=TOL_PRINTED, rtol=0, err_msg=k)
    xy = thesis_camera.pixel_to_photo(cr)
    np.testing.assert_allclose(xy[:, 0], t["x_fotc"], atol=TOL_PRINTED, rtol=0)
    misprint = np.array([(r["photo"], r["point"]) == ("5", "662") for r in rows])
    assert misprint.sum() == 1
    np.testing.assert_allclose(xy[~misprint, 1], t["y_fotc"][~misprint], atol=TOL_PRINTED, rtol=0)
    # the rounding of the printed table bounds the agreement: 3 decimals -> 0.0005 each
    assert np.abs(xy[~misprint, 1] - t["y_fotc"][~misprint]).max() < 0.001


def test_appendix1_misprint_photo5_point662(thesis_camera):
    rows, t = _appendix1()
    i = next(k for k, r in enumerate(rows) if (r["photo"], r["point"]) == ("5", "662"))
    assert (t["L"][i], t["y_fotc"][i]) == (111.6, 17.143)
    y = thesis_camera.pixel_to_photo([t["C"][i], t["L"][i]])[1]
    assert 0.0025 < t["y_fotc"][i] - y < 0.0035      # the printed y is ~0.003 mm off its L
    assert abs(y - 17.140) < 0.0005                  # L = 111.6 gives 17.140
    y_alt = thesis_camera.pixel_to_photo([t["C"][i], 111.23])[1]
    assert abs(y_alt - 17.143) < 0.0005              # L = 111.23 reproduces the printed y
    # x of that row and its corrections are consistent as printed
    assert abs(thesis_camera.pixel_to_photo([t["C"][i], t["L"][i]])[0] - t["x_fotc"][i]) < TOL_PRINTED


def test_eq05_printed_form_is_a_misprint(thesis_camera):
    """The printed eq. 05, P1 (r^2 + 2x), contradicts Appendix 1; 2 x^2 reproduces it."""
    rows, t = _appendix1()
    fot = thesis_camera.pixel_to_fot(np.column_stack([t["C"], t["L"]]))
    x, y = fot[:, 0], fot[:, 1]
    printed_form = thesis_camera.p1 * (x**2 + y**2 + 2 * x)
    disagree = np.abs(np.round(printed_form, 3) - t["dx_des"]) > 0.0005
    assert disagree.sum() == 65  # the count the camera module docstring quotes
    d = thesis_camera.distortion_corrections(fot)
    assert np.all(np.abs(np.round(d["dx_des"], 3) - t["dx_des"]) <= 0.0015)
    # "153 of 153 rows agree": rounded to the 3 printed decimals, every row is the printed value
    assert np.all(np.abs(np.round(d["dx_des"], 3) - t["dx_des"]) < 0.0005)


def test_signs_distortion_subtracted(thesis_camera):
    fot = np.array([[10.0, -5.0]])
    d = thesis_camera.distortion_corrections(fot)
    xy = thesis_camera.pixel_to_photo(thesis_camera.image_centre_to_pixel(
        fot + [thesis_camera.principal_point_x_mm, thesis_camera.principal_point_y_mm]))
    np.testing.assert_allclose(xy[0, 0], 10.0 - d["dx_ra"][0] - d["dx_des"][0], atol=1e-12)
    np.testing.assert_allclose(xy[0, 1], -5.0 - d["dy_ra"][0] - d["dy_des"][0], atol=1e-12)
    assert d["dx_ra"][0] < 0  # K1 < 0: barrel, the radial distortion points inwards


# ------------------------------------------------------------------ eq. 01, 02, 06
def test_eq01_image_centre_and_axes():
    cam = _simple()
    np.testing.assert_array_equal(cam.pixel_to_image_centre([[50, 25]]), [[0.0, 0.0]])
    # column grows to the right (+x), row grows downwards (-y)
    np.testing.assert_allclose(cam.pixel_to_image_centre([[0, 0], [100, 50]]),
                               [[-0.5, 0.25], [0.5, -0.25]], atol=1e-15)
    np.testing.assert_allclose(cam.image_centre_to_pixel([[-0.5, 0.25]]), [[0, 0]], atol=1e-12)


def test_eq02_principal_point():
    cam = _simple(principal_point_x_mm=0.1, principal_point_y_mm=-0.2)
    np.testing.assert_allclose(cam.pixel_to_photo([50, 25]), [-0.1, 0.2], atol=1e-15)


def test_eq06_refraction():
    cam = _simple(refraction_eps45=1e-5)
    x, y = 0.3, -0.2
    d = cam.distortion_corrections([x, y])
    r2 = x * x + y * y
    assert d["dx_ref"] == pytest.approx(x * (1 + r2 / 2500.0) * 1e-5, rel=1e-12)
    assert d["dy_ref"] == pytest.approx(y * (1 + r2 / 2500.0) * 1e-5, rel=1e-12)


def test_no_negative_zero_in_corrections(thesis_camera):
    # at the principal point every correction is 0; the tables must not print "-0.0"
    d = thesis_camera.distortion_corrections([[0.0, -0.0], [-0.0, 0.0]])
    assert all(not np.signbit(v).any() for v in d.values())
    # K1 < 0: unguarded, dx_ra = x r^2 K1 at x = r = 0 is 0.0 * -0.0 = -0.0
    assert np.signbit(0.0 * (0.0 * thesis_camera.k1))


def test_single_point_and_shape_errors(thesis_camera):
    assert thesis_camera.pixel_to_photo([1500.0, 2000.0]).shape == (2,)
    assert thesis_camera.pixel_to_photo(np.zeros((0, 2))).shape == (0, 2)
    with pytest.raises(CameraError, match=r"shape \(N, 2\)"):
        thesis_camera.pixel_to_photo(np.zeros((3, 3)))


# ------------------------------------------------------------------ inverse
def _frame_grid(cam: Camera, n: int = 41) -> np.ndarray:
    c = np.linspace(-0.5, cam.columns_px - 0.5, n)
    r = np.linspace(-0.5, cam.rows_px - 0.5, n)
    return np.stack(np.meshgrid(c, r), -1).reshape(-1, 2)


@pytest.mark.parametrize("which", ["thesis_camera", "lactec_camera"])
def test_round_trip_whole_frame(which, request):
    cam = request.getfixturevalue(which)
    grid = _frame_grid(cam)
    back = cam.photo_to_pixel(cam.pixel_to_photo(grid))
    np.testing.assert_allclose(back, grid, atol=1e-6, rtol=0)
    # and the other way: corrected coordinates reproduce to far below 1e-6 mm
    xy = cam.pixel_to_photo(grid)
    np.testing.assert_allclose(cam.pixel_to_photo(cam.photo_to_pixel(xy)), xy, atol=1e-9, rtol=0)


def test_round_trip_with_refraction_and_decentering():
    cam = _simple(k1=-5e-5, k2=2e-8, k3=-1e-12, p1=-4e-6, p2=3e-6, refraction_eps45=2e-5,
                  columns_px=4000, rows_px=3000, pixel_size_x_mm=0.006, pixel_size_y_mm=0.0065,
                  principal_point_x_mm=0.1, principal_point_y_mm=-0.05)
    grid = _frame_grid(cam, 31)
    np.testing.assert_allclose(cam.photo_to_pixel(cam.pixel_to_photo(grid)), grid, atol=1e-6, rtol=0)


def test_inverse_does_not_feed_in_the_answer(thesis_camera):
    # a single far corner: distortion 0.26 mm = 33 px, so the identity start is far off
    corner = np.array([[0.0, 0.0]])
    xy = thesis_camera.pixel_to_photo(corner)
    assert np.hypot(*(thesis_camera.image_centre_to_pixel(
        xy + [thesis_camera.principal_point_x_mm, thesis_camera.principal_point_y_mm]) - corner)[0]) > 20
    np.testing.assert_allclose(thesis_camera.photo_to_pixel(xy), corner, atol=1e-6)


def test_inverse_non_convergence_names_point(thesis_camera):
    # beyond r ~ 30 mm the thesis polynomial folds over (d(x - dx)/dx -> 0): no inverse
    pts = np.array([[1.0, 1.0], [400.0, 300.0]])
    with pytest.raises(CameraError, match=r"point index 1 \(400, 300\) mm did not converge"):
        thesis_camera.photo_to_pixel(pts)
    out = thesis_camera.photo_to_pixel(pts, on_fail="nan")
    assert np.isfinite(out[0]).all() and np.isnan(out[1]).all()
    nan_in = thesis_camera.photo_to_pixel([[np.nan, 1.0]])
    assert np.isnan(nan_in).all()


def test_jacobian_matches_finite_differences(thesis_camera):
    pts = np.array([[10.0, 20.0], [2900.0, 4400.0], [1500.0, 10.0]])
    jac = thesis_camera.pixel_to_photo_jacobian(pts)
    h = 1e-3
    for k in range(2):
        step = np.zeros(2)
        step[k] = h
        num = (thesis_camera.pixel_to_photo(pts + step) - thesis_camera.pixel_to_photo(pts - step)) / (2 * h)
        np.testing.assert_allclose(jac[:, :, k], num, atol=1e-10)


def test_contains(thesis_camera):
    inside = thesis_camera.contains([[0, 0], [2999.4, 4499.4], [-0.6, 10], [10, 4500]])
    assert inside.tolist() == [True, True, False, False]


@settings(max_examples=40, deadline=None)
@given(k1=st.floats(-8e-5, 8e-5), k2=st.floats(-3e-8, 6e-8), p1=st.floats(-1e-5, 1e-5),
       p2=st.floats(-1e-5, 1e-5), u=st.floats(0, 1), v=st.floats(0, 1))
def test_round_trip_property(k1, k2, p1, p2, u, v):
    cam = _simple(k1=k1, k2=k2, p1=p1, p2=p2, columns_px=3000, rows_px=2000,
                  pixel_size_x_mm=0.008, pixel_size_y_mm=0.008, focal_length_mm=35.0)
    px = np.array([[u * 2999, v * 1999]])
    np.testing.assert_allclose(cam.photo_to_pixel(cam.pixel_to_photo(px)), px, atol=1e-6, rtol=0)


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize("field_name, value, message", [
    ("focal_length_mm", -1.0, "must be positive"),
    ("pixel_size_x_mm", 0.0, "must be positive"),
    ("k1", math.nan, "must be finite"),
    ("p2", math.inf, "must be finite"),
    ("k2", "0.1", "must be a number"),
    ("columns_px", 10.5, "whole number"),
    ("rows_px", 0, "at least 1"),
])
def test_camera_validation_names_field(field_name, value, message):
    with pytest.raises(CameraError, match=f"field '{field_name}': .*{message}") as ei:
        _simple(**{field_name: value})
    assert ei.value.field == field_name


def test_camera_sd_validation():
    with pytest.raises(CameraError, match=r"^field 'sd_zoom': unknown standard-deviation key; "
                                          r"allowed: sd_focal_length_mm, sd_principal_point_x_mm, "):
        _simple(sd={"sd_zoom": 1.0})
    with pytest.raises(CameraError, match=r"^field 'sd_k1': must be a finite number >= 0, got -1.0$"):
        _simple(sd={"sd_k1": -1.0})
    cam = _simple(sd={"sd_k1": 1e-6})
    with pytest.raises(TypeError):
        cam.sd["sd_k1"] = 2.0  # type: ignore[index]
    assert "sd_focal_length_mm" in SD_KEYS


def test_camera_is_immutable(thesis_camera):
    with pytest.raises(AttributeError):
        thesis_camera.k1 = 0.0  # type: ignore[misc]


# ------------------------------------------------------------------ TOML
def test_to_toml_round_trip(tmp_path, thesis_camera, lactec_camera):
    p = tmp_path / "cams.toml"
    p.write_text(thesis_camera.to_toml() + "\n" + lactec_camera.to_toml(), encoding="utf-8")
    cams = load_cameras(p)
    assert list(cams) == ["dcs14n", "lactec_dcs14n"]
    for a, b in ((cams["dcs14n"], thesis_camera), (cams["lactec_dcs14n"], lactec_camera)):
        assert a.to_dict() == b.to_dict()
    odd = _simple(model='say "hi"\\\nnext', source="café")
    p.write_text(Camera("odd id", **{k: v for k, v in odd.to_dict().items() if k != "id"}).to_toml(),
                 encoding="utf-8")
    back = load_cameras(p)["odd id"]
    assert (back.model, back.source) == ('say "hi"\\\nnext', "café")


def _write_cam(tmp_path, text):
    p = tmp_path / "camera.toml"
    p.write_text(text, encoding="utf-8")
    return p


def _thesis_cam_text():
    return (THESIS_SURVEY / "camera.toml").read_text(encoding="utf-8")


def _line_of(text, needle):
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


@pytest.mark.parametrize("old, new, needle, message", [
    ("k3 = 0.0", "k3 = 0.0\nk4 = 0.0", "k4 =", r"field 'k4': camera \[dcs14n\]: unknown key; allowed: model"),
    ("focal_length_mm = 51.902\n", "", "[dcs14n]",
     r"field 'focal_length_mm': camera \[dcs14n\]: missing \(required\)$"),
    ("pixel_size_y_mm = 0.0079", "pixel_size_y_mm = -0.0079", "pixel_size_y_mm",
     r"field 'pixel_size_y_mm': camera \[dcs14n\]: must be positive, got -0.0079$"),
])
def test_load_cameras_located_error(tmp_path, old, new, needle, message):
    """An edit of the thesis camera.toml: the error names the line (the key's, else the table's)."""
    text = _thesis_cam_text()
    assert old in text
    text = text.replace(old, new, 1)
    with pytest.raises(SurveyError, match=rf"camera.toml:{_line_of(text, needle)}: {message}"):
        load_cameras(_write_cam(tmp_path, text))


def test_load_cameras_invalid_toml_and_empty(tmp_path):
    p = _write_cam(tmp_path, "[a]\nk1 = = 3\n")
    with pytest.raises(SurveyError, match=r"camera.toml:2: invalid TOML"):
        load_cameras(p)
    p = _write_cam(tmp_path, "# nothing\n")
    with pytest.raises(SurveyError, match="no camera defined"):
        load_cameras(p)
    p = _write_cam(tmp_path, "focal_length_mm = 3\n")
    with pytest.raises(SurveyError, match=r"camera.toml:1: field 'focal_length_mm': top-level key"):
        load_cameras(p)
    with pytest.raises(SurveyError, match=r"nope.toml: file not found$"):
        load_cameras(tmp_path / "nope.toml")
    with pytest.raises(SurveyError, match=r": cannot read \(Is a directory\)$"):
        load_cameras(tmp_path)
    p.write_bytes('[a]\nmodel = "Câmera"\n'.encode("latin-1"))
    with pytest.raises(SurveyError, match=r"camera.toml:2: byte 0xe2 is not UTF-8 text; "
                                          r"save the file as UTF-8$"):
        load_cameras(p)


def test_load_camera_spec(tmp_path, thesis_camera, lactec_camera):
    p = tmp_path / "two.toml"
    p.write_text(thesis_camera.to_toml() + lactec_camera.to_toml(), encoding="utf-8")
    assert load_camera(f"{p}:lactec_dcs14n").focal_length_mm == 35.975
    with pytest.raises(SurveyError, match="name one as"):
        load_camera(p)
    with pytest.raises(SurveyError, match="no camera 'x'; defined: dcs14n, lactec_dcs14n"):
        load_camera(f"{p}:x")
    assert load_camera(THESIS_SURVEY / "camera.toml").id == "dcs14n"


# ------------------------------------------------------------------ an invertible, lens-sized distortion (issue 24)
def test_k3_minus_one_is_refused_at_load_naming_file_line_and_parameters(tmp_path):
    """The reproducer: k3 = -1 was accepted and `camera correct` reported a 604 km correction."""
    text = _thesis_cam_text().replace("k3 = 0.0", "k3 = -1.0", 1)
    p = _write_cam(tmp_path, text)
    with pytest.raises(SurveyError, match=(
            rf"^{p}:{_line_of(text, 'k3 =')}: field 'k3': camera \[dcs14n\]: radial distortion "
            r"k1 = -3.84309e-05, k2 = 1.16955e-08, k3 = -1 moves a point 21.44 mm from the principal point "
            r"by 2.082e\+09 mm, 9.71e\+07 times its radius \(at most 0.5 within the 23.7 x 35.55 mm frame\): "
            r"not a lens distortion; check the values and their units \(mm\^-2, mm\^-4, mm\^-6\)$")):
        load_cameras(p)


def test_k3_minus_one_in_a_survey_is_one_error_line_for_camera_correct_and_info(tmp_path):
    import shutil

    from click.testing import CliRunner

    from conftest import assert_one_line_error
    from lidarcat.cli.main import cli

    folder = tmp_path / "survey"
    shutil.copytree(THESIS_SURVEY, folder, ignore=shutil.ignore_patterns("out", "published"))
    text = (folder / "camera.toml").read_text(encoding="utf-8").replace("k3 = 0.0", "k3 = -1.0", 1)
    (folder / "camera.toml").write_text(text, encoding="utf-8")
    where = f"{folder / 'camera.toml'}:{_line_of(text, 'k3 =')}: field 'k3': camera [dcs14n]: radial distortion"
    for args in (["camera", "correct", str(folder), "-o", str(tmp_path / "c.csv")],
                 ["camera", "info", str(folder / "camera.toml")], ["adjust", str(folder), "-o", str(tmp_path / "o")]):
        r = CliRunner().invoke(cli, args)
        assert_one_line_error(r, where, "not a lens distortion")
    assert not (tmp_path / "c.csv").exists() and not (tmp_path / "o").exists()


@pytest.mark.parametrize("kw, fld, message", [
    # a 36 x 24 mm frame, principal point (0.1, -0.1) mm: the far corner is R = 21.77 mm away
    # rho'(r) = 1 - 7 k3 r^6 = 0 at r = (1/7)^(1/6) = 0.723 mm: the corrected radius folds over
    (dict(k3=1.0), "k3", r"k3 = 1 folds over within the frame: the corrected radius stops increasing at r = 0.723 mm "
                         r"from the principal point \(the frame reaches 21.77 mm\)"),
    # 1 - 3 k1 r^2 = 0 at r = 12.91 mm
    (dict(k1=2e-3), "k1", r"stops increasing at r = 12.91 mm"),
    # monotonic (barrel), but g(R^2) = k1 R^2 = -0.948: the corner moves by 95 % of its radius
    (dict(k1=-2e-3), "k1", r"moves a point 21.77 mm from the principal point by 20.64 mm, 0.948 times its radius "
                           r"\(at most 0.5 within the 36 x 24 mm frame\): not a lens distortion"),
    # g = eps (1 + R^2 / c^2) = 0.6 (1 + 474 / 2500) = 0.714
    (dict(refraction_eps45=0.6), "refraction_eps45", r"refraction_eps45 = 0.6 moves a point 21.77 mm from the "
                                                     r"principal point by 15.54 mm, 0.714 times its radius"),
    # at the corner (-18.1, 12.1) mm: [[2 p2 y, 2 p2 x], [2 p2 x, 6 p2 y]] has |eigenvalue| 2.42 + 2.18 = 4.6
    (dict(p2=0.05), "p2", r"decentering distortion p1 = 0, p2 = 0.05 changes by 4.6 mm per mm at a frame corner, "
                          r"not small against the radial d rho / dr >= 1"),
])
def test_distortion_that_cannot_be_inverted_is_refused(kw, fld, message):
    with pytest.raises(CameraError, match=rf"^field '{fld}': .*{message}") as ei:
        _simple(**{**dict(columns_px=4500, rows_px=3000, pixel_size_x_mm=0.008, pixel_size_y_mm=0.008,
                          principal_point_x_mm=0.1, principal_point_y_mm=-0.1), **kw})
    assert ei.value.field == fld


def test_a_strong_but_invertible_distortion_is_accepted_and_round_trips():
    # pincushion: rho'(R) = 1 - 3 k1 R^2 = 0.2 at the far corner (R = 21.77 mm); correction 27 % of the radius
    r2 = 18.1 ** 2 + 12.1 ** 2
    cam = _simple(k1=0.8 / (3 * r2), columns_px=4500, rows_px=3000, pixel_size_x_mm=0.008, pixel_size_y_mm=0.008,
                  principal_point_x_mm=0.1, principal_point_y_mm=-0.1, p1=2e-6, p2=-3e-6)
    grid = _frame_grid(cam, 21)
    np.testing.assert_allclose(cam.photo_to_pixel(cam.pixel_to_photo(grid)), grid, atol=1e-6, rtol=0)


def test_every_shipped_and_test_camera_still_loads():
    import glob

    from lidarcat.synthetic.block import selfcal_block
    from lidarcat.synthetic.cavassim import paper_camera
    from lidarcat.synthetic.survey import demo_camera

    tomls = [p for p in glob.glob(str(ROOT / "data" / "**" / "*.toml"), recursive=True)
             + glob.glob(str(ROOT / "tests" / "data" / "**" / "*.toml"), recursive=True)
             if not p.endswith("survey.toml")]
    assert len(tomls) >= 2
    cams = [c for p in tomls for c in load_cameras(p).values()]
    cams += [demo_camera(), paper_camera()]
    assert {c.id for c in cams} >= {"dcs14n", "lactec_dcs14n", "demo", "rc10"}
    b = selfcal_block(0)
    assert b is not None


def test_huge_numbers_and_long_names_in_camera_toml_are_cut(tmp_path):
    text = _thesis_cam_text().replace("columns_px = 3000", "columns_px = " + "9" * 400, 1)
    with pytest.raises(SurveyError, match=rf"camera.toml:{_line_of(text, 'columns_px')}: field 'columns_px': camera "
                                          rf"\[dcs14n\]: 9{{60}}\.\.\. \(400 characters\) pixels is outside the sane "
                                          r"range 1\.\.1,000,000$"):
        load_cameras(_write_cam(tmp_path, text))
    text = _thesis_cam_text().replace("columns_px = 3000", "columns_px = " + "9" * 5000, 1)
    with pytest.raises(SurveyError, match=rf"camera.toml:{_line_of(text, 'columns_px')}: a number of more than "
                                          r"\d+ digits$"):
        load_cameras(_write_cam(tmp_path, text))
    long_id = "c" * 3000
    text = _thesis_cam_text().replace("[dcs14n]", f"[{long_id}]", 1).replace("k3 = 0.0", "k3 = 0.0\n" + "k" * 3000 + " = 1")
    with pytest.raises(SurveyError) as ei:
        load_cameras(_write_cam(tmp_path, text))
    assert str(ei.value).startswith(f"{tmp_path / 'camera.toml'}:{_line_of(text, 'k' * 3000)}: field "
                                    f"'{'k' * 60}...': camera [{'c' * 60}...]: unknown key; allowed: model")
    assert len(str(ei.value)) < 1000
    text = _thesis_cam_text().replace('model = "Kodak DCS Pro 14n"', "model = 1", 1).replace(
        "focal_length_mm = 51.902", 'focal_length_mm = "' + "\\u001b" * 100 + '"', 1)
    with pytest.raises(SurveyError, match=r"field 'focal_length_mm': camera \[dcs14n\]: must be a number, got "
                                          r"'(\\x1b){60}'\.\.\. \(100 characters\) \(str\)$"):
        load_cameras(_write_cam(tmp_path, text))


def test_every_accepted_camera_round_trips_over_its_frame():
    """Seeded: random calibrations over wide ranges; each one the load check accepts inverts over the
    whole frame (the inverse starts from the corrected coordinate and finds the pixel it came from)."""
    rng = np.random.default_rng(24)

    def coef(lo, hi):
        return float(rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(lo, hi))

    accepted = 0
    for _ in range(600):
        kw = dict(focal_length_mm=rng.uniform(5, 200), principal_point_x_mm=rng.uniform(-0.5, 0.5),
                  principal_point_y_mm=rng.uniform(-0.5, 0.5), k1=coef(-8, -2), k2=coef(-12, -5),
                  k3=coef(-16, -8), p1=coef(-8, -3), p2=coef(-8, -3), refraction_eps45=coef(-8, -2),
                  pixel_size_x_mm=0.006, pixel_size_y_mm=0.006, columns_px=int(rng.integers(1000, 9000)),
                  rows_px=int(rng.integers(1000, 9000)))
        try:
            cam = Camera("r", **kw)
        except CameraError:
            continue
        accepted += 1
        grid = _frame_grid(cam, 9)
        np.testing.assert_allclose(cam.photo_to_pixel(cam.pixel_to_photo(grid)), grid, atol=1e-5, rtol=0,
                                   err_msg=str(kw))
    assert 200 < accepted < 600
