"""Library errors: data conditions raise a located LidarcatError subclass, the CLI shows one line.

House rule (STYLE.md, round 3): "a data condition raises a LidarcatError subclass with its
location, never a bare ValueError (argument checks may stay ValueError, as in scipy)".
:func:`test_no_new_bare_builtin_raise` scans the library with :mod:`ast` and holds every
remaining ``raise ValueError/TypeError/...`` against :data:`ALLOWED`, each with its reason, so
a new bare raise fails here until it is made a LidarcatError subclass or argued for.
"""

from __future__ import annotations

import ast
import builtins
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import lidarcat
from lidarcat.errors import CameraError, ClipError, CRSError, LidarcatError, ProductError

SRC = Path(lidarcat.__file__).resolve().parent
MODULES = sorted(str(p.relative_to(SRC)) for p in SRC.rglob("*.py"))


# --------------------------------------------------------------------------- the CLI
def _las(path: Path, classification: int) -> Path:
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.4")
    header.scales, header.offsets = [0.01] * 3, [500000.0, 7000000.0, 0.0]
    las = laspy.LasData(header)
    rng = np.random.default_rng(0)
    las.x = 500000.0 + rng.uniform(0, 40, 300)
    las.y = 7000000.0 + rng.uniform(0, 40, 300)
    las.z = rng.uniform(10, 20, 300)
    las.classification = np.full(300, classification, dtype=np.uint8)
    las.write(str(path))
    return path


@pytest.mark.parametrize("command", [["dtm"], ["dsm", "--ndsm"]])
def test_cli_tile_without_ground_points_is_one_line_naming_the_tile(tmp_path, command):
    """Issue 23: `lidarcat lidar dtm` on a tile without class 2 was a ValueError traceback."""
    from lidarcat.cli.main import cli

    tile = _las(tmp_path / "unclassified.las", classification=1)
    res = CliRunner().invoke(cli, ["lidar", *command, str(tile), "-o", str(tmp_path / "out.tif"),
                                   "--crs", "EPSG:31982"])
    assert res.exit_code == 2, res.output
    assert isinstance(res.exception, SystemExit)           # click's exit, not an uncaught error
    assert res.stderr == (f"Error: {tile}: no ground points (class 2); classify the ground first "
                          f"(lidarcat lidar ground)\n")
    assert "Traceback" not in res.output
    assert not (tmp_path / "out.tif").exists()


def test_cli_ground_onto_its_own_input_is_one_line(tmp_path):
    from lidarcat.cli.main import cli

    tile = _las(tmp_path / "tile.las", classification=1)
    res = CliRunner().invoke(cli, ["lidar", "ground", str(tile), "-o", str(tile), "--crs", "EPSG:31982"])
    assert res.exit_code == 2, res.output
    assert res.stderr == f"Error: {tile}: the output would overwrite the input; choose another name or folder\n"


# --------------------------------------------------------------------------- the library
def _dtm_no_ground():
    from lidarcat.lidar import PointCloud
    from lidarcat.production.terrain import dtm_grid

    dtm_grid(PointCloud(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]),
                        {"classification": np.ones(3, np.uint8)}), 1.0)


def _dtm_unclassified():
    from lidarcat.lidar import PointCloud
    from lidarcat.production.terrain import dtm_grid

    dtm_grid(PointCloud(np.array([[0.0, 0.0, 1.0]])), 1.0)


def _raster_empty():
    from lidarcat.lidar import PointCloud, rasterize

    rasterize(PointCloud(np.zeros((0, 3))), 1.0, "dsm")


def _raster_too_large():
    from lidarcat.lidar import PointCloud, rasterize

    rasterize(PointCloud(np.array([[0.0, 0.0, 0.0], [1e6, 1e6, 1.0]])), 0.01, "dsm")


def _undistort_outside():
    from lidarcat.interop._distortion import undistort

    with np.errstate(all="ignore"):  # Newton's method leaves the domain on the way
        undistort([[0.1, 0.0], [1.0, 0.0]], {"k4": 1.0})   # x / (1 + x^2) never reaches 1


