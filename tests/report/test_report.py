"""The accuracy report: thesis GPS run from an adjustment-output fixture, assess-only runs, bad input."""

from __future__ import annotations

import base64
import csv
import json
import re

import numpy as np
import pytest

from conftest import DATA, THESIS_SURVEY
from lidarcat.accuracy.checkpoints import assess
from lidarcat.errors import AssessmentError
from lidarcat.geometry.collinearity import rotation_matrix
from lidarcat.report.document import SECTIONS, footprints, load_adjustment, write_report

REPORT_FIXTURE = DATA / "report"
SECTION_IDS = [sid for sid, _ in SECTIONS]


@pytest.fixture(scope="module")
def gps_assessment():
    return assess(REPORT_FIXTURE / "points.csv", THESIS_SURVEY / "ground_points.csv", scale=2000,
                  contour_interval_m=2.0, plotting_position="hazen", lilliefors_n_sim=2000)


@pytest.fixture(scope="module")
def gps_report(gps_assessment, tmp_path_factory):
    out = tmp_path_factory.mktemp("rep")
    camera = {"focal_length_mm": 51.902, "pixel_size_x_mm": 0.0079, "pixel_size_y_mm": 0.0079,
              "columns_px": 3000, "rows_px": 4500}  # thesis Table 1 and section 3.1
    paths = write_report(out / "gps.html", assessment=gps_assessment, adjustment_dir=REPORT_FIXTURE,
                         camera=camera, title="Thesis GPS run")
    return paths


def test_fixture_selects_the_13_table7_check_points(gps_assessment):
    assert gps_assessment.points == ("603", "605", "606", "615", "616", "617", "618", "620", "621", "622",
                                     "623", "625", "626")


def test_report_files_and_sections(gps_report):
    assert gps_report["html"].name == "gps.html" and gps_report["markdown"].name == "gps.md"
    html = gps_report["html"].read_text()
    for sid in SECTION_IDS:
        assert f'<section id="{sid}">' in html
    # the thesis sections' content
    for text in ("degrees of freedom", "148.3500", "677344.860 ± 2.429", "-0.122", "Filliben PPCC normality",
                 "t-Student trend", "chi-square precision", "Hotelling T^2", "90 % circular error radius",
                 "Decreto n. 89.817", "PEC-PCD", "ASPRS", "NSSDA", "Tested 0.293 (m) horizontal accuracy"):
        assert text in html, text
    assert html.count('<td class="FAILED">') >= 1  # dh shows a trend in the GPS run (t = -3.0)
    assert "Not applicable: no second run" in html


def test_report_is_self_contained_offline(gps_report):
    html = gps_report["html"].read_text()
    assert not re.search(r'(src|href)="(https?:)?//', html)
    imgs = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)
    assert len(imgs) == 4  # layout, vectors, heights, Q-Q
    for b64 in imgs:
        assert base64.b64decode(b64)[:8] == b"\x89PNG\r\n\x1a\n"
    assert all(p.is_file() and p.read_bytes()[:4] == b"\x89PNG" for p in gps_report["figures"])
    md = gps_report["markdown"].read_text()
    assert "](gps_figures/qq_plots.png)" in md and "## Statistical tests" in md
    assert "| 603 | -0.122 | 0.148 | -0.247 |" in md


def test_report_json(gps_report):
    doc = json.loads(gps_report["json"].read_text())
    assert doc["sections"] == SECTION_IDS
    assert doc["assessment"]["standards"]["pec"]["class"] == {"planimetric": "A", "altimetric": "A"}
    assert doc["adjustment"]["summary"]["dof"] == 128
    assert sorted(doc["footprints"]) == ["1", "2", "3", "4", "5", "6"]


