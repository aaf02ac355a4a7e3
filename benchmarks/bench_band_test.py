"""False-positive rate of the tested break-line buffer on exact planes (``ExtractionParams.edge_buffer_level``).

    PYTHONPATH=src python benchmarks/bench_band_test.py [--roofs 300] [--kinds hip pyramid lgable]
        [--densities 4 10] [--towns 1 2 3] [--town-size 500 400]

:mod:`lidarcat.control.segment` ("Break-line buffer") tests each band of a face along one of its break lines:
``z`` = the band's mean offset from the plane of the face's interior over its sd under the fit's error model,
band by band (``|z| > 3.29`` at the default level 0.999, bands of 3+ points) and pooled over the clip
(``q = sum z^2`` against chi2_K).  On exact planes with the noise the fit assumes, both stages must fire at
the nominal rate 1 - level = 0.1 % and ``z`` must have sd 1.  This script measures it on

- ``synthetic_roof`` roofs (:mod:`lidarcat.synthetic.roofs`, one clip of ``radius_m`` about the first
  vertex of each roof; kinds, sizes, slopes and azimuths drawn per roof; height noise 5 cm, plan noise 3 cm,
  walls and ground as the scanner samples them), and
- the synthetic town of benchmarks/bench_measured_control.py (:func:`lidarcat.synthetic.aerial.aerial_scene`,
  its LiDAR as ``aerial_survey`` samples it: uniform plan positions, the surface, 3 cm height noise, 10
  points per m2), one clip about each true roof vertex.

The clips are cut and height-filtered as :func:`lidarcat.control.vertices.extract_roof` cuts its first
clip, and segmented with the default parameters (:func:`lidarcat.control.facets.segment_faces`).

Printed per source: clips, band tests (3+ points), the sd of ``z`` with its 95 % interval (chi2), the bands
that fire with the Clopper-Pearson 95 % interval of the rate, the clips that pool with theirs, and the mean of
``q / K`` (1 when the bands are independent and the sds honest).  With ``--truth`` the synthetic roofs also
split their bands into those holding points of another TRUE plane (points of the neighbouring face assigned
to this one; the roof's noise-free twin gives each point's true face) and the others: the mean and sd of their
z and how many fire.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from lidarcat.control.facets import segment_faces  # noqa: E402
from lidarcat.control.params import get_params  # noqa: E402
from lidarcat.lidar.clipping import height_window_mask  # noqa: E402


def clip_records(xyz: np.ndarray, center: np.ndarray, p) -> tuple[list[dict], dict | None]:
    """Band records and the pooled test of the clip of ``p.radius_m`` about *center* (as extract_roof's first clip)."""
    sub = xyz[np.sum((xyz[:, :2] - center[:2]) ** 2, axis=1) <= p.radius_m**2]
    sub = sub[height_window_mask(sub[:, 2], p.height_filter, p.height_window_m)]
    if len(sub) < 3 * p.min_points:
        return [], None
    try:
        _, _, info = segment_faces(sub, p)
    except ValueError:
        return [], None
    return list(info.get("edge_bands", [])), info.get("edge_bands_pooled")


def roof_clips(kind: str, n: int, density: float, seed0: int = 0):
    """(xyz, vertex, scene, frame) of *n* synthetic roofs of *kind*; sizes, slope, azimuth drawn per roof."""
    from lidarcat.synthetic.roofs import synthetic_roof

    for k in range(n):
        rng = np.random.default_rng(10_000 + seed0 + k)
        az, slope = float(rng.uniform(0, 90)), float(rng.uniform(25, 45))
        width, length = float(rng.uniform(8, 11)), float(rng.uniform(13, 16))
        s = synthetic_roof(kind, seed=seed0 + k, noise_h_m=0.05, noise_plan_m=0.03, density_m2=density,
                           azimuth_deg=az, slope_deg=slope, width_m=width, length_m=length)
        if len(s.vertices):
            yield s.xyz, s.vertices[0], dict(kind=kind, seed=seed0 + k, az=az, slope=slope, W=width, L=length,
                                             density=density)


def town_clips(seed: int, size: tuple[float, float]):
    """(xyz, vertex) about every true roof vertex of the town of *seed* (aerial_survey's LiDAR: 10 / m2, 3 cm)."""
    from lidarcat.synthetic.aerial import aerial_scene

    w, h = size
    bounds = (680_000.0, 7_184_000.0, 680_000.0 + w, 7_184_000.0 + h)
    sc = aerial_scene(bounds, texel_m=0.1, seed=seed)
    rng = np.random.default_rng(seed)
    for k, b in enumerate(sc.buildings):
        for v in b.vertices(sc.base_height(k)):
            r = 9.0
            m = int(rng.poisson(10.0 * (2 * r) ** 2))
            e = rng.uniform(v[0] - r, v[0] + r, m)
            nn = rng.uniform(v[1] - r, v[1] + r, m)
            z, _ = sc.surface(e, nn)
            yield np.column_stack([e, nn, z + rng.normal(0, 0.03, m)]), np.asarray(v), {"kind": b.kind}


def foreign_bands(xyz: np.ndarray, v: np.ndarray, meta: dict, p) -> tuple[list, list]:
    """z of the bands (3+ points) holding points of another TRUE plane, and of the others (the noise-free
    twin of the roof gives each point's true position, hence its true face)."""
    import lidarcat.control.segment as seg
    from lidarcat.synthetic.roofs import synthetic_roof

    s0 = synthetic_roof(meta["kind"], seed=meta["seed"], noise_h_m=0.0, noise_plan_m=0.0, density_m2=meta["density"],
                        azimuth_deg=meta["az"], slope_deg=meta["slope"], width_m=meta["W"], length_m=meta["L"])
    sel = np.sum((xyz[:, :2] - v[:2]) ** 2, axis=1) <= p.radius_m**2
    sub, x0 = xyz[sel], s0.xyz[sel]  # the same scan: the noise-free twin's points, one for one
    m = height_window_mask(sub[:, 2], p.height_filter, p.height_window_m)
    sub, x0 = sub[m], x0[m]
    ca, sa = math.cos(math.radians(meta["az"])), math.sin(math.radians(meta["az"]))
    dx, dy = x0[:, 0] - 677000.0, x0[:, 1] - 7183000.0
    u, w = ca * dx + sa * dy, -sa * dx + ca * dy
    W, L = meta["W"], (meta["W"] if meta["kind"] == "pyramid" else meta["L"])
    if meta["kind"] == "lgable":  # max of two gables (roof_height)
        in_a = (np.abs(w) <= W / 2) & (u >= -W / 2)
        in_b = (np.abs(u) <= W / 2) & (w >= -W / 2)
        use_a = in_a & (~in_b | (W / 2 - np.abs(w) >= W / 2 - np.abs(u)))
        true_plane = np.where(use_a, np.where(w > 0, 0, 1), np.where(u > 0, 2, 3))
    else:  # hip, pyramid: the least of the four faces' heights
        true_plane = np.argmin(np.column_stack([W / 2 - w, W / 2 + w, L / 2 - u, L / 2 + u]), axis=1)
    seen: list = []
    orig = seg._band_offset

    def spy(xyz_, fit, interior, band, p_, g):
        r = orig(xyz_, fit, interior, band, p_, g)
        seen.append((interior, band, r))
        return r

    seg._band_offset = spy
    try:
        segment_faces(sub, p)
    finally:
        seg._band_offset = orig
    foreign, clean = [], []
    for interior, band, (off, sd, n) in seen:
        if n < 3 or not sd > 0:
            continue
        own = np.bincount(true_plane[interior]).argmax()
        (foreign if np.any(true_plane[band] != own) else clean).append(off / sd)
    return foreign, clean


def clopper_pearson(k: int, n: int, conf: float = 0.95) -> tuple[float, float]:
    from scipy.stats import beta

    a = 1 - conf
    lo = float(beta.ppf(a / 2, k, n - k + 1)) if k > 0 else 0.0
    hi = float(beta.ppf(1 - a / 2, k + 1, n - k)) if k < n else 1.0
    return lo, hi


def summarise(name: str, recs: list[dict], pools: list[dict], level: float) -> str:
    from scipy.stats import chi2, norm

    z_crit = float(norm.ppf(0.5 + 0.5 * level))
    z = np.array([r["z"] for r in recs if r["n"] >= 3 and np.isfinite(r["z"])])
    nz = len(z)
    fired = int(np.sum(np.abs(z) > z_crit))
    sd = float(np.sqrt(np.mean(z**2))) if nz else math.nan
    # 95 % interval of the sd (about zero mean) from chi2_nz
    sd_lo = sd * math.sqrt(nz / chi2.ppf(0.975, nz)) if nz else math.nan
    sd_hi = sd * math.sqrt(nz / chi2.ppf(0.025, nz)) if nz else math.nan
    lo, hi = clopper_pearson(fired, nz) if nz else (math.nan, math.nan)
    pk = [q for q in pools if q and q["k"] > 0]
    npool = sum(int(q["pooled"]) for q in pk)
    plo, phi = clopper_pearson(npool, len(pk)) if pk else (math.nan, math.nan)
    qk = sum(q["q"] for q in pk) / max(1.0, sum(q["k"] for q in pk))
    mean = float(np.mean(z)) if nz else math.nan
    return (f"{name:<22} {len(pools):6d} {nz:6d} {sd:6.3f} [{sd_lo:5.3f}, {sd_hi:5.3f}] {mean:6.3f}"
            f" {fired:5d} {100 * fired / max(nz, 1):6.2f} [{100 * lo:5.2f}, {100 * hi:5.2f}]"
            f" {npool:5d} {100 * npool / max(len(pk), 1):6.2f} [{100 * plo:5.2f}, {100 * phi:5.2f}] {qk:6.3f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roofs", type=int, default=300, help="synthetic roofs per kind and density")
    ap.add_argument("--kinds", nargs="*", default=["hip", "pyramid", "lgable"])
    ap.add_argument("--densities", nargs="*", type=float, default=[4.0, 10.0])
    ap.add_argument("--towns", nargs="*", type=int, default=[1, 2, 3], help="town seeds (none: no town)")
    ap.add_argument("--town-size", nargs=2, type=float, default=(500.0, 400.0))
    ap.add_argument("--truth", action="store_true", help="split the bands by points of another true plane")
    a = ap.parse_args(argv)
    p = get_params()
    head = (f"{'source':<22} {'clips':>6} {'bands':>6} {'sd(z)':>6} {'95 % interval':>14} {'mean':>6} {'fired':>5}"
            f" {'%':>6} {'95 % interval':>14} {'pool':>5} {'%':>6} {'95 % interval':>14} {'q/K':>6}")
    rows, all_r, all_p = [], {}, {}
    t0 = time.time()
    for kind in a.kinds:
        for dens in a.densities:
            recs, pools, fo, cl = [], [], [], []
            for xyz, v, meta in roof_clips(kind, a.roofs, dens):
                r, q = clip_records(xyz, v, p)
                recs += r
                pools.append(q)
                if a.truth:
                    f, c = foreign_bands(xyz, v, meta, p)
                    fo += f
                    cl += c
            name = f"{kind} {dens:g}/m2"
            rows.append(summarise(name, recs, pools, p.edge_buffer_level))
            all_r.setdefault(kind, []).extend(recs)
            all_p.setdefault(kind, []).extend(pools)
            if a.truth:
                fo, cl = np.array(fo), np.array(cl)
                fire = lambda z: int(np.sum(np.abs(z) > 3.2905))  # noqa: E731
                rows.append(f"  {name}: bands with points of another true plane {len(fo)}: mean z "
                            f"{np.mean(fo) if len(fo) else np.nan:.2f}, sd {np.std(fo) if len(fo) else np.nan:.2f}, "
                            f"fire {fire(fo)}; only their own: {len(cl)}, mean z "
                            f"{np.mean(cl) if len(cl) else np.nan:.2f}, sd {np.std(cl) if len(cl) else np.nan:.2f}, "
                            f"fire {fire(cl)}")
            print(rows[-1], f"({time.time() - t0:.0f} s)", flush=True, file=sys.stderr)
    if a.towns:
        recs, pools = [], []
        for seed in a.towns:
            for xyz, v, _ in town_clips(seed, tuple(a.town_size)):
                r, q = clip_records(xyz, v, p)
                recs += r
                pools.append(q)
        rows.append(summarise(f"town {','.join(map(str, a.towns))}", recs, pools, p.edge_buffer_level))
        all_r["town"], all_p["town"] = recs, pools
        print(rows[-1], f"({time.time() - t0:.0f} s)", flush=True, file=sys.stderr)
    exact = [k for k in all_r if k in ("hip", "pyramid", "town")]
    if exact:
        rows.append(summarise("hip+pyramid+town", sum((all_r[k] for k in exact), []),
                              sum((all_p[k] for k in exact), []), p.edge_buffer_level))
    print(f"edge_buffer_level {p.edge_buffer_level} (nominal {100 * (1 - p.edge_buffer_level):.2f} % per stage); "
          f"sd(z) = rms of z; intervals 95 %; {time.time() - t0:.0f} s")
    print(head)
    print("\n".join(rows))


if __name__ == "__main__":
    main()
