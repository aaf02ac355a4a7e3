"""lidarcat.stages.init.init_survey: a survey folder from a folder of photos (issue 28, part 1)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from pyproj import Transformer

from lidarcat.errors import LidarcatError, SurveyError
from lidarcat.geometry.camera import Camera
from lidarcat.stages.init import init_survey
from lidarcat.survey.folder import Survey

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "survey"))
from test_exif import write_photo  # noqa: E402

LATLON = [(-25.4300, -49.2700, 1000.0), (-25.4300, -49.2690, 1001.0), (-25.4300, -49.2680, 999.0)]


def _photos(tmp_path: Path, n: int = 3, **kw) -> Path:
    d = tmp_path / "photos"
    d.mkdir()
    for k in range(n):
        write_photo(d / f"IMG_{k:04d}.jpg", *LATLON[k % 3], direction=90.0, **kw)
    return d


def _nothing_written(folder: Path) -> None:
    assert not folder.exists(), sorted(p.name for p in folder.iterdir())
    assert not list(folder.parent.glob(f".{folder.name}.*.part"))


def test_init_from_exif_loads_with_images_and_positions(tmp_path):
    photos = _photos(tmp_path)
    res = init_survey(tmp_path / "s", photos)
    assert res.crs == "EPSG:32722" and res.photos == ("IMG_0000", "IMG_0001", "IMG_0002")
    s = Survey.load(tmp_path / "s")
    assert s.crs == "EPSG:32722" and len(s.image_points) == 0
    assert [s.image_path(p).resolve() for p in s.photo_ids] == [(photos / f"IMG_{k:04d}.jpg").resolve() for k in range(3)]
    tr = Transformer.from_crs("EPSG:4326", "EPSG:32722", always_xy=True)
    for ph, (lat, lon, h) in zip(s.photos, LATLON):
        e, n = tr.transform(lon, lat)
        assert ph.position_m == pytest.approx([e, n, h], abs=5e-3)
        np.testing.assert_allclose(ph.attitude_deg, [0.0, 0.0, -90.0])
        np.testing.assert_allclose(ph.sd_position_m, 5.0)
        np.testing.assert_allclose(ph.sd_attitude_deg, 5.0)
    cam = s.cameras["camera"]
    assert (cam.columns_px, cam.rows_px, cam.focal_length_mm) == (60, 40, 35.0)
    assert "self-calibration is advised" in cam.source
    assert any("approximate" in n for n in res.notes)


def test_init_with_a_gnss_file_in_the_survey_crs(tmp_path):
    photos = _photos(tmp_path)
    gnss = tmp_path / "gnss.txt"
    gnss.write_text("photo,E,N,h,omega,phi,kappa,sd_E,sd_N,sd_h,sd_omega,sd_phi,sd_kappa\n"
                    "IMG_0000.jpg,677000.0,7183000.0,1200.0,0.5,-0.25,10,0.05,0.05,0.1,0.01,0.01,0.02\n"
                    "IMG_0001,677100.0,7183000.0,1201.0,0,0,10,0.05,0.05,0.1,0.01,0.01,0.02\n"
                    "IMG_0002,677200.0,7183000.0,1199.0,0,0,10,0.05,0.05,0.1,0.01,0.01,0.02\n"
                    "OTHER,677300.0,7183000.0,1199.0,0,0,10,0.05,0.05,0.1,0.01,0.01,0.02\n")
    cam = Camera("c1", 35.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.01, 60, 40)
    (tmp_path / "cam.toml").write_text(cam.to_toml())
    res = init_survey(tmp_path / "s", photos, camera=tmp_path / "cam.toml", gnss=gnss, gnss_crs="EPSG:31982")
    s = Survey.load(tmp_path / "s")
    assert res.crs == s.crs == "EPSG:31982" and s.height_system == "ellipsoidal"
    p0 = s.photo("IMG_0000")
    np.testing.assert_allclose(p0.position_m, [677000.0, 7183000.0, 1200.0])
    np.testing.assert_allclose(p0.attitude_deg, [0.5, -0.25, 10.0])
    np.testing.assert_allclose(p0.sd_position_m, [0.05, 0.05, 0.1])
    np.testing.assert_allclose(p0.sd_attitude_deg, [0.01, 0.01, 0.02])
    assert list(s.cameras) == ["c1"] and s.photos[1].camera == "c1"


def test_init_gnss_lon_lat_to_utm_and_lidar_tiles(tmp_path):
    photos = _photos(tmp_path)
    tiles = tmp_path / "lidar"
    tiles.mkdir()
    for k in range(2):
        (tiles / f"t{k}.laz").write_bytes(b"")
    gnss = tmp_path / "gnss.txt"
    gnss.write_text("photo lon lat h\n" + "".join(f"IMG_{k:04d} {lon} {lat} {h}\n" for k, (lat, lon, h) in enumerate(LATLON)))
    res = init_survey(tmp_path / "s", photos, gnss=gnss, lidar=[str(tiles / "*.laz")])
    assert res.crs == "EPSG:32722" and res.lidar == ("../lidar/t0.laz", "../lidar/t1.laz")
    s = Survey.load(tmp_path / "s")
    assert [p.name for p in s.lidar_paths] == ["t0.laz", "t1.laz"]
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32722", always_xy=True).transform(LATLON[0][1], LATLON[0][0])
    np.testing.assert_allclose(s.photos[0].position_m, [e, n, 1000.0], atol=1e-4)
    assert s.photos[0].attitude_deg is None     # the file gives positions only
    np.testing.assert_allclose(s.photos[0].sd_position_m, 5.0)


def test_photos_without_exif_position_are_reported(tmp_path):
    photos = _photos(tmp_path, 2)
    Image.new("L", (60, 40)).save(photos / "IMG_9999.jpg")    # no EXIF at all
    res = init_survey(tmp_path / "s", photos)
    assert res.without_position == ("IMG_9999",)
    assert any("1 photo(s) without EXIF GNSS position" in n for n in res.notes)
    s = Survey.load(tmp_path / "s")
    assert s.photo("IMG_9999").position_m is None and s.photo("IMG_0000").position_m is not None


def test_no_exif_anywhere_needs_a_camera(tmp_path):
    d = tmp_path / "photos"
    d.mkdir()
    Image.new("L", (60, 40)).save(d / "a.jpg")
    with pytest.raises(SurveyError) as ei:
        init_survey(tmp_path / "s", d)
    assert str(ei.value) == (f"{d}: no photo has an EXIF focal length with a 35 mm equivalent or a focal-plane "
                             f"resolution, so the camera cannot be guessed; give it with --camera FILE[:ID]")
    _nothing_written(tmp_path / "s")
    # with a camera: a local frame, no position
    (tmp_path / "cam.toml").write_text(Camera("c", 35.0, 0, 0, 0, 0, 0, 0, 0, 0, 0.01, 0.01, 60, 40).to_toml())
    res = init_survey(tmp_path / "s", d, camera=tmp_path / "cam.toml")
    assert res.crs.startswith("local:") and res.without_position == ("a",)
    assert Survey.load(tmp_path / "s").photo("a").position_m is None


@pytest.mark.parametrize("case", ["unreadable", "truncated", "other size", "listed twice", "no photos",
                                  "not in gnss", "gnss metres as degrees", "lidar missing"])
def test_bad_input_is_one_located_line_and_nothing_is_written(tmp_path, case):
    photos = _photos(tmp_path)
    kw = {}
    bad = photos / "IMG_0001.jpg"
    if case == "unreadable":
        bad.write_bytes(b"GIF89a? no")
        want = f"{bad}: not a readable image (no JPEG, PNG or TIFF header)"
    elif case == "truncated":
        bad.write_bytes(bad.read_bytes()[:-50])
        want = (f"{bad}: truncated JPEG image: it does not end with the end-of-image marker FF D9 (the file was cut "
                f"short; copy it again)")
    elif case == "other size":
        write_photo(bad, *LATLON[1], size=(40, 60))
        want = (f"{bad}: image is 40 x 60 px but camera 'camera' (EXIF (approximate)) is 60 x 40 px; a photo of "
                f"another camera (give that camera, or leave the photo out)")
    elif case == "listed twice":
        twin = photos / "IMG_0001.png"
        write_photo(twin, *LATLON[1])
        want = (f"{twin}: photo 'IMG_0001' is listed twice: IMG_0001.jpg and IMG_0001.png have the same name; keep "
                f"one or rename it")
    elif case == "no photos":
        shutil.rmtree(photos)
        photos.mkdir()
        want = f"{photos}: no photos in this folder (files ending in .jpg, .jpeg, .png, .tif, .tiff)"
    elif case == "not in gnss":
        kw["gnss"] = tmp_path / "gnss.txt"
        kw["gnss"].write_text("photo,E,N,h\nIMG_0000,677000,7183000,1200\n")
        kw["gnss_crs"] = "EPSG:31982"
        want = (f"{kw['gnss']}: photo 'IMG_0001' is not in this GNSS/IMU file (nor 1 other photo(s)); its first "
                f"column must name each photo (its file name, with or without suffix)")
    elif case == "gnss metres as degrees":
        kw["gnss"] = tmp_path / "gnss.txt"
        kw["gnss"].write_text("photo,E,N,h\n" + "".join(f"IMG_{k:04d},677000,7183000,1200\n" for k in range(3)))
        want = (f"{kw['gnss']}:2: photo 'IMG_0000': 677000, 7.183e+06 is no longitude, latitude of EPSG:4326; give "
                f"the file's CRS with --gnss-crs (e.g. EPSG:31982)")
    else:
        kw["lidar"] = [str(tmp_path / "nope.laz")]
        want = f"{tmp_path / 'nope.laz'}: LiDAR tile not found"
    with pytest.raises(LidarcatError) as ei:
        init_survey(tmp_path / "s", photos, **kw)
    assert str(ei.value) == want
    _nothing_written(tmp_path / "s")


def test_an_existing_folder_is_refused_without_overwrite(tmp_path):
    photos = _photos(tmp_path)
    init_survey(tmp_path / "s", photos)
    before = (tmp_path / "s" / "photos.csv").read_text()
    with pytest.raises(SurveyError) as ei:
        init_survey(tmp_path / "s", photos, position_sd_m=2.0)
    assert str(ei.value) == (f"{tmp_path / 's'}: already holds a survey (survey.toml); choose another folder or "
                             f"pass --overwrite")
    assert (tmp_path / "s" / "photos.csv").read_text() == before
    other = tmp_path / "t"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(SurveyError, match=r"t: is not empty \('notes.txt'\); choose another folder or pass --overwrite"):
        init_survey(other, photos)
    init_survey(tmp_path / "s", photos, position_sd_m=2.0, overwrite=True)
    np.testing.assert_allclose(Survey.load(tmp_path / "s").photos[0].sd_position_m, 2.0)


def test_photos_inside_the_survey_folder(tmp_path):
    """`lidarcat init block --images block/images`: the photos' own folder does not make it 'not empty'."""
    root = tmp_path / "block"
    root.mkdir()
    photos = _photos(root)
    init_survey(root, photos)
    s = Survey.load(root)
    assert s.photo("IMG_0000").image == root / "photos" / "IMG_0000.jpg"


