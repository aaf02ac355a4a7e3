"""EXIF tags of photos (lidarcat.photos): focal length, pixel size, GNSS position projected with pyproj."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image, TiffImagePlugin
from pyproj import Transformer

from lidarcat.errors import FormatError
from lidarcat.photos import exif_orientations, read_exif, read_header
from lidarcat.photos.exif import DIAGONAL_35MM_MM, utm_crs

R = TiffImagePlugin.IFDRational


def _dms(x: float) -> tuple:
    x = abs(x)
    d = int(x)
    m = int((x - d) * 60)
    s = ((x - d) * 60 - m) * 60
    return R(d, 1), R(m, 1), R(int(round(s * 10000)), 10000)


def write_photo(path, lat=None, lon=None, alt=None, *, size=(60, 40), focal=35.0, f35=52, direction=None,
                alt_below=False, plane_res=None):
    """A JPEG/PNG/TIFF with EXIF focal length and (optional) GPS IFD."""
    ex = Image.Exif()
    ex[0x010F], ex[0x0110] = "ACME", "Aerial 1"
    e = ex.get_ifd(0x8769)
    if focal is not None:
        e[0x920A] = R(int(focal * 10), 10)
    if f35 is not None:
        e[0xA405] = f35
    if plane_res is not None:
        e[0xA20E], e[0xA20F], e[0xA210] = R(*plane_res), R(*plane_res), 3
    if lat is not None:
        g = ex.get_ifd(0x8825)
        g[1], g[2] = ("S" if lat < 0 else "N"), _dms(lat)
        g[3], g[4] = ("W" if lon < 0 else "E"), _dms(lon)
        g[5], g[6] = (b"\x01" if alt_below else b"\x00"), R(int(round(abs(alt) * 100)), 100)
        if direction is not None:
            g[16], g[17] = "T", R(int(direction * 100), 100)
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 255, size[::-1], dtype=np.uint8)).save(path, exif=ex)
    return path


def test_exif_focal_pixel_and_position(tmp_path):
    p = write_photo(tmp_path / "a.jpg", -25.43, -49.27, 935.12, direction=45.5)
    info = read_exif(p)
    assert info.has_exif and info.camera_name == "ACME Aerial 1"
    assert (info.columns_px, info.rows_px) == (60, 40)
    assert info.focal_length_mm == 35.0 and info.focal_length_35mm_mm == 52.0
    # the 35 mm equivalent: sensor diagonal 43.267 * 35 / 52 mm over the diagonal of 60 x 40 px
    assert info.pixel_size_mm == pytest.approx(DIAGONAL_35MM_MM * 35 / 52 / math.hypot(60, 40), rel=1e-12)
    assert info.lat_deg == pytest.approx(-25.43, abs=1e-8) and info.lon_deg == pytest.approx(-49.27, abs=1e-8)
    assert info.alt_m == pytest.approx(935.12) and info.direction_deg == pytest.approx(45.5)
    assert info.direction_ref == "T"


def test_focal_plane_resolution_wins(tmp_path):
    p = write_photo(tmp_path / "a.jpg", plane_res=(2000, 1))     # 2000 px per cm: 5 um pixels
    assert read_exif(p).pixel_size_mm == pytest.approx(0.005)


@pytest.mark.parametrize("suffix", [".jpg", ".png"])   # Pillow writes no GPS IFD into a TIFF
def test_positions_in_the_survey_crs_against_pyproj(tmp_path, suffix):
    lat_lon = [(-25.43, -49.27, 1000.0), (-25.431, -49.2695, 1010.5), (-25.4321, -49.2688, 990.0)]
    infos = [read_exif(write_photo(tmp_path / f"p{k}{suffix}", *ll, direction=90.0 if k else None))
             for k, ll in enumerate(lat_lon)]
    infos.append(read_exif(write_photo(tmp_path / f"none{suffix}")))  # no GPS IFD
    pos, att = exif_orientations(infos, "EPSG:31982")
    tr = Transformer.from_crs("EPSG:4326", "EPSG:31982", always_xy=True)
    for k, (lat, lon, h) in enumerate(lat_lon):
        e, n = tr.transform(lon, lat)
        # EXIF seconds carry 1e-4" (3 mm): the projected position agrees to 5 mm
        assert pos[k] == pytest.approx([e, n, h], abs=5e-3)
    assert np.isnan(pos[3]).all()
    assert np.isnan(att[0]).all() and np.isnan(att[3]).all()
    np.testing.assert_allclose(att[1], [0.0, 0.0, -90.0])   # top of the image to the east: kappa = -90


def test_altitude_below_sea_level_and_southern_western_signs(tmp_path):
    info = read_exif(write_photo(tmp_path / "a.jpg", 10.5, 20.25, 12.0, alt_below=True))
    assert (info.lat_deg, info.lon_deg, info.alt_m) == pytest.approx((10.5, 20.25, -12.0))


def test_photo_without_exif(tmp_path):
    p = tmp_path / "plain.jpg"
    Image.new("L", (60, 40)).save(p)
    info = read_exif(p)
    assert not info.has_exif and not info.has_position and info.pixel_size_mm is None
    assert info.focal_length_mm is None


def test_utm_zone():
    assert utm_crs(-49.27, -25.43) == "EPSG:32722"
    assert utm_crs(5.1, 52.1) == "EPSG:32631"


def test_header_of_a_truncated_jpeg_is_one_line(tmp_path):
    p = write_photo(tmp_path / "a.jpg", -25.43, -49.27, 900.0)
    p.write_bytes(p.read_bytes()[:-100])
    with pytest.raises(FormatError) as ei:
        read_exif(p)
    assert str(ei.value) == (f"{p}: truncated JPEG image: it does not end with the end-of-image marker FF D9 "
                             f"(the file was cut short; copy it again)")
    with pytest.raises(FormatError):
        read_header(p)


@pytest.mark.parametrize("name, exif", [("a.jpg", True), ("a.png", True), ("b.png", False), ("a.tif", True)])
def test_nothing_is_decoded(tmp_path, monkeypatch, name, exif):
    """Header and EXIF come without decoding the pixels (a survey of hundreds of 100-MP photos is checked at
    every load): Pillow's decoder is made to fail."""
    from PIL import ImageFile, PngImagePlugin

    p = tmp_path / name
    if exif:
        write_photo(p, 10.0, 20.0, 30.0)
    else:
        Image.new("L", (60, 40)).save(p)

    def no_load(self, *a, **k):
        raise AssertionError("pixels decoded")

    monkeypatch.setattr(ImageFile.ImageFile, "load", no_load)
    monkeypatch.setattr(PngImagePlugin.PngImageFile, "load", no_load, raising=False)
    info = read_exif(p)
    assert (info.columns_px, info.rows_px) == (60, 40)
    assert info.has_exif is exif
    assert info.has_position is (exif and not name.endswith(".tif"))   # Pillow writes no GPS IFD into a TIFF


def test_a_jpeg_with_a_trailer_is_whole_a_cut_one_is_not(tmp_path):
    """A motion photo (a video after the JPEG) ends in no FF D9 but is whole; the same cut inside its scan is
    truncated, also when its EXIF thumbnail (with an EOI of its own) comes before the scan."""
    p = write_photo(tmp_path / "a.jpg", 10.0, 20.0, 30.0)
    whole = p.read_bytes()
    p.write_bytes(whole + b"ftypmp42" + bytes(range(256)) * 8)
    assert read_header(p).columns_px == 60
    thumb = tmp_path / "t.jpg"
    ex = Image.Exif()
    ex.get_ifd(0x8769)[0x927C] = b"\xff\xd8 a thumbnail \xff\xd9"   # MakerNote: an EOI in APP1, before the scan
    Image.fromarray(np.random.default_rng(2).integers(0, 255, (40, 60), dtype=np.uint8)).save(thumb, exif=ex)
    assert b"a thumbnail \xff\xd9" in thumb.read_bytes()
    for q in (p, thumb):
        data = (whole if q == p else thumb.read_bytes())
        q.write_bytes(data[:-30])
        with pytest.raises(FormatError, match="truncated JPEG image"):
            read_header(q)
