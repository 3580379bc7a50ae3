"""Adaptive sampling for the `path` estimator: a pilot pass, then the rest of the budget where the noise is.

The budget is the uniform renderer's: `spp` samples per pixel on average, `spp * pixels` in all.

1. **Pilot**: `pilot_spp` samples in every pixel (half the budget by default). Each pixel keeps the sums
   of its samples' radiance (the film) and of their squares (a second film): its per-sample variance per
   channel.
2. **Allocation**: the other `(spp - pilot_spp) * pixels` samples are shared out so that the expected
   squared error summed over pixels and channels — the RMSE the validation measures — is smallest. The
   mean of n_i samples of a pixel with per-sample variance s_i^2 (summed over channels) has variance
   s_i^2 / n_i; minimising sum_i s_i^2 / n_i under sum_i n_i = N (a Lagrange multiplier) gives
   **n_i proportional to s_i, the standard deviation**, not the variance: allocating by the variance
   over-spends on the noisiest pixels. With the pilot's samples already spent, the optimum under
   n_i >= pilot_spp is water-filling: n_i = max(lambda * s_i, pilot_spp), lambda set by the budget.
   `criterion="relative"` minimises the relative MSE instead (sum_c s_ic^2 / (mu_ic^2 + eps) in place of
   s_i^2: dark pixels count more, as in a tone-mapped image); `criterion="variance"` is the common
   heuristic n_i ~ s_i^2, kept to measure it against.
3. **Adaptive pass**: lanes are samples, each with its own pixel: the counts' prefix sums, and a binary
   search of each lane's index in them, give lane -> pixel for any per-pixel counts. These samples use
   other random streams than the pilot's and splat into the same film, so each pixel is the mean of all
   its own samples, pilot and adaptive.

**Why the image stays unbiased.** Keeping the pilot samples and choosing a pixel's sample count from
those same samples is biased: a pixel whose pilot caught a rare bright path looks noisy, gets many more
samples, and its bright pilot sample is diluted; a pixel whose pilot missed it looks smooth, gets few,
and keeps its dark pilot — the image comes out too dark where it is hardest. Here s_i is estimated
**only from the pixel's neighbours**: the mean of the pilot's sample standard deviations of the 24
other pixels of its 5 x 5 neighbourhood, never its own. Samples of different pixels use independent
random streams, so pixel i's count n_i is independent of pixel i's own pilot samples, and given n_i all
its pilot_spp + n_i samples are independent draws with the pixel's true mean:
E[mean] = E[E[mean | n_i]] = the true value. `tests/test_adaptive.py` shows that the variant that
estimates s_i from the pixel's own pilot is measurably biased and that this one is not.

**Choices, measured on hexagon_room at 128 x 128** (the expected RMSE of an allocation, computed from the
Mitsuba reference's per-pixel variance, over 3 or 4 pilots): the neighbours' mean allocates better than a
pixel's own few pilot samples would even if those were allowed (the noisy features, the light's edges
and its images in the spheres, cover several pixels); averaging standard deviations rather than
variances was better or within 0.5%, since one rare bright pilot sample then draws fewer samples into its
whole neighbourhood; 5 x 5 was better than 3 x 3 with pilots of up to a quarter of the budget and within
2% with half; a pilot of half the budget was the best or within 1% of the best of an eighth, a quarter
and a half from 16 to 1024 spp. The pilot is not wasted (its samples stay in the image); it is the
defensive share that keeps every pixel at half the mean rate whatever its noisy estimate says.

Only the box filter is supported: with a wider filter a sample splats into neighbouring pixels whose
weight sums would then depend on other pixels' sample counts, which changes the image a pixel
converges to.
"""
from __future__ import annotations

import drjit as dr
import numpy as np

from .errors import PlanError, SettingsError
from .film import Film, ReconstructionFilter
from .geometry import SceneGeometry
from .jit import UInt32
from .estimators import PathEstimator
from .launch import seed_state, trace_pass
from .rendering import RenderResult, check_rfilter, check_settings, timed
from .scene import Scene

