r"""Grouping the points of a roof clip into faces (thesis 3.2.5, and two robust alternatives).

**Grouping into faces** (``ExtractionParams.method``):

* ``method="thesis"``: triangles are grouped by the direction of their
  normal (the thesis uses the algebraic signs of a, b; we cluster the
  aspect, which is the same on axis-aligned roofs and also works on rotated
  ones), up to ``max_planes`` directions;
* ``method="ransac"``: sequential RANSAC (plane with most inliers within
  the distance and normal tolerances, its largest connected patch, repeat),
  then the same merge / nearest-face assignment as "region";
* ``method="region"`` (default): region growing on a k-nearest-neighbour
  graph with local PCA normals, accepting a neighbour when its normal is
  within ``angle_tol_deg`` of the region's plane and its distance to the
  plane below ``dist_tol_m``; coplanar regions are merged, thin strips of
  blended normals along edges dropped, and every point is given to a face
  by its plan position relative to the faces' intersection lines (the
  height noise does not enter, so the faces are not biased), points within
  ~1 sigma of a line being left out, as are the points on a face's outer
  edge (eaves, verges: facade points there would pull the face down).
  Assignment and fit are iterated twice.

**Break-line buffer** (``ExtractionParams.edge_buffer_m``: None = 2 x ``sd_en_m``, 0.2 m at the
default sds, the default; 0 = off; region / ransac), **tested** (``edge_buffer_level``, below).
After the last assignment, each face is fitted once more without the points within the buffer (in
plan) of those of its break lines whose band is off its plane (the test below): its intersection
lines with the faces whose points reach them (ridges, hips, valleys; :func:`_break_line_bands`).
Why: a face's plane must not depend on the clip, yet the points along its break lines are both
*systematic* and *assigned differently from clip to clip*.

* Systematic: on the AHN3 tiles the points within 0.2 m of a face's break lines lie a median
  21 mm above the plane of the face's interior (quartiles 4-40 mm, above on 80 % of 284 faces).
  That is ridge and hip tiles, and footprints that straddle the line.  The points used lie at
  -1 mm, and the noise sigma is about 22 mm.
* Clip-dependent: the assignment near a line depends on the clip's noise estimate (``dist_tol``,
  the band left out ~1 sigma of the line) and on lines fitted from the clip's points.  So a different
  share of these biased points enters each clip's fit, and the vertex moved by more than the
  covariance of the difference of two clips explains (docs/extraction.md, "Radius sweep").
* The lines themselves are fixed by the faces' interiors: the points left out are nearly the same
  in every clip.  The selection uses plan positions only, so it does not bias the fit on synthetic
  roofs and leaves the covariance honest (the Monte Carlo of tests/control/test_control.py passes
  with the buffer on: ratios 0.92-1.13).
* The width: a point nearer the line than 2 sd of its plan position may belong to the other face.
  On the sweep, 0.2 m halves the candidates that fail the test of the difference, and the vertex sd
  grows 3 %.  At 0.3 / 0.45 m the sd grows 18 / 52 % for little more stability; a whole outer-edge
  layer more (eaves and the clip rim) made it 48 %.
* The faces' *extent* (adjacency, support of a vertex) stays that of the assignment
  (``info["extent_idx"]``), since the buffer removes points from the fit and not from the roof.
  A face too small to keep ``min_points`` after the buffer keeps its first fit.

**The buffer as a test** (``edge_buffer_level``, default 0.999 two-sided; 0 = no test, every band
leaves the fit: the blanket buffer of session 6).  On exact planes the band points are as good as
any: the blanket buffer only throws them away (the synthetic town of
benchmarks/bench_measured_control.py: vertex rms E error 12.5 -> 16.6 mm on seed 2).  So a band
leaves a face's fit only when the data show it is off the face's plane.  For face i, let the
*interior* I be its points outside all its bands, fitted alone (:func:`lidarcat.control.planes.fit_plane`,
the extraction's settings: :math:`\hat\theta = (n, d)`, cofactor Q, components
:math:`\hat\sigma_0^2, \hat\tau_k^2`), and B the band of one break line (i, j) (:func:`_break_line_bands`),
:math:`n_B` points.  The statistic is the band's mean signed residual (normal upwards: > 0 = above)

.. math:: \bar r = c^T r_B, \qquad c = \mathbf 1 / n_B,\quad r_b = n \cdot x_b + d.

If the band belongs to the plane, its condition errors follow the fit's own model
(:mod:`lidarcat.control.planes`, "Correlated residuals"): :math:`\varepsilon = e + \sum_k Z_k u_k`,
:math:`\mathrm{Cov}(e) = \sigma_0^2 W^{-1}`, :math:`\mathrm{Cov}(u_k) = \tau_k^2 I`, with the SAME cell
offsets u for the band and the interior points of a cell.  Linearised, :math:`r_b = \varepsilon_b + a_b^T
\delta\theta` with :math:`\delta\theta = -Q A_I^T W \varepsilon_I`, so

.. math:: \bar r = c^T \varepsilon_B - g^T \varepsilon_I,\qquad g = W A_I Q \bar a,\quad
          \bar a = A_B^T c = (\bar x_B, 1),

.. math:: \mathrm{Var}(\bar r) = \sigma_0^2 \Big(\sum_b c_b^2 / w_b + \bar a^T Q \bar a\Big)
          + \sum_k \tau_k^2 \sum_{\text{cells } s} \Big(\sum_{b \in s} c_b - \sum_{i \in s} g_i\Big)^2

(:math:`g^T W^{-1} g = \bar a^T Q N Q \bar a = \bar a^T Q \bar a`: the plane's prediction variance).  The
first term is the iid part (:math:`\sigma_0^2 / (n_B w)` for equal weights) plus the plane's error at
the band; the second the cell offsets the band shares: a 1 m cell offset moves all band points of the
cell together, so it does not average out over the band's points but only over its cells (along an
8 m line about 8), minus what the interior fit absorbed of the same cells (a cell shared by band
and interior lifts both, the difference cancels in part).  A naive t-test (:math:`\sigma_0^2 / n_B`
alone) fires far too often on real roofs: on the AHN3 tiles the 1 m design effect is a median 1.62
over the whole face, and a band is a strip one cell wide.  Each component is multiplied by the t
factor f / (f - 2) of its own redundancy, as in the plane's covariance.  The band's points more than
the fit's rejection threshold from the band's median residual (a chimney, a dormer's edge) are left
out of the mean: they are outliers, not an offset of the band.

Decision, in two stages at the same level (0.999):

* **Pooled over the clip.**  :math:`q = \sum z^2` over the clip's bands of at least
  ``MIN_BAND_POINTS`` = 3 points is :math:`\chi^2_K` (K bands) if every band lies on its plane (the
  bands of different faces, or of one face's different lines, are nearly independent).  When
  :math:`P(\chi^2_K > q) < 1 - \text{level}`, the clip's break lines are off their planes as a
  whole, a property of the roofs and the scanner (ridge tiles, footprints across the line), and
  *every* band leaves the fit: the blanket buffer.  This stage is what keeps the faces independent of
  the clip: most biased bands are a few points (AHN3: median 5), too short to show 1-3 cm alone, and a
  decision band by band changes from clip to clip (z 3 in one clip, 3.5 in the next), the very clip
  dependence the buffer removes (measured: docs/extraction.md, "Radius sweep", item 5).
* **Band by band** otherwise: a band leaves the fit when :math:`|z| > \Phi^{-1}(1/2 +
  \text{level}/2)` (3.29 at 0.999) and it has at least 3 points.  The minimum: the mean of one or two
  residuals follows their heavy tails (single points off a roof by 5-10 cm are common), not the
  Gaussian model; on AHN3 C0162 a 2-point band at -69 mm (z -3.8) tilted a 33-point face enough to
  lose the corner at the candidate's own position.

Two-sided: a band below the plane (a sagging valley, a gutter) biases as much as one above.  The final
fit is the face without its dropped bands; a face with no band dropped keeps its fit exactly, identical
to no buffer (so exact planes lose nothing, except at the false-positive rate).  Fallbacks: an interior too small to fit
(fewer than ``min_points``) keeps all bands (nothing to test against); a face left with fewer than
``min_points`` keeps its first fit; the extent is the assignment's in every case.  The tests of all
bands are in ``info["edge_bands"]`` (face, line, points, offset_m, sd_m, z, dropped), the pooled test
in ``info["edge_bands_pooled"]`` (q, k, p, pooled).

Measured (docs/extraction.md, "Radius sweep", item 5): on the synthetic town (exact planes) no clip
pools and 2 of 371 band tests fire: the vertices are the no-buffer ones (to 0.1 mm).  On 1252 clips of
exact planes (synthetic hip and pyramid roofs, the town; benchmarks/bench_band_test.py) 9 of 9182 bands
fire alone (0.10 %, 95 % interval 0.04-0.19 %), 3 clips pool (0.24 %, 0.05-0.70 %), z has sd 1.009 and
q/K 1.02: the model above is honest (tests/control/test_band_rate.py).  Where a band holds points of the
neighbouring face (the cross-gable valleys of ``synthetic_roof("lgable")``), it is off the plane and fires.  On the AHN3
tiles 88 of 89 clips pool (median q/K 7.7) and 87 of the 89 vertices are the blanket buffer's; band by
band alone, the test dropped only 17 % of the bands (median offset +34 mm, kept ones +9 mm) and the
radius sweep lost the blanket's stability (72 failing candidates against 36).

:func:`group_faces` groups the points and fits a plane to each group
(:func:`lidarcat.control.planes.fit_plane`); the slope window, the order and the
outer frame are :func:`lidarcat.control.facets.segment_faces`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .params import ExtractionParams
from .planes import Plane, PlaneFit, fit_plane, t_factor
from .triangles import delaunay_facets

__all__ = ["group_faces"]


def _circular_peaks(angles_deg: np.ndarray, weights: np.ndarray, tol_deg: float, max_peaks: int) -> list[float]:
    if len(angles_deg) == 0:
        return []
    bins = np.arange(0, 361, 5.0)
    hist, _ = np.histogram(angles_deg % 360, bins=bins, weights=weights)
    # circular smoothing over +-10 deg
    k = np.array([0.25, 0.5, 1.0, 0.5, 0.25])
    ext = np.concatenate([hist[-2:], hist, hist[:2]])
    smooth = np.convolve(ext, k, mode="valid")
    centres = bins[:-1] + 2.5
    peaks: list[float] = []
    order = np.argsort(-smooth)
    for i in order:
        if smooth[i] < 0.2 * smooth.max() or len(peaks) >= max_peaks:
            break
        a = centres[i]
        if all(abs((a - b + 180) % 360 - 180) >= tol_deg for b in peaks):
            peaks.append(float(a))
    return peaks


def _segment_thesis(xyz: np.ndarray, p: ExtractionParams) -> tuple[np.ndarray, dict[str, Any]]:
    """Label points by the direction of their Delaunay triangles (thesis 3.2.4-3.2.5)."""
    labels = np.full(len(xyz), -1)
    fac = delaunay_facets(xyz, p.max_edge_m)
    ok = fac.keep & (fac.slope_deg > p.slope_min_deg) & (fac.slope_deg < p.slope_max_deg)
    info = {"n_triangles": len(fac.simplices), "n_in_window": int(ok.sum()),
            "n_flat": int((fac.keep & (fac.slope_deg <= p.slope_min_deg)).sum()),
            "n_steep": int((fac.keep & (fac.slope_deg >= p.slope_max_deg)).sum()), "facets": fac}
    if not ok.any():
        return labels, info
    peaks = _circular_peaks(fac.aspect_deg[ok], fac.area_m2[ok], p.aspect_tol_deg, p.max_planes)
    if not peaks:
        return labels, info
    asp = fac.aspect_deg[ok][:, None]
    dist = np.abs((asp - np.array(peaks)[None, :] + 180) % 360 - 180)
    g = np.argmin(dist, axis=1)
    g[dist[np.arange(len(g)), g] > p.aspect_tol_deg] = -1
    simp = fac.simplices[ok]
    # a point takes the group most of its triangles belong to
    votes = np.zeros((len(xyz), len(peaks)))
    for k in range(len(peaks)):
        sel = simp[g == k].ravel()
        np.add.at(votes[:, k], sel, 1.0)
    has = votes.sum(axis=1) > 0
    labels[has] = np.argmax(votes[has], axis=1)
    return labels, info


def _local_normals(xyz: np.ndarray, k: int):
    from scipy.spatial import cKDTree

    tree = cKDTree(xyz[:, :2])
    k = int(min(k, len(xyz)))
    dist, nb = tree.query(xyz[:, :2], k=k)
    nb = np.asarray(nb).reshape(len(xyz), k)
    pts = xyz[nb]
    c = pts.mean(axis=1, keepdims=True)
    q = pts - c
    cov = np.einsum("nki,nkj->nij", q, q) / k
    val, vec = np.linalg.eigh(cov)
    normals = vec[:, :, 0]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    rms = np.sqrt(np.maximum(val[:, 0], 0.0))
    return normals, rms, nb, dist


def _segment_setup(xyz: np.ndarray, p: ExtractionParams) -> dict[str, Any]:
    """What both segmenters need: local normals, slopes, noise, tolerances, link length."""
    normals, lrms, nb, nbd = _local_normals(xyz, p.k_neighbours)
    k = nb.shape[1]
    slope = np.degrees(np.arccos(np.clip(normals[:, 2], 0.0, 1.0)))
    in_win = (slope > p.slope_min_deg) & (slope < p.slope_max_deg)
    # noise from the quieter local planes: the lower quartile of the local RMS
    # (ridges and edges inflate the upper part); for pure noise it is ~0.70 sigma at k = 12.
    # Vegetation and walls are not roof noise: estimate it on the sloped points.
    pool = lrms[in_win] if in_win.sum() >= 20 else lrms
    sigma = float(np.percentile(pool, 25)) / 0.70 if len(xyz) else 0.0
    dist_tol = p.dist_tol_m if p.dist_tol_m is not None else max(0.05, 3.0 * sigma)
    spacing = float(np.median(nbd[:, 1])) if k > 1 else 1.0
    link = 4.0 * spacing if p.max_edge_m is None else p.max_edge_m
    info = {"sigma_m": sigma, "dist_tol_m": dist_tol, "spacing_m": spacing,
            "n_flat": int((slope <= p.slope_min_deg).sum()),
            "n_steep": int((slope >= p.slope_max_deg).sum()), "n_in_window": int(in_win.sum())}
    return dict(normals=normals, lrms=lrms, nb=nb, nbd=nbd, k=k, slope=slope, in_win=in_win,
                sigma=sigma, dist_tol=dist_tol, spacing=spacing, link=link, info=info)


def _segment_region(xyz: np.ndarray, p: ExtractionParams) -> tuple[np.ndarray, dict[str, Any]]:
    """Region growing on the kNN graph (normal angle + point-to-plane distance)."""
    m = len(xyz)
    labels = np.full(m, -1)
    st = _segment_setup(xyz, p)
    normals, lrms, nb, nbd = st["normals"], st["lrms"], st["nb"], st["nbd"]
    in_win, sigma, dist_tol = st["in_win"], st["sigma"], st["dist_tol"]
    max_link, info = st["link"], st["info"]
    cos_tol = math.cos(math.radians(p.angle_tol_deg))
    linked = nbd <= max_link
    seeds = np.flatnonzero(in_win & (lrms < max(2.0 * sigma, 0.5 * dist_tol)))
    seeds = seeds[np.argsort(lrms[seeds])]
    region = 0
    tried = np.zeros(m, dtype=bool)
    for s in seeds:
        if labels[s] >= 0 or tried[s]:
            continue
        tried[s] = True
        members = [s]
        labels[s] = region
        n_r, c_r = normals[s], xyz[s]
        frontier = np.array([s])
        last_fit = 1
        while len(frontier):
            cand = nb[frontier][linked[frontier]]
            cand = np.unique(cand)
            cand = cand[labels[cand] < 0]
            if len(cand) == 0:
                break
            ok = (np.abs((xyz[cand] - c_r) @ n_r) < dist_tol) & (normals[cand] @ n_r > cos_tol)
            acc = cand[ok]
            if len(acc) == 0:
                break
            labels[acc] = region
            members.extend(acc.tolist())
            frontier = acc
            if len(members) >= 1.3 * last_fit and len(members) >= 6:
                pts = xyz[members]
                c_r = pts.mean(axis=0)
                val, vec = np.linalg.eigh(np.cov((pts - c_r).T))
                n_new = vec[:, 0] * (1 if vec[2, 0] >= 0 else -1)
                n_r = n_new
                last_fit = len(members)
        if len(members) < p.min_points:
            labels[np.array(members)] = -1
            tried[np.array(members)] = True
        else:
            region += 1
    info["n_regions_raw"] = region
    return labels, info


def _segment_ransac(xyz: np.ndarray, p: ExtractionParams) -> tuple[np.ndarray, dict[str, Any]]:
    """Sequential RANSAC: best-supported plane, its largest connected patch, repeat."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(xyz)
    labels = np.full(m, -1)
    st = _segment_setup(xyz, p)
    normals, nb, nbd, k = st["normals"], st["nb"], st["nbd"], st["k"]
    in_win, dist_tol, link, info = st["in_win"], st["dist_tol"], st["link"], st["info"]
    rows = np.repeat(np.arange(m), k)
    cols = nb.ravel()
    ok = nbd.ravel() <= link
    graph = coo_matrix((np.ones(ok.sum()), (rows[ok], cols[ok])), shape=(m, m)).tocsr()
    cos_tol = math.cos(math.radians(p.angle_tol_deg))
    rng = np.random.default_rng(0)
    free = in_win.copy()
    region = 0
    for _ in range(3 * p.max_planes):
        cand = np.flatnonzero(free)
        if len(cand) < p.min_points:
            break
        best, best_n = None, 0
        for _ in range(150):
            tri = xyz[rng.choice(cand, 3, replace=False)]
            n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
            norm = np.linalg.norm(n)
            if norm < 1e-9:
                continue
            n = n / norm * (1 if n[2] >= 0 else -1)
            inl = (np.abs((xyz[cand] - tri[0]) @ n) < dist_tol) & (normals[cand] @ n > cos_tol)
            if inl.sum() > best_n:
                best, best_n = cand[inl], int(inl.sum())
        if best is None or best_n < p.min_points:
            break
        sub = graph[best][:, best]
        _, comp = connected_components(sub, directed=False)
        big = best[comp == np.argmax(np.bincount(comp))]
        if len(big) < p.min_points:
            free[best] = False
            continue
        labels[big] = region
        free[big] = False
        region += 1
    info["n_regions_raw"] = region
    return labels, info


