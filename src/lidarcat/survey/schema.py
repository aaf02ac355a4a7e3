"""The survey.toml schema: every table and key, typed, parsed once and validated at :meth:`Survey.load`.

Each table of survey.toml is a frozen dataclass below; each of its fields is a
key, whose metadata holds the TOML type (:class:`TomlType`), whether it is
required and a one-line description with the unit.  :func:`parse_survey_toml`
reads the file once, refuses unknown tables and keys, ill-typed values and
values out of range with a :class:`~lidarcat.errors.SurveyError` that names
``survey.toml:LINE: field 'key'``, and returns a :class:`SurveyConfig`;
:meth:`lidarcat.Survey.load` keeps it as ``survey.config`` (so
``survey.config.mapping.gsd_m``), and the stages read their tables there
instead of parsing the file again.  Checks that need the survey's other files
(files exist, photo ids, control sets, the CRS's area of use) are made by
``Survey.load`` and :func:`check_photo_ids`.

The reference of docs/survey-format.md is generated from the dataclasses
(:func:`render_reference`; ``python -m lidarcat.survey.schema`` prints it).

>>> from lidarcat.survey.folder import thesis_survey_path
>>> cfg = parse_survey_toml(thesis_survey_path() / "survey.toml")
>>> cfg.assessment.plotting_position, cfg.mapping is None, cfg.tables[:2]
('hazen', True, ('survey', 'files'))
"""

from __future__ import annotations

import copy
import dataclasses
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from .._util import excerpt, read_toml, toml_line
from ..errors import SurveyError, location

__all__ = [
    "TomlType", "SurveyTable", "FilesTable", "AdjustmentTable", "AdjustmentSettings", "LidarTable",
    "AssessmentSettings", "HeightsTable", "MappingSettings", "ProductsSettings", "SelfCalSettings",
    "SurveyConfig", "TABLES", "SURVEY_KEYS", "REQUIRED_TABLES", "parse_survey_toml", "check_photo_ids",
    "render_reference", "keys_of", "split_frame_offset", "DEFAULT_SD_PIXELS", "DEFAULT_SCALE", "DEFAULT_CONTOUR_INTERVAL_M",
    "PEC_CLASSES", "PLOTTING_POSITIONS", "OBSERVATION_KINDS", "VARIANCE_FACTORS", "SD_BOUNDS",
    "MAPPING_INTERPOLATORS",
]


# ---------------------------------------------------------------------- key types
@dataclass(frozen=True)
class TomlType:
    """The TOML type of a key: *kinds* are the Python types tomllib gives for it (a TOML boolean is
    no integer), *name* is the type in docs/survey-format.md."""

    name: str
    kinds: tuple[type, ...]

    @property
    def expected(self) -> str:
        """``int/float``: the kinds as the error message names them."""
        return "/".join(k.__name__ for k in self.kinds)


STRING = TomlType("string", (str,))
BOOLEAN = TomlType("boolean", (bool,))
INTEGER = TomlType("integer", (int,))
NUMBER = TomlType("number", (int, float))
STRINGS = TomlType("list of strings", (list,))
NUMBERS = TomlType("list of numbers", (list,))
STRING_OR_STRINGS = TomlType("string or list of strings", (str, list))
TABLE = TomlType("table", (dict,))


def _key(toml: TomlType, default: Any, doc: str, *, required: bool = False) -> Any:
    """A key of a table: its TOML type, default, description (with the unit) and whether it is required."""
    return field(default=default, metadata={"toml": toml, "doc": doc, "required": required})


def keys_of(table_class: type) -> tuple[dataclasses.Field, ...]:
    """The key fields of a table class, in file order."""
    return tuple(f for f in dataclasses.fields(table_class) if "toml" in f.metadata)


#: fraction of a pixel used as default image sd (thesis 3.3.1: 0.006 mm for a 7.9 um pixel)
DEFAULT_SD_PIXELS = 0.75
#: default map scale denominator of the check-point classification (the thesis's 1:2000); shared by
#: survey.toml [assessment], ``lidarcat run`` and ``lidarcat assess``
DEFAULT_SCALE = 2000.0
#: default contour interval of the altimetric classes, m (the thesis's 2 m); shared likewise
DEFAULT_CONTOUR_INTERVAL_M = 2.0
#: classes of Decreto 89.817 (lidarcat.accuracy.standards has the tolerances; importing it here would pull
#: scipy into every survey load)
PEC_CLASSES = ("A", "B", "C")
#: Filliben plotting positions (lidarcat.accuracy.checkpoints.PLOTTING_POSITIONS, not imported for the same reason)
PLOTTING_POSITIONS = ("filliben", "hazen", "blom")
#: [adjustment] observations
OBSERVATION_KINDS = ("corrected", "pixel")
#: [adjustment] variance_factor
VARIANCE_FACTORS = ("a_priori", "a_posteriori")
#: sane ranges of standard deviations by unit (a value outside is a typo or a unit mix-up)
SD_BOUNDS = {"m": (1e-6, 1e3), "mm": (1e-6, 10.0), "deg": (1e-8, 90.0)}
#: interpolators of the monorestitution ([mapping] interpolators; lidarcat.stages.mapping.INTERPOLATORS
#: describes each)
MAPPING_INTERPOLATORS = ("nearest", "tin", "bilinear")


# ---------------------------------------------------------------------- the tables
@dataclass(frozen=True)
class SurveyTable:
    """``[survey]`` (required): the name and the reference frame."""

    name: str = _key(STRING, None, "name of the survey", required=True)
    description: str = _key(STRING, "", "free text")
    crs: str = _key(STRING, None, "CRS of the ground coordinates: any pyproj string in metres (checked against "
                    "its area of use), or \"local: <text>\" for a model frame that is not georeferenced",
                    required=True)
    height_system: str = _key(STRING, "unspecified", "\"orthometric\", \"ellipsoidal\" or free text")
    default_control: str | None = _key(STRING, None, "control set used when --control is not given; must be "
                                                     "a set of control_sets.csv")


