"""Orthophoto charts (production.charts): title block, UTM grid labels, master labels, true scale, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.errors import ProductError
from lidarcat.lidar.geotiff import GeoTransform
from lidarcat.production.charts import TitleBlock, draw_chart, grid_interval, write_chart
from lidarcat.production.contours import contour_features, contours, spot_heights
from lidarcat.production.conventions import CONVENTIONS, convention
from lidarcat.production.sheets import Sheet, sheet_grid

from pdf_text import pdf_page_size_pt, pdf_text  # noqa: I001  (tests/pdf_text.py)

E0, N0 = 500_000.0, 7_500_000.0
TITLE = TitleBlock("Itaocara test", 5000, "SIRGAS 2000 / UTM zone 23S (EPSG:31983)", -21.5, "2009-06-01",
                   "2026-11-28", 1.0, 5)


@pytest.fixture(scope="module")
def block():
    """Two 1,000 m sheets of a smooth terrain (85..115 m), its contours, spot heights and an RGB mosaic."""
    rng = np.random.default_rng(1)
    x = rng.uniform(E0, E0 + 1500, 6000)
    y = rng.uniform(N0, N0 + 1000, 6000)
    z = 100 + 10 * np.sin((x - E0) / 200) + 5 * np.cos((y - N0) / 150)
    g = np.column_stack([x, y, z])
    feats = contour_features(contours(g, 1.0, master_every=5))
    spots = spot_heights(g, 250.0)
    img = np.zeros((100, 150, 3), np.float32)
    img[..., 0] = np.linspace(40, 220, 150)[None, :]
    img[..., 1] = np.linspace(220, 40, 100)[:, None]
    img[..., 2] = 128
    sheets = sheet_grid((E0, N0, E0 + 1500, N0 + 1000), 1000)   # E500000_N7500000 and E501000_N7500000
    return feats, spots, img, GeoTransform(E0, N0 + 1000, 10.0), sheets


def test_chart_pdf_holds_the_title_block_grid_labels_and_master_labels_at_true_scale(block, tmp_path):
    feats, spots, img, t, sheets = block
    fig = draw_chart(sheets[0], TITLE, image=img, image_transform=t, contours=feats, spots=spots, sheets=sheets,
                     area=(E0, N0, E0 + 1500, N0 + 1000))
    pdf, png = write_chart(fig, tmp_path / "c.pdf", tmp_path / "c.png", dpi=40)
    text = pdf_text(pdf)
    for line in ("ORTHOPHOTO CHART (ortofotocarta)", "Itaocara test", "Sheet: E500000_N7500000", "Scale 1:5,000",
                 "Datum and projection: SIRGAS 2000 / UTM zone 23S (EPSG:31983)",
                 "Magnetic declination: 21°30' W (2009-06-01)", "Contours every 1 m, master curves every 5 m",
                 "Date: 2026-11-28", "Index map", "Conventions"):
        assert line in text, line
    # the grid every 200 m (1,000 m sheet), each line labelled on both sides; none on the frame itself
    for label in ("500200", "500400", "500600", "500800", "7500200", "7500400", "7500600", "7500800"):
        assert text.count(label) == 2, label
    assert "500000" not in text and "7501000" not in text
    # master curves (every 5 m between 85 and 115 m) labelled with their height
    assert {"90", "95", "100", "105", "110"} & set(text)
    assert not {"101", "102", "103", "104"} & set(text)      # intermediate curves are not labelled
    # every convention of the legend names the report's level and colour
    for key in ("master", "intermediate", "spot", "grid", "boundary", "sheet"):
        c = convention(key)
        assert any(f"({c.layer}, colour {c.colour_number})" in s for s in text), key
    # true scale: the 1,000 m map is 20 cm = 7.874 in, plus 0.9 + 0.9 in margins, 3.4 in panel, 0.3 in
    w_pt, h_pt = pdf_page_size_pt(pdf)
    assert w_pt == pytest.approx((0.9 + 1000 / 5000 / 0.0254 + 0.9 + 3.4 + 0.3) * 72, abs=0.01)
    assert h_pt == pytest.approx((1000 / 5000 / 0.0254 + 1.8) * 72, abs=0.01)
    import matplotlib.image

    assert matplotlib.image.imread(png).shape[:2] == (int(h_pt / 72 * 40), int(w_pt / 72 * 40))   # truncated


def test_grid_interval_and_conventions():
    assert [grid_interval(w) for w in (100.0, 1000.0, 3500.0, 99.0)] == [20.0, 200.0, 500.0, 10.0]
    assert [c.level for c in CONVENTIONS] == list(range(8))
    assert [c.layer for c in CONVENTIONS][1:3] == ["Limite de Restituição", "Curvas Mestras"]
    with pytest.raises(ProductError, match="no convention 'roads'"):
        convention("roads")


def test_chart_without_mosaic_or_contours_or_outside_the_data_is_an_error(block):
    feats, spots, img, t, sheets = block
    with pytest.raises(ProductError, match=r"chart of sheet E500000_N7500000: no orthomosaic given"):
        draw_chart(sheets[0], TITLE, image=None, image_transform=None, contours=feats)
    with pytest.raises(ProductError, match=r"chart of sheet E500000_N7500000: no contour lines given"):
        draw_chart(sheets[0], TITLE, image=img, image_transform=t, contours=[])
    far = Sheet("E600000_N7500000", 600_000.0, N0, 601_000.0, N0 + 1000)
    with pytest.raises(ProductError, match=r"chart of sheet E600000_N7500000: the sheet \(E 600000\.\.601000, "
                                           r"N 7500000\.\.7501000\) holds neither orthomosaic cells nor contours"):
        draw_chart(far, TITLE, image=img, image_transform=t, contours=feats)
    with pytest.raises(ProductError, match="chart scale must be a positive whole denominator, got 0"):
        draw_chart(sheets[0], TitleBlock("p", 0, "x", None, "", "d", 1.0, 5), image=img, image_transform=t,
                   contours=feats)


def test_declination_not_given_is_said(block, tmp_path):
    feats, _, img, t, sheets = block
    title = TitleBlock("p", 2000, "x", None, "", "2026-11-28", 1.0, 5)
    fig = draw_chart(sheets[1], title, image=img, image_transform=t, contours=feats)
    text = pdf_text(write_chart(fig, tmp_path / "c.pdf")[0])
    assert "Magnetic declination: not given" in text and "Scale 1:2,000" in text


def test_chart_command_writes_the_named_sheet_and_refuses_one_outside_the_data(block, tmp_path):
    from click.testing import CliRunner

    from lidarcat.cli.main import cli
    from lidarcat.lidar.geotiff import write_geotiff
    from lidarcat.production.contours import spot_features, write_geojson

    feats, spots, img, t, _ = block
    write_geotiff(tmp_path / "mosaic.tif", img, t, "EPSG:31983")
    write_geojson(tmp_path / "c.geojson", feats, "EPSG:31983")
    write_geojson(tmp_path / "s.geojson", spot_features(spots), "EPSG:31983")
    args = ["chart", str(tmp_path / "mosaic.tif"), str(tmp_path / "c.geojson"), "--spots", str(tmp_path / "s.geojson"),
            "--dpi", "20", "--date", "2026-11-28", "--project", "Itaocara test"]
    r = CliRunner().invoke(cli, [*args, "-o", str(tmp_path / "out"), "--sheet", "E501000_N7500000", "--json"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["E501000_N7500000.pdf", "E501000_N7500000.png"]
    text = pdf_text(tmp_path / "out" / "E501000_N7500000.pdf")
    assert "Datum and projection: EPSG:31983 (SIRGAS 2000 / UTM zone 23S)" in text
    assert "Contours every 1 m, master curves every 5 m" in text      # read back from the levels
    assert "Magnetic declination: not given" in text and "Itaocara test" in text
    r = CliRunner().invoke(cli, [*args, "-o", str(tmp_path / "bad"), "--sheet", "E600000_N7500000"])
    assert r.exit_code == 2
    assert ("charts: sheet E600000_N7500000 holds no data of " in r.output
            and "(sheets with data: E500000_N7500000, E501000_N7500000)" in r.output)
    assert not (tmp_path / "bad").exists()