def _fit_groups(xyz: np.ndarray, labels: np.ndarray, p: ExtractionParams,
                grid_origin_m: Any = (0.0, 0.0)) -> list[tuple[Plane, np.ndarray]]:
    """Fit every labelled group with the extraction's own rejection settings (*grid_origin_m*: see fit_plane)."""
    out = []
    for g in np.unique(labels[labels >= 0]):
        idx = np.flatnonzero(labels == g)
        fit = _fit_one(xyz, idx, p, grid_origin_m)
        if fit:
            out.append((fit.plane, idx[fit.used]))
    return out


def _fit_trial(xyz: np.ndarray, p: ExtractionParams) -> PlaneFit:
    """Plane of a trial face while segmenting: robust (MAD) threshold, orthogonal residuals."""
    return fit_plane(xyz, sd_m=(p.sd_en_m, p.sd_en_m, p.sd_h_m), residual_threshold_m=None,
                     min_points=p.min_points)


def _drop_edge_strips(xyz: np.ndarray, idx_sets: list[np.ndarray], p: ExtractionParams,
                      dist_tol: float) -> list[tuple[np.ndarray, PlaneFit]]:
    """Drop small faces whose points are explained by larger faces.

    Points along a ridge, hip or valley have blended local normals and can
    grow into a thin region of intermediate orientation; its points lie within
    the distance tolerance of the two real faces, which take them back.
    Returns the kept point sets with their :func:`_fit_trial` fits.
    """
    order = sorted(range(len(idx_sets)), key=lambda i: -len(idx_sets[i]))
    fits = {i: _fit_trial(xyz[idx_sets[i]], p) for i in order}
    planes = {i: f.plane for i, f in fits.items() if f}
    keep = []
    for a, i in enumerate(order):
        pts = xyz[idx_sets[i]]
        bigger = [planes[j] for j in order[:a] if j in planes and j in keep]
        if bigger and len(idx_sets[i]) < 0.5 * len(idx_sets[order[0]]):
            near = np.zeros(len(pts), dtype=bool)
            for pl in bigger:
                near |= np.abs(pl.distance(pts)) < dist_tol
            if near.mean() >= 0.7:
                continue
        keep.append(i)
    return [(idx_sets[i], fits[i]) for i in sorted(keep)]