def test_orientations_imported_later_keep_the_image_column(tmp_path):
    """`lidarcat import gnss` onto an init survey (interop.block.apply_orientations) keeps each photo's image."""
    from lidarcat.interop.block import apply_orientations
    from lidarcat.interop.gnss import read_gnss

    photos = _photos(tmp_path)
    init_survey(tmp_path / "s", photos, crs="EPSG:31982")
    gnss = tmp_path / "gnss.txt"
    gnss.write_text("photo,E,N,h\n" + "".join(f"IMG_{k:04d},{677000 + 100 * k},7183000,1200\n" for k in range(3)))
    apply_orientations(Survey.load(tmp_path / "s"), read_gnss(gnss, file_crs="EPSG:31982"), tmp_path / "s2",
                       sd_position_m=1.0)
    s2 = Survey.load(tmp_path / "s2")
    assert [s2.image_path(p).resolve() for p in s2.photo_ids] == [(photos / f"IMG_{k:04d}.jpg").resolve()
                                                                  for k in range(3)]
    np.testing.assert_allclose(s2.photo("IMG_0002").position_m, [677200.0, 7183000.0, 1200.0])


@pytest.mark.slow
def test_init_from_the_demos_rendered_photos_a_gnss_file_and_its_camera(tmp_path):
    """The acceptance workflow's first step: rendered photos (PNG, no EXIF) + a GNSS/IMU file (truth here) + the
    camera + the LiDAR tiles -> a survey whose approximate orientation is the file's (about 12 s at load 9)."""
    from lidarcat.synthetic.survey import DEMO_CRS, write_synthetic_survey

    demo = tmp_path / "demo"
    write_synthetic_survey(demo, n_photos=2, images=True, image_downsample=20, lidar_density_m2=0.5)
    truth = (demo / "truth" / "eop.csv").read_text().splitlines()
    gnss = tmp_path / "gnss.csv"
    gnss.write_text("photo,E,N,h,omega,phi,kappa,sd_E,sd_N,sd_h,sd_omega,sd_phi,sd_kappa\n"
                    + "".join(f"{line},2,2,2,0.5,0.5,0.5\n" for line in truth if line[:1].isdigit()))
    res = init_survey(tmp_path / "s", demo / "images", camera=demo / "camera.toml", gnss=gnss, gnss_crs=DEMO_CRS,
                      lidar=[demo / "lidar"])
    assert res.crs == DEMO_CRS and res.photos == ("1", "2") and len(res.lidar) >= 1
    s = Survey.load(tmp_path / "s")
    true = {r.split(",")[0]: [float(v) for v in r.split(",")[1:]] for r in truth if r[:1].isdigit()}
    for ph in s.photos:
        np.testing.assert_allclose([*ph.position_m, *ph.attitude_deg], true[ph.id], atol=1e-4)
        np.testing.assert_allclose([*ph.sd_position_m, *ph.sd_attitude_deg], [2, 2, 2, 0.5, 0.5, 0.5])
        assert s.image_path(ph.id).resolve() == (demo / "images" / f"{ph.id}.png").resolve()
    assert s.cameras["demo"].columns_px == 6000
