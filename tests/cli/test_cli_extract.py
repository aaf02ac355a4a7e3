"""``lidarcat extract``: job files (thesis and CSV), --at, --find, outputs, failures in a batch."""

import csv
import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import DATA
from lidarcat.cli.main import cli
from lidarcat.control.batch import read_jobs
from lidarcat.errors import ExtractionError
from lidarcat.synthetic.roofs import synthetic_roof


def _xyz_file(path, xyz):
    np.savetxt(path, xyz, fmt="%.3f")
    return path


@pytest.fixture()
def synthetic_job(tmp_path):
    s = synthetic_roof("pyramid", slope_deg=25, density_m2=6, noise_h_m=0.03, seed=21)
    _xyz_file(tmp_path / "faixa.xyz", s.xyz)
    flat = synthetic_roof("flat", density_m2=6, seed=22, origin=(677100.0, 7183100.0, 900.0))
    _xyz_file(tmp_path / "flat.xyz", flat.xyz)
    v = s.vertices[0]
    (tmp_path / "jobs.txt").write_text(
        f"# file point E N threshold radius\n"
        f"faixa.xyz P704 {v[0] + 0.4:.1f} {v[1] - 0.3:.1f} 0.15 5.0\n"
        f"flat.xyz P705 677100.0 7183100.0 0.15 5.0\n"
        f"faixa.xyz P706 {v[0] + 300:.1f} {v[1]:.1f} 0.15 5.0\n")
    return tmp_path, v


def test_thesis_job_file_batch_goes_on(synthetic_job):
    tmp, v = synthetic_job
    r = CliRunner().invoke(cli, ["extract", str(tmp / "jobs.txt"), "-o", str(tmp / "control.csv"),
                                 "--planes", str(tmp / "planes.csv"), "--figures", str(tmp / "figs")])
    assert r.exit_code == 0, r.output
    assert "1 of 3 roofs gave a control point" in r.output
    rows = list(csv.DictReader(l for l in open(tmp / "control.csv") if not l.startswith("#")))
    assert [x["point"] for x in rows] == ["P704", "P705", "P706"]
    assert list(rows[0])[:10] == ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "n_planes",
                                  "misclosure_m", "status"]
    assert rows[0]["status"] == "ok" and rows[0]["n_planes"] == "4"
    np.testing.assert_allclose([float(rows[0][k]) for k in "ENh"], v, atol=0.1)
    assert rows[1]["status"] == "flat_roof" and "flat" in rows[1]["reason"]
    assert rows[2]["status"] == "too_few_points"
    assert rows[2]["reason"] == ("0 points within 5 m; 3 planes need at least 18 "
                                 "(increase the radius or check the position)")
    planes = list(csv.DictReader(l for l in open(tmp / "planes.csv") if not l.startswith("#")))
    assert len([p for p in planes if p["point"] == "P704"]) == 4
    for p in planes:
        assert {"a", "b", "c", "d", "sd_a", "n_used", "n_rejected", "rms_m", "slope_deg", "aspect_deg"} <= set(p)
        assert float(p["slope_deg"]) == pytest.approx(25, abs=1.5)
    assert sorted(f.name for f in (tmp / "figs").iterdir()) == ["P704.png", "P705.png", "P706.png"]


def test_thesis_preset_and_spec_sd(synthetic_job):
    tmp, v = synthetic_job
    r = CliRunner().invoke(cli, ["extract", str(tmp / "jobs.txt"), "--preset", "thesis", "--spec-sd",
                                 "0.5", "0.15", "--json"])
    assert r.exit_code == 0, r.output
    pts = json.loads(r.output)["points"]
    assert pts[0]["status"] == "ok"
    assert pts[0]["sd_E"] == pytest.approx(0.5) and pts[0]["sd_h"] == pytest.approx(0.15)
    assert pts[0]["cov_source"] == "specification"