def _refine_assignment(xyz: np.ndarray, faces: list[tuple[Plane, np.ndarray]], p: ExtractionParams,
                       dist_tol: float, spacing: float) -> np.ndarray:
    """Merge coplanar faces, give every point to its nearest face, drop ridge points."""
    from scipy.spatial import cKDTree

    m = len(xyz)
    if not faces:
        return np.full(m, -1)
    # merge coplanar faces (same plane split by a chimney, terraced houses)
    planes = [f[0] for f in faces]
    members = [set(f[1].tolist()) for f in faces]
    parent = list(range(len(faces)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    order_sz = sorted(range(len(faces)), key=lambda i: -len(faces[i][1]))
    for a, i in enumerate(order_sz):
        for j in order_sz[a + 1:]:
            # j is the smaller face: merge it into i when its points lie on i's plane
            if planes[i].n @ planes[j].n < math.cos(math.radians(15.0)):
                continue
            dj = np.abs(planes[i].distance(xyz[faces[j][1]]))
            if np.median(dj) < dist_tol / 2.5:
                parent[root(j)] = root(i)
    groups: dict[int, set] = {}
    for i in range(len(faces)):
        groups.setdefault(root(i), set()).update(members[i])
    kept = _drop_edge_strips(xyz, [np.array(sorted(s)) for s in groups.values()], p, dist_tol)
    idx_sets = [idx for idx, _ in kept]
    nf = len(kept)
    dist = np.full((m, nf), np.inf)
    zpl = np.full((m, nf), np.nan)
    link = 3.0 * spacing + 0.2
    fitted = []
    for k, (idx, fit) in enumerate(kept):
        fitted.append(fit.plane if fit else None)
        if not fit:
            continue
        pl = fit.plane
        tree = cKDTree(xyz[idx[fit.used], :2])
        near, _ = tree.query(xyz[:, :2], k=1, distance_upper_bound=link)
        dk = np.abs(pl.distance(xyz))
        dk[~np.isfinite(near)] = np.inf
        dist[:, k] = dk
        if pl.n[2] > 0.05:
            zpl[:, k] = pl.height_at(xyz[:, 0], xyz[:, 1])
    # which side of the intersection line of faces i and j face i lies on:
    # sign of (z_i - z_j) over face i's own points (-1 ridge/hip, +1 valley)
    side = np.zeros((nf, nf))
    for i in range(nf):
        for j in range(nf):
            if i != j and fitted[i] is not None and fitted[j] is not None:
                diff = zpl[idx_sets[i], i] - zpl[idx_sets[i], j]
                side[i, j] = np.sign(np.nanmedian(diff)) if np.isfinite(diff).any() else 0.0
    labels = np.full(m, -1)
    cand = dist < max(2.0 * dist_tol, 0.5)
    ncand = cand.sum(axis=1)
    one = ncand == 1
    best1 = np.argmax(cand, axis=1)
    labels[one] = best1[one]
    # several faces close in height: decide by the plan position relative to
    # their intersection line (noise-free), not by the noisy distance
    band = dist_tol / 3.0
    for i_pt in np.flatnonzero(ncand > 1):
        faces_i = np.flatnonzero(cand[i_pt])
        win = faces_i[0]
        for c in faces_i[1:]:
            dz = zpl[i_pt, c] - zpl[i_pt, win]
            # the point is on c's side when sign(z_c - z_win) matches c's own side
            if side[c, win] != 0 and np.sign(dz) == side[c, win]:
                win = c
        # too close to an intersection line to tell the faces apart: leave it out
        gaps = [abs(zpl[i_pt, c] - zpl[i_pt, win]) for c in faces_i if c != win and side[c, win] != 0]
        labels[i_pt] = -1 if gaps and min(gaps) < band else win
    ok = labels >= 0
    ok[ok] = dist[np.flatnonzero(ok), labels[ok]] < dist_tol
    labels[~ok] = -1
    return labels


def _drop_outer_edges(xyz: np.ndarray, labels: np.ndarray, k: int = 12,
                      gap_deg: float = 150.0, max_slope_deg: float = 65.0,
                      noise_m: float = 0.25) -> np.ndarray:
    """Leave out the points on a face's outer edge (eaves, verges, clip rim).

    Facade points just below an eave lie within the distance tolerance of the
    roof plane and always below it, so they pull the face down.  They, and the
    roof points along the same edge, are the points whose same-face plan
    neighbours all lie on one side (angular gap > *gap_deg*) with no other
    face beyond the gap.  Edges between two faces (ridges, hips, valleys) are
    kept.  A face across the gap makes an internal edge only when it continues
    this face in height (height step at most ``plan distance x tan(max_slope_deg)
    + noise_m``): the ground segmented below an eave is another face too, and
    taking it for a ridge kept the facade points of the sides facing the
    scanner (a 0.2-sigma bias of pyramid apexes towards the scanner).  The
    choice depends on plan positions and metre-scale steps only, not on the
    height noise, so it removes the facade bias without biasing the face.
    """
    from scipy.spatial import cKDTree

    m = len(xyz)
    if m < 4:
        return labels
    k = int(min(k + 1, m))
    _, nb = cKDTree(xyz[:, :2]).query(xyz[:, :2], k=k)
    nb = nb[:, 1:]
    d = xyz[nb, :2] - xyz[:, None, :2]
    ang = np.arctan2(d[..., 1], d[..., 0])  # (m, k-1)
    lab_nb = labels[nb]
    same = lab_nb == labels[:, None]
    step = np.abs(xyz[nb, 2] - xyz[:, None, 2])
    joined = step <= np.hypot(d[..., 0], d[..., 1]) * math.tan(math.radians(max_slope_deg)) + noise_m
    other = (lab_nb >= 0) & ~same & joined
    a = np.where(same, ang, np.inf)
    a_sorted = np.sort(a, axis=1)
    n_same = same.sum(axis=1)
    out = labels.copy()
    for_pts = np.flatnonzero((labels >= 0) & (n_same >= 2))
    if len(for_pts) == 0:
        return out
    a_s = a_sorted[for_pts]
    cnt = n_same[for_pts]
    # angular gaps between consecutive same-face neighbours, with the wrap-around
    idx = np.arange(a_s.shape[1])[None, :]
    valid = idx < cnt[:, None]
    nxt = np.where(idx + 1 < cnt[:, None], np.roll(a_s, -1, axis=1), a_s[:, :1] + 2 * np.pi)
    gaps = np.where(valid, nxt - a_s, -np.inf)
    j = np.argmax(gaps, axis=1)
    gmax = gaps[np.arange(len(for_pts)), j]
    edge = gmax > np.radians(gap_deg)
    # another face inside the gap: an internal edge (ridge, hip, valley)
    rel = (ang[for_pts] - a_s[np.arange(len(for_pts)), j][:, None]) % (2 * np.pi)
    in_gap = (rel > 0) & (rel < gmax[:, None])
    internal = np.any(other[for_pts] & in_gap, axis=1)
    drop = for_pts[edge & ~internal]
    out[drop] = -1
    # lone points (no same-face neighbour) are dropped too
    out[(labels >= 0) & (n_same < 2)] = -1
    return out


def _break_line_bands(xyz: np.ndarray, faces: list[tuple[Plane, np.ndarray]], buffer_m: float,
                      spacing: float) -> list[tuple[int, int, np.ndarray]]:
    """The bands of the faces along their break lines: ``(i, j, idx)`` per face i and break line (i, j).

    A break line of face i is its intersection line with a face j whose points reach it (a ridge, hip or
    valley of the roof, not the extension of a distant face's line across i): a point of i is in the band
    (i, j) when its plan distance from the line of (i, j) is below *buffer_m* and a point of j lies within
    ``2 buffer_m + 3 spacing`` of it.  The line is fixed by both faces' interior points, so a band is nearly
    the same in every clip (module docstring, "Break-line buffer").  *idx* are point indices into *xyz*
    (a point near two lines is in both bands).
    """
    from scipy.spatial import cKDTree

    bands: list[tuple[int, int, np.ndarray]] = []
    if len(faces) < 2 or buffer_m <= 0:
        return bands
    trees = [cKDTree(xyz[idx, :2]) for _, idx in faces]
    reach = 2.0 * buffer_m + 3.0 * spacing
    for i, (pi, idx_i) in enumerate(faces):
        for j, (pj, idx_j) in enumerate(faces):
            if i == j or len(idx_i) == 0 or len(idx_j) == 0:
                continue
            u = np.cross(pi.n, pj.n)
            hu = float(np.hypot(u[0], u[1]))
            if hu < 1e-6 or np.linalg.norm(u) < math.sin(math.radians(3.0)):
                continue  # (nearly) parallel faces, or a line (nearly) vertical in plan
            # a point of the line: n_i . x = -d_i, n_j . x = -d_j, u . x = 0
            x0 = np.linalg.solve(np.array([pi.n, pj.n, u]), [-pi.d, -pj.d, 0.0])
            ud = u[:2] / hu
            rel = xyz[idx_i, :2] - x0[:2]
            near = np.abs(rel[:, 0] * ud[1] - rel[:, 1] * ud[0]) < buffer_m
            if not near.any():
                continue
            dj, _ = trees[j].query(xyz[idx_i[near], :2], k=1, distance_upper_bound=reach)
            sel = idx_i[near][np.isfinite(dj)]
            if len(sel):
                bands.append((i, j, sel))
    return bands


def _band_offset(xyz: np.ndarray, fit: PlaneFit, interior: np.ndarray, band: np.ndarray, p: ExtractionParams,
                 grid_origin_m: Any) -> tuple[float, float, int]:
    """Mean offset of a band from the plane of the face's interior, and its sd under the fit's error model.

    *fit* is the fit of the points *interior* (indices into *xyz*), *band* the band's point indices.  Returns
    (offset_m, sd_m, n): the mean of the band's condition residuals ``n . x + d`` (normal upwards, so > 0 =
    above the plane), the sd of that mean if the band belonged to the plane (module docstring, "Break-line
    buffer": iid part, cell components, the plane's own error and its correlation with the band through
    shared cells), and the number of band points averaged (those within the fit's rejection threshold).
    """
    pl = fit.plane
    n, d = np.asarray(pl.n), float(pl.d)
    org = xyz[interior].mean(axis=0)
    xi = xyz[interior][fit.used] - org
    xb = xyz[band] - org
    d_loc = d + float(n @ org)
    s2 = np.array([p.sd_en_m, p.sd_en_m, p.sd_h_m]) ** 2
    w = 1.0 / float(s2 @ (n * n))  # the same condition weight for every point (one sd per axis)
    r_i = xi @ n + d_loc
    r_b = xb @ n + d_loc
    thr = p.residual_threshold_m
    if thr is None:  # fit_plane's own robust threshold
        thr = max(0.03, 3.5 * 1.4826 * float(np.median(np.abs(r_i - np.median(r_i)))))
    keep = np.abs(r_b - np.median(r_b)) <= thr  # a chimney point does not make a band
    xb, r_b = xb[keep], r_b[keep]
    nb, ni = len(r_b), len(r_i)
    if nb == 0 or ni < 4:
        return math.nan, math.nan, nb
    # Q: the 4x4 block of the bordered inverse of N = A' W A, constraint n . dn = 0
    a_i = np.column_stack([xi, np.ones(ni)])
    big = np.zeros((5, 5))
    big[:4, :4] = w * a_i.T @ a_i
    big[:3, 4] = big[4, :3] = n
    q = np.linalg.inv(big)[:4, :4]
    abar = np.append(xb.mean(axis=0), 1.0)
    g = w * (a_i @ (q @ abar))  # mean band residual = mean(eps_B) - g . eps_I
    comps = fit.components if fit.components else (fit.sigma0**2,)
    var = t_factor(ni - 3) * comps[0] * (1.0 / (nb * w) + float(g @ g) / w)
    en = np.vstack([xyz[band][keep, :2], xyz[interior][fit.used, :2]]) + np.asarray(grid_origin_m).reshape(2)
    coef = np.concatenate([np.full(nb, 1.0 / nb), -g])
    for c, tau2 in zip(p.cells_m, comps[1:]):
        if tau2 <= 0:
            continue
        _, inv = np.unique(np.floor(en / float(c)).astype(np.int64), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        # each component times the t factor of its redundancy, as in the plane's covariance
        var += t_factor(len(np.unique(inv[nb:])) - 3) * tau2 * float(np.sum(np.bincount(inv, weights=coef) ** 2))
    return float(r_b.mean()), math.sqrt(max(var, 0.0)), nb


#: a band of fewer points is kept whatever its offset: the mean of one or two residuals follows their heavy
#: tails, not the Gaussian model of the test (module docstring, "Break-line buffer")
MIN_BAND_POINTS = 3


def _tested_buffer(xyz: np.ndarray, faces: list[tuple[Plane, np.ndarray]], buf: float, p: ExtractionParams,
                   spacing: float, grid_origin_m: Any
                   ) -> tuple[list[tuple[Plane, np.ndarray]], list[dict], dict[str, float]]:
    """The faces' final fits with the offset bands left out (module docstring, "Break-line buffer").

    Returns the faces (a face with no band dropped, or too few points left, is returned as given), one record
    per band (face i, line (i, j), points, offset_m, sd_m, z, dropped) and the pooled test of the clip
    (``q`` = sum of z^2 over the bands of ``MIN_BAND_POINTS`` or more, ``k`` their number, ``p`` its chi2_k
    tail probability, ``pooled`` 1.0 when significant: every band dropped).
    """
    from scipy.stats import chi2 as _chi2
    from scipy.stats import norm as _norm

    bands = _break_line_bands(xyz, faces, buf, spacing)
    level = p.edge_buffer_level
    z_crit = float(_norm.ppf(0.5 + 0.5 * level)) if level > 0 else 0.0
    records: list[dict] = []
    per_face = []
    for k, face in enumerate(faces):
        mine = [(j, sel) for i, j, sel in bands if i == k]
        if not mine:
            continue
        in_band = np.zeros(len(xyz), dtype=bool)
        for _, sel in mine:
            in_band[sel] = True
        interior = face[1][~in_band[face[1]]]
        fit = _fit_one(xyz, interior, p, grid_origin_m) if len(interior) >= p.min_points else None
        for j, sel in mine:
            off, sd, nb, z = math.nan, math.nan, len(sel), math.nan
            if z_crit > 0 and fit:
                off, sd, nb = _band_offset(xyz, fit, interior, sel, p, grid_origin_m)
                z = off / sd if sd > 0 else math.nan
            records.append({"face": k, "line": (k, j), "n": nb, "offset_m": off, "sd_m": sd, "z": z,
                            "dropped": True, "_sel": sel})
        per_face.append((k, face, in_band, interior, fit))
    # the pooled test: are this clip's break-line bands off their planes as a whole?
    zs = np.array([r["z"] for r in records if r["n"] >= MIN_BAND_POINTS and np.isfinite(r["z"])])
    q = float(np.sum(zs**2))
    p_tail = float(_chi2.sf(q, len(zs))) if len(zs) else 1.0
    pooled = z_crit <= 0 or p_tail < 1.0 - level
    for r in records:
        # blanket (level 0) or a significant pool: every band; else a band significant alone (nan -- no
        # interior fit, or no usable band point -- keeps the band, as a face too small keeps its first fit)
        r["dropped"] = bool(pooled or (r["n"] >= MIN_BAND_POINTS and abs(r["z"]) > z_crit))
    out = list(faces)
    for k, face, in_band, interior, fit in per_face:
        drop = np.zeros(len(xyz), dtype=bool)
        for r in records:
            if r["face"] == k and r["dropped"]:
                drop[r["_sel"]] = True
        if not drop.any():
            continue  # no band offset: the face keeps its fit, identical to no buffer
        keep = face[1][~drop[face[1]]]
        if not (~drop[face[1]] & in_band[face[1]]).any():
            final = fit if fit else None  # every band dropped: the interior fit is the final one
        else:
            final = _fit_one(xyz, keep, p, grid_origin_m) if len(keep) >= p.min_points else None
        # a face too small for the buffer keeps its first fit (a few points more than none)
        if final:
            sel_idx = interior if final is fit else keep
            out[k] = (final.plane, sel_idx[final.used])
    for r in records:
        del r["_sel"]
    return out, records, {"q": q, "k": float(len(zs)), "p": p_tail, "pooled": float(pooled)}


def group_faces(loc: np.ndarray, p: ExtractionParams,
                grid_origin_m: Any = (0.0, 0.0)) -> tuple[list[tuple[Plane, np.ndarray]], dict[str, Any]]:
    """Group the points *loc* (reduced to their centroid) into faces and fit a plane to each.

    Parameters
    ----------
    loc : (N, 3) float
        Clip points in metres, reduced to their centroid.
    p : ExtractionParams
    grid_origin_m : (2,) float
        E, N (m) of the origin of *loc*: the planes' correlation cells (``p.cells_m``) are a fixed
        grid of the outer frame, the same in every clip.

    Returns
    -------
    faces : list of (Plane, (k,) int)
        Plane of each face (in the frame of *loc*) and the indices of its points, any slope.
    info : dict
        Counts for diagnostics (flat and steep elements, noise estimate...).
    """
    segment = {"thesis": _segment_thesis, "ransac": _segment_ransac, "region": _segment_region}[p.method]
    labels, info = segment(loc, p)
    faces = _fit_groups(loc, labels, p, grid_origin_m)
    if p.method != "thesis":
        # assign by the fitted faces, re-fit, and assign again with the better
        # intersection lines (a self-consistent partition)
        for it in range(2):
            lab2 = _refine_assignment(loc, faces, p, info["dist_tol_m"], info["spacing_m"])
            if it == 1 and p.drop_outer_edges:
                lab2 = _drop_outer_edges(loc, lab2, max_slope_deg=p.slope_max_deg)
            faces = _fit_groups(loc, lab2, p, grid_origin_m)
        buf = 2.0 * p.sd_en_m if p.edge_buffer_m is None else float(p.edge_buffer_m)
        info["edge_buffer_m"] = buf
        if buf > 0 and len(faces) > 1:
            refit, info["edge_bands"], info["edge_bands_pooled"] = _tested_buffer(
                loc, faces, buf, p, info["spacing_m"], grid_origin_m)
            # the faces' extent (support of a vertex, adjacency) stays that of the assignment
            info["extent_idx"] = [idx for _, idx in faces]
            faces = refit
    return faces, info


def _fit_one(xyz: np.ndarray, idx: np.ndarray, p: ExtractionParams, grid_origin_m: Any) -> PlaneFit:
    """Fit of the points *idx* with the extraction's own rejection settings (as :func:`_fit_groups`)."""
    return fit_plane(xyz[idx], sd_m=(p.sd_en_m, p.sd_en_m, p.sd_h_m),
                     residual_threshold_m=p.residual_threshold_m, residual_kind=p.residual_kind,
                     min_points=p.min_points, posterior_variance=p.posterior_variance, cells_m=p.cells_m,
                     grid_origin_m=grid_origin_m)

