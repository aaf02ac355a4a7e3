"""Synthetic landscapes with known ground, for judging ground filters beyond the AHN3 tiles.

The AHN3 tiles in the repository are flat Dutch town; a filter's default
parameters must also hold on steep and forested slopes, bridges, dense city
blocks with large flat roofs and low outliers (the landscapes of the ISPRS
filter test).  Each landscape here is a seeded, vectorised simulation of an
airborne scan with the truth known per point:

* pulses fall uniformly at ``density`` per m2 over a ``size_m`` square;
* a pulse on open ground gives one return on the terrain (ground);
* a pulse on a roof or a bridge deck gives one return there (object: in the
  ISPRS convention a bridge deck is not ground);
* a pulse into a tree crown gives a first return in the crown and, with the
  probability ``penetration``, a last return on the ground (or, in the
  forest, in the understorey 0.5-3 m above it); otherwise the crown return
  is the only (and last) one;
* low outliers (multipath) are single returns 5-20 m below the terrain.

Heights carry 3 cm of Gaussian noise.  Landscapes (``LANDSCAPES``):

``steep``
    A hillside rising at 35 deg with a ridge-and-gully swell across it
    (slopes 30-40 deg) and scattered trees.
``forest``
    A 25 deg slope under a closed canopy (85 % cover, crowns 12-25 m high,
    20 % of the pulses reaching the ground or the understorey).
``bridge``
    A valley 12 m deep with steep banks and a river bed, crossed by a 10 m
    wide deck 80 m long at the level of the banks.
``city``
    Dense blocks: flat roofs 40-60 m across and 8-30 m high along 15-25 m
    streets, a few street trees.
``low_outliers``
    Gently rolling terrain with houses and trees and 0.3 % of the pulses
    returned 5-20 m below the ground.

Broken terrain (``BROKEN_LANDSCAPES``, not in ``LANDSCAPES``, whose figures
the benchmarks keep):

``terraces``
    8 m cliffs every 40 m (wavy in plan) on a 10 % slope, a mesa 30 m across
    and 15 m high, houses 12 x 12 m and 6 m high on the terraces; one return
    per pulse (no trees).  The weakest case of the adaptive SMRF at 0.1-0.3
    pulses/m2 (docs/figures.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._util.frozen import frozen_array

__all__ = ["Landscape", "make_landscape", "LANDSCAPES", "BROKEN_LANDSCAPES"]

LANDSCAPES = ("steep", "forest", "bridge", "city", "low_outliers")
BROKEN_LANDSCAPES = ("terraces",)


@dataclass(frozen=True, eq=False)
class Landscape:
    """Points of a synthetic landscape and their truth.

    Attributes
    ----------
    name : str
    xyz : ndarray, shape (N, 3)
        E, N, h in metres (local coordinates, origin at the south-west corner).
    return_number, number_of_returns : ndarray of uint8, shape (N,)
    ground : ndarray of bool, shape (N,)
        True where the point is on the terrain (the reference).
    """

    name: str
    xyz: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    ground: np.ndarray

    def __post_init__(self) -> None:
        for f in ("xyz", "return_number", "number_of_returns", "ground"):
            a = getattr(self, f)
            object.__setattr__(self, f, frozen_array(a, dtype=np.asarray(a).dtype))

    def __len__(self) -> int:
        return len(self.xyz)


def _terrain(name: str, x: np.ndarray, y: np.ndarray, size: float) -> np.ndarray:
    if name == "steep":
        return math.tan(math.radians(35.0)) * x + 4.0 * np.sin(2 * math.pi * y / 80.0)
    if name == "forest":
        return math.tan(math.radians(25.0)) * x + 3.0 * np.sin(2 * math.pi * y / 120.0)
    if name == "bridge":
        c = size / 2
        bank = 12.0 / (1.0 + np.exp(-(np.abs(x - c) - 22.0) / 3.0))  # valley floor 0, banks at 12 m
        return 20.0 + 0.02 * y + bank - 12.0 + 0.3 * np.sin(y / 7.0)
    if name == "city":
        return 50.0 + 0.01 * x + 0.005 * y
    return 10.0 + 0.05 * x + 2.0 * np.sin(x / 30.0) * np.cos(y / 40.0)


def _trees(rng: np.random.Generator, size: float, n: int, r_lo: float, r_hi: float,
           h_lo: float, h_hi: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    c = rng.uniform(0, size, (n, 2))
    return c, rng.uniform(r_lo, r_hi, n), rng.uniform(h_lo, h_hi, n)


def _crown(x: np.ndarray, y: np.ndarray, trees: tuple[np.ndarray, np.ndarray, np.ndarray],
           cell: float = 10.0) -> np.ndarray:
    """Height of the highest crown (half-ellipsoid) over each plan point above the terrain; 0 outside."""
    c, r, h = trees
    top = np.zeros(len(x))
    if len(r) == 0:
        return top
    # bin the trees by cell; test each point against the trees of its 3 x 3 cells (crowns < cell)
    ti = np.floor(c / cell).astype(np.int64)
    px = np.floor(x / cell).astype(np.int64)
    py = np.floor(y / cell).astype(np.int64)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            key_t = ti[:, 0] * 100_003 + ti[:, 1]
            order = np.argsort(key_t, kind="stable")
            ks = key_t[order]
            key_p = (px + dx) * 100_003 + (py + dy)
            lo = np.searchsorted(ks, key_p, side="left")
            hi = np.searchsorted(ks, key_p, side="right")
            most = int((hi - lo).max(initial=0))
            for k in range(most):  # at most a handful of trees per cell: a loop over trees per cell, not points
                has = lo + k < hi
                t = order[np.minimum(lo + k, len(order) - 1)]
                d2 = ((x - c[t, 0]) ** 2 + (y - c[t, 1]) ** 2) / r[t] ** 2
                inside = has & (d2 < 1.0)
                z = np.where(inside, h[t] * (0.6 + 0.4 * np.sqrt(np.clip(1.0 - d2, 0.0, 1.0))), 0.0)
                top = np.maximum(top, z)
    return top


def make_landscape(name: str, *, size_m: float = 200.0, density: float = 6.0, seed: int = 0) -> Landscape:
    """A synthetic landscape *name* (see the module docstring) with its true ground.

    Parameters
    ----------
    name : {"steep", "forest", "bridge", "city", "low_outliers", "terraces"}
    size_m : float
        Side of the square area, metres.
    density : float
        Pulses per m2.
    seed : int
        Random seed (the same seed gives the same points).

    Examples
    --------
    >>> ls = make_landscape("bridge", size_m=100, density=1, seed=3)
    >>> len(ls) > 9000, bool(ls.ground.any() and not ls.ground.all())
    (True, True)
    """
    if name not in LANDSCAPES + BROKEN_LANDSCAPES:
        raise ValueError(f"unknown landscape {name!r}; use one of {', '.join(LANDSCAPES + BROKEN_LANDSCAPES)}")
    if not (size_m > 0 and density > 0):
        raise ValueError("size_m and density must be positive")
    rng = np.random.default_rng(seed)
    n = int(round(size_m * size_m * density))
    if name == "terraces":
        return _terraces(rng, n, size_m)
    x = rng.uniform(0, size_m, n)
    y = rng.uniform(0, size_m, n)
    zg = _terrain(name, x, y, size_m)
    obj_h = np.zeros(n)  # height above the terrain of a single-return object (roof, deck)
    deck = np.zeros(n, dtype=bool)
    trees = (np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    penetration = 0.5
    understorey = 0.0
    if name == "steep":
        trees = _trees(rng, size_m, int(size_m * size_m / 400), 2.0, 4.0, 8.0, 15.0)
    elif name == "forest":
        trees = _trees(rng, size_m, int(size_m * size_m / 22), 3.0, 5.0, 12.0, 25.0)
        penetration, understorey = 0.2, 0.4
    elif name == "bridge":
        c = size_m / 2
        deck = (np.abs(x - c) <= 40.0) & (np.abs(y - c) <= 5.0)
        deck_z = 20.0 + 0.02 * y + 0.5  # level with the banks, 0.5 m above their crest
        obj_h = np.where(deck, deck_z - zg, 0.0)
        trees = _trees(rng, size_m, int(size_m * size_m / 1500), 2.0, 4.0, 6.0, 12.0)
    elif name == "city":
        pitch = 75.0
        bx = np.floor(x / pitch)
        by = np.floor(y / pitch)
        brng = np.random.default_rng(seed + 7919)
        nb = int(math.ceil(size_m / pitch)) + 1
        w = brng.uniform(40.0, 60.0, (nb, nb, 2))
        hgt = brng.uniform(8.0, 30.0, (nb, nb))
        ix, iy = bx.astype(np.int64), by.astype(np.int64)
        u = x - bx * pitch - pitch / 2
        v = y - by * pitch - pitch / 2
        roof = (np.abs(u) <= w[ix, iy, 0] / 2) & (np.abs(v) <= w[ix, iy, 1] / 2)
        obj_h = np.where(roof, hgt[ix, iy], 0.0)
        trees = _trees(rng, size_m, int(size_m * size_m / 2500), 2.0, 3.5, 6.0, 10.0)
    elif name == "low_outliers":
        u = np.mod(x, 40.0)
        v = np.mod(y, 40.0)
        house = (u > 12) & (u < 26) & (v > 14) & (v < 26)
        obj_h = np.where(house, 6.0 + 0.5 * (6.0 - np.abs(v - 20.0)), 0.0)
        trees = _trees(rng, size_m, int(size_m * size_m / 600), 2.0, 4.0, 6.0, 14.0)
    crown = np.where(obj_h > 0, 0.0, _crown(x, y, trees))
    in_crown = crown > 0
    # crown returns: first return somewhere in the upper crown
    crown_z = zg + crown * rng.uniform(0.75, 1.0, n)
    through = in_crown & (rng.random(n) < penetration)
    under = through & (rng.random(n) < understorey)
    last_z = zg + np.where(under, rng.uniform(0.5, 3.0, n), 0.0)
    # points: the first (or only) return of every pulse, then the last returns of the pulses that went through
    first_z = np.where(obj_h > 0, zg + obj_h, np.where(in_crown, crown_z, zg))
    first_ground = (obj_h <= 0) & ~in_crown
    nret_first = np.where(through, 2, 1).astype(np.uint8)
    xs = np.concatenate([x, x[through]])
    ys = np.concatenate([y, y[through]])
    zs = np.concatenate([first_z, last_z[through]])
    gt = np.concatenate([first_ground, ~under[through]])
    rn = np.concatenate([np.ones(n, np.uint8), np.full(int(through.sum()), 2, np.uint8)])
    nr = np.concatenate([nret_first, np.full(int(through.sum()), 2, np.uint8)])
    if name == "low_outliers":
        lo = rng.random(len(zs)) < 0.003
        lo &= rn == nr  # a single (last) return replaced by an echo far below the ground
        zs = np.where(lo, _terrain(name, xs, ys, size_m) - rng.uniform(5.0, 20.0, len(zs)), zs)
        gt &= ~lo
    zs = zs + rng.normal(0.0, 0.03, len(zs))
    return Landscape(name, np.column_stack([xs, ys, zs]), rn, nr, gt)


def _terraces(rng: np.random.Generator, n: int, size: float) -> Landscape:
    """The ``terraces`` landscape (module docstring): *n* single returns over a *size* square."""
    x, y = rng.uniform(0, size, n), rng.uniform(0, size, n)
    zg = 8.0 * np.floor((x + 10 * np.sin(y / 25)) / 40.0) + 0.1 * x + 0.05 * y
    mesa = np.hypot(x - 0.7 * size, y - 0.3 * size) < 15
    zg = zg + np.where(mesa, 15.0, 0.0)
    house = ((np.mod(x, 50) > 20) & (np.mod(x, 50) < 32) & (np.mod(y, 60) > 10) & (np.mod(y, 60) < 22)
             & ~mesa)
    xyz = np.column_stack([x, y, zg + np.where(house, 6.0, 0.0) + rng.normal(0, 0.03, n)])
    one = np.ones(n, np.uint8)
    return Landscape("terraces", xyz, one, one, ~house)
