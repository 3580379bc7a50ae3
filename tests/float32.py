"""Helpers for tests that compare float32 kernels with float64 references."""
import numpy as np

from tracer.jit import Array3f

U = 2.0 ** -24  # float32 unit roundoff


def f32(x) -> np.ndarray:
    """The float32 value the kernel sees, back in float64 for exact reference arithmetic."""
    return np.asarray(x, np.float32).astype(np.float64)


def arr3(x) -> Array3f:
    """(N, 3) NumPy array to an N-wide Array3f."""
    return Array3f(np.ascontiguousarray(np.atleast_2d(np.asarray(x, np.float32)).T))


def unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)
