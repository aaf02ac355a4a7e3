"""MeasureParams validates every field: one line naming the field, its allowed range and the value given.

A bad value did not fail before, it changed what is measured without a word: a negative ``weak_edge_w``
dropped every weak edge, ``local_search_px=0`` divided by zero, ``dark >= saturation`` refused every
photo as too dark or saturated.  The CLI builds MeasureParams from click-checked options only (the
survey.toml has no measurement table and refuses unknown tables), so a bad option is a located error there.
"""

from __future__ import annotations

import dataclasses
import math

import pytest
from click.testing import CliRunner

from lidarcat.photocontrol import MeasureParams

#: field -> (a bad value, the exact message)
BAD = {
    "search_sigma": (0.0, "search_sigma must be a finite number > 0, got 0.0"),
    "max_search_px": (0, "max_search_px must be an integer >= 1, got 0"),
    "local_search_px": (2.5, "local_search_px must be an integer >= 1, got 2.5"),
    "band_px": (-1.0, "band_px must be a finite number > 0, got -1.0"),
    "wide_band_px": (1.0, "wide_band_px must be a finite number >= band_px (1.5), got 1.0"),
    "min_points": (2, "min_points must be an integer >= 3 (a line with one redundancy), got 2"),
    "min_contrast": (-0.5, "min_contrast must be a finite number >= 0, got -0.5"),
    "min_ratio": (math.nan, "min_ratio must be a finite number >= 0, got nan"),
    "max_scatter_px": (0.0, "max_scatter_px must be a finite number > 0, got 0.0"),
    "smooth_px": (-1.5, "smooth_px must be a finite number >= 0, got -1.5"),
    "min_sd_px": (0.0, "min_sd_px must be a finite number > 0, got 0.0"),
    "two_line_ratio": (-3.5, "two_line_ratio must be a finite number >= 0, got -3.5"),
    "line_sd_px": (math.inf, "line_sd_px must be a finite number >= 0, got inf"),
    "direction_sd_deg": (90.0, "direction_sd_deg must be an angle in [0, 90) deg, got 90.0"),
    "vertex_sd_px": (-0.1, "vertex_sd_px must be a finite number >= 0, got -0.1"),
    "vertex_texture_px": ("1", "vertex_texture_px must be a finite number >= 0, got '1'"),
    "line_direction_sd_deg": (-0.5, "line_direction_sd_deg must be an angle in [0, 90) deg, got -0.5"),
    "border": ("clip", "border must be 'edges' or 'fit', got 'clip'"),
    "along_min_angle_deg": (0.0, "along_min_angle_deg must be an angle in (0, 90) deg, got 0.0"),
    "along_max_sd_px": (-5.0, "along_max_sd_px must be a finite number >= 0, got -5.0"),
    "weak_edge_w": (-1.96, "weak_edge_w must be a number > 0 (inf: never dropped), got -1.96"),
    "min_angle_deg": (90.0, "min_angle_deg must be an angle in (0, 90) deg, got 90.0"),
    "max_edge_px": (0.0, "max_edge_px must be a finite number > 0, got 0.0"),
    "template_m": (-8.0, "template_m must be a finite number > 0, got -8.0"),
    "coarse": ("sift", "coarse must be 'lines' or 'likelihood', got 'sift'"),
    "refine_px": (-4.0, "refine_px must be a finite number >= 0, got -4.0"),
    "dark": (-1.0, "dark must be a finite number >= 0, got -1.0"),
    "saturation": (12.0, "saturation must be a finite number > dark (12), got 12.0"),
}


def test_every_field_has_a_rule_here():
    """A new field gets its rule and its case in BAD (the list is the fields, in order)."""
    assert list(BAD) == [f.name for f in dataclasses.fields(MeasureParams)]


@pytest.mark.parametrize("name", list(BAD))
def test_a_bad_value_is_one_line_naming_field_range_and_value(name):
    value, message = BAD[name]
    with pytest.raises(ValueError) as err:
        MeasureParams(**{name: value})
    assert str(err.value) == message


@pytest.mark.parametrize("kw", [dict(max_search_px=True), dict(min_points=8.0), dict(weak_edge_w=math.nan),
                                dict(search_sigma=math.inf)])
def test_bools_floats_for_counts_nan_and_inf_are_refused(kw):
    with pytest.raises(ValueError, match=f"^{next(iter(kw))} must be "):
        MeasureParams(**kw)


def test_dark_above_the_default_saturation_names_the_pair():
    with pytest.raises(ValueError) as err:
        MeasureParams(dark=300.0)
    assert str(err.value) == "saturation must be a finite number > dark (300), got 250.0"


def test_the_documented_switches_and_limits_are_accepted():
    """The values the docs give a meaning: 0 switches off, inf never drops, the ends of the ranges."""
    MeasureParams()
    MeasureParams(border="fit", coarse="lines", weak_edge_w=math.inf, along_max_sd_px=0.0, refine_px=0.0,
                  direction_sd_deg=0.0, line_direction_sd_deg=0.0, smooth_px=0.0, line_sd_px=0.0, vertex_sd_px=0.0,
                  vertex_texture_px=0.0, two_line_ratio=0.0, min_ratio=0.0, min_contrast=0.0, dark=0.0,
                  wide_band_px=1.5, min_points=3, max_search_px=1, local_search_px=1)
    p = MeasureParams()
    assert dataclasses.replace(p, band_px=p.wide_band_px).band_px == 3.5     # the first pass's copy
    with pytest.raises(ValueError, match=r"^wide_band_px must be a finite number >= band_px \(4\), got 3.5$"):
        dataclasses.replace(p, band_px=4.0)


@pytest.mark.parametrize("args, message", [
    (["--search-sigma", "-1"], "Error: Invalid value for '--search-sigma': -1.0 is not in the range x>0."),
    (["--search-sigma", "nan"], "Error: Invalid value for '--search-sigma': nan is not a finite number."),
    (["--border", "clip"], "Error: Invalid value for '--border': 'clip' is not one of 'edges', 'fit'."),
])
def test_the_cli_refuses_a_bad_measure_option_naming_it(tmp_path, args, message):
    """The CLI's MeasureParams comes from --search-sigma and --border: click names the option, exit 2,
    before anything is read or written."""
    from lidarcat.cli.main import cli

    res = CliRunner().invoke(cli, ["measure-control", str(tmp_path), *args])
    assert res.exit_code == 2, res.output
    assert res.stderr.splitlines()[-1] == message
    assert "Traceback" not in res.output
    assert list(tmp_path.iterdir()) == []


def test_the_survey_toml_has_no_measurement_table(tmp_path):
    """survey.toml cannot carry MeasureParams: an unknown table is a located error naming the file."""
    from lidarcat.errors import LidarcatError
    from lidarcat.survey.schema import parse_survey_toml

    f = tmp_path / "survey.toml"
    f.write_text('[survey]\nname = "x"\n[measure_control]\nweak_edge_w = -1\n', encoding="utf-8")
    with pytest.raises(LidarcatError, match=r"survey\.toml:3: .*measure_control.*allowed tables"):
        parse_survey_toml(f)
