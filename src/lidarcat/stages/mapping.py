"""Stage ``mapping``: orthophotos, a mosaic and monorestituted features of the adjusted photos, when asked.

survey.toml::

    [mapping]
    orthophotos = true        # make them (default false: the stage is skipped)
    surface = "dsm"           # "dsm": true orthophotos (occlusions masked), "dtm": standard
    gsd_m = 0.2               # output cell, m
    cell_m = 0.5              # cell of the surface model rasterised from the LiDAR tiles, m
    mosaic = true             # also the mosaic and its seamlines
    feather_m = 0.0           # mosaic: blend across seamlines over +- this many metres (0: hard seams)
    equalize = false          # mosaic: balance the photos first (gain/offset per photo from the overlaps)
    images = "images"         # folder of the photo files <photo>.png/.tif/.jpg
    photos = ["1", "2"]       # optional: a subset (default: every adjusted photo)
    features = { "3" = "features/p3.geojson" }   # photo -> features digitised on it (pixels)
    reference = "features/reference.csv"         # their true / map positions: feature,vertex,E,N
    interpolators = ["nearest", "tin"]           # surfaces of the monorestitution (default: the paper's two)
    method = "exact"          # first hit ("exact") or the paper's height iteration ("iterate")
    image_sd_px = 0.5         # pointing sd of the digitised pixels, px
    surface_sd_m = 0.15       # height sd of the surface, m

The stage is planned only for a survey with a ``[mapping]`` table (skipped,
with the reason, when it asks for neither orthophotos nor features, or nothing
was adjusted).

Monorestitution (:func:`lidarcat.mapping.monoplot.monoplot`): the features of each
photo are intersected with the LiDAR surface by each interpolator --
``nearest`` and ``tin`` on the first returns themselves (no grid), ``bilinear``
on a highest-first-return DSM of ``cell_m`` -- and written as
``monoplot_<photo>_<interpolator>.geojson``.  With a ``reference`` the
vertices are judged as Cavassim (2005) judges them
(:func:`lidarcat.mapping.accuracy.assess_monoplot`): per interpolator and
feature class the mean and sd of dE, dN and the resultant, K-S of the
generalized distances, Hotelling's T^2, the 90 % radius and the PEC class at
the survey's ``[assessment]`` scale and alpha -- the paper's Tables 07/08 (one
per interpolator) and Table 09 (r90 by interpolator and class), in
``accuracy.csv``, the stage result (summary.json) and the run report
(:func:`markdown`).  The
orientations are those of the default control set's adjustment
(``adjust-<set>/eop.csv``); the surface model is rasterised from the survey's
LiDAR tiles over the photos' footprints (:func:`lidarcat.lidar.rasterize`,
highest first return or lowest ground point) and written as ``dsm.tif`` /
``dtm.tif`` next to ``ortho_<photo>.tif``, ``mosaic.tif`` and
``seamlines.geojson`` (:mod:`lidarcat.mapping.ortho`, :mod:`lidarcat.mapping.mosaic`)
by :func:`orthophotos`, the action of ``lidarcat ortho``, which reads that
surface file as the command reads its ``--dsm``/``--dtm``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from .._util import output_root, safe_component
from ..survey.schema import MappingSettings
from .context import StageContext as Context

__all__ = ["orthophotos", "run", "settings", "markdown", "MAPPING_KEYS", "INTERPOLATORS", "ACCURACY_COLUMNS"]

#: keys of the [mapping] table and their defaults (lidarcat.survey.schema.MappingSettings)
MAPPING_KEYS: dict[str, Any] = MappingSettings().to_dict()
#: interpolators of the monorestitution: surface of each
INTERPOLATORS = {"nearest": "first returns, nearest point", "tin": "first returns, triangular plane (TIN)",
                 "bilinear": "highest-first-return DSM of cell_m (empty cells interpolated), bilinear"}
#: columns of accuracy.csv (m; Cavassim Tables 07-09)
ACCURACY_COLUMNS = ("interpolator", "class", "n", "mean_E", "sd_E", "mean_N", "sd_N", "mean_resultant",
                    "sd_resultant", "ks_D", "ks_critical", "ks_p", "ks_passed", "hotelling_T2",
                    "hotelling_critical", "hotelling_passed", "r90_m", "pec_class")


def settings(survey: Any) -> dict[str, Any]:
    """The ``[mapping]`` table of the survey with its defaults (``{}`` when there is none); checked by
    :meth:`lidarcat.Survey.load` (:class:`lidarcat.survey.schema.MappingSettings`)."""
    cfg = survey.config.mapping
    return {} if cfg is None else cfg.to_dict()


def orthophotos(survey: Any, outdir: str | os.PathLike, photo_ids: Sequence[str], surface: str | os.PathLike, *,
                true_ortho: bool, gsd_m: float = 0.2, eop: str | os.PathLike | None = None,
                images: str | os.PathLike | None = None, bounds: Sequence[float] | None = None,
                mosaic: bool = False, feather_m: float = 0.0, tile_px: int = 1024, equalize: bool = False,
                progress: Callable[[str, int, int], Any] | None = None) -> dict[str, Any]:
    """The action of ``lidarcat ortho`` and of the stage's orthophotos: adjusted photos over a surface GeoTIFF.

    Writes ``ortho_<photo>.tif`` (+ ``.png``) per photo
    (:func:`lidarcat.mapping.ortho.orthophoto`) and, with *mosaic*, ``mosaic.tif``
    (+ ``.png``) and ``seamlines.geojson`` (:func:`lidarcat.mapping.mosaic.mosaic`)
    into *outdir*, in the survey CRS.

    Parameters
    ----------
    survey : lidarcat.Survey
    outdir : path
        Output folder.
    photo_ids : sequence of str
        The photos, in this order.
    surface : path
        Terrain or surface model GeoTIFF (:meth:`lidarcat.mapping.monoplot.GridSurface.from_geotiff`,
        bilinear).
    true_ortho : bool
        True: *surface* is a DSM and cells a photo does not see are nodata (z-buffer).
    gsd_m : float
        Output cell, m.
    eop : path, optional
        ``eop.csv`` of the adjustment (default :func:`lidarcat.mapping.inputs.default_eop_path`).
    images : path, optional
        Folder of the photo files ``<photo>.png/.tif/.jpg`` (default ``SURVEY/images``).
    bounds : (xmin, ymin, xmax, ymax), optional
        Output area, m (default: each photo's footprint; the mosaic: their union).
    mosaic : bool
        Also the mosaic of the photos and its seamlines.
    feather_m : float
        Mosaic: blend across each seamline over +- this many metres (0: hard seams).
    equalize : bool
        Mosaic: a gain and an offset per photo from the overlaps first (:func:`lidarcat.mapping.mosaic.equalization_gains`).
    tile_px : int
        Rows/columns computed at once.
    progress : callable, optional
        ``progress(step, done, total)``; *step* is ``"ortho <photo>"`` or ``"mosaic"``.

    Returns
    -------
    dict
        ``orthophotos``: one :meth:`OrthoResult.to_dict` per photo with ``photo``;
        ``mosaic``: :meth:`MosaicResult.to_dict` (with *mosaic*).

    Raises
    ------
    SurveyError
        A photo not in the survey or not adjusted, a missing or wrong-sized image.
    """
    from ..mapping.inputs import adjusted_orientations, photo_image
    from ..mapping.monoplot import GridSurface
    from ..mapping.ortho import PhotoModel

    out = Path(outdir)
    photos_file = survey.files.get("photos", survey.toml_path)
    names = {pid: f"ortho_{safe_component(pid, 'photo id', photos_file)}.tif" for pid in photo_ids}
    grid = GridSurface.from_geotiff(surface)
    folder = Path(images) if images is not None else survey.root / "images"
    eos = adjusted_orientations(survey, list(photo_ids), eop)
    photos = [PhotoModel(pid, photo_image(pid, folder, survey.camera_of(pid)), survey.camera_of(pid),
                         eos[pid].params) for pid in photo_ids]

    def step(name: str) -> Callable[[int, int], Any] | None:
        return None if progress is None else (lambda done, total: progress(name, done, total))

    done: dict[str, Any] = {"orthophotos": []}
    with output_root(out):  # nothing written below leaves *outdir* nor goes through a link in it
        _orthophotos_into(out, names, photos, grid, gsd_m, bounds, true_ortho, survey.crs, tile_px, mosaic,
                          feather_m, step, done, equalize)
    return done


def _orthophotos_into(out: Path, names: dict[str, str], photos: list[Any], grid: Any, gsd_m: float, bounds: Any,
                      true_ortho: bool, crs: Any, tile_px: int, mosaic: bool, feather_m: float,
                      step: Callable[[str], Any], done: dict[str, Any], equalize: bool = False) -> None:
    from ..mapping.mosaic import mosaic as mosaic_photos
    from ..mapping.ortho import orthophoto

    for ph in photos:
        r = orthophoto(ph, grid, gsd_m, out / names[ph.photo_id], bounds=bounds, true_ortho=true_ortho,
                       crs=crs, tile_px=tile_px, progress=step(f"ortho {ph.photo_id}"))
        done["orthophotos"].append(r.to_dict() | {"photo": ph.photo_id})
    if mosaic:
        m = mosaic_photos(photos, grid, gsd_m, out / "mosaic.tif", seams_path=out / "seamlines.geojson",
                          bounds=bounds, true_ortho=true_ortho, crs=crs, tile_px=tile_px,
                          feather_m=feather_m, equalize=equalize, progress=step("mosaic"))
        done["mosaic"] = m.to_dict()


def run(ctx: Context, tmp: Path) -> dict:
    """Orthophotos (and the mosaic) and monorestituted features of the adjusted photos (module docstring)."""
    from ..errors import SurveyError
    from ..lidar import TileIndex
    from ..mapping.inputs import read_orientations

    survey = ctx["survey"]
    par = ctx.params
    cfg = settings(survey)
    eop = ctx.folder(par["adjust"]) / "eop.csv"
    eos = read_orientations(eop)
    asked = [*(cfg["photos"] or []), *(cfg["features"] or {})]
    missing = [p for p in dict.fromkeys(asked) if p not in eos]
    if missing:
        raise SurveyError(f"{survey.toml_path}: [mapping] photos {', '.join(missing)} were not adjusted "
                          f"(not in {eop})")
    index = TileIndex.build([str(p) for p in survey.lidar_paths], crs=survey.lidar_crs)
    done: dict[str, Any] = {}
    if cfg["orthophotos"]:
        done.update(_orthophotos(ctx, cfg, tmp, eos, index))
    if cfg["features"]:
        done.update(_monoplot(ctx, cfg, tmp, eos, index))
    return done


def _orthophotos(ctx: Context, cfg: dict[str, Any], tmp: Path, eos: Any, index: Any) -> dict[str, Any]:
    """The surface model of the photos' footprints (``dsm.tif``/``dtm.tif``), then :func:`orthophotos` over it."""
    import numpy as np

    from ..lidar.raster import rasterize, write_raster
    from ..mapping.ortho import PhotoModel

    survey = ctx["survey"]
    ids = cfg["photos"] or [p for p in survey.photo_ids if p in eos]
    for pid in ids:  # each names a file: refused before the surface model is computed
        safe_component(pid, "photo id", survey.files.get("photos", survey.toml_path))
    images = Path(cfg["images"])
    images = images if images.is_absolute() else survey.root / images
    b = index.bounds
    h_mid = 0.5 * (b.zmin + b.zmax)
    cams = {pid: survey.camera_of(pid) for pid in ids}
    # the footprint needs the camera and orientation only: a blank frame (no memory) stands for the photo,
    # which the action reads
    fps = np.vstack([PhotoModel(pid, np.broadcast_to(np.uint8(0), (c.rows_px, c.columns_px)), c,
                                eos[pid].params).footprint(h_mid) for pid, c in cams.items()])
    area = (max(fps[:, 0].min(), b.xmin), max(fps[:, 1].min(), b.ymin),
            min(fps[:, 0].max(), b.xmax), min(fps[:, 1].max(), b.ymax))
    what = cfg["surface"]
    grid, transform = rasterize(index.query_box(*area), float(cfg["cell_m"]), what, bounds=area)
    write_raster(tmp / f"{what}.tif", grid, transform, survey.crs, what)
    with_mosaic = bool(cfg["mosaic"]) and len(ids) > 1
    steps = [f"ortho {pid}" for pid in ids] + (["mosaic"] if with_mosaic else [])

    def prog(name: str, done: int, total: int) -> None:
        if done >= total:
            ctx.progress(steps.index(name) + 1, len(steps))

    res = orthophotos(survey, tmp, ids, tmp / f"{what}.tif", true_ortho=what == "dsm", gsd_m=float(cfg["gsd_m"]),
                      eop=ctx.folder(ctx.params["adjust"]) / "eop.csv", images=images, mosaic=with_mosaic,
                      feather_m=float(cfg["feather_m"]), equalize=bool(cfg.get("equalize")), progress=prog)
    out: dict[str, Any] = {"surface": f"{what}.tif", "orthophotos": [
        r | {"path": f"ortho_{r['photo']}.tif"} for r in res["orthophotos"]]}
    if with_mosaic:
        out["mosaic"] = res["mosaic"] | {"path": "mosaic.tif", "seams": "seamlines.geojson"}
    return out


def _monoplot(ctx: Context, cfg: dict[str, Any], tmp: Path, eos: Any, index: Any) -> dict[str, Any]:
    """Features of each photo by each interpolator; judged against the reference when there is one."""
    import json

    import numpy as np

    from .._util import write_csv_atomic, write_text_atomic
    from ..errors import SurveyError
    from ..mapping.features import features_geojson, read_features
    from ..lidar.raster import rasterize
    from ..mapping.accuracy import assess_monoplot, read_reference
    from ..mapping.inputs import ray_area
    from ..mapping.monoplot import GridSurface, PointSurface, monoplot

    survey = ctx["survey"]
    reference = None
    if cfg["reference"]:                    # read first: a bad reference stops the stage before the monoplots
        ref_path = Path(cfg["reference"])
        reference = read_reference(ref_path if ref_path.is_absolute() else survey.root / ref_path)
    b = index.bounds
    out: dict[str, Any] = {"interpolators": list(cfg["interpolators"]), "method": cfg["method"], "photos": {}}
    collected: dict[str, list[tuple[list[Any], np.ndarray, np.ndarray]]] = {i: [] for i in cfg["interpolators"]}
    for pid in cfg["features"]:
        safe_component(pid, "photo id", survey.toml_path)
    for pid, fpath in cfg["features"].items():
        path = Path(fpath) if Path(fpath).is_absolute() else survey.root / fpath
        feats = read_features(path)
        px = np.vstack([f.colrow_px for f in feats])
        cam, eo = survey.camera_of(pid), eos[pid]
        box = ray_area(cam, eo.params, px, b.zmin, b.zmax)
        cloud = index.query_box(*box)
        first = cloud.first_returns()
        if first.sum() < 3:
            raise SurveyError(f"{path}: the rays of photo {pid}'s features cross E {box[0]:.1f}..{box[2]:.1f}, "
                              f"N {box[1]:.1f}..{box[3]:.1f}, where the LiDAR tiles have no points")
        entry: dict[str, Any] = {"features": str(fpath), "n_features": len(feats), "n_vertices": len(px)}
        for interp in cfg["interpolators"]:
            if interp == "bilinear":
                grid, gt = rasterize(cloud, float(cfg["cell_m"]), "dsm", bounds=box, fill="interpolate")
                surface: Any = GridSurface(grid, gt, "bilinear", sd_m=float(cfg["surface_sd_m"]))
            else:
                surface = PointSurface(np.asarray(cloud.xyz)[first], interp, sd_m=float(cfg["surface_sd_m"]))
            res = monoplot(px, cam, eo, surface, method=cfg["method"], image_sd_px=float(cfg["image_sd_px"]))
            name = f"monoplot_{pid}_{interp}.geojson"  # pid checked above
            doc = features_geojson(feats, res, crs=survey.crs, extra={
                "photo": pid, "method": cfg["method"], "interpolator": interp, "surface": INTERPOLATORS[interp],
                "image_sd_px": cfg["image_sd_px"], "surface_sd_m": cfg["surface_sd_m"]})
            write_text_atomic(tmp / name, json.dumps(doc, indent=1))
            entry[interp] = {"path": name, "status": res.counts()}
            collected[interp].append((feats, res.enh, res.status))
        out["photos"][pid] = entry
    if reference is not None:
        scale, alpha = survey.assessment.scale or 2000.0, survey.assessment.alpha
        acc: dict[str, Any] = {}
        for interp, parts in collected.items():
            feats = [f for p in parts for f in p[0]]
            acc[interp] = assess_monoplot(feats, np.vstack([p[1] for p in parts]),
                                          [str(s) for p in parts for s in p[2]], reference,
                                          scale=scale, alpha=alpha)
        out.update(reference=str(cfg["reference"]), scale=scale, alpha=alpha, accuracy=acc,
                   table_09={i: {c: t["r90_m"] for c, t in a["classes"].items()} for i, a in acc.items()})
        write_csv_atomic(tmp / "accuracy.csv", ACCURACY_COLUMNS, _accuracy_rows(acc),
                         comments=[f"monorestituted features against {cfg['reference']} (reference minus "
                                   f"monoplot), m; K-S and Hotelling at alpha {alpha:g}; PEC at 1:{scale:g}"])
        out["accuracy_csv"] = "accuracy.csv"
    return out


def _accuracy_rows(acc: dict[str, Any]) -> list[list[Any]]:
    rows = []
    for interp, a in acc.items():
        for c, t in a["classes"].items():
            ks, ht = t["ks"], t["hotelling"]
            rows.append([interp, c, t["n"], *(t[k] for k in ACCURACY_COLUMNS[3:9]), ks.get("D"), ks.get("critical"),
                         ks.get("p_value"), ks.get("passed"), ht.get("T2"), ht.get("critical"), ht.get("passed"),
                         t["r90_m"], t["pec_class"]])
    return rows


def markdown(res: dict[str, Any]) -> list[str]:
    """Report section of the stage: products, and the per-interpolator accuracy tables (Cavassim Tables 07-09)."""
    from .._util.formatting import format_number as num

    lines = ["", "## Mapping", ""]
    if res.get("orthophotos"):
        lines.append(f"{len(res['orthophotos'])} orthophoto(s) over the {res['surface']} in ../mapping/"
                     + (f", mosaic {res['mosaic']['path']} with {res['mosaic']['seams']}" if res.get("mosaic") else "")
                     + ".")
    for pid, e in (res.get("photos") or {}).items():
        lines.append(f"Photo {pid}: {e['n_features']} features ({e['n_vertices']} vertices) of {e['features']} "
                     f"monorestituted ({res['method']}): "
                     + "; ".join(f"{i} " + ", ".join(f"{k} {v}" for k, v in e[i]["status"].items())
                                 for i in res["interpolators"]) + ".")
    if not res.get("accuracy"):
        return lines
    lines += ["", f"Monorestituted vertices against {res['reference']} (reference minus monoplot, m), as "
                  f"Cavassim (2005) Tables 07-09: K-S of the generalized distances and Hotelling's T^2 of a "
                  f"zero mean at alpha {res['alpha']:g}, r90 = radius holding 90 % of the points, PEC class at "
                  f"1:{res['scale']:g}. Only vertices with status ok are judged."]
    for interp, a in res["accuracy"].items():
        lines += ["", f"### Interpolator {interp} ({INTERPOLATORS[interp]})", "",
                  f"{a['n_assessed']} of {a['n_vertices']} vertices judged ({a['n_not_ok']} not ok, "
                  f"{a['n_no_reference']} without reference).", "",
                  "| class | n | mean dE | sd dE | mean dN | sd dN | mean resultant | sd resultant | K-S D "
                  "(critical) | normal | T^2 (critical) | zero mean | r90 | PEC |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c, t in a["classes"].items():
            ks, ht = t["ks"], t["hotelling"]
            lines.append(f"| {c} | {t['n']} | " + " | ".join(num(t[k], 3) for k in ACCURACY_COLUMNS[3:9])
                         + f" | {num(ks.get('D'), 3)} ({num(ks.get('critical'), 3)}) | {_yes(ks)} | "
                         f"{num(ht.get('T2'), 2)} ({num(ht.get('critical'), 2)}) | {_yes(ht)} | "
                         f"{num(t['r90_m'], 2)} | {t['pec_class'] or '-'} |")
    classes = list(dict.fromkeys(c for a in res["accuracy"].values() for c in a["classes"]))
    lines += ["", "Radius holding 90 % of the points, m (Cavassim Table 09):", "",
              "| interpolator | " + " | ".join(classes) + " |", "|---|" + "---|" * len(classes)]
    for interp, t9 in res["table_09"].items():
        lines.append(f"| {interp} | " + " | ".join(num(t9.get(c), 2) for c in classes) + " |")
    return lines


def _yes(test: dict[str, Any]) -> str:
    return "-" if not test.get("applicable", True) or test.get("passed") is None else (
        "yes" if test["passed"] else "no")
