"""The survey.toml schema (lidarcat.survey.schema): every key typed and checked at Survey.load, the file
read once per run, the reference of docs/survey-format.md generated from the schema."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from conftest import ROOT, THESIS_SURVEY

from lidarcat.errors import SurveyError
from lidarcat.survey import Survey, thesis_survey_path
from lidarcat.survey.schema import (
    BOOLEAN,
    MAPPING_INTERPOLATORS,
    SURVEY_KEYS,
    TABLES,
    keys_of,
    parse_survey_toml,
    render_reference,
)

SURVEY_FORMAT = ROOT / "docs" / "survey-format.md"
BEGIN = "<!-- survey.toml reference: generated from lidarcat/survey/schema.py -->"
END = "<!-- end of the generated reference -->"

#: every (table, key) of the schema: a key added to a table class is tested without editing this file
EVERY_KEY = [(table, f) for table, cls in TABLES.items() for f in keys_of(cls)]


def _copy(tmp_path: Path) -> Path:
    dest = tmp_path / "s"
    shutil.copytree(THESIS_SURVEY, dest, ignore=shutil.ignore_patterns("out", "published"))
    return dest


def _with_line(text: str, table: str, line: str) -> str:
    """*text* with *line* (``key = value``) in ``[table]``: replacing the key's line, else after the
    table's header, else in a new table at the end."""
    key = line.split("=")[0].strip()
    lines = text.splitlines()
    header = next((i for i, s in enumerate(lines) if s.strip() == f"[{table}]"), None)
    if header is None:
        return text + f"\n[{table}]\n{line}\n"
    end = next((i for i in range(header + 1, len(lines)) if lines[i].lstrip().startswith("[")), len(lines))
    at = next((i for i in range(header + 1, end) if lines[i].split("=")[0].strip() == key), None)
    if at is None:
        lines.insert(header + 1, line)
    else:
        lines[at] = line
    return "\n".join(lines) + "\n"


def _line_of(text: str, needle: str) -> int:
    return next(i for i, s in enumerate(text.splitlines(), 1) if s == needle)


@pytest.mark.parametrize("table, key", EVERY_KEY, ids=[f"{t}.{f.name}" for t, f in EVERY_KEY])
def test_every_key_refuses_a_wrong_type_at_its_line(tmp_path, table, key):
    toml = key.metadata["toml"]
    wrong = '"yes"' if bool in toml.kinds else "true"     # a string for a boolean, a boolean for the rest
    assert (toml is BOOLEAN) == (bool in toml.kinds)
    folder = _copy(tmp_path)
    text = _with_line((folder / "survey.toml").read_text(encoding="utf-8"), table, f"{key.name} = {wrong}")
    (folder / "survey.toml").write_text(text, encoding="utf-8")
    with pytest.raises(SurveyError) as ei:
        Survey.load(folder)
    line = _line_of(text, f"{key.name} = {wrong}")
    got = "'yes'" if bool in toml.kinds else "True"
    assert str(ei.value) == (f"{folder / 'survey.toml'}:{line}: field '{key.name}': in [{table}], expected "
                             f"{toml.expected}, got {got}")


@pytest.mark.parametrize("table", list(TABLES))
def test_an_unknown_key_is_refused_at_its_line(tmp_path, table):
    folder = _copy(tmp_path)
    text = _with_line((folder / "survey.toml").read_text(encoding="utf-8"), table, "bogus_key = 1")
    (folder / "survey.toml").write_text(text, encoding="utf-8")
    with pytest.raises(SurveyError) as ei:
        Survey.load(folder)
    assert str(ei.value) == (f"{folder / 'survey.toml'}:{_line_of(text, 'bogus_key = 1')}: field 'bogus_key': "
                             f"unknown key 'bogus_key' in [{table}]; allowed: {', '.join(SURVEY_KEYS[table])}")


def test_an_unknown_table_and_a_sub_table_key_are_located(tmp_path):
    folder = _copy(tmp_path)
    base = (folder / "survey.toml").read_text(encoding="utf-8")
    (folder / "survey.toml").write_text(base + "\n[mappings]\ngsd_m = 0.2\n", encoding="utf-8")
    with pytest.raises(SurveyError, match=rf"survey.toml:{len(base.splitlines()) + 2}: field 'mappings': "
                                          r"unknown key/table 'mappings'; allowed tables: \[survey\], \[files\]"):
        Survey.load(folder)
    # [self_calibration.gnss_lines] is the key gnss_lines: an error in it names the sub-table's header
    text = base + '\n[self_calibration.gnss_lines]\na = ["1", "2"]\nb = ["2", "9"]\n'
    (folder / "survey.toml").write_text(text, encoding="utf-8")
    with pytest.raises(SurveyError) as ei:
        Survey.load(folder)
    assert str(ei.value) == (f"{folder / 'survey.toml'}:{_line_of(text, '[self_calibration.gnss_lines]')}: "
                             "field 'gnss_lines': photo '2' is in lines 'a' and 'b'; a photo belongs to one line")


