"""The adjustment's CSV tables name the CRS and height system of their coordinates (issue 25)."""
import json

from lidarcat.survey.adjustment import adjust_survey
from lidarcat.survey.folder import Survey


def test_every_adjustment_table_names_its_crs(tmp_path):
    adjust_survey(Survey.load(), outdir=tmp_path, snooping="off", precision="none")
    for name in ("eop.csv", "points.csv", "residuals.csv"):
        prov = json.loads((tmp_path / f"{name}.json").read_text())["provenance"]
        assert (prov["crs"], prov["height_system"]) == ("EPSG:29192", "orthometric"), name
        # the CSV itself stays plain: the header on the first line
        assert (tmp_path / name).read_text().splitlines()[0].split(",")[0] in ("photo", "point", "kind")
