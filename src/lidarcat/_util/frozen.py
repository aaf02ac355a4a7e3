"""The one read-only array helper of the frozen value types.

Value types holding numpy arrays (``@dataclass(frozen=True, eq=False)``) keep
their own copy of each array with ``setflags(write=False)`` (STYLE.md).  This
module is deliberately tiny and imports only numpy, so that any module can use
it without pulling in others.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["frozen_array"]


def frozen_array(a: Any, dtype: Any = np.float64, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A read-only copy of *a*.

    Parameters
    ----------
    a : array_like
    dtype : dtype or None
        Dtype of the copy (default float64); ``None`` keeps the dtype of *a*.
    shape : tuple of int, optional
        Required shape of the copy.

    Returns
    -------
    ndarray
        A new array (never a view of *a*) with ``flags.writeable`` False.

    Raises
    ------
    ValueError
        *a* does not have *shape*.

    Examples
    --------
    >>> src = [[1, 2, 3]]
    >>> a = frozen_array(src, shape=(1, 3))
    >>> a.dtype, a.flags.writeable
    (dtype('float64'), False)
    >>> frozen_array(np.arange(3), dtype=None).dtype == np.arange(3).dtype
    True
    >>> frozen_array([1.0, 2.0], shape=(3,))
    Traceback (most recent call last):
    ...
    ValueError: expected shape (3,), got (2,)
    """
    arr = np.array(a, dtype=dtype, copy=True)
    if shape is not None and arr.shape != tuple(shape):
        raise ValueError(f"expected shape {tuple(shape)}, got {arr.shape}")
    arr.setflags(write=False)
    return arr
