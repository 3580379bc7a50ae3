"""Denoising with Intel Open Image Denoise (OIDN) through its Python binding `pyoidn`.

OIDN's `RT` filter is a convolutional network trained on path-traced images. It takes the noisy colour
(here HDR: linear float32 radiance in [0, inf)) and, optionally, the albedo and the shading normal of
the first non-specular surface per pixel (tracer.aov), which let it keep edges and textures the noise
would otherwise hide. The auxiliary images here are themselves Monte Carlo estimates (a few samples per
pixel), so OIDN is told they are not clean (`cleanAux` off, its default).

OIDN's documentation warns that it supports pixel filters only when they are importance-sampled: a
filter that splats each sample into several pixels (our Film's gaussian and tent) correlates
neighbouring pixels and the noise is then not removed. `splatting_warning` says so for such a film.
"""
from __future__ import annotations

import numpy as np

from .film import ReconstructionFilter


class DenoiseError(RuntimeError):
    """OIDN is unavailable or failed; the message says which and why."""


def denoise(color: np.ndarray, albedo: np.ndarray | None = None, normal: np.ndarray | None = None,
            quality: str = "high") -> np.ndarray:
    """The denoised image, (height, width, 3) float32 linear radiance, finite and non-negative.

    `albedo` (in [0, 1]) and `normal` (in [-1, 1]) have color's shape; a normal needs an albedo, as
    OIDN's filters take colour, colour + albedo, or colour + albedo + normal.
    """
    color = _checked(color, "color", 0.0, np.inf)
    if normal is not None and albedo is None:
        raise ValueError("denoise: a normal image needs an albedo image too")
    aux = [_checked(a, name, lo, hi, color.shape) if a is not None else None
           for a, name, lo, hi in ((albedo, "albedo", 0.0, 1.0), (normal, "normal", -1.0, 1.0))]
    try:
        import pyoidn
    except ImportError as e:
        raise DenoiseError(f"Open Image Denoise is unavailable: {e} (install it with `pip install pyoidn`)") from e
    try:
        out = pyoidn.denoise(color, aux[0], aux[1], hdr=True, quality=quality)
    except Exception as e:  # noqa: BLE001 - the binding raises RuntimeError, and OSError when its library fails to load
        raise DenoiseError(f"Open Image Denoise failed: {type(e).__name__}: {e}") from e
    out = np.asarray(out, dtype=np.float32)
    if out.shape != color.shape or not np.isfinite(out).all():
        raise DenoiseError("Open Image Denoise returned an image of the wrong shape or with NaN/infinity")
    return np.maximum(out, 0.0)


def splatting_warning(rfilter: ReconstructionFilter) -> str | None:
    """A one-line warning when the film splats samples into neighbouring pixels (not the box filter)."""
    if rfilter.kind == "box":
        return None
    return (f"the film's {rfilter.describe()} filter splats each sample into several pixels; Open Image Denoise "
            "expects uncorrelated pixels (box filter) and may leave noise in place")


def _checked(image, name: str, lo: float, hi: float, shape: tuple | None = None) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) == 0:
        raise ValueError(f"denoise: {name} must have shape (height, width, 3), got {a.shape}")
    if shape is not None and a.shape != shape:
        raise ValueError(f"denoise: {name} has shape {a.shape}, the colour image {shape}")
    a = np.ascontiguousarray(a, dtype=np.float32)
    if not np.isfinite(a).all():
        raise ValueError(f"denoise: {name} holds NaN or infinite values")
    if a.min() < lo or a.max() > hi:
        raise ValueError(f"denoise: {name} must lie in [{lo:g}, {hi:g}], found [{a.min():g}, {a.max():g}]")
    return a
