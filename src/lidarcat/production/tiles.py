"""The production chain's tile functions by product name, as tile jobs of :mod:`lidarcat.lidar.jobs`.

The tile engine knows no product; this table names the products' own tile
functions, for the ``lidarcat lidar ground|dtm|dsm`` commands and their stage:

=========  =====================================================  ===========
``ground``  :func:`lidarcat.production.ground.ground_tile`         ``.las``/``.laz`` copy, class 2 set
``dtm``     :func:`lidarcat.production.terrain.dtm_tile`           GeoTIFF (and extras)
``dsm``     :func:`lidarcat.production.terrain.dsm_tile`           GeoTIFF (and extras)
``stats``   :func:`lidarcat.production.terrain.stats_tile`         GeoTIFF: min, max, mean, count, stdev bands
=========  =====================================================  ===========
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from ..lidar.jobs import TileFunction, TileJob, tile_jobs
from .ground import ground_tile
from .terrain import dsm_tile, dtm_tile, stats_tile

__all__ = ["PRODUCT_TILE_FUNCTIONS", "product_jobs"]

#: product name -> its tile function
PRODUCT_TILE_FUNCTIONS: dict[str, TileFunction] = {"ground": ground_tile, "dtm": dtm_tile, "dsm": dsm_tile,
                                                      "stats": stats_tile}


def product_jobs(product: str, paths: Sequence[str | os.PathLike], out: str | os.PathLike, *, crs: Any = None,
                 params: dict[str, Any] | None = None, overlap_m: float = 0.0,
                 suffix: str | None = None) -> list[TileJob]:
    """One tile job of *product* (``"ground"``, ``"dtm"``, ``"dsm"`` or ``"stats"``) per tile.

    The other arguments as :func:`lidarcat.lidar.jobs.tile_jobs`.

    Raises
    ------
    ValueError
        An unknown product name.
    """
    try:
        func = PRODUCT_TILE_FUNCTIONS[product]
    except KeyError:
        raise ValueError(f"unknown product {product!r}; use one of {', '.join(PRODUCT_TILE_FUNCTIONS)}") from None
    return tile_jobs(func, paths, out, crs=crs, params=params, overlap_m=overlap_m, suffix=suffix)