@dataclass(frozen=True)
class FilesTable:
    """``[files]`` (required): the input files, relative to the folder; each must exist."""

    camera: str = _key(STRING, None, "camera TOML (docs: camera.toml below)", required=True)
    photos: str = _key(STRING, None, "photos.csv", required=True)
    image_points: str = _key(STRING, None, "image_points.csv", required=True)
    ground_points: str | None = _key(STRING, None, "ground_points.csv (no control without it)")
    control_sets: str | None = _key(STRING, None, "control_sets.csv")
    lidar: tuple[str, ...] = _key(STRING_OR_STRINGS, (), "LiDAR tile files or globs (LAS/LAZ/ASCII); a glob "
                                                         "matching nothing or a missing file is an error")
    extraction_jobs: str | None = _key(STRING, None, "roofs to extract (jobs.csv or the thesis job file)")
    rigs: str | None = _key(STRING, None, "rig TOML: cameras with fixed relative poses, moved as one body per "
                                          "photos.csv rig_exposure (docs/cameras.md, Rigs)")
    line_control: str | None = _key(STRING, None, "line_control.csv: control lines (LiDAR roof edges) and their "
                                                  "measurements in the photos (docs/lines.md)")
    control_decisions: str | None = _key(STRING, None, "control_decisions.csv: the user's review of the LiDAR "
                                                       "control measured in the photos (docs/photocontrol.md)")


@dataclass(frozen=True)
class AdjustmentTable:
    """``[adjustment]``: how the bundle adjustment weighs and tests (``observations`` and ``image_sd_mm``
    default to values derived from the data; ``survey.settings`` holds the resolved :class:`AdjustmentSettings`)."""

    observations: str | None = _key(STRING, None, "\"corrected\" (x_mm, y_mm) or \"pixel\" (col_px, row_px "
                                                  "through eq. 01-07); default: \"corrected\" when "
                                                  "image_points.csv has x_mm, y_mm, else \"pixel\"")
    image_sd_mm: float | None = _key(NUMBER, None, "default sd of a photo coordinate, mm; default: 3/4 of the "
                                                   "largest pixel of the cameras")
    exclude_points: tuple[str, ...] = _key(STRINGS, (), "points left out of every adjustment (each measured or "
                                                       "a ground point; in no control set)")
    variance_factor: str = _key(STRING, "a_priori", "parameter sds from sigma0^2 = 1 (\"a_priori\") or its "
                                                    "estimate (\"a_posteriori\")")
    chi2_level: float = _key(NUMBER, 0.05, "level of the two-sided chi-square test of the variance factor "
                                           "(0 < level < 1)")


@dataclass(frozen=True)
class AdjustmentSettings:
    """The ``[adjustment]`` table of survey.toml, with defaults resolved (``survey.settings``).

    Attributes
    ----------
    observations : {"corrected", "pixel"}
        Which image coordinates the adjustment uses: the file's ``x_mm, y_mm``
        or ``col_px, row_px`` run through the camera (eq. 01-07).  Default:
        "corrected" when image_points.csv has x_mm/y_mm columns, else "pixel".
    image_sd_mm : float
        Default sd of a photo coordinate, mm.  Default: 3/4 of the largest pixel
        of the survey's cameras (the thesis used 0.006 mm for 7.9 um pixels).
    exclude_points : frozenset of str
        Points left out of every adjustment.
    variance_factor : {"a_priori", "a_posteriori"}
        Parameter sds from sigma0^2 = 1 (as the thesis tables) or the estimate.
    chi2_level : float
        Level of the two-sided chi-square test of the variance factor (0 < a < 1).
    """

    observations: str = "corrected"
    image_sd_mm: float = 0.006
    exclude_points: frozenset[str] = field(default_factory=frozenset)
    variance_factor: str = "a_priori"
    chi2_level: float = 0.05

    def to_dict(self) -> dict[str, Any]:
        return {"observations": self.observations, "image_sd_mm": self.image_sd_mm,
                "exclude_points": sorted(self.exclude_points),
                "variance_factor": self.variance_factor, "chi2_level": self.chi2_level}


@dataclass(frozen=True)
class LidarTable:
    """``[lidar]``: the LiDAR tiles."""

    crs: str | None = _key(STRING, None, "CRS of tiles that carry none (in metres)")


@dataclass(frozen=True)
class AssessmentSettings:
    """The ``[assessment]`` table of survey.toml: how ``lidarcat run`` judges check points.

    Attributes
    ----------
    scale : float
        Map scale denominator of the product (PEC classes, the chi-square
        sigma0, the CE90 limit).  Default 2000, the thesis's 1:2000.
    contour_interval_m : float
        Contour interval for the altimetric classes, m.  Default 2 (thesis).
    alpha : float
        Level of every test (thesis: 0.10).
    pec_class : str
        Decreto 89.817 class whose EP is the chi-square sigma0 ("A" in the thesis).
    plotting_position : str
        Positions of the Filliben normal-probability test: ``filliben``
        (Filliben 1975, matches its critical-value table), ``hazen``
        ``(i - 0.5)/n`` (the thesis's Z_i, Tables 14/15) or ``blom``.
    """

    scale: float = _key(NUMBER, DEFAULT_SCALE, "map scale denominator of the product (PEC classes, chi-square "
                                               "sigma0, CE90 limit); 2000 for 1:2000")
    contour_interval_m: float = _key(NUMBER, DEFAULT_CONTOUR_INTERVAL_M, "contour interval of the altimetric "
                                                                         "classes, m")
    alpha: float = _key(NUMBER, 0.10, "level of every test (0 < alpha < 1)")
    pec_class: str = _key(STRING, "A", "Decreto 89.817 class whose EP is the chi-square sigma0: A, B or C")
    plotting_position: str = _key(STRING, "filliben", "Filliben test positions: filliben (its critical table), "
                                                      "hazen (i - 0.5)/n (the thesis's Tables 14/15) or blom")

    def to_dict(self) -> dict[str, Any]:
        return {"scale": self.scale, "contour_interval_m": self.contour_interval_m, "alpha": self.alpha,
                "pec_class": self.pec_class, "plotting_position": self.plotting_position}