def _collinear_clip():
    from lidarcat.control.facets import delaunay_facets

    delaunay_facets(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]))


def _two_points_clip():
    from lidarcat.control.facets import delaunay_facets

    delaunay_facets(np.zeros((2, 3)))


def _unknown_sheet_index():
    from lidarcat.production.sheets import index_sheets

    index_sheets((0.0, 0.0, 10.0, 10.0), "brazil-7")


def _sheet_index_without_crs():
    from lidarcat.production.sheets import index_sheets

    index_sheets((0.0, 0.0, 10.0, 10.0), "brazil-250000")


def _empty_area():
    from lidarcat.production.mapindex import sheets_covering

    sheets_covering((10.0, 0.0, 0.0, 10.0), "EPSG:31982", 250_000)


def _outside_the_index():
    from lidarcat.production.mapindex import sheet_names

    sheet_names([0.0], [89.0], 250_000)


@pytest.mark.parametrize("call,error,message", [
    (_dtm_no_ground, ProductError, "no ground points (class 2); classify the ground first (lidarcat lidar ground)"),
    (_dtm_unclassified, ProductError, "the points carry no classification; classify the ground first "
                                      "(lidarcat lidar ground)"),
    (_raster_empty, ProductError, "cannot rasterize an empty point cloud without bounds"),
    (_raster_too_large, ProductError, "the data ask for a grid of 100,000,000 x 100,000,000 cells over E 0..1e+06 "
                                      "N 0..1e+06 at 0.01 m, more than the limit of 100,000,000; give the area "
                                      "to grid (--bounds XMIN YMIN XMAX YMAX), a coarser cell, or a larger "
                                      "--max-cells"),
    (_undistort_outside, CameraError, "undistortion did not converge at point index 1 (normalised 1, 0): "
                                      "a point outside the calibrated field?"),
    (_collinear_clip, ClipError, "points are collinear or coincident in plan; no triangulation"),
    (_two_points_clip, ClipError, "2 points: a triangulation needs at least 3"),
    (_unknown_sheet_index, ProductError, "unknown sheet index 'brazil-7'; use grid or brazil-N with N one of "
                                         "1000000, 500000, 250000, 100000, 50000, 25000, 10000, 5000, 2000"),
    (_sheet_index_without_crs, ProductError, "the brazil-250000 sheet index needs the CRS of the products"),
    (_empty_area, ProductError, "empty area: E 10.0..0.0, N 0.0..10.0"),
    (_outside_the_index, ProductError, "point 0: longitude 0.0, latitude 89.0 deg is outside the index "
                                       "(|lat| < 88, |lon| <= 180)"),
], ids=lambda v: getattr(v, "__name__", None) if callable(v) else None)
def test_data_condition_raises_a_lidarcat_error(call, error, message):
    with pytest.raises(error) as info:
        call()
    assert str(info.value) == message
    assert isinstance(info.value, LidarcatError) and isinstance(info.value, ValueError)  # old callers


def test_undistortion_error_is_a_value_error_still():
    """Callers that caught ValueError keep working: every subclass mixes in the builtin."""
    assert issubclass(CameraError, ValueError) and issubclass(CRSError, ValueError)
    assert issubclass(ProductError, LidarcatError) and issubclass(ProductError, ValueError)


def test_copy_survey_files_is_public():
    """interop.heights used interop.block's private _copy_survey."""
    from lidarcat.interop import block, heights

    assert "copy_survey_files" in block.__all__
    assert "_copy_survey" not in Path(heights.__file__).read_text(encoding="utf-8")


# --------------------------------------------------------------------------- the scan
#: builtin exceptions a library ``raise`` must not use for a data condition
#: (NotImplementedError marks abstract methods; StopIteration is iteration protocol)
BUILTIN_ERRORS = frozenset(
    n for n in dir(builtins)
    if isinstance(getattr(builtins, n), type) and issubclass(getattr(builtins, n), Exception)
) - {"NotImplementedError", "StopIteration", "StopAsyncIteration"}

