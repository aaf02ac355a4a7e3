"""What the measure-control review tests share: the small block (2 photos of 640 x 480 px, the synthetic
town's roof vertices as LiDAR control) before and after one measure-control, and CSV rows in and out."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from lidarcat.stages.measure_control import measure_control
from lidarcat.synthetic.aerial import aerial_survey

# L003's roof edges by plane numbers.  control.facets numbers a vertex's faces by their points, largest first.
# With the break-line buffer dropping every band (the blanket buffer of session 7's first hours) 1 = the south
# face (426 points), 2 = the north face (418), 3 = the west hip face (180).  The default buffer is a test
# (lidarcat.control.segment, "Break-line buffer"): on this synthetic town, whose faces are exact planes, no band
# is significant, nothing leaves the fits, the two long faces tie at 451 points and the north face comes first,
# so 1-3 is the north-west hip.  The edges themselves do not change with the numbering: on photo 102 the
# north-west hip has no image edge, and the south-west hip is found at the same pixels (0.01 px);
# test_vertex_outside_every_photo_and_edge_without_image_edge_are_reported checks which hip is which.
L003_NO_EDGE = "L003/1-3"   # the north-west hip (north face x hip face): no image edge on photo 102
L003_HIP = "L003/2-3"       # the south-west hip (south face x hip face): found on 102, carried by L003's point


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV written with ``#`` comment lines above its header."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def write_rows(path: Path, fields, rows) -> None:
    """*rows* (dicts) under the header *fields*, as a user's editor would save them."""
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fields)
        w.writeheader()
        w.writerows(rows)


def copy_survey(src: Path, tmp_path: Path) -> Path:
    """A copy of the survey folder *src* under *tmp_path* (the module-scoped blocks are never changed)."""
    dst = tmp_path / "s"
    shutil.copytree(src, dst)
    return dst


def make_block(root: Path) -> tuple[Any, np.ndarray]:
    """The block written to *root* with the town's roof vertices as LiDAR control ``L001`` ..: (the
    :class:`~lidarcat.synthetic.aerial.AerialSurvey` with its truth, the vertices (N, 3) m in id order)."""
    s = aerial_survey(root, n_strips=1, photos_per_strip=2, gsd_m=0.12, image_size_px=(640, 480),
                      lidar_density_m2=10, lidar_noise_m=0.03, n_gps_points=4, seed=2)
    sc = s.scene
    verts = np.array([v for k, b in enumerate(sc.buildings) for v in b.vertices(sc.base_height(k))])
    gp = root / "ground_points.csv"
    gp.write_text(gp.read_text().rstrip("\n") + "\n" + "\n".join(
        f"L{i + 1:03d},{v[0]:.3f},{v[1]:.3f},{v[2]:.3f},0.02,0.02,0.02,lidar" for i, v in enumerate(verts)) + "\n")
    return s, verts


def measured_block(base: Path) -> tuple[Path, Path]:
    """(unmeasured survey folder, the same measured by measure-control) under *base*: copy before changing
    either."""
    root = base / "s"
    make_block(root)
    measured = base / "m"
    shutil.copytree(root, measured)
    measure_control(measured, gallery=False)
    return root, measured


def edited_decisions(root: Path, point_changes: dict | None = None, line_changes: dict | None = None,
                     keep: Any = None) -> tuple[Path, Path]:
    """The measured block's decisions.csv and line_decisions.csv with *changes* ((point|line, photo) -> cells)
    applied (and only the rows *keep* says yes to), written beside line_candidates.csv as a user's edit."""
    from lidarcat.stages.measure_control import DECISION_FIELDS, LINE_DECISION_FIELDS

    out = root / "out" / "measure_control"
    dec, ldec = read_rows(out / "decisions.csv"), read_rows(out / "line_decisions.csv")
    for r in dec:
        r.update((point_changes or {}).get((r["point"], r["photo"]), {}))
    for r in ldec:
        r.update((line_changes or {}).get((r["line"], r["photo"]), {}))
    if keep is not None:
        dec, ldec = [r for r in dec if keep(r)], [r for r in ldec if keep(r)]
    write_rows(out / "edited_decisions.csv", DECISION_FIELDS, dec)
    write_rows(out / "edited_lines.csv", LINE_DECISION_FIELDS, ldec)
    return out / "edited_decisions.csv", out / "edited_lines.csv"
