"""Hypothesis: a number of any data line of any format replaced by garbage gives a FormatError
located at that file, that line and a named field -- and no output folder appears."""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lidarcat.errors import FormatError
from lidarcat.interop.block import Block, block_from_survey, write_survey
from lidarcat.interop.colmap import read_colmap, write_colmap
from lidarcat.interop.gnss import read_gnss, read_kapture_gnss
from lidarcat.interop.metashape import read_metashape
from lidarcat.interop.odm import read_gcp_list, read_geo_txt
from lidarcat.interop.opensfm import read_opensfm, write_opensfm
from lidarcat.interop.opk import read_borea, read_opk

D = Path(__file__).parents[1] / "data" / "interop"
ADJ = Path(__file__).parents[1] / "data" / "report"
GARBAGE = st.sampled_from(["x", "1.2.3", "nan", "inf", "-inf", "1e999", "--", "0x1g", "é", "1,5e"])


def _colmap(d: Path) -> Path:
    write_colmap(block_from_survey(None, ADJ), d / "m")
    return d / "m"


def _opensfm(d: Path) -> Path:
    write_opensfm(block_from_survey(None, ADJ), d / "o")
    return d / "o"


def _gnss(d: Path) -> Path:
    p = d / "gnss.csv"
    p.write_text("photo,E,N,h,roll,pitch,yaw,sd_E\n1,677100,7183500,2100,1,2,90,0.1\n2,677500,7183500,2101,0,0,91,0.1\n")
    return p


def _geo(d: Path) -> Path:
    p = d / "geo.txt"
    p.write_text("EPSG:29192\n1 677100 7183500 2100 90 1 2 0.5 1\n2 677500 7183500 2101 91 0 1 0.5 1\n")
    return p


# name -> (prepare(tmpdir) -> folder or file, file to corrupt (relative), separator, {line: numeric fields}, read)
CASES = {
    "colmap-cameras": (_colmap, "cameras.txt", " ", {5: range(4, 7)}, lambda p: read_colmap(p, pixel_size_mm=0.0079)),
    "colmap-images": (_colmap, "images.txt", " ", {6: range(1, 8), 8: range(1, 8)}, lambda p: read_colmap(p)),
    "colmap-points": (_colmap, "points3D.txt", " ", {4: range(1, 4), 9: range(1, 4)}, lambda p: read_colmap(p)),
    "opensfm-tracks": (_opensfm, "tracks.csv", "\t", {2: (3, 4), 40: (3, 4)},
                       lambda p: read_opensfm(p / "reconstruction.json")),
    "opk": (lambda d: shutil.copytree(D / "opk", d / "opk"), "borea_23FD1305_alt_test.OPK", None,
            {k: range(1, 7) for k in range(2, 9)}, lambda p: read_opk(p / "borea_23FD1305_alt_test.OPK")),
    "borea-mes": (lambda d: shutil.copytree(D / "opk", d / "opk"), "borea_liaisons_test.mes", None,
                  {k: (2, 3) for k in range(2, 18)},
                  lambda p: read_borea(p / "borea_23FD1305_alt_test.OPK", [p / "borea_Camera1.txt"],
                                       measurements=[p / "borea_liaisons_test.mes"])),
    "borea-app": (lambda d: shutil.copytree(D / "opk", d / "opk"), "borea_GCP_test.app", None,
                  {1: (2, 3, 4), 3: (2, 3, 4)},
                  lambda p: read_borea(p / "borea_23FD1305_alt_test.OPK", [p / "borea_Camera1.txt"],
                                       points=p / "borea_GCP_test.app")),
    "odm-gcp": (lambda d: shutil.copytree(D / "odm", d / "odm"), "bellus_gcp_list.txt", None,
                {k: range(0, 5) for k in range(2, 6)}, lambda p: read_gcp_list(p / "bellus_gcp_list.txt")),
    "odm-geo": (_geo, "", None, {2: range(1, 9), 3: range(1, 9)}, lambda p: read_geo_txt(p)),
    "gnss": (_gnss, "", ",", {2: range(1, 8), 3: range(1, 8)}, lambda p: read_gnss(p, file_crs="EPSG:29192")),
    "kapture-gnss": (lambda d: shutil.copy(D / "colmap" / "kapture_maupertuis" / "kapture_records_gnss.txt", d / "g.txt"),
                     "", ",", {3: (2, 3, 4, 6), 6: (2, 3, 4, 6)}, lambda p: read_kapture_gnss(p, crs="EPSG:32631")),
}