@dataclass(frozen=True)
class HeightsTable:
    """``[heights]``: what each ground-point source's heights are (read by :mod:`lidarcat.interop.heights`)."""

    sources: Mapping[str, str] | None = _key(TABLE, None, "source -> \"ellipsoidal\" or \"orthometric\", "
                                                          "e.g. { lidar = \"ellipsoidal\" } (default: [survey] "
                                                          "height_system)")
    geoid_grid: str | None = _key(STRING, None, "geoid undulation grid (GTX or GeoTIFF), relative to the folder")


@dataclass(frozen=True)
class MappingSettings:
    """``[mapping]``: orthophotos, mosaic and monoplot of ``lidarcat run`` (:mod:`lidarcat.stages.mapping`)."""

    orthophotos: bool = _key(BOOLEAN, False, "make orthophotos")
    surface: str = _key(STRING, "dsm", "\"dsm\": true orthophotos (occlusions masked) or \"dtm\": standard")
    gsd_m: float = _key(NUMBER, 0.2, "output cell, m (> 0)")
    cell_m: float = _key(NUMBER, 0.5, "cell of the surface model rasterised from the LiDAR, m (> 0)")
    mosaic: bool = _key(BOOLEAN, True, "also mosaic.tif and seamlines.geojson")
    images: str = _key(STRING, "images", "folder of the photo files <photo>.png/.tif/.jpg")
    photos: tuple[str, ...] | None = _key(STRINGS, None, "a subset of the photos (default: every adjusted photo)")
    features: Mapping[str, str] | None = _key(TABLE, None, "photo -> file of the features digitised on it, px "
                                                           "(.geojson or .csv)")
    reference: str | None = _key(STRING, None, "their map / true positions, feature,vertex,E,N (m): accuracy "
                                               "tables per interpolator")
    interpolators: tuple[str, ...] = _key(STRINGS, ("nearest", "tin"), "surfaces of the monorestitution: "
                                                                      "nearest, tin, bilinear")
    method: str = _key(STRING, "exact", "\"exact\" (first hit) or \"iterate\" (the paper's height iteration)")
    image_sd_px: float = _key(NUMBER, 0.5, "pointing sd of the digitised pixels, px (>= 0)")
    surface_sd_m: float = _key(NUMBER, 0.15, "height sd of the surface, m (>= 0)")
    feather_m: float = _key(NUMBER, 0.0, "mosaic: blend across seamlines over +- this many m (0: hard seams)")
    equalize: bool = _key(BOOLEAN, False, "mosaic: balance the photos first, a gain and an offset per photo "
                                          "from the overlaps")

    def to_dict(self) -> dict[str, Any]:
        """The table as the stage's parameters (lists and dicts, as in the file)."""
        out = {f.name: getattr(self, f.name) for f in keys_of(type(self))}
        out["photos"] = None if self.photos is None else list(self.photos)
        out["features"] = None if self.features is None else dict(self.features)
        out["interpolators"] = list(self.interpolators)
        return out