_ARG = "argument check of a Python caller (the CLI validates the option)"
_SHAPE = "array shape/length check of a Python caller"
_ENUM = "invalid enum value from a Python caller (the CLI offers a click.Choice)"
_INTERNAL = "internal invariant: cannot follow from any file or option"
_PARAMS = ("parameter object: CLI options are click ranges, survey.toml values are validated at load "
           "with file:line")

#: (module, function qualname, exception, message head) -> why a builtin is right there.
#: The message head is the message's text up to 40 characters, ``{}`` for each placeholder.
ALLOWED: dict[tuple[str, str, str, str], str] = {
    ("__init__.py", "__getattr__", "AttributeError", "module 'lidarcat' has no attribute {}"):
        "module __getattr__ protocol (PEP 562) requires AttributeError",
    ("_util/frozen.py", "frozen_array", "ValueError", "expected shape {}, got {}"): _SHAPE,
    ("_util/tables.py", "to_json", "TypeError", "cannot serialise {} to JSON"):
        "json.dumps default hook: TypeError is the json protocol; objects come from code",
    ("_util/tables.py", "parse_float", "ValueError", "{} is not a number: only ASCII digits 0-"):
        "parser like float(): every caller re-raises it as a located error (SurveyError, ...)",
    ("_util/tables.py", "parse_float", "ValueError", "{} is not a number: write the decimal se"):
        "parser like float(): every caller re-raises it as a located error (SurveyError, ...)",
    ("_util/tables.py", "parse_float", "ValueError", "{} is not a number"):
        "parser like float(): every caller re-raises it as a located error (SurveyError, ...)",
    ("_util/values.py", "parse_number", "ValueError", "{} is not a finite number"):
        "parser like float(): every caller re-raises it as a located error (FormatError, ...)",
    ("_util/values.py", "parse_number", "ValueError", "{}"):
        "parser like float(): every caller re-raises it as a located error (FormatError, ...)",
    ("_util/values.py", "parse_whole", "ValueError", "{} is not a whole number: only ASCII dig"):
        "parser like float(): every caller re-raises it as a located error (FormatError, ...)",
    ("_util/values.py", "parse_whole", "ValueError", "{} is not a whole number"):
        "parser like float(): every caller re-raises it as a located error (FormatError, ...)",
    ("_util/values.py", "parse_whole", "ValueError", "{} is outside the sane range {}..{} {}"):
        "parser like float(): every caller re-raises it as a located error (FormatError, ...)",
    ("_util/values.py", "parse_whole", "ValueError", "{} has more than 18 digits"):
        "parser like float(): every caller re-raises it as a located error (FormatError, ...)",
    ("bundle/bal.py", "read_bal", "ValueError", "negative count"):
        "caught on the next line and re-raised as BalFormatError with file:line",
    ("bundle/bal.py", "_locate_token", "IndexError", "{}"): _INTERNAL,
    ("bundle/cholesky.py", "SupernodalCholesky.__init__", "ValueError",
     "unit sizes do not add up to the matrix s"): _INTERNAL,
    ("bundle/cholesky.py", "SupernodalCholesky.locate", "ValueError",
     "requested block outside the pattern of t"): _INTERNAL,
    ("bundle/cholesky.py", "SelectedInverse.blocks", "ValueError",
     "blocks(): all units of one call must hav"): _INTERNAL,
    ("bundle/precision.py", "covariance_blocks", "ValueError", "`precision` must be one of {}, got {}"): _ENUM,
    ("bundle/problem.py", "_frozen_array", "ValueError", "`{}` must have shape (n, {})"): _SHAPE,
    ("bundle/problem.py", "ExteriorOrientation.__post_init__", "ValueError",
     "exterior orientation of photo {} is not "):
        "BundleProblem inputs: survey.folder and the interop readers refuse such data with file:line",
    ("bundle/problem.py", "_check_range", "ValueError", "`{}` out of range of `{}`: {} (there are"): _SHAPE,
    ("bundle/problem.py", "_sigmas", "ValueError", "`{}` must be positive (use inf for a fre"):
        "BundleProblem inputs: survey.folder refuses non-positive sds with file:line",
    ("bundle/problem.py", "BundleProblem.__post_init__", "ValueError", "duplicate {} id(s): {}"):
        "BundleProblem inputs: survey.folder refuses duplicate ids with file:line",
    ("bundle/problem.py", "BundleProblem.__post_init__", "ValueError",
     "`photo_index`, `point_index`, `xy_mm` an"): _SHAPE,
    ("bundle/problem.py", "BundleProblem.__post_init__", "ValueError", "`sd_mm` must be positive"):
        "BundleProblem inputs: survey.folder refuses non-positive sds with file:line",
    ("bundle/problem.py", "BundleProblem.__post_init__", "ValueError",
     "a point is constrained twice in `constra"):
        "BundleProblem inputs: survey.folder refuses a point twice in a control set with file:line",
    ("bundle/problem.py", "BundleProblem.__post_init__", "ValueError",
     "`point_role` must have one entry per poi"): _SHAPE,
    ("bundle/redundancy.py", "check_level", "ValueError", "`level` (alpha of the w-test) must be in"): _ARG,
    ("bundle/redundancy.py", "check_level", "ValueError", "`power` must be in (0.5, 1), got {}"): _ARG,
    ("bundle/reliability.py", "snoop", "ValueError", "`snooping` must be one of {}, got {}"): _ENUM,
    ("bundle/reliability.py", "snoop", "ValueError", "`robust` must be one of {}, got {}"): _ENUM,
    ("bundle/reliability.py", "snoop", "ValueError", "`start` must be one of {}, got {}"): _ENUM,
    ("bundle/robust.py", "loss_weight", "ValueError", "`loss` must be one of {}, got {}"): _ENUM,
    ("bundle/robust.py", "robust_start", "ValueError", "`loss` must be one of none, auto, {}, go"): _ENUM,
    ("bundle/selfcal.py", "SelfCalResult.index", "ValueError", "no additional parameter {}; there are: {"):
        "lookup by name from Python code, like list.index",
    ("bundle/selfcal.py", "adjust_with_parameters", "ValueError", "`alpha` must be in (0, 1)"): _ARG,
    ("bundle/result.py", "_position", "ValueError", "{} {} is not in the adjustment"):
        "lookup by id from Python code (BundleResult.pose/point), like list.index",
    ("bundle/solve.py", "adjust", "ValueError", "`variance_factor` must be 'a_priori' or "): _ENUM,
    ("bundle/solve.py", "adjust", "ValueError", "`chi2_level` must be in (0, 1)"): _ARG,
    ("bundle/solve.py", "adjust", "ValueError", "`precision` must be one of {}, got {}"): _ENUM,
    ("bundle/solve.py", "adjust", "ValueError", "`solver` must be one of auto, direct, pc"): _ENUM,
    ("control/planes.py", "Plane.__post_init__", "ValueError", "plane normal must be a finite non-zero v"):
        "constructor argument check; fitted planes always have a unit normal",
    ("control/planes.py", "Plane.thesis_form", "ValueError", "plane passes through the origin; d canno"):
        "argument check of the datum form asked by Python code (a plane through the CRS origin)",
    **{("control/params.py", "ExtractionParams.__post_init__", "ValueError", head): _PARAMS for head in (
        "method must be one of {}, got {}", "residual_kind must be one of {}, got {}",
        "height_filter must be None, 'thesis' or ", "slope window must satisfy 0 <= slope_min",
        "height_window_m must be positive, got {}", "radius_m must be positive, got {}",
        "min_points must be >= 4 (a plane has 3 d", "sd_en_m and sd_h_m must be positive",
        "residual_threshold_m must be positive, g", "max_offset_m must be positive, got {}",
        "near_m must be positive, got {}", "scales must be fractions in (0, 1), got ",
        "ambiguity_m must be >= 0, got {}", "cells_m must be positive sizes in metres",
        "edge_buffer_m must be >= 0, got {}", "edge_buffer_level must be in [0, 1), got",
        "stability_scales must be positive multip", "stability_level must be in (0, 1), got {",
        "fit_radius_m must be positive (m) or Non")},
    ("control/params.py", "get_params", "ValueError", "unknown preset {}; choose one of {}"): _ENUM,
    ("control/search.py", "find_jobs", "ValueError", "block_cells must be at least 1, got {}"): _ARG,
    ("control/vertices.py", "ControlPoint.__post_init__", "ValueError", "unknown status {}"): _INTERNAL,
    ("photocontrol/measure.py", "Measurement.__post_init__", "ValueError", "unknown status {}"): _INTERNAL,
    ("photocontrol/measure.py", "_scores", "ValueError", "coarse must be 'lines' or 'likelihood', "): _ENUM,
    ("photocontrol/measure.py", "_setup", "ValueError", "border must be 'edges' or 'fit', got {}"): _ENUM,
    ("photocontrol/measure.py", "MeasureParams.__post_init__", "ValueError", "{} must be {}, got {}"): _PARAMS,
    ("control/vertices.py", "_as_xyz", "ValueError", "points must be an (N, 3) array or a Poin"):
        "shape check; extract_roof turns it into status 'bad_input'",
    ("control/vertices.py", "extract_roof", "ValueError", "center_en must be (E, N) in metres, got "): _SHAPE,
    ("geometry/camera.py", "Camera.photo_to_fot", "ValueError", "on_fail must be 'raise' or 'nan'"): _ENUM,
    ("interop/block.py", "Block.__post_init__", "ValueError", "Block: eo and photo_camera need one row "):
        _SHAPE + "; the readers build it from checked files",
    ("interop/block.py", "Block.__post_init__", "ValueError", "Block: obs_* need one row per observatio"):
        _SHAPE + "; the readers build it from checked files",
    ("interop/block.py", "Block.__post_init__", "ValueError", "Block: points_m needs one row per point "):
        _SHAPE + "; the readers build it from checked files",
    ("lidar/clipping.py", "height_window_mask", "ValueError", "height_window_m must be positive, got {}"): _ARG,
    ("lidar/clipping.py", "height_window_mask", "ValueError", "unknown height_filter {}; use 'thesis', "): _ENUM,
    ("lidar/clipping.py", "clip", "ValueError", "unknown height_filter {}; use 'thesis', "): _ENUM,
    ("lidar/cloud.py", "_attribute", "ValueError", "attribute {} has shape {}, expected ({},"): _SHAPE,
    ("lidar/cloud.py", "PointCloud.__post_init__", "ValueError", "xyz must have shape (N, 3), got {}"): _SHAPE,
    ("lidar/cloud.py", "PointCloud._owned", "ValueError", "xyz must have shape (N, 3), got {}"): _SHAPE,
    ("lidar/cloud.py", "PointCloud.select", "ValueError", "mask has shape {}, expected ({},)"): _SHAPE,
    ("lidar/crs.py", "transform_points", "ValueError", "xy must have 2 or 3 columns, got shape {"): _SHAPE,
    ("lidar/jobs.py", "tile_jobs", "ValueError", "no tiles given"):
        "argument check; the CLI expands TILE... and refuses a glob matching nothing",
    ("lidar/jobs.py", "_client", "ValueError", "workers must be at least 1, got {}"): _ARG,
    ("lidar/copc_write.py", "hierarchy_pages", "ValueError", "page_entries must be at least 9 (a node "): _ARG,
    ("lidar/copc_write.py", "write_copc", "ValueError", "grid must be a power of two from 8 to 12"): _ARG,
    ("lidar/copc_write.py", "write_copc", "ValueError", "max_points, bucket_points and chunk_poin"): _ARG,
    ("lidar/copc_write.py", "write_copc", "ValueError", "page_entries must be at least 9 (a node "): _ARG,
    ("lidar/raster.py", "rasterize", "ValueError", "unknown raster {}; use one of {}"): _ENUM,
    ("lidar/raster.py", "rasterize", "ValueError", "cell_m must be positive, got {}"): _ARG,
    ("lidar/raster.py", "rasterize", "ValueError", "unknown fill {}"): _ENUM,
    ("lidar/raster.py", "rasterize", "ValueError", "bounds are required when rasterizing a s"): _ARG,
    ("lidar/readers.py", "iter_las_ranges", "ValueError", "piece_points and max_read_points must be"): _ARG,
    ("lidar/readers.py", "iter_points", "ValueError", "chunk_size must be positive, got {}"): _ARG,
    ("lidar/tiles.py", "BlockIndex.__post_init__", "ValueError", "block_points ({}) must be a positive mul"):
        _INTERNAL + " (the index cache is read through its own checked loader)",
    ("lidar/tiles.py", "BlockIndex.__post_init__", "ValueError", "{} boxes for {} points in cells of {}"):
        _INTERNAL + " (the index cache is read through its own checked loader)",
    ("lidar/tiles.py", "BlockBoxes.add", "ValueError", "more points than the tile holds"):
        _INTERNAL + " (the reader streams the header's count; the file is checked unchanged)",
    ("lidar/tileindex.py", "TileIndex.__init__", "ValueError", "decode must be one of {}, got {}"): _ENUM,
    ("lidar/tileindex.py", "TileIndex.__init__", "ValueError", "block_points and cell_points must be pos"): _ARG,
    ("lidar/tileindex.py", "TileIndex.query_radius", "ValueError", "radius_m must be positive, got {}"): _ARG,
    ("lidar/tileindex.py", "TileIndex.query_polygon", "ValueError", "a polygon needs at least 3 vertices as a"):
        _SHAPE,
    ("pipeline/runner.py", "PipelineResult.stage", "KeyError", "no stage {}; stages: {}"):
        "lookup by name from Python code, like dict[key]",
    ("pipeline/runner.py", "run_stages", "ValueError", "duplicate stage names in {}"):
        "argument check: the stage list is code, not data",
    ("production/contours.py", "contours", "ValueError", "interval_m must be positive, got {}"): _ARG,
    ("production/contours.py", "contours", "ValueError", "master_every must be at least 1, got {}"): _ARG,
    ("production/contours.py", "write_contours", "ValueError", "{}: contour output must end in {}, got {"):
        "argument check; the CLI refuses the -o suffix first (click.BadParameter)",
    ("production/contours.py", "write_layers", "ValueError", "{}: a GeoJSON file holds one layer, got "):
        "argument check: the layer set is built by code",
    ("production/ground.py", "PTDParameters.__post_init__", "ValueError", "{} must be a positive number, got {}"):
        _PARAMS,
    ("production/ground.py", "PTDParameters.__post_init__", "ValueError",
     "iteration_angle_deg must be below 90, go"): _PARAMS,
    ("production/ground.py", "PTDParameters.__post_init__", "ValueError", "max_iterations must be at least 1"):
        _PARAMS,
    ("production/ground.py", "SMRFParameters.__post_init__", "ValueError", "{} must be a positive number, got {}"):
        _PARAMS,
    ("production/ground.py", "classify_ground", "ValueError", "method 'ptd' takes PTDParameters"): _ARG,
    ("production/ground.py", "classify_ground", "ValueError", "method 'smrf' takes SMRFParameters"): _ARG,
    ("production/ground.py", "classify_ground", "ValueError", "unknown ground method {}; use one of {}"): _ENUM,
    ("production/ground.py", "confusion", "ValueError", "reference and classification differ in s"): _SHAPE,
    ("production/ground.py", "write_classified_copy", "ValueError", "{}: {} points but {} ground flags"):
        _SHAPE,
    ("production/ground.py", "classify_tiles", "ValueError", "unknown ground method {}; use one of {}"): _ENUM,
    ("production/ground.py", "classify_ground", "ValueError", "method 'csf' takes CSFParameters"): _ARG,
    ("production/ground.py", "write_classified_copy", "ValueError", "{}: {} points but {} noise flags"): _SHAPE,
    ("production/ground.py", "write_classified_copy", "ValueError", "{}: {} points but {} heights above groun"):
        _SHAPE,
    ("production/csf.py", "CSFParameters.__post_init__", "ValueError", "{} must be a positive number, got {}"):
        _PARAMS,
    ("production/csf.py", "CSFParameters.__post_init__", "ValueError", "rigidness must be 1, 2 or 3, got {}"):
        _PARAMS,
    ("production/csf.py", "CSFParameters.__post_init__", "ValueError", "iterations must be at least 1"): _PARAMS,
    ("production/noise.py", "statistical_outliers", "ValueError", "mean_k must be at least 1, got {}"): _ARG,
    ("production/noise.py", "height_above_ground", "ValueError", "ground has shape {}, expected ({},)"): _SHAPE,
    ("production/mapindex.py", "_check_scale", "ValueError", "no Brazilian index sheet at 1:{}; use on"):
        _ENUM + "; index_sheets refuses a bad brazil-N with ProductError first",
    ("production/mapindex.py", "sheet_names", "ValueError", "lon and lat differ in shape: {} and {}"): _SHAPE,
    ("production/mapindex.py", "sheet_from_name", "ValueError", "sheet name {}: it must start with a 1:1,"):
        "parses a sheet name given by Python code (no file or option reaches it)",
    ("production/mapindex.py", "sheet_from_name", "ValueError", "sheet name {}: more parts than the index"):
        "parses a sheet name given by Python code (no file or option reaches it)",
    ("production/mapindex.py", "sheet_from_name", "ValueError", "sheet name {}: {} is not a 1:{} symbol ("):
        "parses a sheet name given by Python code (no file or option reaches it)",
    ("production/terrain.py", "tin_grid", "ValueError", "cannot grid an empty point set without b"):
        "argument check: dtm_grid always passes bounds",
    ("production/terrain.py", "ndsm", "ValueError", "DSM and DTM grids differ: {} vs {}"): _SHAPE,
    ("stages/extract.py", "_toml_value", "TypeError", "cannot write {} to TOML"): _INTERNAL,
    ("survey/_tables.py", "ImagePoints.__post_init__", "ValueError", "ImagePoints.{} has {} rows, expected {}"):
        _SHAPE,
    ("survey/schema.py", "split_frame_offset", "ValueError", "frame offset {} must be SOURCE:REFERENCE"):
        "parser: its callers re-raise it as SurveyError at survey.toml:line",
    ("synthetic/landscapes.py", "make_landscape", "ValueError", "unknown landscape {}; use one of {}"): _ENUM,
    ("synthetic/landscapes.py", "make_landscape", "ValueError", "size_m and density must be positive"): _ARG,
    ("synthetic/roofs.py", "roof_height", "ValueError", "unknown roof kind {}; choose one of {}"): _ENUM,
    ("synthetic/roofs.py", "synthetic_roof", "ValueError", "unknown roof kind {}; choose one of {}"): _ENUM,
    ("synthetic/roofs.py", "synthetic_roof", "ValueError", "density_m2 must be positive"): _ARG,
    ("synthetic/roofs.py", "synthetic_roof", "ValueError", "strips must be 1 or 2, got {}"): _ARG,
    ("synthetic/roofs.py", "synthetic_roof", "ValueError", "a hip roof needs length_m > width_m (equ"): _ARG,
    ("testing.py", "assert_poses_close", "AssertionError", "{}"):
        "an assertion helper for tests, like numpy.testing",
    # added with the house-by-stage layout (issue 23)
    ("lidar/geotiff.py", "GeoTiffWriter.write_rows", "ValueError", "{}: row block of shape {} does not fit a"): _SHAPE,
    ("lidar/geotiff.py", "_values", "ValueError", "grid must be a non-empty (rows, cols) or"): _SHAPE,
    ("lidar/geotiff.py", "write_bands", "ValueError", "give a (bands, rows, cols) stack and one"): _SHAPE,
    ("lidar/geotiff.py", "write_vrt", "ValueError", "a VRT needs at least one source GeoTIFF"): _ARG,
    # orthophoto files (issue 26): the writer's options, chosen by code (the CLI offers a click.Choice)
    ("lidar/geotiff.py", "_profile", "ValueError", "JPEG compression takes 1- or 3-band uint"): _ARG,
    ("lidar/geotiff.py", "_profile", "ValueError", "compression must be DEFLATE or JPEG, got"): _ENUM,
    ("lidar/geotiff.py", "GeoTiffWriter.write_rows", "ValueError", "{}: a masked GeoTIFF needs the valid cel"): _SHAPE,
    ("lidar/jobs.py", "TileJob.__post_init__", "ValueError", "a tile job's function must be a module-l"): _ARG,
    ("production/tiles.py", "product_jobs", "ValueError", "unknown product {}; use one of {}"): _ENUM,
    ("report/render.py", "_html_block", "TypeError", "not a report block: {}"): _INTERNAL,
    ("report/render.py", "_md_section", "TypeError", "not a report block: {}"): _INTERNAL,
    ("stages/lidar.py", "mosaic_grids", "ValueError", "give one area per grid, and at least one"): _SHAPE,
    ("stages/lidar.py", "mosaic_grids", "ValueError", "the grids have different cells"): _INTERNAL,
    ("stages/lidar.py", "terrain_model", "ValueError", "kind must be 'dtm' or 'dsm', got {}"): _ENUM,
}


