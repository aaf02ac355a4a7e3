"""``lidarcat match`` on rendered photos: tie points within 1 px of truth, written atomically; bad input."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.errors import LidarcatError, SurveyError
from lidarcat.match import MatchError
from lidarcat.stages.match import match, planned
from lidarcat.survey.folder import Survey
from lidarcat.synthetic.textured import observation_errors, write_textured_survey


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Six 640 x 480 photos in two strips (60 % / 30 %), orientations 2 m / 0.5 deg off."""
    return write_textured_survey(tmp_path_factory.mktemp("textured") / "survey", seed=1)


@pytest.fixture
def survey(rendered, tmp_path):
    folder = tmp_path / "survey"
    shutil.copytree(rendered.folder, folder)
    return folder


def _errors(rendered, folder):
    ip = Survey.load(folder).image_points
    auto = np.char.startswith(ip.point.astype(str), "tp")
    idx = {p: i for i, p in enumerate(rendered.ids)}
    photo = np.array([idx[p] for p in ip.photo[auto]])
    track = np.unique(ip.point[auto], return_inverse=True)[1]
    return ip, observation_errors(rendered.ground, rendered.camera, rendered.true_eo, track, photo,
                                  ip.pixel_px[auto])


def test_match_end_to_end_within_a_pixel_of_truth(rendered, survey):
    res = match(survey)
    ip, err = _errors(rendered, survey)
    assert res.n_observations == len(err) > 1500
    assert np.mean(err < 1.0) >= 0.99
    assert res.n_pairs == 13 and res.n_pairs_verified == 13          # 2 x 3 photos at 60 / 30 %: 13 pairs
    per_photo = {r["photo"]: r for r in res.summary["per_photo"]}
    assert all(r["tie_points"] >= 100 for r in per_photo.values())
    # every tie point has two rays or more, on different photos
    s = Survey.load(survey)
    assert len(s.tie_points) == res.n_tie_points
    # report and provenance
    out = survey / "out" / "match"
    assert {p.name for p in out.iterdir()} >= {"match_report.json", "match_pairs.csv", "match_photos.csv", "features"}
    assert len(list((out / "features").glob("*.npz"))) == 6
    side = json.loads((survey / "image_points.csv.json").read_text())
    assert side["provenance"]["parameters"]["prefix"] == "tp"
    assert (survey / "image_points.csv").read_text().splitlines()[0] == "photo,point,col_px,row_px,sd_x_mm,sd_y_mm"
    # a second run replaces its own rows (features from the cache): the same table
    before = (survey / "image_points.csv").read_bytes()
    again = match(survey)
    assert again.n_replaced == res.n_observations
    assert (survey / "image_points.csv").read_bytes() == before
    assert planned(Survey.load(survey)) is not None      # enough tie points: `lidarcat run` skips the stage


def test_hand_measured_rows_are_kept(survey):
    from lidarcat.match import FeatureOptions

    (survey / "image_points.csv").write_text("photo,point,col_px,row_px\n01,G1,100.5,200.25\n02,G1,400,210\n")
    match(survey, features=FeatureOptions(max_features=1000))
    ip = Survey.load(survey).image_points
    g1 = ip.point == "G1"
    assert ip.photo[g1].tolist() == ["01", "02"]
    assert ip.pixel_px[g1].tolist() == [[100.5, 200.25], [400.0, 210.0]]


def _unchanged(survey, before):
    assert (survey / "image_points.csv").read_bytes() == before
    assert not (survey / "image_points.csv.json").exists()
    assert not (survey / "out" / "match" / "match_report.json").exists()


def test_corrupt_image_is_a_located_error(survey):
    before = (survey / "image_points.csv").read_bytes()
    img = survey / "images" / "03.png"
    data = bytearray(img.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 2000] = bytes(2000)            # header and end intact, the pixel data broken
    img.write_bytes(bytes(data))
    with pytest.raises(SurveyError, match=r"photos\.csv:4: field 'image': photo '03'"):
        match(survey)
    _unchanged(survey, before)


def test_truncated_image_is_a_located_error(survey):
    before = (survey / "image_points.csv").read_bytes()
    img = survey / "images" / "02.png"
    img.write_bytes(img.read_bytes()[:5000])
    with pytest.raises(SurveyError, match=r"photos\.csv:3: field 'image'"):
        match(survey)
    _unchanged(survey, before)


def test_image_of_another_size_is_a_located_error(survey):
    import cv2

    before = (survey / "image_points.csv").read_bytes()
    cv2.imwrite(str(survey / "images" / "05.png"), np.zeros((300, 400), np.uint8))
    with pytest.raises(SurveyError, match=r"photos\.csv:6: field 'image': photo '05'.* 400 x 300 px but camera"):
        match(survey)
    _unchanged(survey, before)


def test_no_overlap_at_all_writes_nothing(survey):
    lines = (survey / "photos.csv").read_text().splitlines()
    moved = [lines[0]]
    for k, line in enumerate(lines[1:]):
        cells = line.split(",")
        cells[3] = f"{float(cells[3]) + 1000.0 * k:.3f}"      # 1 km apart: footprints of 160 m never meet
        moved.append(",".join(cells))
    (survey / "photos.csv").write_text("\n".join(moved) + "\n")
    before = (survey / "image_points.csv").read_bytes()
    with pytest.raises(MatchError, match=r"no two of the 6 photos overlap by 10% or more"):
        match(survey)
    _unchanged(survey, before)


