"""Photos in the survey: the photos.csv ``image`` column, Survey.image_path, the checks at load, and a
survey without image observations yet (issue 28, part 1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lidarcat.errors import SurveyError
from lidarcat.geometry.camera import Camera
from lidarcat.survey.adjustment import problem_from_survey
from lidarcat.survey.folder import Survey

W, H = 60, 40


def _camera(cols: int = W, rows: int = H) -> Camera:
    return Camera("cam", 35.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.01, cols, rows)


def _survey(tmp_path: Path, rows: list[str], *, header: str = "photo,image", images: dict[str, tuple] | None = None,
            image_points: str = "photo,point,col_px,row_px\n") -> Path:
    """A survey folder with a 60 x 40 px camera, photos.csv of *rows* and the *images* (name -> (w, h))."""
    root = tmp_path / "s"
    (root / "images").mkdir(parents=True)
    for name, (w, h) in (images or {}).items():
        Image.new("L", (w, h), 128).save(root / "images" / name)
    (root / "camera.toml").write_text(_camera().to_toml())
    (root / "photos.csv").write_text(header + "\n" + "".join(r + "\n" for r in rows))
    (root / "image_points.csv").write_text(image_points)
    (root / "survey.toml").write_text('[survey]\nname = "t"\ncrs = "EPSG:31982"\n\n[files]\ncamera = "camera.toml"\n'
                                      'photos = "photos.csv"\nimage_points = "image_points.csv"\n')
    return root


def _err(root: Path) -> str:
    with pytest.raises(SurveyError) as ei:
        Survey.load(root)
    msg = str(ei.value)
    assert "\n" not in msg
    return msg


def test_image_column_round_trip(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg", "b,images/b.png", "c,"],
                   images={"a.jpg": (W, H), "b.png": (W, H), "c.tif": (W, H)})
    s = Survey.load(root)
    assert s.image_path("a") == root / "images" / "a.jpg"
    assert s.image_path("b") == root / "images" / "b.png"
    # an empty cell: the images/<photo>.<ext> convention of the orthophoto stage
    assert s.image_path("c") == root / "images" / "c.tif"
    assert [p.image for p in s.photos] == [root / "images" / "a.jpg", root / "images" / "b.png", None]
    assert s.has_images and s.to_dict()["n_images"] == 2
    # photos.csv written back with the same column reads the same
    assert Survey.load(root).photo("a").image == s.photo("a").image


def test_image_path_of_a_photo_without_image_is_located(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg", "b,"], images={"a.jpg": (W, H)})
    s = Survey.load(root)
    assert not s.has_images
    with pytest.raises(SurveyError) as ei:
        s.image_path("b")
    assert str(ei.value) == (f"{root / 'photos.csv'}:3: field 'image': photo 'b' has no image: give its file in the "
                             f"column 'image' (relative to the survey folder) or put it in {root / 'images'} as "
                             f"b.jpg/.png/.tif")
    (root / "images" / "a.jpg").unlink()   # gone after the load
    with pytest.raises(SurveyError, match=r"photos\.csv:2: field 'image': photo 'a': image .*a\.jpg not found"):
        s.image_path("a")


def test_missing_image_is_a_located_error(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg", "b,images/nope.jpg"], images={"a.jpg": (W, H)})
    assert _err(root) == (f"{root / 'photos.csv'}:3: field 'image': photo 'b': image 'images/nope.jpg' not found "
                          f"({root / 'images' / 'nope.jpg'})")


def test_same_image_for_two_photos(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg", "b,./images/a.jpg"], images={"a.jpg": (W, H)})
    assert _err(root) == (f"{root / 'photos.csv'}:3: field 'image': photo 'b': image './images/a.jpg' is also the "
                          f"image of photo 'a' (line 2); each photo has its own file")


def test_photo_listed_twice(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg", "a,images/b.jpg"], images={"a.jpg": (W, H), "b.jpg": (W, H)})
    assert _err(root) == f"{root / 'photos.csv'}:3: field 'photo': duplicate photo id (photo='a'); first defined on line 2"


def test_image_of_another_size_than_its_camera(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg"], images={"a.jpg": (H, W)})
    assert _err(root) == (f"{root / 'photos.csv'}:2: field 'image': photo 'a': image 'images/a.jpg' is 40 x 60 px "
                          f"but camera 'cam' is 60 x 40 px; fix the camera of this photo or the image")


@pytest.mark.parametrize("name, cut, why", [
    ("a.jpg", 30, "truncated JPEG image: it does not end with the end-of-image marker FF D9"),
    ("a.png", 20, "truncated PNG image: no IEND chunk at its end"),
])
def test_truncated_image(tmp_path, name, cut, why):
    root = _survey(tmp_path, [f"a,images/{name}"])
    rng = np.random.default_rng(1)
    Image.fromarray(rng.integers(0, 255, (H, W), dtype=np.uint8)).save(root / "images" / name)
    p = root / "images" / name
    p.write_bytes(p.read_bytes()[:-cut])
    assert _err(root) == f"{root / 'photos.csv'}:2: field 'image': photo 'a': {p}: {why} (the file was cut short; copy it again)"


def test_truncated_tiff(tmp_path):
    root = _survey(tmp_path, ["a,images/a.tif"])
    p = root / "images" / "a.tif"
    Image.fromarray(np.full((H, W), 7, np.uint8)).save(p)
    size = p.stat().st_size
    data = p.read_bytes()
    # a TIFF whose strip runs past the end of the file (what a cut-short copy of a TIFF with the IFD first
    # looks like): patch the StripByteCounts entry of Pillow's uncompressed file
    im = Image.open(p)
    off, cnt = im.tag_v2[273], im.tag_v2[279]
    im.close()
    off = off[0] if isinstance(off, tuple) else off
    cnt = cnt[0] if isinstance(cnt, tuple) else cnt
    assert off + cnt <= size
    import struct
    # StripByteCounts entry: patch its value to run past the end of the file
    marker = struct.pack("<HHI", 279, 4, 1) + struct.pack("<I", cnt)
    assert marker in data
    p.write_bytes(data.replace(marker, struct.pack("<HHI", 279, 4, 1) + struct.pack("<I", size)))
    assert _err(root) == (f"{root / 'photos.csv'}:2: field 'image': photo 'a': {p}: truncated TIFF image: its data "
                          f"runs to byte {off + size} but the file has {size} bytes (the file was cut short; copy it again)")


def test_unreadable_image(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg"])
    p = root / "images" / "a.jpg"
    p.write_bytes(b"this is no JPEG at all\n")
    assert _err(root) == (f"{root / 'photos.csv'}:2: field 'image': photo 'a': {p}: not a readable image "
                          f"(no JPEG, PNG or TIFF header)")


def test_image_of_another_format(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg"])
    p = root / "images" / "a.jpg"
    Image.new("L", (W, H)).save(p, format="GIF")
    assert _err(root) == f"{root / 'photos.csv'}:2: field 'image': photo 'a': {p}: a GIF image; photos must be JPEG, PNG or TIFF"


def test_a_survey_without_image_observations_loads_and_adjust_says_match_first(tmp_path):
    root = _survey(tmp_path, ["a,images/a.jpg", "b,images/b.jpg"], images={"a.jpg": (W, H), "b.jpg": (W, H)})
    s = Survey.load(root)
    assert len(s.image_points) == 0 and s.tie_points == ()
    with pytest.raises(SurveyError) as ei:
        problem_from_survey(s)
    assert str(ei.value) == (f"{root / 'image_points.csv'}: no image observations: run `lidarcat match {root}` first "
                             f"(or measure tie and control points into it)")


def test_adjust_command_on_a_survey_without_observations(tmp_path):
    from click.testing import CliRunner

    from conftest import assert_one_line_error
    from lidarcat.cli.main import cli

    root = _survey(tmp_path, ["a,images/a.jpg", "b,images/b.jpg"], images={"a.jpg": (W, H), "b.jpg": (W, H)})
    r = CliRunner().invoke(cli, ["adjust", str(root), "-o", str(tmp_path / "out")])
    assert_one_line_error(r, "no image observations: run `lidarcat match", "image_points.csv")
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_demo_synthetic_images_are_named_in_photos_csv(tmp_path):
    """`lidarcat demo synthetic --images`: photos.csv names each rendered photo (11 s at load 9)."""
    from lidarcat.synthetic.survey import write_synthetic_survey

    write_synthetic_survey(tmp_path / "d", n_photos=2, images=True, image_downsample=20, lidar_density_m2=0.5)
    s = Survey.load(tmp_path / "d")
    assert [p.image for p in s.photos] == [tmp_path / "d" / "images" / "1.png", tmp_path / "d" / "images" / "2.png"]
    assert s.image_path("2") == tmp_path / "d" / "images" / "2.png"
    assert (tmp_path / "d" / "photos.csv").read_text().splitlines()[:2] == ["photo,camera,image", "1,demo,images/1.png"]


def test_copy_photos_csv_keeps_the_images_of_a_derived_survey(tmp_path):
    """The extract stage's derived survey (out/extract/survey) copies photos.csv elsewhere: the image paths are
    rewritten relative to the copy, so the copy names the same files."""
    import shutil

    root = _survey(tmp_path, ["a,images/a.jpg", "b,"], images={"a.jpg": (W, H), "b.jpg": (W, H)})
    s = Survey.load(root)
    other = tmp_path / "out" / "extract" / "survey"
    other.mkdir(parents=True)
    for name in ("camera.toml", "image_points.csv", "survey.toml"):
        shutil.copyfile(root / name, other / name)
    s.copy_photos_csv(other / "photos.csv")
    assert (other / "photos.csv").read_text().splitlines() == ["photo,image", "a,../../../s/images/a.jpg", "b,"]
    d = Survey.load(other)
    assert d.photo("a").image.resolve() == (root / "images" / "a.jpg").resolve() and d.photo("b").image is None
