"""Error of an image against a Mitsuba reference (GUIDE section 3).

- RMSE and relative MSE on linear radiance, each with the reference's own variance subtracted: for a
  reference mean r with variance v, E[(x - r)^2] = (x - truth)^2 + v, so the mean of v is taken off.
- SSIM (scikit-image) on sRGB-encoded images clipped to [0, 1], data_range 1.
- Mean bias per channel: mean(x - r).
- Welch's per-block test (validation.verdict.stats) when independent passes of the image exist.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from skimage.metrics import structural_similarity

from tracer.imageio import srgb_encode

from .references import BLOCK, Reference
from .stats import AgreementTest, block_means, welch_test
from .protocol import ALPHA   # family-wise false-positive rate of one comparison

REL_EPS = 1e-2   # the relative MSE's guard against dark pixels: (x - r)^2 / (r^2 + REL_EPS)


@dataclass
class Metrics:
    rmse: float
    rel_mse: float
    ssim: float
    bias: tuple[float, float, float]


def rmse(image: np.ndarray, ref: Reference) -> float:
    """Root of the mean squared error less the reference's mean variance (0 if that goes negative)."""
    mse = np.mean((image.astype(np.float64) - ref.mean) ** 2) - np.mean(ref.var, dtype=np.float64)
    return float(np.sqrt(max(mse, 0.0)))


def rel_mse(image: np.ndarray, ref: Reference) -> float:
    """Mean of ((x - r)^2 - v) / (r^2 + REL_EPS) over pixels and channels."""
    return relative_mse(image, ref.mean, ref.var)


def relative_mse(image: np.ndarray, mean: np.ndarray, var: np.ndarray | float = 0.0) -> float:
    """rel_mse's against a reference image `mean` of variance `var` (0: one taken as exact)."""
    r = mean.astype(np.float64)
    return float(np.mean(((image - r) ** 2 - var) / (r * r + REL_EPS)))


def ssim(image: np.ndarray, ref: Reference) -> float:
    """SSIM of the sRGB-encoded images."""
    return float(structural_similarity(srgb_encode(image), srgb_encode(ref.mean), channel_axis=-1, data_range=1.0))


def bias(image: np.ndarray, ref: Reference) -> tuple[float, float, float]:
    """Mean signed difference per channel."""
    return tuple(float(b) for b in np.mean(image - ref.mean, axis=(0, 1), dtype=np.float64))


def measure(image: np.ndarray, ref: Reference) -> Metrics:
    return Metrics(rmse(image, ref), rel_mse(image, ref), ssim(image, ref), bias(image, ref))


def agreement(passes: np.ndarray, ref: Reference, alpha: float = ALPHA) -> AgreementTest:
    """Welch's test of (K, H, W, 3) passes against the reference, per BLOCK x BLOCK tile and channel."""
    return welch_test(block_means(passes, BLOCK), ref.blocks, alpha=alpha, block=1)