def test_at_json_on_ahn3(tmp_path):
    lid = DATA / "lidar"
    r = CliRunner().invoke(cli, ["extract", "--lidar", str(lid / "ahn3_cropped_1.laz"),
                                 "--lidar", str(lid / "ahn3_cropped_2.laz"), "--crs", "EPSG:7415",
                                 "--at", "85010.0", "447475.0", "--json"])
    assert r.exit_code == 0, r.output
    d = json.loads(r.output)
    assert {"point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "n_planes", "misclosure_m", "status",
            "planes"} <= set(d)
    # A11 of tests/data/extract/ahn3_vertices.csv: the apex of 4 faces, listed at radius 8 m (the default)
    assert d["status"] == "ok" and d["n_planes"] == 4
    np.testing.assert_allclose([d["E"], d["N"], d["h"]], [85010.170, 447474.781, 14.220], atol=0.05)


def test_find_writes_geojson_and_csv(tmp_path):
    lid = DATA / "lidar"
    out = tmp_path / "cand.geojson"
    r = CliRunner().invoke(cli, ["extract", "--find", "--lidar", str(lid / "ahn3_cropped_2.laz"),
                                 "--crs", "EPSG:7415", "--classes", "6",
                                 "--box", "85000", "447460", "85050", "447520", "-o", str(out),
                                 "--index-cache", str(tmp_path / "index.json")])
    assert r.exit_code == 0, r.output
    assert "ahn3_cropped_2.laz" in (tmp_path / "index.json").read_text()  # --index-cache serves --find too
    fc = json.loads(out.read_text())
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) >= 3
    f0 = fc["features"][0]
    assert f0["geometry"]["type"] == "Point" and 0 < f0["properties"]["score"] <= 1
    assert f0["properties"]["n_planes"] >= 3
    # A10 (85036.956, 447493.697) of the test list is proposed
    xy = np.array([f["geometry"]["coordinates"][:2] for f in fc["features"]])
    assert np.min(np.hypot(*(xy - [85036.956, 447493.697]).T)) < 0.1
    r = CliRunner().invoke(cli, ["extract", "--find", "--lidar", str(lid / "ahn3_cropped_2.laz"),
                                 "--crs", "EPSG:7415", "--classes", "6",
                                 "--box", "85000", "447460", "85050", "447520", "-o", str(tmp_path / "c.csv")])
    assert r.exit_code == 0
    rows = list(csv.DictReader(open(tmp_path / "c.csv")))
    assert len(rows) == len(fc["features"]) and "score" in rows[0]


def test_usage_errors():
    r = CliRunner().invoke(cli, ["extract"])
    assert r.exit_code == 2 and "exactly one of" in r.output
    r = CliRunner().invoke(cli, ["extract", "--at", "1", "2"])
    assert r.exit_code == 2 and "need --lidar" in r.output
    # no traceback from the parameter checks of the library
    r = CliRunner().invoke(cli, ["extract", "--at", "1", "2", "--radius", "-1"])
    assert r.exit_code == 2 and "Invalid value for --radius: must be positive (m), got -1" in r.output
    r = CliRunner().invoke(cli, ["extract", "--find", "--box", "10", "0", "5", "20"])
    assert r.exit_code == 2 and "Invalid value for --box: 10 0 5 20: need XMIN < XMAX and YMIN < YMAX" in r.output
    r = CliRunner().invoke(cli, ["extract", "--find", "--lidar", ".", "--planes", "p.csv", "--spec-sd", "0.5", "0.15"])
    assert r.exit_code == 2 and "--planes, --spec-sd: for jobs and --at, not --find" in r.output  # were ignored


