"""Array shapes: padding arrays to a few bucket sizes, so jitted functions compile once per bucket rather than once per
size; telling traced arrays (inside ``jit``/``vmap``, where nothing can be checked or raised) from concrete ones."""

import jax
import jax.core
import numpy as np
from numpy.typing import ArrayLike


def bucket(n: int) -> int:
    """Padded size of ``n`` rows: the next power of two up to 4096, then the next multiple of 4096."""
    n = max(int(n), 1)
    return 1 << (n - 1).bit_length() if n <= 4096 else -(-n // 4096) * 4096


def pad(array, size: int, fill: ArrayLike = 0):
    """``array`` with rows of ``fill`` appended up to ``size`` rows."""
    array = np.asarray(array)
    filler = np.full((size - array.shape[0],) + array.shape[1:], fill, dtype=array.dtype)
    return np.concatenate([array, filler])


def padded_to_bucket(array):
    """``array`` with copies of its first row appended up to :func:`bucket` of its rows: the padding computes like
    real data (no NaN, no degenerate geometry), and the caller cuts the results back to the real rows."""
    array = np.asarray(array)
    return pad(array, bucket(array.shape[0]), array[0] if array.shape[0] else 0)


def is_traced(*arrays) -> bool:
    """True when any argument is a JAX tracer (inside jit, vmap or grad), where no error can be raised."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(arrays))
