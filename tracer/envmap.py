"""Mitsuba's `envmap` emitter on the host: the latitude-longitude image and the distribution shadow rays
towards it are drawn from (the kernel side is in geometry.py).

Radiance (Mitsuba 3.9's RGB variants): a world direction d is taken to the map's frame, v = to_world^-1 d,
and to u = atan2(v.x, -v.z) / 2 pi (wrapped to [0, 1)), t = acos(v.y) / pi; the image is interpolated
bilinearly, texel-centred and periodic in u, with rows at t = j / (H - 1) (clamped), and scaled by `scale`.

Sampling (the tracer's own; any density that is positive wherever the map is makes the estimate
unbiased): with probability MIX_UNIFORM a direction uniform on the sphere, otherwise a cell of the W x H
(u, t) grid with probability proportional to its texel's luminance times sin(theta), then a point uniform
in the cell.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

MIX_UNIFORM = 0.1
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])   # Rec. 709 Y, as Mitsuba's luminance()


class EnvmapError(ValueError):
    pass


def read_exr_rgb(path: Path) -> np.ndarray:
    """The RGB channels of an OpenEXR image as (H, W, 3) float32 (an alpha channel is dropped, as Mitsuba's
    conversion to RGB does)."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path)) as f:
            channels = f.parts[0].channels
            if "RGB" in channels or "RGBA" in channels:
                pixels = np.asarray(channels.get("RGB", channels.get("RGBA")).pixels)[..., :3]
            elif all(c in channels for c in "RGB"):
                pixels = np.stack([np.asarray(channels[c].pixels) for c in "RGB"], axis=-1)
            else:
                raise EnvmapError(f"{path}: no R, G, B channels (has {', '.join(channels)})")
    except (OSError, RuntimeError) as e:
        raise EnvmapError(f"{path}: not a readable OpenEXR image ({e})") from None
    image = pixels.astype(np.float32)
    if not np.all(np.isfinite(image)) or np.any(image < 0):
        raise EnvmapError(f"{path}: pixels must be finite and non-negative")
    return image


@dataclass(frozen=True)
class Distribution:
    """The sampling tables: row CDF (H), per-row CDFs (H x W) and cell probabilities (H x W)."""

    row_cdf: np.ndarray
    col_cdf: np.ndarray
    cell_p: np.ndarray
    mix_uniform: float


def distribution(image: np.ndarray) -> Distribution:
    h, w, _ = image.shape
    sin_theta = np.sin(np.pi * (np.arange(h) + 0.5) / h)
    weight = (image.astype(float) @ LUMINANCE).clip(min=0) * sin_theta[:, None]
    total = weight.sum()
    if not total > 0:        # a black map: uniform directions only
        return Distribution(np.linspace(1 / h, 1, h), np.tile(np.linspace(1 / w, 1, w), (h, 1)),
                            np.full((h, w), 1.0 / (h * w)), 1.0)
    cell_p = weight / total
    row_p = cell_p.sum(axis=1)
    row_cdf = np.cumsum(row_p)
    col_cdf = np.cumsum(cell_p, axis=1) / np.where(row_p > 0, row_p, 1.0)[:, None]
    row_cdf[-1] = 1.0
    col_cdf[:, -1] = 1.0
    return Distribution(row_cdf, col_cdf, cell_p, MIX_UNIFORM)