def test_bad_job_file_is_located(tmp_path):
    p = tmp_path / "jobs.txt"
    p.write_text("faixa.xyz P704 677757.8 7183482.0 0.15\n")
    with pytest.raises(ExtractionError, match=r"jobs.txt:1: 5 fields, expected 6"):
        read_jobs(p)
    p.write_text("faixa.xyz P704 677757,8 7183482,0 0,15 5,0\n")  # decimal commas (thesis files)
    job = read_jobs(p)[0]
    assert (job.point, job.e_m, job.n_m, job.threshold_m, job.radius_m) == ("P704", 677757.8, 7183482.0, 0.15, 5.0)
    p.write_text("faixa.xyz P704 677757.8 7183482.0 0.15 0\n")
    with pytest.raises(ExtractionError, match=r"jobs.txt:1: field 'radius': must be positive \(got 0\)"):
        read_jobs(p)
    p.write_text("faixa.xyz P704 677757.8 x 0.15 5.0\n")
    r = CliRunner().invoke(cli, ["extract", str(p)])
    assert r.exit_code == 2 and "jobs.txt:1: field 'N': 'x' is not a number" in r.output
    c = tmp_path / "jobs.csv"
    c.write_text("point,E,N,radius_m\nA,1.0,2.0,6\n")
    jobs = read_jobs(c)
    assert jobs[0].point == "A" and jobs[0].radius_m == 6.0 and jobs[0].threshold_m is None
    assert jobs[0].sd_en_m is None and jobs[0].sd_h_m is None
    c.write_text("point,E,N,sd_en_m,sd_h_m\nA,1.0,2.0,0.03,0.05\nB,1.0,2.0,,\n")
    jobs = read_jobs(c)
    assert (jobs[0].sd_en_m, jobs[0].sd_h_m) == (0.03, 0.05) and jobs[1].sd_en_m is None
    c.write_text("point,E,N,sd_en_m,sd_h_m\nA,1.0,2.0,0.03,0.05\nB,1.0,2.0,0,0.05\n")
    with pytest.raises(ExtractionError, match=r"jobs.csv:3: field 'sd_en_m': must be positive"):
        read_jobs(c)
    # a zero radius or negative threshold in a CSV job is located too (was a traceback / silent no_planes)
    c.write_text("point,E,N,radius_m,threshold_m\nA,1.0,2.0,0,\n")
    with pytest.raises(ExtractionError, match=r"jobs.csv:2: field 'radius_m': must be positive \(got 0\)"):
        read_jobs(c)
    c.write_text("point,E,N,radius_m,threshold_m\nA,1.0,2.0,6,-0.15\n")
    with pytest.raises(ExtractionError, match=r"jobs.csv:2: field 'threshold_m': must be positive \(got -0.15\)"):
        read_jobs(c)


def test_pdal_two_plane_building_in_a_batch(tmp_path):
    laspy = pytest.importorskip("laspy")
    src = DATA / "lidar" / "pdal_sample_c.las"
    shutil.copy(src, tmp_path / "sample_c.las")
    las = laspy.read(src)
    c = np.median(np.column_stack([las.x, las.y]), axis=0)
    (tmp_path / "jobs.csv").write_text(f"point,E,N,radius_m,file\nG1,{c[0]:.2f},{c[1]:.2f},8,sample_c.las\n")
    r = CliRunner().invoke(cli, ["extract", str(tmp_path / "jobs.csv"), "--json"])
    assert r.exit_code == 1, r.output   # no roof gave a point: exit status 1, the rows still printed
    p = json.loads(r.output)["points"][0]
    # the low-pitch gable of tests/test_facets.py: two faces, a row with the reason, no exception
    assert p["status"] == "two_planes" and p["n_planes"] == 2
    assert p["reason"] == "two faces found: they meet in a ridge line, not a point"


def test_find_classes_on_text_points_is_a_clear_error(tmp_path):
    s = synthetic_roof("hip", density_m2=4, seed=3)
    _xyz_file(tmp_path / "a.xyz", s.xyz)
    r = CliRunner().invoke(cli, ["extract", "--find", "--lidar", str(tmp_path / "a.xyz"), "--classes", "6"])
    assert r.exit_code == 2 and "the points carry no classification" in r.output
    r = CliRunner().invoke(cli, ["extract", "--find", "--lidar", str(tmp_path / "a.xyz"), "--json"])
    assert r.exit_code == 0, r.output
    feats = json.loads(r.output)["candidates"]
    xy = np.array([f["geometry"]["coordinates"] for f in feats])
    for v in s.vertices:  # both ridge ends of the hip roof are proposed
        assert np.min(np.linalg.norm(xy - v, axis=1)) < 0.15


def test_job_file_not_utf8_is_a_located_error(tmp_path):
    from lidarcat.errors import ExtractionError
    from lidarcat.control.batch import read_jobs

    p = tmp_path / "jobs.csv"
    p.write_bytes(b"point,E,N\nPra\xe7a,85000,447472\n")
    with pytest.raises(ExtractionError, match=r"jobs.csv:2: byte 0xe7 is not UTF-8 text; save the file as UTF-8$"):
        read_jobs(p)
    with pytest.raises(ExtractionError, match=r"nope.csv: file not found"):
        read_jobs(tmp_path / "nope.csv")