@dataclass(frozen=True)
class ProductsSettings:
    """``[products]``: the LiDAR products of ``lidarcat run`` (:mod:`lidarcat.stages.products`)."""

    ground: bool = _key(BOOLEAN, True, "classify ground (class 2) into copies of the tiles (false: use their "
                                       "class 2)")
    filter: str = _key(STRING, "smrf", "\"smrf\" (simple morphological filter), \"ptd\" (TIN densification) "
                                       "or \"csf\" (cloth simulation)")
    dtm: bool = _key(BOOLEAN, True, "dtm.tif: TIN of the ground, gaps NaN")
    dsm: bool = _key(BOOLEAN, True, "dsm.tif: highest first return per cell")
    ndsm: bool = _key(BOOLEAN, False, "ndsm.tif = DSM - DTM (needs dtm and dsm)")
    hillshade: bool = _key(BOOLEAN, False, "<model>_hillshade.tif of each model")
    text_grid: bool = _key(BOOLEAN, False, "<model>.txt: the report's E N H text grid")
    cell_m: float = _key(NUMBER, 1.0, "cell of the models, m (> 0)")
    max_edge_m: float = _key(NUMBER, 50.0, "TIN triangles with a longer edge are gaps, m (> 0)")
    contours: bool = _key(BOOLEAN, True, "contours.geojson + spot_heights.geojson from the ground TIN")
    contour_interval_m: float = _key(NUMBER, 1.0, "equidistance, m (> 0)")
    master_every: int = _key(INTEGER, 5, "every N-th level is a master curve (>= 1)")
    smooth: int = _key(INTEGER, 0, "Chaikin passes (0: vertices exactly on the TIN)")
    spots_m: float = _key(NUMBER, 100.0, "spot heights: highest and lowest ground point per square, m (> 0)")
    hypsometry: bool = _key(BOOLEAN, False, "hypsometry.png and .tif")
    hypsometry_cell_m: float = _key(NUMBER, 0.45, "cell of the hypsometric image, m (> 0)")
    sheet_size_m: float = _key(NUMBER, 0.0, "> 0: also cut every product along a sheet grid of this size, m")
    sheet_index: str = _key(STRING, "grid", "\"grid\" or the Brazilian systematic index \"brazil-25000\", "
                                            "\"brazil-10000\", \"brazil-5000\", \"brazil-2000\"")
    vector_format: str = _key(STRING, "geojson", "\"geojson\" or \"gpkg\" (GeoPackage, lidarcat[gis])")
    charts: bool = _key(BOOLEAN, False, "charts/<sheet>.pdf and .png: orthophoto charts of the sheets holding "
                                        "data (needs contours, a sheet index and the orthomosaic)")
    chart_mosaic: str | None = _key(STRING, None, "orthomosaic GeoTIFF of the charts (default: the mapping "
                                                  "stage's mosaic.tif, [mapping] mosaic = true)")
    chart_scale: int = _key(INTEGER, 5000, "scale denominator of the charts (the report: 1:5,000)")
    chart_project: str | None = _key(STRING, None, "project name in the title block (default: [survey] name)")
    chart_declination_deg: float | None = _key(NUMBER, None, "magnetic declination, degrees, east positive "
                                                             "(not computed; default: \"not given\")")
    chart_declination_date: str | None = _key(STRING, None, "date (epoch) of the declination value")
    chart_date: str | None = _key(STRING, None, "date in the title block (default: the day of the run, UTC)")
    chart_dpi: int = _key(INTEGER, 150, "resolution of the PNG charts, dots per inch")
    contour_levels: tuple[float, ...] | None = _key(NUMBERS, None, "fixed contour levels, m (instead of the "
                                                                   "interval's)")
    contour_min_ring_m: float = _key(NUMBER, 0.0, "closed contour rings shorter than this are left out, m")
    contour_edge_peel: int = _key(INTEGER, 3, "rings of triangles at the TIN's boundary left out of the contours "
                                              "(0: none)")
    contour_review: bool = _key(BOOLEAN, False, "contour verification: stretches over sparse ground as the layer "
                                                "review (contours_review.geojson or a layer of contours.gpkg)")
    contour_sparse_edge_m: float | None = _key(NUMBER, None, "a TIN edge longer than this is sparse ground, m "
                                                             "(default: 3 x the median edge)")
    contour_profiles: int = _key(INTEGER, 0, "profile plots across the N longest review stretches "
                                             "(contours_profiles/)")
    contour_polygons: bool = _key(BOOLEAN, False, "filled bands between the levels (contours_bands.geojson or "
                                                  "a layer of contours.gpkg)")
    contour_3d: bool = _key(BOOLEAN, False, "contour lines with the level as z (LineString Z) in the contours file")
    swath: bool = _key(BOOLEAN, False, "swath.tif/.png/.json: swath separation image of the flight lines "
                                       "(point source ids), USGS interswath limits")
    swath_cell_m: float = _key(NUMBER, 1.0, "cell of the swath separation image, m (> 0)")
    swath_quality_level: str = _key(STRING, "QL2", "\"QL0\" .. \"QL3\": the USGS limits the swath image is "
                                                   "checked against")
    calibration_trajectory: str | None = _key(STRING, None, "SBET or CSV trajectory of the flight: calibration.json "
                                                            "(boresight, scan-angle scale, elevation bias)")
    calibration_control: str | None = _key(STRING, None, "control surface (runway) CSV id,E,N,H of the "
                                                         "calibration (gives the elevation bias)")
    delivery: tuple[str, ...] = _key(STRINGS, (), "delivery formats: \"tfw\" (world file beside every GeoTIFF), "
                                                  "\"shp\" (shp/: Shapefile layers), \"dxf\" (contours.dxf, "
                                                  "lidarcat[cad])")
    noise: bool = _key(BOOLEAN, False, "ground: class 7 on isolated points (statistical outlier test)")
    hag: bool = _key(BOOLEAN, False, "ground: extra dimension HeightAboveGround (m) in the classified copies")
    stats: bool = _key(BOOLEAN, False, "stats.tif: min, max, mean, count, stdev of the point heights per cell")
    smrf_adaptive: bool = _key(BOOLEAN, True, "ground (smrf): cell grown to the point spacing, trend continued "
                                               "beyond the edge (false: Pingel's fixed grid, lidar ground "
                                               "--fixed-grid)")
    copc: bool = _key(BOOLEAN, False, "ground: the classified copies as COPC, ground/<tile>.copc.laz (lidar "
                                      "ground --copc)")
    workers: int = _key(INTEGER, 1, "tile runner of ground, the models, stats and the charts: 1 runs them in "
                                    "the run's process, N > 1 on one local Dask cluster of N worker processes "
                                    "(lidarcat[cluster]; --workers of the lidar commands and lidarcat chart); "
                                    "the products are the same")
    scheduler: str | None = _key(STRING, None, "address of a running Dask scheduler, e.g. \"tcp://10.0.0.5:8786\" "
                                               "(every worker must see the survey's paths); wins over workers")

    def to_dict(self) -> dict[str, Any]:
        """The table as the stage's parameters."""
        out = {f.name: getattr(self, f.name) for f in keys_of(type(self))}
        out["delivery"] = list(self.delivery)
        out["contour_levels"] = None if self.contour_levels is None else list(self.contour_levels)
        return out