def test_footprint_convention_matches_thesis_image_measurements():
    # projecting the adjusted points with Table 6 gives the Appendix 1 photo coordinates (0.02 mm),
    # so the rotation used for the footprints is the thesis's; measured points lie inside their photo
    adj = load_adjustment(REPORT_FIXTURE)
    eop = {r["photo"]: r for r in adj["eop"]}
    pts = {r["point"]: np.array([float(r[k]) for k in ("E", "N", "h")]) for r in adj["points"]}
    cam = {"*": {"focal_length_mm": 51.902, "width_mm": 3000 * 0.0079, "height_mm": 4500 * 0.0079}}
    errs = []
    with open(THESIS_SURVEY / "image_points.csv", newline="") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    for r in rows:
        if r["point"] not in pts:
            continue
        e = eop[r["photo"]]
        m = rotation_matrix(np.radians([float(e["omega"]), float(e["phi"]), float(e["kappa"])]))
        u = m @ (pts[r["point"]] - np.array([float(e["X0"]), float(e["Y0"]), float(e["Z0"])]))
        errs.append([-51.902 * u[0] / u[2] - float(r["x_mm"]), -51.902 * u[1] / u[2] - float(r["y_mm"])])
    assert np.max(np.abs(errs)) < 0.03
    from matplotlib.path import Path as MplPath

    # each measured point whose corrected photo coordinates are inside the frame lies inside its photo's
    # footprint on the plane at the point's own height (627 on photos 2 and 4 is on the border row)
    inside = [MplPath(footprints(adj["eop"], cam, pts[r["point"]][2])[r["photo"]]).contains_point(pts[r["point"]][:2])
              for r in rows if r["point"] in pts
              and abs(float(r["x_mm"])) < 11.85 and abs(float(r["y_mm"])) < 17.775]
    assert len(inside) == 149 and all(inside)


def test_assess_only_report_marks_sections_not_applicable(tmp_path):
    a = assess({"1": (0, 0, 0), "2": (100, 0, 0)}, {"1": (0.1, 0.0, 0.2), "2": (100.0, 0.1, -0.1)},
               scale=2000, contour_interval_m=2)
    paths = write_report(tmp_path / "out", assessment=a)
    assert paths["html"] == tmp_path / "out" / "report.html"
    html = paths["html"].read_text()
    assert "Not applicable: no adjustment output was given (assess-only run)." in html
    assert "Not applicable: no exterior orientation was given" in html
    assert "Not applicable: fewer than 3 check points." in html
    assert "needs at least 3 points, got 2" in html
    assert '<td class="na">not applicable</td>' in html
    assert (tmp_path / "out" / "report.md").is_file() and (tmp_path / "out" / "report.json").is_file()


def test_adjustment_only_report_and_dict_input(tmp_path):
    adj = load_adjustment(REPORT_FIXTURE)
    paths = write_report(tmp_path, adjustment_dir={"eop": adj["eop"], "points": adj["points"],
                                                   "summary": adj["summary"]}, survey=THESIS_SURVEY)
    html = paths["html"].read_text()
    assert "Not available: no check-point assessment was given." in html
    assert json.loads(paths["json"].read_text())["assessment"] is None
    assert len(json.loads(paths["json"].read_text())["footprints"]) == 6  # camera from the survey folder


def test_comparison_section(tmp_path, gps_assessment):
    other = assess(REPORT_FIXTURE / "points.csv", THESIS_SURVEY / "ground_points.csv", scale=2000,
                   contour_interval_m=2.0, sign="adjusted_minus_reference", lilliefors_n_sim=500)
    paths = write_report(tmp_path / "c.html", assessment=gps_assessment, comparison=("LiDAR run", other))
    html = paths["html"].read_text()
    assert "Check-point statistics of this run and of LiDAR run." in html
    # Table 7 side by side: the other sign flips the means (dh -0.397 m), never the sd
    md = paths["markdown"].read_text()
    assert "| h | mean | -0.397 | 0.397 |" in md and "| h | std | 0.476 | 0.476 |" in md
    assert "| t-Student trend (eq. 43, 44) | h | FAILED | FAILED |" in md
    doc = json.loads(paths["json"].read_text())
    assert doc["comparison"]["settings"]["sign"] == "adjusted_minus_reference"


