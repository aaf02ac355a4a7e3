"""Writes small COPC 1.0 files for the tests with copc-lib (PyPI ``copclib``, test extra only).

laspy cannot write COPC, and no COPC file is shipped in ../shared.  Here the
octree is built by hand: the cube is the points' bounding cube (centre =
centre of the bounds, half-size = half the largest extent + 1 m); point ``i``
lives at depth ``depth - k`` where ``4**k`` is the largest power of 4 (up to
``4**depth``) dividing ``i`` -- with ``depth=2`` every 16th point in the root,
every other 4th at depth 1, the rest at depth 2 -- in the node holding it;
within a node the points keep their input order.  The points are packed as LAS point format 6 records by
laspy (X/Y/Z integers of ``scale``), and copc-lib compresses one LAZ chunk per
node and writes the COPC info VLR and the hierarchy EVLR.  Each file is
checked by the tests with laspy's own :class:`laspy.CopcReader`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True, eq=False)
class CopcFixture:
    """What was written: the file, the cube, each node's key and the indices of its points (input order)."""

    path: Path
    center: np.ndarray
    halfsize: float
    nodes: dict            # (d, x, y, z) -> ndarray of point indices into the input, in file order

    def node_box(self, key) -> tuple[float, float, float, float]:
        d, x, y, _ = key
        cell = 2 * self.halfsize / 2 ** d
        x0, y0 = self.center[0] - self.halfsize + x * cell, self.center[1] - self.halfsize + y * cell
        return x0, y0, x0 + cell, y0 + cell

    def file_order(self) -> np.ndarray:
        """Input indices of the points in the order the file stores them."""
        return np.concatenate(list(self.nodes.values()))


def write_copc(path, xyz, *, classification=None, intensity=None, scale=0.01, depth=2, wkt=""):
    """Write *xyz* (N, 3) as a COPC file with an octree of the given *depth*; returns a CopcFixture."""
    import copclib
    import laspy

    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    offset = np.floor(lo)
    center = (lo + hi) / 2.0
    halfsize = float((hi - lo).max() / 2.0 + 1.0)
    cfg = copclib.CopcConfigWriter(6, copclib.Vector3(scale, scale, scale), copclib.Vector3(*offset), wkt)
    writer = copclib.FileWriter(str(path), cfg)
    header = writer.copc_config.las_header
    header.min, header.max = copclib.Vector3(*lo), copclib.Vector3(*hi)
    info = writer.copc_config.copc_info
    info.center_x, info.center_y, info.center_z = map(float, center)
    info.halfsize = halfsize
    info.spacing = 2 * halfsize / 64
    idx = np.arange(n)
    # depth d - k for the points whose index 4**k divides (k <= d): every level is populated
    level = np.full(n, depth)
    for k in range(1, depth + 1):
        level[idx % 4 ** k == 0] = depth - k
    rec = laspy.ScaleAwarePointRecord.zeros(n, point_format=laspy.PointFormat(6), scales=np.full(3, scale),
                                            offsets=offset)
    for k, dim in enumerate("XYZ"):
        setattr(rec, dim, np.round((xyz[:, k] - offset[k]) / scale).astype(np.int32))
    rec.intensity = (idx % 1000 if intensity is None else np.asarray(intensity)).astype(np.uint16)
    rec.return_number = np.ones(n, np.uint8)
    rec.number_of_returns = np.ones(n, np.uint8)
    rec.classification = (np.ones(n) if classification is None else np.asarray(classification)).astype(np.uint8)
    keys = np.zeros((n, 4), np.int64)
    keys[:, 0] = level
    for k in range(3):
        cell = 2 * halfsize / 2.0 ** level
        keys[:, k + 1] = np.clip(np.floor((xyz[:, k] - (center[k] - halfsize)) / cell), 0, 2 ** level - 1)
    order = np.lexsort((idx, keys[:, 3], keys[:, 2], keys[:, 1], keys[:, 0]))
    uk, first = np.unique(keys[order], axis=0, return_index=True)
    edges = list(first) + [n]
    nodes = {}
    for key, a, b in zip(uk, edges[:-1], edges[1:]):
        sel = order[a:b]
        writer.AddNode(copclib.VoxelKey(*map(int, key)), copclib.VectorChar(np.frombuffer(rec.array[sel].tobytes(),
                                                                                           np.int8)))
        nodes[tuple(int(v) for v in key)] = sel
    writer.Close()
    # copc-lib writes the nodes in the order given: check that the file agrees (laspy reads chunk by chunk)
    return CopcFixture(Path(path), center, halfsize, nodes)