@dataclass(frozen=True)
class SelfCalSettings:
    """``[self_calibration]``: additional parameters of ``lidarcat adjust`` (:mod:`lidarcat.survey.selfcal`);
    nothing switched on by default."""

    parameters: tuple[str, ...] | None = _key(STRING, None, "interior orientation to estimate per camera: c, x0, "
                                                            "y0, k1, k2, k3, p1, p2 (comma separated) or \"all\"")
    use_priors: bool = _key(BOOLEAN, True, "weight them by the sd_* of camera.toml (no sd: free)")
    frame_offset: tuple[str, str] | None = _key(STRING, None, "SOURCE:REFERENCE: shift the control of "
                                                              "ground-point source SOURCE into REFERENCE's frame")
    similarity: bool = _key(BOOLEAN, False, "7-parameter similarity instead of the 3-D shift")
    control: str | None = _key(STRING, None, "control set(s); \"a+b\" joins two sets of control_sets.csv")
    alpha: float = _key(NUMBER, 0.05, "level of the t-tests and group tests (0 < alpha < 1)")
    gnss_lines: Mapping[str, str] | None = _key(TABLE, None, "GNSS antenna offset per flight line: the sub-table "
                                                             "[self_calibration.gnss_lines] with a line per key, "
                                                             "a = [\"1\", \"2\"] (its photo ids; photos.csv X0, "
                                                             "Y0, Z0 with sd_X0.. become constraints)")
    gnss_drift: bool = _key(BOOLEAN, False, "with gnss_lines: also a drift along each line, m/km")

    @property
    def active(self) -> bool:
        return bool(self.parameters) or self.frame_offset is not None or bool(self.gnss_lines)


#: every table of survey.toml -> its class, in the order of docs/survey-format.md
TABLES: dict[str, type] = {
    "survey": SurveyTable, "files": FilesTable, "adjustment": AdjustmentTable, "lidar": LidarTable,
    "assessment": AssessmentSettings, "heights": HeightsTable, "mapping": MappingSettings,
    "products": ProductsSettings, "self_calibration": SelfCalSettings,
}
#: allowed keys of survey.toml, per table (True = required)
SURVEY_KEYS: dict[str, dict[str, bool]] = {
    table: {f.name: f.metadata["required"] for f in keys_of(cls)} for table, cls in TABLES.items()}
#: tables every survey.toml has
REQUIRED_TABLES = ("survey", "files")


# ---------------------------------------------------------------------- the parsed file
@dataclass(frozen=True, eq=False)
class SurveyConfig:
    """survey.toml parsed and validated: one attribute per table (``Survey.config``).

    Attributes
    ----------
    path : Path
        The survey.toml.
    survey, files, adjustment, lidar, assessment, heights, self_calibration
        The tables (defaults where the file has none).
    mapping, products : MappingSettings, ProductsSettings or None
        None when the file has no such table (the stage is not planned).
    tables : tuple of str
        The tables the file has, in file order.
    """

    path: Path
    survey: SurveyTable
    files: FilesTable
    adjustment: AdjustmentTable
    lidar: LidarTable
    assessment: AssessmentSettings
    heights: HeightsTable
    mapping: MappingSettings | None
    products: ProductsSettings | None
    self_calibration: SelfCalSettings
    tables: tuple[str, ...]
    text: str = field(repr=False, default="")
    data: Mapping[str, Any] = field(repr=False, default_factory=dict)

    def line(self, table: str | None, key: str | None = None) -> int | None:
        """Line of *key* in ``[table]`` (a sub-table ``[table.key]`` too; the table's header line when the
        key is not written; a top-level key when *table* is None)."""
        return _line(self.text, table, key)

    def error(self, table: str | None, key: str | None, message: str) -> SurveyError:
        """A :class:`SurveyError` located at *key* of ``[table]``: ``survey.toml:LINE: field 'key': message``."""
        return _error(self.path, self.text, table, key, message)

    def written(self, table: str) -> dict[str, Any]:
        """The keys of ``[table]`` the file gives, with their values as written (a copy)."""
        return copy.deepcopy(dict(self.data.get(table, {})))


def _line(text: str, table: str | None, key: str | None) -> int | None:
    if table is None:
        return toml_line(text, key) or toml_line(text, None, key)
    line = toml_line(text, table, key)
    if key is not None and (line is None or line == toml_line(text, table)):
        line = toml_line(text, f"{table}.{key}") or line
    return line


def _error(path: Path, text: str, table: str | None, key: str | None, message: str) -> SurveyError:
    fld = key if key is not None else (f"[{table}]" if table else None)
    if fld is not None and len(fld) > 60:  # a key is file content: a short excerpt only
        fld = fld[:60] + "..."
    return SurveyError(f"{location(path, _line(text, table, key), fld)}: {message}")


# ---------------------------------------------------------------------- parsing
class _Reader:
    """The file being parsed: typed values of a table and located errors."""

    def __init__(self, path: Path, data: dict[str, Any], text: str):
        self.path, self.data, self.text = path, data, text

    def err(self, table: str | None, key: str | None, message: str) -> SurveyError:
        return _error(self.path, self.text, table, key, message)

    def value(self, table: str, f: dataclasses.Field) -> Any:
        """The typed value of key *f* in ``[table]``, its default when absent."""
        tab = self.data.get(table, {})
        key, toml = f.name, f.metadata["toml"]
        if key not in tab:
            if f.metadata["required"]:
                raise SurveyError(f"{location(self.path, _line(self.text, table, None), key)}: missing required key "
                                  f"{key!r} in [{table}] (see docs/survey-format.md)")
            return f.default
        v = tab[key]
        if not isinstance(v, toml.kinds) or (isinstance(v, bool) and bool not in toml.kinds):  # true is no int
            raise self.err(table, key, f"in [{table}], expected {toml.expected}, got {excerpt(v)}")
        if isinstance(v, str) and not v.strip() and key != "description":
            raise self.err(table, key, "must not be empty")
        if isinstance(v, float) and not math.isfinite(v):
            raise self.err(table, key, f"must be a finite number, got {excerpt(v)}")
        if toml is NUMBER:
            return float(v)
        return v

    def raw(self, table: str, key: str) -> Any:
        """The value of *key* as written (for messages: ``got 0``, not ``got 0.0``)."""
        return self.data[table][key]

    def table(self, table: str) -> dict[str, Any]:
        cls = TABLES[table]
        return {f.name: self.value(table, f) for f in keys_of(cls)}