def test_bad_input(tmp_path):
    with pytest.raises(AssessmentError, match="nothing to report"):
        write_report(tmp_path)
    with pytest.raises(AssessmentError, match="adjustment output folder not found"):
        write_report(tmp_path, adjustment_dir=tmp_path / "missing")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "summary.json").write_text("{not json")
    with pytest.raises(AssessmentError, match=r"summary\.json: cannot read the adjustment summary"):
        write_report(tmp_path / "o", adjustment_dir=bad)
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_standards_notes_the_report_cites_exist_in_the_repo_and_the_wheel(gps_report):
    """The report and `assess` cite STANDARDS.md (open items, [K] tags, "confidence P"): the file is
    docs/standards.md, shipped in the wheel as lidarcat/standards_data/STANDARDS.md, and every open
    item and label cited by the code or its data is explained there."""
    import tomllib
    from pathlib import Path

    from conftest import ROOT
    from lidarcat.accuracy.standards import CONFIDENCE_LABELS, notes_path

    notes = notes_path()
    assert notes.is_file()
    text = (ROOT / "docs" / "standards.md").read_text(encoding="utf-8")
    assert notes.read_text(encoding="utf-8") == text
    force = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["hatch"]["build"]["targets"]["wheel"]
    assert force["force-include"]["docs/standards.md"] == "lidarcat/standards_data/STANDARDS.md"
    open_items = text[text.index("## 6. Open items"):]
    cited = set()
    src = ROOT / "src" / "lidarcat"
    for p in [*src.rglob("*.py"), *src.rglob("*.json")]:
        cited |= {int(n) for n in re.findall(r"STANDARDS\.md open item (\d+)", p.read_text(encoding="utf-8"))}
    assert cited and all(re.search(rf"^{n}\. ", open_items, re.M) for n in cited), cited
    for label, meaning in CONFIDENCE_LABELS.items():  # each label explained on the page and in the report
        assert re.search(rf"^> \| {label} \| ", text, re.M), label
    html = gps_report["html"].read_text()
    assert "Confidence of the rules of each standard, and tags such as [K] in the notes: P = primary text" in html
    assert "K = domain knowledge, not confirmed against the standard" in html
    assert "STANDARDS.md (docs/standards.md; installed as lidarcat/standards_data/STANDARDS.md)" in html
    assert isinstance(notes, Path)


def test_pipeline_markdown_goes_through_the_one_renderer(tmp_path):
    """The pipeline's index.md is read into the report model and rendered by the same to_html as the
    per-run report: its title, sections with anchors, tables with verdict cells, lists, links, and
    figures embedded from their PNG files."""
    from lidarcat.report.model import Bullets, Figure, Paragraph, Table, parse_markdown
    from lidarcat.report.render import markdown_to_html, to_markdown

    png = base64.b64decode("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8/5+hHgAHggJ/PchI7wAAAABJRU5ErkJggg==")
    (tmp_path / "f.png").write_bytes(png)
    md = ("# lidarcat report: s\n\n**Statistical test failed**\n\n## Stages\n\n| stage | state |\n|---|---|\n"
          "| adjust | FAILED |\n\n## Accuracy reports\n\n- [control set gps](../assess-gps/report.html)\n"
          "- [control set lidar](../assess-lidar/report.html)\n\n## Run gps\n\n![Run gps: block layout](f.png)\n")
    doc = parse_markdown(md)
    assert doc.title == "lidarcat report: s"
    assert [s.title for s in doc.sections] == ["", "Stages", "Accuracy reports", "Run gps"]
    assert isinstance(doc.sections[0].blocks[0], Paragraph)
    assert isinstance(doc.sections[1].blocks[0], Table) and doc.sections[1].blocks[0].rows == [["adjust", "FAILED"]]
    assert isinstance(doc.sections[2].blocks[0], Bullets) and len(doc.sections[2].blocks[0].items) == 2
    assert isinstance(doc.sections[3].blocks[0], Figure)
    page = markdown_to_html(md, "ignored: the # heading is the title", base=tmp_path)
    assert "<title>lidarcat report: s</title>" in page and "<h1>lidarcat report: s</h1>" in page
    assert "<section id='stages'><h2>Stages</h2>" in page and "<a href='#run-gps'>Run gps</a>" in page
    assert "<td class='FAILED'>FAILED</td>" in page and "<p><strong>Statistical test failed</strong></p>" in page
    assert ("<ul><li><a href='../assess-gps/report.html'>control set gps</a></li>"
            "<li><a href='../assess-lidar/report.html'>control set lidar</a></li></ul>") in page
    b64 = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", page)
    assert len(b64) == 1 and base64.b64decode(b64[0]) == png
    assert "<figcaption>Run gps: block layout</figcaption>" in page
    # a figure whose file is missing keeps its path
    assert "src='g.png'" in markdown_to_html("# t\n\n![x](g.png)\n", "t", base=tmp_path)
    # and back to Markdown: the same tables, lists and headings
    back = to_markdown(doc)
    assert "| adjust | FAILED |" in back and "- [control set gps](../assess-gps/report.html)" in back
    assert back.startswith("# lidarcat report: s\n\n**Statistical test failed**\n\n## Stages\n")
