"""Step 2 of :mod:`lidarcat.photocontrol.measure`: a roof edge fitted in the photo to sub-pixel, across its
predicted segment.

Private to :mod:`lidarcat.photocontrol` (``measure._refine`` fits each edge of a vertex through here; the method
and its settings are the measure module docstring's step 2): :func:`fit_edge` samples profiles across the
predicted segment (:func:`sample`, bilinear), smooths their derivatives along it, takes each station's peak to a
parabola's sub-pixel vertex and fits the line ``s = a + b t`` robustly (3 MAD sigmas), with its covariance
(the stations' correlation counted) and, optionally, the predicted direction as an observation of the slope;
an edge too short, too weak against the texture or too scattered comes back as None with the reason.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["sample", "fit_edge"]


def sample(img: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """*img* at the pixel positions (*cols*, *rows*) (any shape, the result's), bilinear, the border replicated."""
    from scipy.ndimage import map_coordinates

    return map_coordinates(img, [rows.ravel(), cols.ravel()], order=1, mode="nearest").reshape(cols.shape)


def fit_edge(img: np.ndarray, origin: np.ndarray, u: np.ndarray, length_px: float, t0: float,
             band_px: float, min_points: int, min_contrast: float, min_sd_px: float,
             min_ratio: float = 2.5, max_scatter_px: float = 0.7, smooth_px: float = 1.5, end_px: float = 1.0,
             direction_sd_deg: float = 0.0):
    """Edge points across the predicted segment and a robust line s = a + b t; None if too weak.

    Stations run from *t0* to ``length_px - end_px``: clear of the junctions at both ends (the vertex
    measured, and the far vertex or eave corner where other edges branch off and pull the gradient
    peaks, tilting the line).  ``direction_sd_deg > 0``: the slope ``b`` (0 along the predicted
    direction) is observed 0 with sd ``tan(direction_sd_deg)`` as well (the prediction's direction
    is good to about the orientation's attitude error; texture correlated over several pixels tilts
    a free line by more)."""
    nvec = np.array([-u[1], u[0]])
    t = np.arange(t0, max(length_px - end_px, t0), 0.5)
    if len(t) < min_points:
        return None, f"edge {length_px:.0f} px long: too short to fit"
    # the profile reaches 3 px beyond the band: the texture is measured there, the edge searched in the band
    s_all = np.arange(-band_px - 3.0, band_px + 3.0 + 1e-9, 0.25)
    cols = origin[0] + t[:, None] * u[0] + s_all[None] * nvec[0]
    rows = origin[1] + t[:, None] * u[1] + s_all[None] * nvec[1]
    prof = sample(img, cols, rows)
    g_all = np.gradient(prof, 0.25, axis=1)
    if smooth_px > 0 and len(t) > 3:   # along the edge: texture averages out, the edge does not
        from scipy.ndimage import uniform_filter1d

        g_all = uniform_filter1d(g_all, size=max(1, int(round(2 * smooth_px))), axis=0, mode="nearest")
    inner = np.abs(s_all) <= band_px + 1e-9
    s, g = s_all[inner], g_all[:, inner]
    sign = 1.0 if np.median(g[np.arange(len(t)), np.argmax(np.abs(g), axis=1)]) >= 0 else -1.0
    gs = sign * g
    k = np.clip(np.argmax(gs, axis=1), 1, len(s) - 2)
    peak = gs[np.arange(len(t)), k]
    if float(np.median(peak)) < min_contrast:
        return None, f"median edge gradient {float(np.median(peak)):.1f} below {min_contrast:g} grey levels/px"
    # texture: the gradient off the edge (more than 2 px from each station's peak)
    off = np.abs(s_all[None, :] - s[k][:, None]) > 2.0
    texture = float(np.median(np.abs(g_all[off]))) if off.any() else 0.0
    if float(np.median(peak)) < min_ratio * texture:
        return None, (f"edge gradient {float(np.median(peak)):.1f} less than {min_ratio:g} x the texture's "
                      f"{texture:.1f}: no edge")
    y0, y1, y2 = gs[np.arange(len(t)), k - 1], peak, gs[np.arange(len(t)), k + 1]
    den = y0 - 2 * y1 + y2
    frac = np.where(np.abs(den) > 1e-9, 0.5 * (y0 - y2) / np.where(np.abs(den) > 1e-9, den, 1.0), 0.0)
    sp = s[k] + 0.25 * np.clip(frac, -0.5, 0.5)
    keep = (np.argmax(gs, axis=1) > 0) & (np.argmax(gs, axis=1) < len(s) - 1) & (peak > 0.5 * np.median(peak))
    a_mat = np.column_stack([np.ones_like(t), t])
    for _ in range(3):
        if keep.sum() < min_points:
            return None, f"{int(keep.sum())} edge points (< {min_points})"
        coef, *_ = np.linalg.lstsq(a_mat[keep], sp[keep], rcond=None)
        r = sp - a_mat @ coef
        mad = 1.4826 * float(np.median(np.abs(r[keep] - np.median(r[keep]))))
        keep = keep & (np.abs(r) <= max(3.0 * mad, 0.3))
    if keep.sum() < min_points:
        return None, f"{int(keep.sum())} edge points (< {min_points})"
    coef, *_ = np.linalg.lstsq(a_mat[keep], sp[keep], rcond=None)
    r = sp[keep] - a_mat[keep] @ coef
    dof = max(int(keep.sum()) - 2, 1)
    if math.sqrt(float(r @ r) / dof) > max_scatter_px:
        return None, f"edge points scatter {math.sqrt(float(r @ r) / dof):.2f} px about the line (> {max_scatter_px:g})"
    # stations 0.5 px apart are not independent (bilinear sampling, the smoothing along the edge):
    # count one per max(1, 2 smooth_px) px
    sig2 = max(float(r @ r) / dof, min_sd_px**2) * 2.0 * max(1.0, 2.0 * smooth_px)
    n_mat = a_mat[keep].T @ a_mat[keep] / sig2
    free = (coef.copy(), np.linalg.inv(n_mat))   # the line alone (EdgeLine): no direction observed
    if direction_sd_deg > 0:   # the predicted direction as an observation of the slope: b = 0
        n_mat = n_mat + np.diag([0.0, 1.0 / math.tan(math.radians(direction_sd_deg)) ** 2])
        coef = np.linalg.solve(n_mat, a_mat[keep].T @ sp[keep] / sig2)
    cov = np.linalg.inv(n_mat)
    return (coef, cov, t[keep], float(np.median(peak)) / max(texture, 1e-9), free), ""
