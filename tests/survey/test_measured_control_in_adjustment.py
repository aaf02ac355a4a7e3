"""The survey side of measured LiDAR control (issue 29): a ground point seen on one photo is left out of a
set where it is not control (it stays control where it is), and a line measured at a LiDAR point is control
only where that point is."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from lidarcat import Survey
from lidarcat.survey.adjustment import problem_from_survey
from lidarcat.survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS
from lidarcat.synthetic import write_synthetic_survey


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    return write_synthetic_survey(tmp_path_factory.mktemp("demo") / "s", lidar_density_m2=0.2).path


def _copy(demo, tmp_path):
    root = tmp_path / "s"
    shutil.copytree(demo, root)
    ip = root / "image_points.csv"
    rows = ip.read_text().splitlines()
    g2 = [k for k, r in enumerate(rows) if r.split(",")[1:2] == ["G02"]]
    assert len(g2) >= 2
    ip.write_text("\n".join(r for k, r in enumerate(rows) if k not in g2[1:]) + "\n")   # G02 on one photo
    cs = root / "control_sets.csv"
    cs.write_text(cs.read_text().rstrip("\n") + "\n" + "".join(f"g2,{g},control,,,\n" for g in
                                                                 ("G01", "G02", "G03", "G04")))
    return root, rows[g2[0]].split(",")[0]


def test_one_ray_ground_point_is_left_out_where_it_is_not_control(demo, tmp_path):
    root, photo = _copy(demo, tmp_path)
    s = Survey.load(root)
    p = problem_from_survey(s, "gps")              # G02 a check point of one ray: left out (was a DatumError)
    assert "G02" not in list(p.point_ids) and p.info["one_ray_dropped"] == ["G02"]
    p2 = problem_from_survey(s, "g2")              # G02 control: kept, on its one photo
    assert "G02" in list(p2.point_ids) and "one_ray_dropped" not in p2.info
    assert int(np.sum(np.asarray(p2.point_ids)[p2.point_index] == "G02")) == 1


def test_line_of_a_lidar_point_is_control_only_where_the_point_is(demo, tmp_path):
    root, photo = _copy(demo, tmp_path)
    header = ",".join(LINE_COLUMNS + LINE_EXTRA_COLUMNS)
    empty = [""] * len(LINE_COLUMNS + LINE_EXTRA_COLUMNS)
    col = {c: k for k, c in enumerate(LINE_COLUMNS + LINE_EXTRA_COLUMNS)}

    def row(**kw):
        r = list(empty)
        for k, v in kw.items():
            r[col[k]] = str(v)
        return ",".join(r)

    gp = {ln.split(",")[0]: ln.split(",") for ln in (root / "ground_points.csv").read_text().splitlines()[1:]}
    a = np.array(gp["G02"][1:4], float)
    lines = [row(line="G02/1-2", point="G02", e1_m=a[0], n1_m=a[1], h1_m=a[2], e2_m=a[0] + 5, n2_m=a[1],
                 h2_m=a[2], sd_across_m=0.02),
             row(line="G02/1-2", photo=photo, x1_mm=-1.0, y1_mm=2.0, x2_mm=3.0, y2_mm=2.5, sd_mm=0.003)]
    (root / "line_control.csv").write_text(header + "\n" + "\n".join(lines) + "\n")
    toml = root / "survey.toml"
    toml.write_text(toml.read_text().replace('extraction_jobs = "jobs.csv"',
                                             'extraction_jobs = "jobs.csv"\nline_control = "line_control.csv"'))
    s = Survey.load(root)
    assert len(problem_from_survey(s, "gps").lines.line_index) == 0
    p2 = problem_from_survey(s, "g2")
    assert list(p2.lines.line_ids) == ["G02/1-2"] and len(p2.lines.line_index) == 1
