"""Charts drawn on the tile runner (a Dask LocalCluster): the same bytes as drawn serially, progress per chart,
errors re-raised."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.errors import ProductError
from lidarcat.lidar.geotiff import GeoTransform
from lidarcat.production.charts import TitleBlock, draw_chart, render_charts, write_chart
from lidarcat.production.contours import contour_features, contours, spot_heights
from lidarcat.production.sheets import sheet_grid

E0, N0 = 500_000.0, 7_500_000.0
TITLE = TitleBlock("Itaocara test", 5000, "SIRGAS 2000 / UTM zone 23S (EPSG:31983)", -21.5, "2009-06-01",
                   "2026-11-28", 1.0, 5)


@pytest.fixture(scope="module")
def block():
    """Three 500 m sheets of a smooth terrain, its contours, spot heights and an RGB mosaic (10 m cells)."""
    rng = np.random.default_rng(1)
    x = rng.uniform(E0, E0 + 1500, 3000)
    y = rng.uniform(N0, N0 + 500, 3000)
    z = 100 + 10 * np.sin((x - E0) / 200) + 5 * np.cos((y - N0) / 150)
    g = np.column_stack([x, y, z])
    feats = contour_features(contours(g, 1.0, master_every=5))
    img = np.zeros((50, 150, 3), np.uint8)
    img[..., 0] = np.linspace(40, 220, 150).astype(np.uint8)[None, :]
    img[..., 1] = 90
    return feats, spot_heights(g, 250.0), img, GeoTransform(E0, N0 + 500, 10.0), sheet_grid(
        (E0, N0, E0 + 1500, N0 + 500), 500)


def test_parallel_charts_are_the_serial_charts(block, tmp_path):
    feats, spots, img, t, sheets = block
    assert len(sheets) == 3
    names = [s.name for s in sheets]
    kw = dict(image=img, image_transform=t, contours=feats, spots=spots, sheets=sheets,
              area=(E0, N0, E0 + 1500, N0 + 500), dpi=30)
    seen = []
    (tmp_path / "par").mkdir()
    files = render_charts(sheets, names, TITLE, tmp_path / "par", workers=2,
                          progress=lambda d, n: seen.append((d, n)), **kw)
    assert files == [f"{n}.{e}" for n in names for e in ("pdf", "png")]
    assert seen == [(1, 3), (2, 3), (3, 3)]
    (tmp_path / "ser").mkdir()
    assert render_charts(sheets, names, TITLE, tmp_path / "ser", **kw) == files   # serially, in this process
    # the reference: draw_chart on the whole mosaic, in this process
    for s in sheets:
        fig = draw_chart(s, TITLE, image=img, image_transform=t, contours=feats, spots=spots, sheets=sheets,
                         area=kw["area"])
        pdf, png = write_chart(fig, tmp_path / f"{s.name}.pdf", tmp_path / f"{s.name}.png", dpi=30)
        assert (tmp_path / "par" / f"{s.name}.pdf").read_bytes() == pdf.read_bytes(), s.name
        assert (tmp_path / "par" / f"{s.name}.png").read_bytes() == png.read_bytes(), s.name
        for f in (pdf, png):
            assert (tmp_path / "ser" / f.name).read_bytes() == f.read_bytes(), f.name


def test_a_worker_error_is_raised_in_the_caller(block, tmp_path):
    feats, spots, img, t, sheets = block
    far = sheet_grid((E0 + 9000, N0, E0 + 9500, N0 + 500), 500)[0]
    with pytest.raises(ProductError, match=r"chart of sheet E509000_N7500000: the sheet .* outside the data"):
        render_charts([sheets[0], far], ["a", "b"], TITLE, tmp_path, image=img, image_transform=t,
                      contours=feats, spots=spots, sheets=sheets, workers=2, dpi=20)