def _check_keys(r: _Reader) -> None:
    for table, value in r.data.items():
        if table not in SURVEY_KEYS:
            raise r.err(None, table, f"unknown key/table {excerpt(table)}; allowed tables: "
                        + ", ".join(f"[{k}]" for k in SURVEY_KEYS))
        if not isinstance(value, dict):
            raise r.err(None, table, f"{excerpt(table)} must be a table ([{table}])")
        for key in value:
            if key not in SURVEY_KEYS[table]:
                raise r.err(table, key, f"unknown key {excerpt(key)} in [{table}]; allowed: "
                            + ", ".join(SURVEY_KEYS[table]))
    for table in REQUIRED_TABLES:
        if table not in r.data:
            raise SurveyError(f"{r.path}: missing table [{table}] (see docs/survey-format.md)")


def _one_of(r: _Reader, table: str, key: str, value: str, allowed: tuple[str, ...], quote: bool = True) -> None:
    if value not in allowed:
        raise r.err(table, key, f"{excerpt(value)} is not one of {', '.join(map(repr, allowed) if quote else allowed)}")


def _files(r: _Reader, v: dict[str, Any]) -> FilesTable:
    items = [v["lidar"]] if isinstance(v["lidar"], str) else v["lidar"]
    for item in items:
        if not isinstance(item, str) or not item.strip():
            raise r.err("files", "lidar", f"entries must be non-empty strings, got {excerpt(item)}")
    v["lidar"] = tuple(items)
    return FilesTable(**v)


def _adjustment(r: _Reader, v: dict[str, Any]) -> AdjustmentTable:
    if v["observations"] is not None:
        _one_of(r, "adjustment", "observations", v["observations"], OBSERVATION_KINDS)
    sd = v["image_sd_mm"]
    lo_mm, hi_mm = SD_BOUNDS["mm"]
    if sd is not None and not lo_mm <= sd <= hi_mm:
        raise r.err("adjustment", "image_sd_mm",
                    f"must be positive, got {excerpt(sd)}" if not sd > 0 else
                    f"{excerpt(sd)} mm is outside the sane range {lo_mm:g}..{hi_mm:g} mm")
    for p in v["exclude_points"]:
        if isinstance(p, bool) or not isinstance(p, (str, int)):
            raise r.err("adjustment", "exclude_points", f"point ids must be strings, got {excerpt(p)}")
    v["exclude_points"] = tuple(str(p) for p in v["exclude_points"])
    _one_of(r, "adjustment", "variance_factor", v["variance_factor"], VARIANCE_FACTORS)
    if not 0 < v["chi2_level"] < 1:
        raise r.err("adjustment", "chi2_level", f"must lie between 0 and 1, got {excerpt(r.raw('adjustment', 'chi2_level'))}")
    return AdjustmentTable(**v)


def _assessment(r: _Reader, v: dict[str, Any]) -> AssessmentSettings:
    t = "assessment"
    if not v["scale"] > 0:
        raise r.err(t, "scale", f"must be a positive scale denominator (2000 for 1:2000), got {excerpt(r.raw(t, 'scale'))}")
    if not v["contour_interval_m"] > 0:
        raise r.err(t, "contour_interval_m", f"must be positive (metres), got {excerpt(r.raw(t, 'contour_interval_m'))}")
    if not 0 < v["alpha"] < 1:
        raise r.err(t, "alpha", f"must lie between 0 and 1, got {excerpt(r.raw(t, 'alpha'))}")
    _one_of(r, t, "pec_class", v["pec_class"], PEC_CLASSES, quote=False)
    _one_of(r, t, "plotting_position", v["plotting_position"], PLOTTING_POSITIONS, quote=False)
    return AssessmentSettings(**v)


def _heights(r: _Reader, v: dict[str, Any]) -> HeightsTable:
    if v["sources"] is not None:
        bad = [k for k, s in v["sources"].items() if not isinstance(s, str)]
        if bad:
            raise r.err("heights", "sources", f"source {excerpt(bad[0])}: expected a string (\"ellipsoidal\" or "
                                              f"\"orthometric\"), got {excerpt(v['sources'][bad[0]])}")
        v["sources"] = MappingProxyType(dict(v["sources"]))
    return HeightsTable(**v)


def _mapping(r: _Reader, v: dict[str, Any]) -> MappingSettings:
    t = "mapping"
    if v["surface"] not in ("dsm", "dtm"):
        raise r.err(t, "surface", f"{excerpt(v['surface'])} is not 'dsm' (true orthophotos) or 'dtm'")
    for key in ("gsd_m", "cell_m"):
        if not v[key] > 0:
            raise r.err(t, key, f"must be positive (metres), got {excerpt(r.raw(t, key))}")
    if v["photos"] is not None:
        v["photos"] = tuple(str(p) for p in v["photos"])
    if v["features"] is not None:
        bad = [str(p) for p, f in v["features"].items() if not isinstance(f, str) or not f.strip()]
        if bad:
            raise r.err(t, "features", f"photo {bad[0]}: expected the path of a feature file (.geojson or .csv)")
        v["features"] = MappingProxyType({str(p): f for p, f in v["features"].items()})
    wrong = [str(i) for i in v["interpolators"] if i not in MAPPING_INTERPOLATORS]
    if wrong or not v["interpolators"]:
        raise r.err(t, "interpolators", f"{', '.join(wrong) or 'none given'}: use {', '.join(MAPPING_INTERPOLATORS)}")
    v["interpolators"] = tuple(v["interpolators"])
    if v["method"] not in ("exact", "iterate"):
        raise r.err(t, "method", f"{excerpt(v['method'])} is not 'exact' (first hit) or 'iterate'")
    if v["reference"] is not None and not v["features"]:
        raise r.err(t, "reference", "a reference needs the features to judge ([mapping] features)")
    for key in ("image_sd_px", "surface_sd_m", "feather_m"):
        if not v[key] >= 0:
            raise r.err(t, key, f"must not be negative, got {excerpt(r.raw(t, key))}")
    return MappingSettings(**v)