def _head(node: ast.expr | None) -> str:
    """The message's text up to 40 characters, ``{}`` for each placeholder ("" without one)."""
    if node is None:
        return ""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        text = node.value
    elif isinstance(node, ast.JoinedStr):
        text = "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in node.values)
    elif isinstance(node, ast.BinOp):          # "..." + "..." or "..." % (...)
        return _head(node.left)
    elif isinstance(node, ast.IfExp):          # one of two messages
        return _head(node.body)
    else:
        text = "{}"
    return text[:40]


def bare_raises(module: str, root: Path = SRC) -> list[tuple[int, tuple[str, str, str, str]]]:
    """(line, key) of every ``raise <builtin exception>(...)`` in *module* (relative to *root*)."""
    found: list[tuple[int, tuple[str, str, str, str]]] = []
    scope: list[str] = []

    class Visitor(ast.NodeVisitor):
        def visit_FunctionDef(self, node):
            scope.append(node.name)
            self.generic_visit(node)
            scope.pop()

        visit_AsyncFunctionDef = visit_ClassDef = visit_FunctionDef

        def visit_Raise(self, node):
            exc = node.exc
            func = exc.func if isinstance(exc, ast.Call) else exc
            if isinstance(func, ast.Name) and func.id in BUILTIN_ERRORS:
                msg = exc.args[0] if isinstance(exc, ast.Call) and exc.args else None
                found.append((node.lineno, (module, ".".join(scope) or "<module>", func.id, _head(msg))))
            self.generic_visit(node)

    Visitor().visit(ast.parse((root / module).read_text(encoding="utf-8")))
    return found


