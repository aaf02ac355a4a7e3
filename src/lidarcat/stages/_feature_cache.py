"""The feature cache of the match stage: each photo's SIFT features in ``<folder>/<key>.npz``.

The key is a hash of the image file's resolved path, size and modification time and of the
detection options (:meth:`lidarcat.match.FeatureOptions.key`): a rerun of ``lidarcat match``
with other matching options reads the features back instead of detecting them again, and an
edited image or other detection options miss the cache.  A damaged entry is detected again.
Each entry is written atomically (``_util.atomic_write``).  The engine
(:func:`lidarcat.match.detect`) takes an array and returns :class:`~lidarcat.match.Features`;
only this stage-side helper touches files.

:class:`PhotoFeatures` is the ``features(i)`` callable the stage gives
:func:`lidarcat.match.match_block`: the cache and, per photo, its id, image file, size and the
location of its photos.csv row for errors -- no survey object, so it pickles small and a Dask worker
process reads or detects a photo's features from the same folder (on a cluster, a folder every
worker sees).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_write
from ..match.features import FeatureOptions, Features, detect

__all__ = ["FeatureCache", "PhotoImage", "PhotoFeatures", "load_photo_image"]


class FeatureCache:
    """Features per photo in ``<folder>/<key>.npz`` (see the module docstring).

    Parameters
    ----------
    folder : path or None
        Where the files go; None: a temporary folder removed by :meth:`close` or when the cache is
        garbage-collected (the features of a block are never all in memory, and a photo the
        matching's LRU dropped is read back, not detected again).
    spill_in : path or None
        Where that temporary folder goes (default the system's temporary folder); the stage puts
        it inside its output folder (``lidarcat run`` writes nothing outside OUTDIR).
    options : FeatureOptions
    """

    def __init__(self, folder: str | os.PathLike | None, options: FeatureOptions = FeatureOptions(), *,
                 spill_in: str | os.PathLike | None = None):
        if folder is None:     # spill to a private temporary folder, removed with the cache object
            import shutil
            import tempfile
            import weakref

            if spill_in is not None:
                Path(spill_in).mkdir(parents=True, exist_ok=True)
            folder = tempfile.mkdtemp(prefix=".features-", dir=spill_in)
            self._finalizer = weakref.finalize(self, shutil.rmtree, folder, True)
        self.folder = Path(folder)
        self.options = options

    def __getstate__(self) -> dict[str, Any]:   # to a worker process: the folder, not its removal
        return {"folder": self.folder, "options": self.options}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.folder, self.options = state["folder"], state["options"]

    def close(self) -> None:
        """Remove the temporary folder of a cache made with ``folder=None`` (no-op otherwise)."""
        fin = getattr(self, "_finalizer", None)
        if fin is not None:
            fin()

    def _file(self, photo_id: str, source: Path) -> Path | None:
        if self.folder is None:
            return None
        st = source.stat()
        tag = hashlib.sha256(json.dumps([str(source.resolve()), st.st_size, st.st_mtime_ns,
                                         self.options.key()]).encode()).hexdigest()[:16]
        safe = hashlib.sha256(photo_id.encode()).hexdigest()[:12]
        return self.folder / f"{safe}-{tag}.npz"

    def get(self, photo_id: str, source: Path, load: Callable[[], np.ndarray]) -> Features:
        """The features of *photo_id* whose image file is *source*; *load()* reads the image
        (called only when the cache has no valid entry)."""
        f = self._file(photo_id, source)
        if f is not None and f.is_file():
            try:
                with np.load(f) as z:
                    return Features(z["xy_px"], z["descriptors"], z["response"], z["size_px"], int(z["level"]))
            except (OSError, KeyError, ValueError):
                pass   # a damaged cache entry: detect again
        feats = detect(load(), self.options)
        if f is not None:
            f.parent.mkdir(parents=True, exist_ok=True)
            with atomic_write(f, "wb") as fh:
                np.savez(fh, xy_px=feats.xy_px, descriptors=feats.descriptors, response=feats.response,
                         size_px=feats.size_px, level=np.int64(feats.level))
        return feats


@dataclass(frozen=True)
class PhotoImage:
    """A photo's image file and what it must be: ``columns_px x rows_px``; *where* locates its row."""

    photo_id: str
    path: Path
    columns_px: int
    rows_px: int
    camera_id: str
    where: str


def load_photo_image(p: PhotoImage, error: Callable[[str], Exception]) -> np.ndarray:
    """The photo's image, decoded; ``error("<where>: photo 'ID': ...")`` for a file that cannot be
    decoded or has another size than its camera."""
    from ..match import read_image

    img = read_image(p.path, lambda msg: error(f"{p.where}: photo {p.photo_id!r}: {msg}"))
    if img.shape[:2] != (p.rows_px, p.columns_px):
        raise error(f"{p.where}: photo {p.photo_id!r}: image {p.path} is {img.shape[1]} x {img.shape[0]} px but "
                    f"camera {p.camera_id!r} is {p.columns_px} x {p.rows_px} px")
    return img


class PhotoFeatures:
    """``features(i)``: the cached features of photo *i* of *photos* (module docstring); picklable.

    *error* builds the exception of an unreadable image (a module-level class, e.g. SurveyError).
    """

    def __init__(self, cache: FeatureCache, photos: Sequence[PhotoImage], error: Callable[[str], Exception]):
        self.cache, self.photos, self.error = cache, tuple(photos), error

    def __call__(self, i: int) -> Features:
        p = self.photos[i]
        return self.cache.get(p.photo_id, p.path, lambda: load_photo_image(p, self.error))