def test_cli_json_and_one_line_error(survey):
    r = CliRunner().invoke(cli, ["match", str(survey), "--per-cell", "4", "--max-features", "1000", "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert rep["photos"] == 6 and rep["options"]["per_cell"] == 4 and rep["tie_points"] > 100
    (survey / "images" / "01.png").write_bytes(b"not an image")
    r = CliRunner().invoke(cli, ["match", str(survey)])
    assert r.exit_code == 2
    assert r.output.count("\n") == 1 and r.output.startswith("Error: ") and "photos.csv:2: field 'image'" in r.output


def test_cli_scheduler_names_the_choices(survey):
    r = CliRunner().invoke(cli, ["match", str(survey), "--scheduler", "cluster"])
    assert r.exit_code == 2
    assert ("Invalid value for '--scheduler': 'cluster': one of synchronous, threads, processes, or a Dask "
            "scheduler's address (tcp://host:8786)") in r.output
    assert not (survey / "out").exists()


def test_a_large_block_without_orientation_is_refused():
    from lidarcat.match import Features, MatchOptions, match_block
    from lidarcat.synthetic.textured import small_camera

    cam = small_camera()
    empty = Features(np.empty((0, 2)), np.empty((0, 128), np.uint8), np.empty(0, np.float32),
                     np.empty(0, np.float32), 0)
    with pytest.raises(LidarcatError, match=r"a block of 31 photos is matched by footprints"):
        match_block([cam] * 31, [None] * 31, lambda i: empty, options=MatchOptions(max_exhaustive=30))


def test_lidarcat_run_matches_first_and_writes_only_into_its_folder(survey):
    from lidarcat.pipeline.plan import run_pipeline

    before = (survey / "image_points.csv").read_bytes()
    res = run_pipeline(survey)
    ran = res.summary["stages_ran"]
    assert ran[:2] == ["match", "camera"]
    table = survey / "out" / "match" / "image_points.csv"
    assert (survey / "image_points.csv").read_bytes() == before          # the survey folder is not written
    n = len(table.read_text().splitlines()) - 1
    assert n > 1000 and len((survey / "out" / "camera" / "corrected.csv").read_text().splitlines()) - 1 == n
    again = run_pipeline(survey)
    assert again.summary["stages_reused"][:2] == ["match", "camera"]


@pytest.mark.slow
def test_match_on_realistic_aerial_photos_with_lidar(tmp_path):
    """synthetic.aerial (helper render's photos: fields, trees, shadows, roofs) with its LiDAR tiles as the
    surface: every observation within 1 px of where its track's first observation truly appears."""
    from lidarcat.synthetic.aerial import aerial_survey

    a = aerial_survey(tmp_path / "aer", n_strips=2, photos_per_strip=3, image_size_px=(640, 480), image_column=True,
                      seed=2)
    res = match(tmp_path / "aer")
    assert res.surface == "lidar dsm"
    ip = Survey.load(tmp_path / "aer").image_points
    auto = np.char.startswith(ip.point.astype(str), "tp")
    pts, ph, xy = ip.point[auto], ip.photo[auto], ip.pixel_px[auto]
    order = np.lexsort((ph, pts))
    pts, ph, xy = pts[order], ph[order], xy[order]
    first = np.r_[True, pts[1:] != pts[:-1]]
    head = np.maximum.accumulate(np.where(first, np.arange(len(pts)), 0))
    err = np.array([np.hypot(*(a.transfer(ph[head[k]], xy[head[k]][None], ph[k])[0] - xy[k]))
                    for k in np.flatnonzero(~first)])
    err = err[np.isfinite(err)]
    assert len(err) > 300 and np.mean(err < 1.0) >= 0.99


def test_the_scheduler_does_not_change_the_tie_points(tmp_path):
    """Serial, 2 threads and 2 Dask worker processes (features through the on-disk cache, a pair task
    reading only its two photos) write the same image_points.csv, byte for byte."""
    small = write_textured_survey(tmp_path / "base", n_strips=1, per_strip=3, columns_px=480, rows_px=360, seed=3)
    tables, reports = {}, {}
    for sched in ("synchronous", "threads", "processes"):
        folder = tmp_path / sched
        shutil.copytree(small.folder, folder)
        seen = []
        res = match(folder, workers=2, scheduler=sched, cache=False,
                    progress=lambda step, done, total: seen.append((step, done, total)))
        tables[sched] = (folder / "image_points.csv").read_text()
        reports[sched] = res.summary
        # a progress call per photo, then per pair, ending at the totals
        assert [s for s in seen if s[0] == "features"][-1] == ("features", 3, 3)
        assert [s for s in seen if s[0] == "pairs"][-1] == ("pairs", res.n_pairs, res.n_pairs)
        assert not list((folder / "out" / "match").glob(".features-*"))      # the spilled features are removed
    assert reports["synchronous"]["tie_points"] > 100
    assert tables["synchronous"] == tables["threads"] == tables["processes"]
    assert [r["keypoints"] for r in reports["processes"]["per_photo"]] == \
        [r["keypoints"] for r in reports["synchronous"]["per_photo"]]
    assert reports["processes"]["scheduler"] == "processes"