#: a Dask scheduler address: PROTOCOL://HOST[:PORT] (tcp, tls, ucx, inproc, ...)
_SCHEDULER_ADDRESS = re.compile(r"[a-z][a-z0-9+.-]*://[^\s/]+")


def _products(r: _Reader, v: dict[str, Any]) -> ProductsSettings:
    from ..production.ground import GROUND_METHODS
    from ..production.sheets import SHEET_INDEXES

    t = "products"
    _one_of(r, t, "filter", v["filter"], GROUND_METHODS)
    for key in ("cell_m", "max_edge_m", "contour_interval_m", "spots_m", "hypsometry_cell_m"):
        if not v[key] > 0:
            raise r.err(t, key, f"must be positive (metres), got {excerpt(r.raw(t, key))}")
    if v["master_every"] < 1:
        raise r.err(t, "master_every", f"must be 1 or more, got {excerpt(v['master_every'])}")
    if v["smooth"] < 0:
        raise r.err(t, "smooth", f"must be 0 or more, got {excerpt(v['smooth'])}")
    if v["sheet_size_m"] < 0:
        raise r.err(t, "sheet_size_m", f"must be 0 (no sheets) or positive (metres), got {excerpt(r.raw(t, 'sheet_size_m'))}")
    _one_of(r, t, "sheet_index", v["sheet_index"], SHEET_INDEXES)
    if v["sheet_index"] != "grid" and v["sheet_size_m"] > 0:
        raise r.err(t, "sheet_size_m", f"applies to sheet_index = 'grid' only; the {v['sheet_index']} sheets have "
                                       f"their own size (drop it)")
    if v["vector_format"] not in ("geojson", "gpkg"):
        raise r.err(t, "vector_format", f"{excerpt(v['vector_format'])} is not 'geojson' or 'gpkg'")
    if v["ndsm"] and not (v["dtm"] and v["dsm"]):
        raise r.err(t, "ndsm", "needs dtm = true and dsm = true")
    _charts(r, v)
    if v["contour_levels"] is not None:
        lv = v["contour_levels"]
        if not lv or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                             for x in lv):
            raise r.err(t, "contour_levels", f"expected a list of finite numbers (metres), got {excerpt(lv)}")
        v["contour_levels"] = tuple(float(x) for x in lv)
    if not v["contour_min_ring_m"] >= 0:
        raise r.err(t, "contour_min_ring_m", f"must not be negative, got {excerpt(r.raw(t, 'contour_min_ring_m'))}")
    if v["contour_edge_peel"] < 0:
        raise r.err(t, "contour_edge_peel", f"must be 0 or more, got {excerpt(v['contour_edge_peel'])}")
    _checks(r, v)
    if v["workers"] < 1:
        raise r.err(t, "workers", f"must be 1 (in the run's process) or more (Dask worker processes), got "
                                  f"{excerpt(v['workers'])}")
    if v["scheduler"] is not None and not _SCHEDULER_ADDRESS.fullmatch(v["scheduler"]):
        raise r.err(t, "scheduler", f"expected the address of a Dask scheduler such as 'tcp://10.0.0.5:8786', "
                                    f"got {excerpt(v['scheduler'])}")
    wrong = [str(x) for x in v["delivery"] if x not in ("tfw", "shp", "dxf")]
    if wrong:
        raise r.err(t, "delivery", f"{', '.join(map(excerpt, wrong))}: use tfw, shp, dxf")
    v["delivery"] = tuple(dict.fromkeys(v["delivery"]))
    return ProductsSettings(**v)


def _checks(r: _Reader, v: dict[str, Any]) -> None:
    """The contour-verification, swath and calibration keys of ``[products]``."""
    t = "products"
    if v["contour_sparse_edge_m"] is not None and not v["contour_sparse_edge_m"] > 0:
        raise r.err(t, "contour_sparse_edge_m", f"must be positive (metres), got "
                                                f"{excerpt(r.raw(t, 'contour_sparse_edge_m'))}")
    if v["contour_profiles"] < 0:
        raise r.err(t, "contour_profiles", f"must be 0 or more, got {excerpt(v['contour_profiles'])}")
    for k in ("contour_review", "contour_polygons", "contour_3d"):
        if v[k] and not v["contours"]:
            raise r.err(t, k, "needs contours = true")
    if v["contour_profiles"] and not v["contour_review"]:
        raise r.err(t, "contour_profiles", "needs contour_review = true (profiles are drawn across its stretches)")
    if not v["swath_cell_m"] > 0:
        raise r.err(t, "swath_cell_m", f"must be positive (metres), got {excerpt(r.raw(t, 'swath_cell_m'))}")
    _one_of(r, t, "swath_quality_level", v["swath_quality_level"], ("QL0", "QL1", "QL2", "QL3"))
    if v["calibration_control"] is not None and v["calibration_trajectory"] is None:
        raise r.err(t, "calibration_control", "needs calibration_trajectory (the SBET or CSV trajectory)")


def _charts(r: _Reader, v: dict[str, Any]) -> None:
    """The chart keys of ``[products]``: a chart is the mosaic with the contours, cut along a sheet index."""
    t = "products"
    if v["chart_scale"] < 1:
        raise r.err(t, "chart_scale", f"must be a positive scale denominator, got {excerpt(v['chart_scale'])}")
    if not 10 <= v["chart_dpi"] <= 1200:
        raise r.err(t, "chart_dpi", f"must be 10 to 1200 dots per inch, got {excerpt(v['chart_dpi'])}")
    dec = v["chart_declination_deg"]
    if dec is not None and not -180 <= dec <= 180:
        raise r.err(t, "chart_declination_deg",
                    f"must be -180 to 180 degrees, got {excerpt(r.raw(t, 'chart_declination_deg'))}")
    if v["charts"]:
        if not v["contours"]:
            raise r.err(t, "charts", "an orthophoto chart shows the contours: needs contours = true")
        if v["sheet_index"] == "grid" and not v["sheet_size_m"] > 0:
            raise r.err(t, "charts", "one chart per sheet: give the sheet index (sheet_size_m > 0, or "
                                     "sheet_index = 'brazil-5000')")


