"""The feature cache of the match stage: each photo's SIFT features in ``<folder>/<key>.npz``.

The key is a hash of the image file's resolved path, size and modification time and of the
detection options (:meth:`lidarcat.match.FeatureOptions.key`): a rerun of ``lidarcat match``
with other matching options reads the features back instead of detecting them again, and an
edited image or other detection options miss the cache.  A damaged entry is detected again.
Each entry is written atomically (``_util.atomic_write``).  The engine
(:func:`lidarcat.match.detect`) takes an array and returns :class:`~lidarcat.match.Features`;
only this stage-side helper touches files.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .._util import atomic_write
from ..match.features import FeatureOptions, Features, detect

__all__ = ["FeatureCache"]


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