def _corrupt(path: Path, sep: str | None, line: int, field: int, token: str) -> None:
    lines = path.read_text().splitlines()
    cells = re.split(r"\s+", lines[line - 1].strip()) if sep is None else lines[line - 1].split(sep)
    cells[field] = token
    lines[line - 1] = ("\t" if sep is None else sep).join(cells)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("case", sorted(CASES))
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), token=GARBAGE)
def test_garbage_number_is_located(case, data, token):
    prepare, rel, sep, where, read = CASES[case]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(prepare(Path(tmp)))
        target = root / rel if rel else root
        line = data.draw(st.sampled_from(sorted(where)), label="line")
        field = data.draw(st.sampled_from(list(where[line])), label="field")
        if sep == ",":  # a decimal comma in a comma-separated file is a field separator
            token = token.replace(",", ".")
        _corrupt(target, sep, line, field, token)
        with pytest.raises(FormatError) as ei:
            blk = read(root)
            if isinstance(blk, Block):
                write_survey(blk, Path(tmp) / "survey")
        assert str(ei.value).startswith(f"{target}:{line}: field '"), str(ei.value)
        assert not (Path(tmp) / "survey").exists()


@settings(max_examples=15, deadline=None)
@given(data=st.data(), token=st.sampled_from(['"x"', "null", "[]", '"1e999"', "true"]))
def test_opensfm_json_garbage_is_located(data, token):
    with tempfile.TemporaryDirectory() as tmp:
        root = _opensfm(Path(tmp))
        p = root / "reconstruction.json"
        rec = json.loads(p.read_text())
        shot = data.draw(st.sampled_from(sorted(rec[0]["shots"])), label="shot")
        key = data.draw(st.sampled_from(["rotation", "translation"]), label="key")
        i = data.draw(st.integers(0, 2), label="component")
        rec[0]["shots"][shot][key][i] = json.loads(token)
        text = json.dumps(rec, indent=1)
        p.write_text(text)
        with pytest.raises(FormatError) as ei:
            read_opensfm(p)
        m = re.match(rf"{re.escape(str(p))}:(\d+): field '{key}': ", str(ei.value))
        assert m, str(ei.value)
        assert json.dumps(shot) in text.splitlines()[int(m.group(1)) - 1]


@settings(max_examples=15, deadline=None)
@given(data=st.data(), token=GARBAGE)
def test_metashape_marker_garbage_is_located(data, token):
    with tempfile.TemporaryDirectory() as tmp:
        frame = Path(tmp) / "frame.xml"
        lines = (D / "metashape" / "easyidp_wheat_tanashi_frame.doc.xml").read_text().splitlines()
        locs = [k for k, ln in enumerate(lines, start=1) if "<location camera_id" in ln]
        line = data.draw(st.sampled_from(locs), label="line")
        attr = data.draw(st.sampled_from(["x", "y"]), label="attr")
        lines[line - 1] = re.sub(rf' {attr}="[^"]*"', f' {attr}="{token}"', lines[line - 1])
        frame.write_text("\n".join(lines) + "\n")
        with pytest.raises(FormatError) as ei:
            read_metashape(D / "metashape" / "easyidp_wheat_tanashi_chunk.doc.xml", frame)
        assert str(ei.value).startswith(f"{frame}:{line}: field '{attr}': "), str(ei.value)