def split_frame_offset(text: str) -> tuple[str, str]:
    """``"lidar:gps"`` -> ``("lidar", "gps")`` (ValueError unless SOURCE:REFERENCE)."""
    parts = [s.strip() for s in str(text).split(":")]
    if len(parts) != 2 or not all(parts):
        raise ValueError(f"frame offset {excerpt(text)} must be SOURCE:REFERENCE, e.g. lidar:gps")
    return parts[0], parts[1]


def _self_calibration(r: _Reader, v: dict[str, Any]) -> SelfCalSettings:
    from ..bundle.additional import parse_parameters

    t = "self_calibration"
    for key, parse in (("parameters", parse_parameters), ("frame_offset", split_frame_offset)):
        try:
            v[key] = parse(v[key]) if v[key] is not None else None
        except ValueError as ex:
            raise r.err(t, key, str(ex)) from ex
    if not 0 < v["alpha"] < 1:
        raise r.err(t, "alpha", f"must lie between 0 and 1, got {excerpt(r.raw(t, 'alpha'))}")
    if v["gnss_lines"] is not None:
        lines: dict[str, str] = {}
        for label, photos in v["gnss_lines"].items():
            if not isinstance(photos, list) or not all(isinstance(p, str) for p in photos):
                raise r.err(t, "gnss_lines", f"line {excerpt(label)} must be a list of photo ids (strings), got {excerpt(photos)}")
            for ph in photos:
                if ph in lines:
                    raise r.err(t, "gnss_lines", f"photo {excerpt(ph)} is in lines {excerpt(lines[ph])} and {excerpt(label)}; a photo "
                                                 "belongs to one line")
                lines[ph] = str(label)
        v["gnss_lines"] = MappingProxyType(lines)
    return SelfCalSettings(**v)


_BUILD: dict[str, Callable[[_Reader, dict[str, Any]], Any]] = {
    "survey": lambda r, v: SurveyTable(**v), "files": _files, "adjustment": _adjustment,
    "lidar": lambda r, v: LidarTable(**v), "assessment": _assessment, "heights": _heights,
    "mapping": _mapping, "products": _products, "self_calibration": _self_calibration,
}


def parse_survey_toml(path: str | Path) -> SurveyConfig:
    """Read survey.toml once and check every table and key against the schema.

    Parameters
    ----------
    path : str or Path
        The survey.toml.

    Raises
    ------
    SurveyError
        Invalid TOML, an unknown table or key, a missing required table or key, a value of the wrong
        type, empty, not finite or out of range: ``survey.toml:LINE: field 'key': ...``.
    """
    path = Path(path)
    data, text = read_toml(path)
    r = _Reader(path, data, text)
    _check_keys(r)
    tables = {name: (_BUILD[name](r, r.table(name)) if name in data or name not in ("mapping", "products")
                     else None) for name in TABLES}
    return SurveyConfig(path, **tables, tables=tuple(data), text=text, data=data)


def check_photo_ids(config: SurveyConfig, photo_ids: set[str] | tuple[str, ...]) -> None:
    """The photo ids that ``[mapping] photos / features`` and ``[self_calibration] gnss_lines`` name must be
    photos of the survey (SurveyError located at the key)."""
    m = config.mapping
    if m is not None:
        for key, ids in (("photos", m.photos), ("features", m.features)):
            unknown = [p for p in (ids or ()) if p not in photo_ids]
            if unknown:
                raise config.error("mapping", key, f"photo(s) {', '.join(unknown)} are not in the survey")
    lines = config.self_calibration.gnss_lines or {}
    for ph, label in lines.items():
        if ph not in photo_ids:
            raise config.error("self_calibration", "gnss_lines", f"line {excerpt(label)}: photo {excerpt(ph)} is not in photos.csv")


# ---------------------------------------------------------------------- docs/survey-format.md
def _default_text(f: dataclasses.Field) -> str:
    d = f.default
    if f.metadata["required"]:
        return "required"
    if d is None or d == () or (isinstance(d, Mapping) and not d):
        return "-"
    if isinstance(d, bool):
        return f"`{str(d).lower()}`"
    if isinstance(d, str):
        return f'`"{d}"`'
    if isinstance(d, tuple):
        return "`[" + ", ".join(f'"{x}"' for x in d) + "]`"
    return f"`{d:g}`" if isinstance(d, float) else f"`{d}`"


def render_reference() -> str:
    """The survey.toml reference of docs/survey-format.md: one Markdown table per survey.toml table."""
    out = []
    for table, cls in TABLES.items():
        doc = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())
        doc = re.sub(r"^(The )?``\[\w+\]``( table of survey.toml)?( \(required\))?:\s*", "", doc)
        doc = re.sub(r"(:\w+:)?``?([^`]+)``?", r"`\2`", doc)      # reST literals and roles -> Markdown
        req = "required table" if table in REQUIRED_TABLES else "optional table"
        out += [f"### [{table}]", "", f"{req}: {doc}", "", "| key | type | default | meaning |", "|---|---|---|---|"]
        for f in keys_of(cls):
            out.append(f"| `{f.name}` | {f.metadata['toml'].name} | {_default_text(f)} | "
                       f"{f.metadata['doc'].replace('|', '/')} |")
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":  # pragma: no cover
    print(render_reference())
