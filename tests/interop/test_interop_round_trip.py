"""Issue 25: import -> export -> import gives the same block for every format that lidarcat both
reads and writes (orientations, cameras, observations, points, CRS and heights), through the
commands a user runs; ``lidarcat convert`` writes what import + export write; an orientation-only
OpenSfM reconstruction converts (no tie points)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.interop.block import block_from_survey
from lidarcat.interop.opensfm import read_opensfm
from lidarcat.survey.folder import Survey

D = Path(__file__).parents[1] / "data" / "interop"
THESIS_ADJ = Path(__file__).parents[1] / "data" / "report"
REC = D / "opensfm" / "berlin_reconstruction_example.json"


def _cli(*args) -> str:
    res = CliRunner().invoke(cli, [str(a) for a in args])
    assert res.exit_code == 0, (args, res.output)
    return res.output


def _assert_same_survey(a: Path, b: Path) -> None:
    sa, sb = Survey.load(a), Survey.load(b)
    assert (sa.crs, sa.height_system) == (sb.crs, sb.height_system)
    assert [p.id for p in sa.photos] == [p.id for p in sb.photos]
    for pa, pb in zip(sa.photos, sb.photos):
        np.testing.assert_allclose(pb.position_m, pa.position_m, rtol=0, atol=1e-8)
        np.testing.assert_allclose(pb.attitude_deg, pa.attitude_deg, rtol=0, atol=1e-9)
    ka = {(p, q): x for p, q, x in zip(sa.image_points.photo.tolist(), sa.image_points.point.tolist(),
                                      sa.image_points.pixel_px)}
    kb = {(p, q): x for p, q, x in zip(sb.image_points.photo.tolist(), sb.image_points.point.tolist(),
                                      sb.image_points.pixel_px)}
    assert set(ka) == set(kb)
    assert max(np.abs(ka[k] - kb[k]).max() for k in ka) < 1e-9
    ga, gb = sa.ground_points, sb.ground_points
    assert ga.point.tolist() == gb.point.tolist()
    np.testing.assert_allclose(gb.enh_m, ga.enh_m, rtol=0, atol=1e-8)
    def cams(s):  # the camera's provenance ("source": file and line) names the file it came from
        return {c: {k: v for k, v in cam.to_dict().items() if k != "source"} for c, cam in s.cameras.items()}

    assert cams(sa) == cams(sb)


IMPORTS = {
    "colmap": ["colmap", D / "colmap" / "kapture_maupertuis", "--crs", "local: kapture test frame",
               "--control-sd-m", "0.01"],
    "opensfm": ["opensfm", REC, "--tracks", D / "opensfm" / "berlin_tracks_example.csv", "--control-sd-m", "0.01"],
}


@pytest.mark.parametrize("fmt", sorted(IMPORTS))
def test_import_export_import_same_survey(tmp_path, fmt):
    """import FORMAT -> export FORMAT -> import FORMAT: the same survey, georeference included
    (COLMAP: the CRS comment of images.txt; OpenSfM: reference_lla)."""
    _cli("import", *IMPORTS[fmt], "-o", tmp_path / "s1")
    _cli("export", fmt, tmp_path / "s1", "-o", tmp_path / "x")
    src = tmp_path / "x" / "reconstruction.json" if fmt == "opensfm" else tmp_path / "x"
    extra = ["--tracks", tmp_path / "x" / "tracks.csv"] if fmt == "opensfm" else []
    _cli("import", fmt, src, *extra, "--control-sd-m", "0.01", "-o", tmp_path / "s2")
    _assert_same_survey(tmp_path / "s1", tmp_path / "s2")
    s1 = Survey.load(tmp_path / "s1")
    assert s1.crs.startswith("local: kapture" if fmt == "colmap" else "local ENU (OpenSfM reference_lla)")
    assert json.loads((tmp_path / "s1" / "source_cameras.json").read_text()) == \
        json.loads((tmp_path / "s2" / "source_cameras.json").read_text())


@pytest.mark.parametrize("flavour,name", [("pix4d", "a.opk"), ("ign", "a.OPK"), ("orthority", "a.csv")])
def test_opk_export_import_export(tmp_path, flavour, name):
    """An adjusted block exported as OPK, imported into its survey and exported again: the same
    file, byte for byte, and the CRS and heights come back from the sidecar."""
    _cli("export", "opk", THESIS_ADJ, "--flavour", flavour, "-o", tmp_path / name)
    _cli("import", "opk", tmp_path / name, "-o", tmp_path / "s")
    s = Survey.load(tmp_path / "s")
    b = block_from_survey(None, THESIS_ADJ)
    for k, ph in enumerate(s.photos):
        np.testing.assert_allclose(ph.position_m, b.eo[k, :3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.radians(ph.attitude_deg), b.eo[k, 3:], rtol=0, atol=1e-12)
    from lidarcat.interop.opk import write_opk

    again = tmp_path / ("b" + Path(name).suffix)
    write_opk(block_from_survey(tmp_path / "s"), again, flavour=flavour)
    assert again.read_text() == (tmp_path / name).read_text()
    side = json.loads((tmp_path / (name + ".json")).read_text())
    assert (side["crs"], side["height_system"]) == (b.crs, b.height_system)
    from lidarcat.interop.opk import read_opk

    o = read_opk(tmp_path / name)
    assert (o.crs, o.height_system) == (b.crs, b.height_system)


def test_survey_convert_survey(tmp_path):
    _cli("import", *IMPORTS["colmap"], "-o", tmp_path / "s1")
    _cli("convert", "survey", tmp_path / "s1", "survey", tmp_path / "s2")
    _assert_same_survey(tmp_path / "s1", tmp_path / "s2")


def test_convert_equals_import_then_export(tmp_path):
    """convert colmap -> opensfm writes what import colmap + export opensfm write."""
    _cli("convert", "colmap", D / "colmap" / "kapture_maupertuis", "opensfm", tmp_path / "c",
         "--crs", "local: kapture test frame")
    _cli("import", *IMPORTS["colmap"][:4], "-o", tmp_path / "s")
    _cli("export", "opensfm", tmp_path / "s", "-o", tmp_path / "e")
    a = json.loads((tmp_path / "c" / "reconstruction.json").read_text())[0]
    b = json.loads((tmp_path / "e" / "reconstruction.json").read_text())[0]
    assert a["cameras"] == b["cameras"] and a["shots"].keys() == b["shots"].keys()
    for k in a["shots"]:
        np.testing.assert_allclose(a["shots"][k]["rotation"], b["shots"][k]["rotation"], atol=1e-12)
        np.testing.assert_allclose(a["shots"][k]["translation"], b["shots"][k]["translation"], atol=1e-9)


def test_orientation_only_opensfm_converts(tmp_path):
    """A reconstruction.json without points and tracks (as OpenDroneMap writes) is read as oriented
    photos; it converts to COLMAP and OPK, and import names the next step (convert)."""
    rec = json.loads(REC.read_text())
    del rec[0]["points"]
    p = tmp_path / "reconstruction.json"
    p.write_text(json.dumps(rec))
    b = read_opensfm(p)
    assert b.n_photos == 3 and len(b.obs_photo) == 0 and np.isfinite(b.eo).all()
    out = _cli("convert", "opensfm", p, "colmap", tmp_path / "m")
    assert "3 photos, 0 observations" in out
    _cli("convert", "opensfm", p, "opk", tmp_path / "o.opk")
    assert len((tmp_path / "o.opk").read_text().splitlines()) == 4
    res = CliRunner().invoke(cli, ["import", "opensfm", str(p), "-o", str(tmp_path / "s")])
    assert res.exit_code == 2 and "or write the orientations to another format with lidarcat convert" in res.output