def test_a_bad_value_fails_at_load_not_at_run(tmp_path):
    """[mapping] gsd_m = "abc" was accepted by Survey.load and refused by `lidarcat run` only."""
    folder = _copy(tmp_path)
    text = (folder / "survey.toml").read_text(encoding="utf-8") + '\n[mapping]\ngsd_m = "abc"\n'
    (folder / "survey.toml").write_text(text, encoding="utf-8")
    with pytest.raises(SurveyError) as ei:
        Survey.load(folder)
    line = _line_of(text, 'gsd_m = "abc"')
    assert str(ei.value) == (f"{folder / 'survey.toml'}:{line}: field 'gsd_m': in [mapping], expected int/float, "
                             "got 'abc'")
    (folder / "survey.toml").write_text(text.replace('"abc"', "2"), encoding="utf-8")
    s = Survey.load(folder)
    assert s.config.mapping.gsd_m == 2.0 and isinstance(s.config.mapping.gsd_m, float)
    assert s.config.mapping.interpolators == ("nearest", "tin") and s.config.products is None


def test_the_thesis_survey_loads_with_its_tables():
    s = Survey.load()
    cfg = s.config
    assert cfg.path == s.toml_path and cfg.tables == ("survey", "files", "adjustment", "assessment")
    assert cfg.survey.name == s.name == "thesis-fierro-2007" and cfg.survey.default_control == "gps"
    assert cfg.files.camera == "camera.toml" and cfg.files.lidar == ()
    assert cfg.adjustment.exclude_points == ("417",) and cfg.adjustment.image_sd_mm == 0.006
    assert cfg.assessment is s.assessment and s.assessment.plotting_position == "hazen"
    assert cfg.mapping is None and cfg.products is None and not cfg.self_calibration.active
    assert cfg.heights.sources is None and cfg.lidar.crs is None


def test_the_synthetic_demo_survey_loads(tmp_path):
    from lidarcat.synthetic.survey import write_synthetic_survey

    write_synthetic_survey(tmp_path / "d", n_photos=2)
    s = Survey.load(tmp_path / "d")
    assert s.config.survey.name == s.name and s.settings.observations == "pixel"
    assert s.config.tables[:2] == ("survey", "files")


def test_survey_toml_is_read_once_per_run(tmp_path, monkeypatch):
    """`lidarcat run` on the thesis block: Survey.load reads survey.toml; no stage reads it again."""
    from lidarcat._util import tables
    from lidarcat.pipeline.plan import run_pipeline

    reads: list[str] = []
    real_read_text, real_path_read_text = tables.read_text, Path.read_text

    def read_text(path, *a, **k):
        if Path(path).name == "survey.toml":
            reads.append(str(path))
        return real_read_text(path, *a, **k)

    def path_read_text(self, *a, **k):
        if self.name == "survey.toml":
            reads.append(str(self))
        return real_path_read_text(self, *a, **k)

    monkeypatch.setattr(tables, "read_text", read_text)
    monkeypatch.setattr(Path, "read_text", path_read_text)
    result = run_pipeline(None, tmp_path / "out")
    assert result.ok
    assert reads == [str(thesis_survey_path() / "survey.toml")]


def test_mapping_interpolators_are_the_stages():
    from lidarcat.stages.mapping import INTERPOLATORS

    assert tuple(INTERPOLATORS) == MAPPING_INTERPOLATORS


def test_parse_is_the_loaders_parse(tmp_path):
    cfg = parse_survey_toml(THESIS_SURVEY / "survey.toml")
    assert cfg.written("adjustment") == {"observations": "corrected", "image_sd_mm": 0.006,
                                         "exclude_points": ["417"], "variance_factor": "a_priori",
                                         "chi2_level": 0.05}
    assert cfg.written("mapping") == {}


def test_survey_format_reference_is_generated_from_the_schema():
    text = SURVEY_FORMAT.read_text(encoding="utf-8")
    assert BEGIN in text and END in text, "docs/survey-format.md lacks the generated reference markers"
    body = text.split(BEGIN, 1)[1].split(END, 1)[0]
    assert body.strip() == render_reference().strip(), (
        "docs/survey-format.md's survey.toml reference is stale; regenerate it with "
        "`python -m lidarcat.survey.schema` and paste it between the markers")
    for table, cls in TABLES.items():
        assert f"### [{table}]" in body
        for f in keys_of(cls):
            assert re.search(rf"^\| `{f.name}` \| {re.escape(f.metadata['toml'].name)} \|", body.split(
                f"### [{table}]")[1], re.MULTILINE), f"{table}.{f.name} undocumented"
