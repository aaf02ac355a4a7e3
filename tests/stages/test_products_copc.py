"""[products] copc and smrf_adaptive through the products stage of ``lidarcat run``."""

from __future__ import annotations

import numpy as np

from lidarcat.lidar.copc import is_copc
from lidarcat.production.ground import SMRFParameters, classify_tiles

from test_products_stage import BASE, CRS, run_products, survey  # noqa: F401  (the fixture survey: two tiles of the scene)


def test_products_copc_and_fixed_grid(survey, tmp_path, monkeypatch):  # noqa: F811
    import laspy

    import lidarcat.stages.lidar as actions

    seen = []
    real = actions.ground

    def spy(*args, **kw):
        seen.append(kw)
        return real(*args, **kw)

    # on this scene the fixed and the adaptive grid classify alike (measured: 0 of 93,093 points differ),
    # so the parameters the stage passes are checked directly
    monkeypatch.setattr(actions, "ground", spy)
    root, _, truth = survey
    rec, folder = run_products(root, tmp_path, BASE + '\n[products]\ncopc = true\nsmrf_adaptive = false\ndtm = true\n'
                                                      'dsm = false\ncontours = false\ncell_m = 2.0\n')
    assert sorted(rec.result["ground"]["tiles"]) == ["ground/east.copc.laz", "ground/west.copc.laz"]
    assert len(seen) == 1 and seen[0]["copc"] is True and seen[0]["params"] == SMRFParameters(adaptive=False)
    assert (folder / "dtm.tif").exists()
    # the same classes as the fixed-grid SMRF run directly (LAZ copies)
    direct = classify_tiles(sorted((root / "lidar").glob("*.laz")), tmp_path / "direct", crs=CRS,
                            params=SMRFParameters(adaptive=False), resume=False)
    for name, ref in truth.items():
        path = folder / "ground" / f"{name}.copc.laz"
        assert is_copc(path)
        with laspy.CopcReader.open(str(path)) as r:
            got = r.query()
        d = laspy.read(next(p for p in direct if p.stem == name))
        key = lambda p: np.lexsort((np.asarray(p.Z), np.asarray(p.Y), np.asarray(p.X)))  # noqa: E731
        np.testing.assert_array_equal(np.asarray(got.classification)[key(got)],
                                      np.asarray(d.classification)[key(d)])
        assert np.mean((np.asarray(d.classification) == 2) != ref) < 0.02, name
