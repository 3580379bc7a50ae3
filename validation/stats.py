"""Statistical agreement between two renderers from independent passes of each.

Welch's t-test per block of pixels and channel, Bonferroni-corrected over all blocks: with a
family-wise false-positive rate `alpha`, two unbiased renderers fail together with probability at most
`alpha` (given approximately normal pass means, which averaging blocks of samples provides).

Blocks lit only by rare events (a caustic a few samples reach) have pass means far from normal and a
pass variance that few passes underestimate. A block is therefore rejected only if its difference is
also larger than `resolution` times the reference image's mean radiance (default 1e-3): the test
resolves biases down to 0.1% of the image's brightness, not below.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats


@dataclass
class AgreementTest:
    passed: bool
    alpha: float
    tests: int
    rejected: int
    min_p: float
    worst_block: tuple[int, int, int]   # (row, column, channel) of the smallest p-value
    worst_t: float

    def summary(self) -> str:
        verdict = "agree" if self.passed else "DISAGREE"
        return (f"{verdict}: {self.rejected}/{self.tests} blocks rejected at family-wise alpha {self.alpha:g} "
                f"(Bonferroni), min p {self.min_p:.3g} at block {self.worst_block}, t = {self.worst_t:.2f}")


def block_means(passes: np.ndarray, block: int) -> np.ndarray:
    """(K, H, W, C) passes averaged over block x block tiles; edges that do not fill a tile are dropped."""
    k, h, w, c = passes.shape
    hb, wb = h // block, w // block
    tiles = passes[:, :hb * block, :wb * block].reshape(k, hb, block, wb, block, c)
    return tiles.mean(axis=(2, 4), dtype=np.float64)


def welch_test(a: np.ndarray, b: np.ndarray, alpha: float = 0.01, block: int = 4,
               resolution: float = 1e-3) -> AgreementTest:
    """Do passes `a` and `b` (each (K, H, W, 3), `b` the reference) estimate the same image?"""
    xa, xb = block_means(a, block), block_means(b, block)
    ka, kb = len(xa), len(xb)
    if ka < 2 or kb < 2:
        raise ValueError("Welch's test needs at least two passes of each renderer")
    ma, mb = xa.mean(0), xb.mean(0)
    va, vb = xa.var(0, ddof=1) / ka, xb.var(0, ddof=1) / kb
    se2 = va + vb
    diff = ma - mb
    with np.errstate(divide="ignore", invalid="ignore"):
        t = diff / np.sqrt(se2)
        df = se2 ** 2 / (va ** 2 / (ka - 1) + vb ** 2 / (kb - 1))
        p = 2 * stats.t.sf(np.abs(t), df)
    # Blocks without variance in either renderer (black, or one constant emitter) agree only if equal.
    exact = se2 == 0
    scale = np.maximum(np.abs(ma), np.abs(mb))
    p = np.where(exact, np.where(np.abs(diff) <= 1e-6 * scale, 1.0, 0.0), p)
    t = np.where(exact, np.where(np.abs(diff) <= 1e-6 * scale, 0.0, np.inf), t)
    n = p.size
    resolvable = np.abs(diff) > resolution * float(b.mean())
    rejected = int(((p < alpha / n) & resolvable).sum())
    worst = np.unravel_index(int(np.argmin(p)), p.shape)
    return AgreementTest(rejected == 0, alpha, n, rejected, float(p.min()), tuple(int(i) for i in worst),
                         float(t[worst]))
