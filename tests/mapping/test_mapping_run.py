"""``lidarcat run`` on a synthetic survey whose survey.toml asks for monorestituted features and a reference:
the per-interpolator accuracy tables (Cavassim Tables 07-09) reach summary.json and the report."""

from __future__ import annotations

import json

import pytest

from lidarcat._util import read_csv_table
from lidarcat.synthetic.survey import write_synthetic_survey
from lidarcat.pipeline.plan import run_pipeline


def test_run_reports_the_accuracy_tables_of_each_interpolator(tmp_path):
    root = tmp_path / "d"
    write_synthetic_survey(root, n_photos=2, lidar_density_m2=0.5)
    # the features: the measured image points of photo 1 (tie and GPS points, roof vertices), one point each;
    # the reference: their true coordinates
    pts = read_csv_table(root / "truth" / "points.csv", allow_extra=True)
    kind = dict(zip(pts.column("point"), pts.column("kind")))
    obs = read_csv_table(root / "image_points.csv", allow_extra=True)
    photo = obs.column("photo")[0]
    rows = [(p, c, r) for ph, p, c, r in zip(obs.column("photo"), obs.column("point"), obs.column("col_px"),
                                            obs.column("row_px")) if ph == photo]
    (root / "features.csv").write_text("feature,class,col_px,row_px\n"
                                       + "".join(f"{p},{kind[p]},{c},{r}\n" for p, c, r in rows))
    (root / "reference.csv").write_text("feature,vertex,E,N\n" + "".join(
        f"{p},0,{e},{n}\n" for p, e, n in zip(pts.column("point"), pts.column("E"), pts.column("N"))))
    with open(root / "survey.toml", "a", encoding="utf-8") as f:
        f.write(f'\n[mapping]\nfeatures = {{ "{photo}" = "features.csv" }}\nreference = "reference.csv"\n')
    res = run_pipeline(root, tmp_path / "out")
    stage = next(s for s in res.summary["stages"] if s["name"] == "mapping")
    assert stage["status"] == "ran", stage
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    mp = summary["mapping"]
    classes = sorted({kind[p] for p, _, _ in rows})
    assert sorted(mp["table_09"]) == ["nearest", "tin"] and all(sorted(t) == classes for t in mp["table_09"].values())
    for interp, acc in mp["accuracy"].items():
        assert acc["n_assessed"] == acc["n_vertices"] == len(rows)
        assert sum(c["n"] for c in acc["classes"].values()) == len(rows)
        # true coordinates against an adjusted block: every class within class A of 1:2000 (PEC 1 m)
        assert all(c["pec_class"] == "A" and c["r90_m"] < 1.0 for c in acc["classes"].values()), interp
    md = (tmp_path / "out" / "report" / "index.md").read_text()
    html = (tmp_path / "out" / "report" / "index.html").read_text()
    for interp in ("nearest", "tin"):
        assert f"### Interpolator {interp}" in md and f"Interpolator {interp}" in html
        order = list(res.summary["mapping"]["table_09"]["nearest"])   # columns: classes as they first appear
        assert f"| {interp} | " + " | ".join(f"{mp['table_09'][interp][c]:.2f}" for c in order) + " |" in md
    assert "Radius holding 90 % of the points, m (Cavassim Table 09)" in html
    table = read_csv_table(tmp_path / "out" / "mapping" / "accuracy.csv", allow_extra=True)
    assert table.header[:3] == ("interpolator", "class", "n") and len(table.rows) == 2 * len(classes)
    assert (tmp_path / "out" / "mapping" / f"monoplot_{photo}_tin.geojson").is_file()


@pytest.mark.parametrize("toml, message", [
    ('reference = "r.csv"', "field 'reference': a reference needs the features to judge ([mapping] features)"),
    ('features = { "1" = "" }', "field 'features': photo 1: expected the path of a feature file (.geojson or .csv)"),
    ("gsd_m = nan", "field 'gsd_m': must be a finite number, got nan"),
    ("feather_m = inf", "field 'feather_m': must be a finite number, got inf"),
    ("gsd_m = 0", "field 'gsd_m': must be positive (metres), got 0"),
    ("image_sd_px = -0.5", "field 'image_sd_px': must not be negative, got -0.5"),
])
def test_mapping_table_errors_are_located(tmp_path, toml, message):
    from lidarcat.errors import SurveyError
    from lidarcat.stages import mapping
    from lidarcat.survey.folder import Survey

    root = tmp_path / "d"
    write_synthetic_survey(root, n_photos=2, lidar_density_m2=0.2)
    with open(root / "survey.toml", "a", encoding="utf-8") as f:
        f.write(f"\n[mapping]\n{toml}\n")
    with pytest.raises(SurveyError) as ei:
        mapping.settings(Survey.load(root))
    assert str(ei.value).startswith(f"{root / 'survey.toml'}:") and str(ei.value).endswith(message)


def test_mapping_keys_of_the_survey_file_are_the_stages_keys():
    """survey.toml's key check (survey.SURVEY_KEYS) and the stage's defaults list the same [mapping] keys:
    a key added to one only would be refused as unknown, or accepted and never read."""
    from lidarcat.stages.mapping import MAPPING_KEYS
    from lidarcat.survey.folder import SURVEY_KEYS

    assert sorted(SURVEY_KEYS["mapping"]) == sorted(MAPPING_KEYS)
    assert not any(SURVEY_KEYS["mapping"].values())          # every key optional


@pytest.mark.parametrize("orthophotos", [False, True])
def test_mapping_stage_inputs_hold_the_photos_only_when_it_makes_orthophotos(tmp_path, orthophotos):
    from lidarcat.pipeline.plan import plan_pipeline
    from lidarcat.survey.folder import Survey

    root = tmp_path / "d"
    write_synthetic_survey(root, n_photos=2, lidar_density_m2=0.2)
    (root / "images").mkdir()
    (root / "images" / "1.png").write_bytes(b"")
    (root / "f.csv").write_text("feature,col_px,row_px\np,600,400\n")
    with open(root / "survey.toml", "a", encoding="utf-8") as f:
        f.write(f'\n[mapping]\northophotos = {str(orthophotos).lower()}\nfeatures = {{ "1" = "f.csv" }}\n')
    stage = next(st for st in plan_pipeline(Survey.load(root)) if st.name == "mapping")
    inputs = stage.inputs(None)
    assert (root / "images" / "1.png" in inputs) == orthophotos
    assert root / "f.csv" in inputs
