"""`lidarcat match` names a blank photo as a reported skip and writes its tie points for the others."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.synthetic.textured import write_textured_survey


def test_a_blank_photo_is_named_and_the_others_are_matched(tmp_path):
    import cv2

    ts = write_textured_survey(tmp_path / "s", n_strips=1, per_strip=3, columns_px=320, rows_px=240, seed=2)
    cv2.imwrite(str(tmp_path / "s" / "images" / "03.png"), np.full((240, 320), 128, np.uint8))   # blank
    r = CliRunner().invoke(cli, ["match", str(ts.folder), "--per-cell", "0"])
    assert r.exit_code == 0, r.output
    assert "no tie point on 1 photo(s): 03 (no overlapping photo, no features, or no pair verified" in r.output
    rep = json.loads((tmp_path / "s" / "out" / "match" / "match_report.json").read_text())
    by_photo = {p["photo"]: p for p in rep["per_photo"]}
    assert by_photo["03"]["keypoints"] == 0 and by_photo["03"]["tie_points"] == 0
    assert by_photo["01"]["tie_points"] > 50 and by_photo["02"]["tie_points"] > 50


# --- bad input of the acceptance line (issue 28): one located line, nothing written --------------------

def _survey(tmp_path):
    ts = write_textured_survey(tmp_path / "s", n_strips=1, per_strip=3, columns_px=320, rows_px=240, seed=2)
    return ts.folder


def _refused(folder, want):
    """`lidarcat match` exits 2 with exactly *want* on one line, and the survey folder is as it was."""
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    r = CliRunner().invoke(cli, ["match", str(folder)])
    assert r.exit_code == 2, r.output
    assert r.output == f"Error: {want}\n"
    after = {p for p in folder.rglob("*") if p.is_file()}
    assert after == set(before) and all(p.read_bytes() == before[p] for p in after)


def _rows(folder):
    return (folder / "photos.csv").read_text().splitlines()


def test_a_photo_listed_twice_is_one_located_line(tmp_path):
    folder = _survey(tmp_path)
    lines = _rows(folder)
    (folder / "photos.csv").write_text("\n".join(lines + [lines[2]]) + "\n")
    _refused(folder, f"{folder / 'photos.csv'}:5: field 'photo': duplicate photo id (photo='02'); first defined "
                     f"on line 3")


def test_two_photos_of_one_image_file_is_one_located_line(tmp_path):
    folder = _survey(tmp_path)
    lines = _rows(folder)
    (folder / "photos.csv").write_text("\n".join(lines + ["04" + lines[2][2:]]) + "\n")
    _refused(folder, f"{folder / 'photos.csv'}:5: field 'image': photo '04': image 'images/02.png' is also the "
                     f"image of photo '02' (line 3); each photo has its own file")


def test_a_truncated_jpeg_is_one_located_line(tmp_path):
    import cv2

    folder = _survey(tmp_path)
    jpg = folder / "images" / "02.jpg"
    cv2.imwrite(str(jpg), cv2.imread(str(folder / "images" / "02.png")))
    (folder / "images" / "02.png").unlink()
    jpg.write_bytes(jpg.read_bytes()[:len(jpg.read_bytes()) // 2])
    (folder / "photos.csv").write_text((folder / "photos.csv").read_text().replace("images/02.png",
                                                                                   "images/02.jpg"))
    _refused(folder, f"{folder / 'photos.csv'}:3: field 'image': photo '02': {jpg}: truncated JPEG image: it does "
                     f"not end with the end-of-image marker FF D9 (the file was cut short; copy it again)")


def test_a_missing_image_file_is_one_located_line(tmp_path):
    folder = _survey(tmp_path)
    (folder / "images" / "02.png").unlink()
    _refused(folder, f"{folder / 'photos.csv'}:3: field 'image': photo '02': image 'images/02.png' not found "
                     f"({folder / 'images' / '02.png'})")


def test_photos_with_nothing_in_common_is_one_line_and_no_result(tmp_path):
    """Overlapping footprints but nothing to match on any pair (blank photos): no tie point is written."""
    import cv2

    folder = _survey(tmp_path)
    for p in (folder / "images").glob("*.png"):
        cv2.imwrite(str(p), np.full((240, 320), 128, np.uint8))
    before = (folder / "image_points.csv").read_bytes() if (folder / "image_points.csv").exists() else None
    r = CliRunner().invoke(cli, ["match", str(folder)])
    assert r.exit_code == 2 and r.output == ("Error: no pair of the 3 overlapping pairs has verified matches "
                                             "(first: photos '01'-'02': no matches)\n"), r.output
    after = (folder / "image_points.csv").read_bytes() if (folder / "image_points.csv").exists() else None
    assert after == before and not (folder / "image_points.csv.json").exists()
    assert not (folder / "out" / "match" / "match_report.json").exists()


def test_a_photo_without_orientation_in_a_small_block_is_matched_with_all_pairs(tmp_path):
    """A photo whose EXIF had no GNSS (photos.csv without its position and attitude): a small block is
    matched over all pairs, and the summary says so."""
    folder = _survey(tmp_path)
    lines = _rows(folder)
    cells = lines[2].split(",")
    cells[3:9] = [""] * 6
    lines[2] = ",".join(cells)
    (folder / "photos.csv").write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(cli, ["match", str(folder), "--per-cell", "0"])
    assert r.exit_code == 0, r.output
    assert "of 3 pairs verified (exhaustive" in r.output
    rep = json.loads((folder / "out" / "match" / "match_report.json").read_text())
    assert all(p["tie_points"] > 50 for p in rep["per_photo"])
