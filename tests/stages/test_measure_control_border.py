"""``lidarcat measure-control --border fit`` on the small review block (2 photos of 640 x 480 px): vertices whose
roof edges reach past the photo's border, ``near_border`` by default, are measured on the part of the photo there
is, against their true projection (the renderer's truth); the default stays as it was."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.synthetic.aerial import project_to_pixels

from control_block import make_block, read_rows


def test_border_fit_measures_the_vertices_the_default_leaves_at_the_border(tmp_path):
    got, truth = {}, {}
    for border in ("edges", "fit"):
        s, verts = make_block(tmp_path / f"s-{border}")      # the same block (seeded), one folder per run
        ids = [f"L{i + 1:03d}" for i in range(len(verts))]
        truth = {(pid, v): px for k, pid in enumerate(s.photo_ids)
                 for v, px in zip(ids, project_to_pixels(s.camera, s.true_eo[k], verts))}
        out = tmp_path / f"out-{border}"
        r = CliRunner().invoke(cli, ["measure-control", str(s.path), "--border", border, "--no-gallery", "--lines",
                                     "none", "-o", str(out)])
        assert r.exit_code == 0, r.output
        got[border] = {(d["photo"], d["point"]): d for d in read_rows(out / "decisions.csv")}
    edge = [k for k, d in got["edges"].items() if d["status"] == "near_border"]
    gained = [k for k in edge if got["fit"][k]["status"] == "measured"]
    assert gained, f"no near_border pair measured with --border fit: {edge}"
    for k in gained:
        px = np.array([float(got["fit"][k]["col_px"]), float(got["fit"][k]["row_px"])])
        assert np.hypot(*(px - truth[k])) < 1.0, (k, px, truth[k])
    # what the default measured stays measured, to the same pixel
    for k, d in got["edges"].items():
        if d["status"] == "measured":
            assert got["fit"][k]["status"] == "measured"
            assert abs(float(got["fit"][k]["col_px"]) - float(d["col_px"])) < 0.05