@pytest.mark.parametrize("module", MODULES)
def test_no_new_bare_builtin_raise(module):
    """Every raise of a builtin exception is an argued argument check (ALLOWED); a data condition
    raises a LidarcatError subclass from lidarcat.errors with its location."""
    new = [f"src/lidarcat/{module}:{line}: raise {key[2]}({key[3]!r}...) in {key[1]}"
           for line, key in bare_raises(module) if key not in ALLOWED]
    assert not new, ("a data condition raises a LidarcatError subclass with its location (lidarcat.errors); "
                     "an argument check goes into ALLOWED with its reason:\n" + "\n".join(new))


def test_allow_list_has_no_stale_entry():
    """An entry whose raise is gone (converted or reworded) is dropped, so the list stays exact."""
    present = {key for module in MODULES for _, key in bare_raises(module)}
    assert sorted(set(ALLOWED) - present) == []


def test_the_scan_sees_a_bare_raise(tmp_path):
    """The scan itself: a ValueError in an f-string, a bare TypeError and a LidarcatError subclass."""
    code = ("from lidarcat.errors import SurveyError\n"
            "class K:\n"
            "    def f(self, x):\n"
            "        if x:\n"
            "            raise ValueError(f'bad {x} value')\n"
            "        raise TypeError\n"
            "def g():\n"
            "    raise SurveyError('fine')\n")
    (tmp_path / "mod.py").write_text(code, encoding="utf-8")
    assert bare_raises("mod.py", tmp_path) == [(5, ("mod.py", "K.f", "ValueError", "bad {} value")),
                                     (6, ("mod.py", "K.f", "TypeError", ""))]
