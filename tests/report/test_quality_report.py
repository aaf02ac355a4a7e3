"""Issue 25: the run report is a quality report (Pix4D / OpenDroneMap style), every section present.

One synthetic survey (``write_synthetic_survey``, a sparse LiDAR survey, GPS
control) through ``lidarcat run``: the report must hold the verdict line at the
top and every section of :data:`lidarcat.report.quality.SECTION_IDS` (by the
HTML ids of their headings), each with an embedded figure (a data URI, no file
link) or, for the standards, the CE90/LE90 columns; the Markdown twin holds the
same headings and links the PNG files written beside it.  The thumbnails of
products and orthophotos are tested on GeoTIFFs placed where those stages
write them.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.accuracy.standards import ce90_le90
from lidarcat.cli.main import cli
from lidarcat.report.quality import SECTION_IDS, quality_report
from lidarcat.report.quality_figures import ellipse_axes
from lidarcat.synthetic.survey import write_synthetic_survey


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """``lidarcat run`` of a synthetic survey (GPS control only: no extraction jobs), then a DTM and a
    mosaic GeoTIFF placed where the products and mapping stages write them (those stages take minutes
    on two shared cores; the documented screenshot check in docs/report.md runs them)."""
    root = tmp_path_factory.mktemp("quality")
    survey = root / "s"
    write_synthetic_survey(survey, seed=2, lidar_density_m2=0.3)
    toml = (survey / "survey.toml").read_text(encoding="utf-8")
    (survey / "survey.toml").write_text(re.sub(r'(?m)^extraction_jobs = .*\n', "", toml), encoding="utf-8")
    out = root / "out"
    r = CliRunner().invoke(cli, ["run", str(survey), "-o", str(out)])
    assert r.exit_code == 0, r.output
    return survey, out


def _sections(html: str) -> dict[str, str]:
    parts = re.split(r"(?=<section id=['\"])", html)
    return {m.group(1): p for p in parts if (m := re.match(r"<section id=['\"]([^'\"]+)['\"]", p))}


@pytest.mark.slow
def test_run_report_holds_every_quality_section_with_its_figure(run_dir):
    _, out = run_dir
    html = (out / "report" / "index.html").read_text(encoding="utf-8")
    sections = _sections(html)
    want = [s for s in SECTION_IDS if s != "products-and-orthophotos"]   # no products in this run
    assert [s for s in want if s not in sections] == []
    assert "products-and-orthophotos" not in sections
    # the verdict is the first section and one line
    assert next(iter(sections)) == "verdict"
    verdict = re.findall(r"<p>(.*?)</p>", sections["verdict"])
    assert len(verdict) == 1 and verdict[0].startswith("<strong>PASSED"), verdict
    assert "run gps: sigma0^2" in verdict[0] and "check RMSE plan" in verdict[0]
    for sid in want:
        if sid in ("verdict", "accuracy-standards"):
            continue
        assert "<img " in sections[sid] and "src='data:image/png;base64," in sections[sid], sid
    assert "CE90 / LE90 (m)" in sections["accuracy-standards"] and "NSSDA 95 %" in sections["accuracy-standards"]
    assert "src='quality/" not in html                         # self-contained: every figure embedded
    md = (out / "report" / "index.md").read_text(encoding="utf-8")
    for title in ("Verdict", "Image residuals", "Precision", "Overlap", "Control and check points",
                  "Camera distortion", "Accuracy standards", "Tie points", "LiDAR density"):
        assert f"\n## {title}\n" in md, title
    links = re.findall(r"!\[[^\]]*\]\((quality/[^)]+)\)", md)
    assert len(links) >= 8 and all((out / "report" / link).is_file() for link in links)
    assert md.index("## Verdict") < md.index("## Stages")


@pytest.mark.slow
def test_products_and_orthophotos_are_thumbnails(run_dir):
    survey_dir, out = run_dir
    from lidarcat.lidar.geotiff import GeoTransform, write_geotiff
    from lidarcat.report.render import markdown_to_html
    from lidarcat.survey import Survey

    (out / "products").mkdir(exist_ok=True)
    (out / "mapping").mkdir(exist_ok=True)
    yy, xx = np.mgrid[0:60, 0:80]
    write_geotiff(out / "products" / "dtm.tif", 900.0 + 0.1 * xx + 0.05 * yy, GeoTransform(680000, 7184400, 5),
                  "EPSG:31982")
    rgb = np.dstack([xx * 3, yy * 4, np.full_like(xx, 128)]).astype(np.uint8)
    write_geotiff(out / "mapping" / "mosaic.tif", rgb, GeoTransform(680000, 7184400, 5), "EPSG:31982")
    q = quality_report(out, Survey.load(survey_dir), {}, stages=[], products={"files": ["dtm.tif"]},
                       mapping={"orthophotos": ["ortho_1.tif"]})
    assert q.verdict == "**PASSED**: 1 LiDAR product file(s); 1 orthophoto(s)."
    assert "thumbnails.png" in q.figures and q.figures["thumbnails.png"][:8] == b"\x89PNG\r\n\x1a\n"
    md = "# t\n" + "\n".join(q.lines)
    (out / "q").mkdir(exist_ok=True)
    (out / "q" / "quality").mkdir(exist_ok=True)
    for name, png in q.figures.items():
        (out / "q" / "quality" / name).write_bytes(png)
    sections = _sections(markdown_to_html(md, "t", base=out / "q"))
    part = sections["products-and-orthophotos"]
    assert "products/dtm.tif" in part and "mapping/mosaic.tif" in part and "data:image/png;base64," in part


def test_ce90_le90_of_normal_errors_match_their_rmse_reading():
    rng = np.random.default_rng(5)
    d = rng.normal(0.0, [0.1, 0.1, 0.2], size=(20000, 3))
    r = ce90_le90(d)
    assert r["ce90_m"] == pytest.approx(2.1460 * 0.1, rel=0.02)      # 2.1460 sigma for a circular normal
    assert r["le90_m"] == pytest.approx(1.6449 * 0.2, rel=0.02)
    assert r["ce90_empirical_m"] == pytest.approx(r["ce90_m"], rel=0.03)
    assert r["le90_empirical_m"] == pytest.approx(r["le90_m"], rel=0.03)


def test_ellipse_axes_of_a_rotated_covariance():
    t = np.radians(30.0)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    cov = rot @ np.diag([9.0, 1.0]) @ rot.T
    ab, theta = ellipse_axes(cov[None])
    np.testing.assert_allclose(ab[0], [3.0, 1.0], rtol=1e-12)
    assert np.degrees(theta[0]) == pytest.approx(30.0, abs=1e-9)
