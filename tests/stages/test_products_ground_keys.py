"""[products] noise, hag, stats and filter = "csf" through the products stage of ``lidarcat run``."""

from __future__ import annotations

import numpy as np

from lidarcat.lidar import read_points

from test_products_stage import BASE, run_products, survey  # noqa: F401  (the fixture survey: two tiles of the scene)


def test_products_noise_hag_stats_and_csf(survey, tmp_path):  # noqa: F811
    import laspy
    import rasterio

    root, _, truth = survey
    rec, folder = run_products(root, tmp_path, BASE + '\n[products]\nfilter = "csf"\nnoise = true\nhag = true\n'
                                                      'stats = true\ncell_m = 2.0\ncontours = false\n')
    assert rec.result["ground"]["filter"] == "csf" and "stats.tif" in rec.result["files"]
    for name, ref in truth.items():
        las = laspy.read(folder / "ground" / f"{name}.laz")
        got = np.asarray(las.classification) == 2
        assert np.mean(got != ref) < 0.02, name
        hag = np.asarray(las.HeightAboveGround)
        assert np.all(hag[got] == 0.0) and np.nanmax(hag) > 2.0
    with rasterio.open(folder / "stats.tif") as ds:
        assert ds.descriptions == ("min", "max", "mean", "count", "stdev") and ds.crs.to_epsg() == 31982
        n = sum(len(read_points(folder / "ground" / f"{k}.laz")) for k in truth)
        cls7 = sum(int(np.sum(np.asarray(read_points(folder / "ground" / f"{k}.laz")
                                         .attributes["classification"]) == 7)) for k in truth)
        assert ds.read(4).sum() == n - cls7   # every point but the noise counted once