CRITERIA = ("stddev", "relative", "variance")
STREAM = 0xADA9_7105_0000          # random streams of adaptive rendering: (seed, STREAM, pass)
REL_EPS = 1e-2                     # the relative criterion's guard for dark pixels (validation's REL_EPS)
RADIUS = 2                         # neighbourhood: (2 RADIUS + 1)^2 pixels, the pixel itself left out
NOISE_FROM = ("neighbours", "own")  # where a pixel's noise estimate comes from; "own" is the biased variant


def default_pilot(spp: int) -> int:
    """Half the budget, at least 2 samples (a per-pixel variance needs two)."""
    return max(2, spp // 2)


def render_adaptive(scene: Scene, spp: int | None = None, seed: int | None = None, max_depth: int | None = None,
                    rfilter: ReconstructionFilter | None = None, pilot_spp: int | None = None,
                    criterion: str = "stddev", progress: bool = False, noise_from: str = "neighbours") -> RenderResult:
    """The path estimator with `spp` samples per pixel on average, placed adaptively (module docstring).
    `noise_from="own"` estimates a pixel's noise from its own pilot: the biased variant the module's
    docstring explains, kept so that the validation can show its bias.

    `result.settings` holds "adaptive": True, "pilot_spp", "criterion" and "samples", the
    (height, width) number of samples each pixel received (pilot included)."""
    _, spp, seed, max_depth = check_settings(scene, "path", spp, seed, max_depth)
    if pilot_spp is None and spp < 3:
        raise SettingsError(f"adaptive sampling needs at least 3 samples per pixel (a pilot of 2, then more), "
                            f"got {spp}")
    pilot_spp = default_pilot(spp) if pilot_spp is None else pilot_spp
    rfilter = check_rfilter(scene.camera.rfilter if rfilter is None else rfilter)
    if rfilter.kind != "box":
        raise SettingsError(f"adaptive sampling needs the box filter, not {rfilter.describe()} (--filter box)")
    geo = SceneGeometry(scene)

    estimator = PathEstimator(max_depth)

    def sampler(sample, pixel, state):
        return estimator.samples(geo, scene, sample, pixel, state)

    cam = scene.camera
    film = Film(cam.width, cam.height, rfilter)
    (rays, counts, image), seconds, compile_s = timed(
        lambda: (*adaptive_passes(film, sampler, spp, pilot_spp, seed, criterion, progress, noise_from),
                 film.develop()))
    settings = {"adaptive": True, "pilot_spp": pilot_spp, "criterion": criterion,
                "samples": counts.reshape(cam.height, cam.width)}
    return RenderResult(image, "path", spp, max_depth, seconds, compile_s, rays, settings=settings)


def adaptive_passes(film: Film, sampler, spp: int, pilot_spp: int, seed: int, criterion: str = "stddev",
                    progress: bool = False, noise_from: str = "neighbours") -> tuple[int, np.ndarray]:
    """Pilot, allocation and adaptive pass into `film` (box filter). `sampler(sample, pixel, seed_state)`
    returns (x, y, L, rays) per lane, as PathEstimator.samples. Returns the rays traced and each pixel's
    total sample count (pilot included), flattened."""
    if criterion not in CRITERIA:
        raise SettingsError(f"unknown adaptive criterion '{criterion}'; choose one of {', '.join(CRITERIA)}")
    if noise_from not in NOISE_FROM:
        raise SettingsError(f"unknown noise estimate '{noise_from}'; choose one of {', '.join(NOISE_FROM)}")
    if pilot_spp < 2:
        raise SettingsError(f"the pilot needs at least 2 samples per pixel to estimate a variance, got {pilot_spp}")
    if spp <= pilot_spp:
        raise SettingsError(f"adaptive sampling needs more samples per pixel ({spp}) than its pilot ({pilot_spp})")
    w, h = film.width, film.height
    pixels = w * h
    if spp * pixels >= 2**32:
        raise PlanError(f"{spp} spp at {w} x {h} is more than 2^32 samples, adaptive sampling's most")
    squares = Film(w, h, film.rfilter)

    # 1. Pilot: pilot_spp samples per pixel, sums and sums of squares.
    rays = trace_pass(film, sampler, pixels * pilot_spp, lambda sample: sample // pilot_spp,
                      seed_state(seed, STREAM, 0), progress, "pilot", squares, run=pilot_spp)

    # 2. Allocation, from each pixel's neighbours only (or, the biased variant, from its own pilot).
    mean, second = film.develop().astype(np.float64), squares.develop().astype(np.float64)
    var = np.maximum(second - mean * mean, 0.0) * pilot_spp / (pilot_spp - 1)    # per sample, per channel
    if criterion == "relative":
        var = var / (mean * mean + REL_EPS)
    var = var.sum(axis=-1)
    spread = var if criterion == "variance" else np.sqrt(var)
    weight = neighbour_mean(spread) if noise_from == "neighbours" else spread
    extra = allocate(weight.ravel(), (spp - pilot_spp) * pixels, pilot_spp)

    # 3. Adaptive pass: lane j belongs to the pixel i with ends[i-1] <= j < ends[i].
    ends_np = np.cumsum(extra, dtype=np.int64)
    ends = UInt32(ends_np.astype(np.uint32))
    rays += trace_pass(film, sampler, int(ends_np[-1]),
                       lambda sample: dr.binary_search(0, pixels - 1, lambda i: dr.gather(UInt32, ends, i) <= sample),
                       seed_state(seed, STREAM, 1), progress, "adaptive")
    return rays, extra + pilot_spp


def neighbour_mean(values: np.ndarray, radius: int = RADIUS) -> np.ndarray:
    """Each pixel's mean of the other pixels' values in its (2 radius + 1)^2 neighbourhood, itself left
    out (module docstring); fewer neighbours at the image's border."""
    h, w = values.shape
    r = radius
    padded = np.pad(values.astype(np.float64), r)
    ones = np.pad(np.ones((h, w)), r)
    total, count = np.zeros((h, w)), np.zeros((h, w))
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dy == 0 and dx == 0:
                continue
            total += padded[r + dy:r + dy + h, r + dx:r + dx + w]
            count += ones[r + dy:r + dy + h, r + dx:r + dx + w]
    return total / np.maximum(count, 1)


def allocate(weight: np.ndarray, budget: int, already: int) -> np.ndarray:
    """Extra samples per pixel, summing to `budget`, for totals proportional to `weight` where the
    `already` samples every pixel has do not exceed that share (water-filling):
    extra_i = max(lambda * weight_i - already, 0). With the weights sorted in decreasing order and the
    k largest active, lambda = (budget + k * already) / (sum of those k weights); k is the largest count
    whose smallest member is still active. Rounded to integers by largest remainders. Without any
    positive weight the budget is shared evenly."""
    weight = np.asarray(weight, dtype=np.float64)
    if budget <= 0:
        return np.zeros(weight.shape, dtype=np.int64)
    weight = np.where(np.isfinite(weight) & (weight > 0), weight, 0.0)
    if not weight.any():
        weight = np.ones_like(weight)
    ordered = np.sort(weight)[::-1]
    k = np.arange(1, weight.size + 1)
    lam = (budget + k * already) / np.cumsum(ordered)
    active = np.nonzero(lam * ordered > already)[0]
    lam = lam[active[-1]]
    target = np.maximum(lam * weight - already, 0.0)
    target *= budget / target.sum()                        # exact up to rounding already
    extra = np.floor(target).astype(np.int64)
    remainder = budget - int(extra.sum())
    assert 0 <= remainder <= extra.size
    extra[np.argsort(extra - target, kind="stable")[:remainder]] += 1      # the largest fractions
    return extra
