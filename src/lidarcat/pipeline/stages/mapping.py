"""Stage ``mapping``: orthophotos and a mosaic of the adjusted photos, when survey.toml asks for them.

survey.toml::

    [mapping]
    orthophotos = true        # make them (default false: the stage is skipped)
    surface = "dsm"           # "dsm": true orthophotos (occlusions masked), "dtm": standard
    gsd_m = 0.2               # output cell, m
    cell_m = 0.5              # cell of the surface model rasterised from the LiDAR tiles, m
    mosaic = true             # also the mosaic and its seamlines
    images = "images"         # folder of the photo files <photo>.png/.tif/.jpg
    photos = ["1", "2"]       # optional: a subset (default: every adjusted photo)

The stage is planned only for a survey with a ``[mapping]`` table (skipped,
with the reason, when ``orthophotos`` is false or nothing was adjusted).  The
orientations are those of the default control set's adjustment
(``adjust-<set>/eop.csv``); the surface model is rasterised from the survey's
LiDAR tiles over the photos' footprints (:func:`lidarcat.lidar.rasterize`,
highest first return or lowest ground point) and written as ``dsm.tif`` /
``dtm.tif`` next to ``ortho_<photo>.tif``, ``mosaic.tif`` and
``seamlines.geojson`` (:mod:`lidarcat.ortho`, :mod:`lidarcat.mosaic`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..runner import Context

__all__ = ["run", "settings", "MAPPING_KEYS"]

#: keys of the [mapping] table and their defaults
MAPPING_KEYS: dict[str, Any] = {"orthophotos": False, "surface": "dsm", "gsd_m": 0.2, "cell_m": 0.5,
                                "mosaic": True, "images": "images", "photos": None}


def settings(survey: Any) -> dict[str, Any]:
    """The ``[mapping]`` table of the survey with its defaults (``{}`` when there is none).

    Raises
    ------
    SurveyError
        A value of the wrong type or out of range (file, line and key).
    """
    from ._settings import optional_table

    kinds = {"orthophotos": bool, "surface": str, "gsd_m": (int, float), "cell_m": (int, float), "mosaic": bool,
             "images": str, "photos": list}
    out, t = optional_table(survey, "mapping", kinds, MAPPING_KEYS)
    if not out:
        return {}
    if out["surface"] not in ("dsm", "dtm"):
        raise t.err("mapping", "surface", f"{out['surface']!r} is not 'dsm' (true orthophotos) or 'dtm'")
    for key in ("gsd_m", "cell_m"):
        if not out[key] > 0:
            raise t.err("mapping", key, f"must be positive (metres), got {out[key]!r}")
    if out["photos"] is not None:
        unknown = [str(p) for p in out["photos"] if str(p) not in survey.photo_ids]
        if unknown:
            raise t.err("mapping", "photos", f"photo(s) {', '.join(unknown)} are not in the survey")
        out["photos"] = [str(p) for p in out["photos"]]
    return out


def run(ctx: Context, tmp: Path) -> dict:
    """Orthophotos (and the mosaic) of the adjusted photos over a surface model from the LiDAR."""
    import numpy as np

    from ...errors import SurveyError
    from ...lidar import TileIndex
    from ...lidar.raster import rasterize, write_raster
    from ...monoplot import GridSurface, read_orientations
    from ...mosaic import mosaic
    from ...ortho import PhotoModel, orthophoto
    from ...mapping_inputs import photo_image

    survey = ctx["survey"]
    par = ctx.params
    cfg = settings(survey)
    eos = read_orientations(ctx.folder(par["adjust"]) / "eop.csv")
    ids = cfg["photos"] or [p for p in survey.photo_ids if p in eos]
    missing = [p for p in ids if p not in eos]
    if missing:
        raise SurveyError(f"{survey.toml_path}: [mapping] photos {', '.join(missing)} were not adjusted "
                          f"(not in {ctx.folder(par['adjust']) / 'eop.csv'})")
    images = Path(cfg["images"])
    images = images if images.is_absolute() else survey.root / images
    photos = []
    for pid in ids:
        cam = survey.camera_of(pid)
        photos.append(PhotoModel(pid, photo_image(pid, images, cam), cam, eos[pid].params))
    index = TileIndex.build([str(p) for p in survey.lidar_paths], crs=survey.lidar_crs)
    b = index.bounds
    h_mid = 0.5 * (b.zmin + b.zmax)
    fps = np.vstack([p.footprint(h_mid) for p in photos])
    area = (max(fps[:, 0].min(), b.xmin), max(fps[:, 1].min(), b.ymin),
            min(fps[:, 0].max(), b.xmax), min(fps[:, 1].max(), b.ymax))
    what = cfg["surface"]
    cloud = index.query_box(*area)
    grid, transform = rasterize(cloud, float(cfg["cell_m"]), what, bounds=area)
    write_raster(tmp / f"{what}.tif", grid, transform, survey.crs, what)
    surface = GridSurface(grid, transform, "bilinear")
    true = what == "dsm"
    done: dict[str, Any] = {"surface": f"{what}.tif", "orthophotos": []}
    total = len(photos) + (1 if cfg["mosaic"] and len(photos) > 1 else 0)
    for k, ph in enumerate(photos):
        r = orthophoto(ph, surface, float(cfg["gsd_m"]), tmp / f"ortho_{ph.photo_id}.tif", true_ortho=true,
                       crs=survey.crs)
        done["orthophotos"].append(r.to_dict() | {"photo": ph.photo_id, "path": f"ortho_{ph.photo_id}.tif"})
        ctx.progress(k + 1, total)
    if cfg["mosaic"] and len(photos) > 1:
        m = mosaic(photos, surface, float(cfg["gsd_m"]), tmp / "mosaic.tif", seams_path=tmp / "seamlines.geojson",
                   true_ortho=true, crs=survey.crs)
        done["mosaic"] = m.to_dict() | {"path": "mosaic.tif", "seams": "seamlines.geojson"}
        ctx.progress(total, total)
    return done
