"""Statistical agreement between two renderers from independent passes of each.

Two tests on the same blocks (the passes averaged over block x block tiles, per channel):

- `compare` — the verdict `validate check` gives (its design and its measured false-alarm rate:
  reports/calibration.md). Welch's t-test per block and channel (Welch 1947; for renderers: Jung,
  Hanika and Dachsbacher, JCGT 9(2), 2020), Bonferroni-corrected, on an equal-budget design: both sides
  have the same passes and samples per pass, so the skew of the two pass means cancels in their
  difference; the image means per channel are tested beside the blocks. Differences below
  FLOAT_RESOLUTION of a block's mean (float32 round-off) are not resolved. A block whose passes hold an
  outlier on either side (Grubbs' test, Grubbs 1950), whose mean rests on fewer than MIN_NONZERO non-black
  passes, or whose passes on one side take fewer than MIN_DISTINCT values while the other side's vary (a
  count of rare events: the camera rays of a pass that see a small lit region) is decided by a few rare
  samples; the normal approximation is not trusted there, and a rejection there makes the verdict
  `inconclusive`, never `disagree`. Every comparison states its detectable bias (`detectable_bias`: the
  bias its test finds with probability POWER), and with a `Margin` it tests equivalence (`tost`):
  `equivalent`, `disagree` or `inconclusive`.
- `welch_test` — the earlier test, kept for the calibration report's comparison: the same Welch test
  against any reference, with a `resolution` floor (a difference below `resolution` times the reference's
  mean radiance is never rejected).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import special

GRUBBS_ALPHA = 0.01   # level of the per-side outlier test that marks a block as untrusted
MIN_NONZERO = 4       # a block's mean must rest on at least this many non-black passes of each side
MIN_DISTINCT = 4      # and on at least this many distinct pass values, where the other side's vary
FLOAT_RESOLUTION = 1e-5   # relative differences below this (about 100 float32 steps) are not resolved
POWER = 0.8               # the power at which a check states the bias it would have detected
VERDICTS = ("agree", "equivalent", "disagree", "inconclusive")


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
    if len(xa) < 2 or len(xb) < 2:
        raise ValueError("Welch's test needs at least two passes of each renderer")
    t, p = _welch(xa, xb)
    diff = xa.mean(0) - xb.mean(0)
    n = p.size
    resolvable = np.abs(diff) > resolution * float(b.mean())
    rejected = int(((p < alpha / n) & resolvable).sum())
    worst = np.unravel_index(int(np.argmin(p)), p.shape)
    return AgreementTest(rejected == 0, alpha, n, rejected, float(p.min()), tuple(int(i) for i in worst),
                         float(t[worst]))


@dataclass(frozen=True)
class Margin:
    """An equivalence margin (GUIDE: TOST): `image`, a fraction of the reference's image mean, per channel;
    `block`, a fraction of a block's reference mean, or of the image mean where the block is darker (so
    that a dark block is held to an absolute tolerance, not to a fraction of almost nothing)."""
    image: float
    block: float

    def __post_init__(self):
        for name in ("image", "block"):
            value = getattr(self, name)
            if not 0 < value < 1:
                raise ValueError(f"the {name} margin must lie strictly between 0 and 100%, got {value:.4g}")


@dataclass
class Comparison:
    """The outcome of `compare`: a verdict and the numbers behind it."""
    verdict: str                  # agree | disagree | inconclusive; with a margin: equivalent | disagree | inconclusive
    alpha: float                  # family-wise false-positive rate
    tests: int                    # blocks x channels
    rejected: int                 # rejected tests (blocks and image means) whose normal approximation is trusted
    untrusted_rejected: int       # rejected tests decided by a few rare samples
    untrusted: int                # blocks decided by a few rare samples (rejected or not)
    min_p: float                  # smallest p-value over all blocks
    worst_block: tuple[int, int, int]   # (block row, block column, channel) of min_p
    worst_t: float
    mean_test: float              # image means of the two sides
    mean_reference: float
    detectable_image: np.ndarray = field(repr=False)   # (3,) bias of the image mean detected with POWER, relative
    detectable_block: float = float("nan")             # median over lit blocks and channels of the same, relative
    margin: Margin | None = None
    equivalent_image: np.ndarray | None = field(default=None, repr=False)   # (3,) TOST passed
    equivalent_map: np.ndarray | None = field(default=None, repr=False)     # (rows, columns, 3) TOST passed
    needed: float = float("nan")  # factor on the samples per pass at which the TOSTs would pass with POWER if the
    #                               measured differences were true (inf: one lies at or beyond its margin)
    needed_unbiased: float = float("nan")   # the same for an unbiased renderer (every difference 0)
    p: np.ndarray = field(default=None, repr=False)          # (rows, columns, 3) p-values
    rejected_map: np.ndarray = field(default=None, repr=False)   # (rows, columns, 3) bool
    trusted: np.ndarray = field(default=None, repr=False)        # (rows, columns, 3) bool
    p_image: np.ndarray = field(default=None, repr=False)        # (3,) p-values of the image means
    image_rejected: np.ndarray = field(default=None, repr=False)   # (3,) bool

    @property
    def relative_mean_difference(self) -> float:
        scale = abs(self.mean_reference)
        return (self.mean_test - self.mean_reference) / scale if scale > 0 else (0.0 if self.mean_test == 0
                                                                                   else float("inf"))

    def detectable(self) -> str:
        """The bias this comparison would have detected with POWER, as the verdict line states it."""
        rgb = "/".join(_percent(x) for x in self.detectable_image)
        return f"detectable bias ({POWER:.0%} power): image mean {rgb} (RGB), median block {_percent(self.detectable_block)}"

    def summary(self) -> str:
        r, c, ch = self.worst_block
        within = (f"; within +-{_percent(self.margin.image)} (blocks +-{_percent(self.margin.block)}): "
                  f"{int(self.equivalent_image.sum())}/3 image means, {int(self.equivalent_map.sum())}/{self.tests} "
                  "blocks" if self.margin else "")
        return (f"{self.verdict}: {self.rejected}/{self.tests + 3} tests rejected"
                f"{f' (+{self.untrusted_rejected} decided by rare samples)' if self.untrusted_rejected else ''}"
                f" at family-wise alpha {self.alpha:g}; worst block ({r}, {c}) {'RGB'[ch]} p = {self.min_p:.3g}, "
                f"t = {self.worst_t:.2f}; image mean {self.relative_mean_difference:+.2%} vs reference; "
                f"{self.detectable()}{within}")


def _percent(x: float) -> str:
    return "inf" if not np.isfinite(x) else f"{100 * x:.2g}%" if x < 0.1 else f"{100 * x:.0f}%"


def _t_sf(x, df):
    """Student's t survival function, from scipy.special (scipy.stats takes about a second to import, most of
    a refused check's time)."""
    return special.stdtr(df, -x)


def _t_isf(q, df):
    """Student's t inverse survival function (see _t_sf)."""
    return -special.stdtrit(df, q)


def grubbs_critical(k: int, alpha: float = GRUBBS_ALPHA) -> float:
    """Two-sided critical value of Grubbs' outlier statistic max|x - mean| / s for k normal samples."""
    t = _t_isf(alpha / (2 * k), k - 2)
    return (k - 1) / np.sqrt(k) * np.sqrt(t * t / (k - 2 + t * t))


def rare_sample_blocks(x: np.ndarray) -> np.ndarray:
    """(K, ...) pass means -> bool (...): blocks whose mean a few passes decide (an outlier pass, or
    fewer than MIN_NONZERO non-black passes in a block that is not black)."""
    k = len(x)
    s = x.std(0, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(s > 0, np.abs(x - x.mean(0)).max(0) / s, 0.0)
    return (g > grubbs_critical(k)) | sparse_blocks(x)


def sparse_blocks(x: np.ndarray) -> np.ndarray:
    """(K, ...) pass means -> bool (...): blocks lit in fewer than MIN_NONZERO passes (but in some)."""
    nonzero = (x != 0).sum(0)
    return (nonzero > 0) & (nonzero < MIN_NONZERO)


def counted_blocks(x: np.ndarray, other: np.ndarray) -> np.ndarray:
    """(K, ...) pass means of one side and the other's -> bool (...): blocks where x's passes take fewer
    than MIN_DISTINCT values while the other's vary by more than FLOAT_RESOLUTION (two constant sides, as an
    emitter seen directly, are compared as they are)."""
    ordered = np.sort(x, axis=0)
    distinct = 1 + (ordered[1:] != ordered[:-1]).sum(0)
    varies = other.max(0) - other.min(0) > FLOAT_RESOLUTION * np.abs(other).max(0)
    return (distinct < MIN_DISTINCT) & varies


def _moments(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, ...]:
    """Means of (K, ...) samples `a` and `b`, the standard error of their difference and its
    Welch-Satterthwaite degrees of freedom (NaN where neither side varies), elementwise."""
    ka, kb = len(a), len(b)
    ma, mb = a.mean(0), b.mean(0)
    va, vb = a.var(0, ddof=1) / ka, b.var(0, ddof=1) / kb
    se2 = va + vb
    with np.errstate(divide="ignore", invalid="ignore"):   # in shares of se2: squares of tiny variances underflow
        df = 1 / ((va / se2) ** 2 / (ka - 1) + (vb / se2) ** 2 / (kb - 1))
    return ma, mb, np.sqrt(se2), df


def _welch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Welch's t and two-sided p of (K, ...) samples `a` against `b`, elementwise; elements without
    variance on either side get p = 1 if the means are equal, else p = 0."""
    ma, mb, se, df = _moments(a, b)
    diff = ma - mb
    with np.errstate(divide="ignore", invalid="ignore"):
        t = diff / se
        p = 2 * _t_sf(np.abs(t), df)
    exact = se == 0
    equal = resolved(diff, ma, mb) == 0
    return np.where(exact, np.where(equal, 0.0, np.inf), t), np.where(exact, np.where(equal, 1.0, 0.0), p)


def detectable_bias(se: np.ndarray, df: np.ndarray, level: float) -> np.ndarray:
    """The smallest difference a two-sided Welch test at `level` detects with probability POWER:
    (t_{1 - level/2} + t_{POWER}) x the standard error of the difference (the normal approximation of the
    power of a t-test, e.g. Cohen 1988, ch. 2; GUIDE section 7), on the Welch degrees of freedom; 0 where
    neither side varies."""
    with np.errstate(invalid="ignore"):
        q = _t_isf(level / 2, df) + _t_isf(1 - POWER, df)
    return np.where(se > 0, q * se, 0.0)


def tost(diff: np.ndarray, se: np.ndarray, df: np.ndarray, delta: np.ndarray, level: float,
         exact: np.ndarray) -> np.ndarray:
    """Two one-sided tests (Schuirmann 1987): where both "difference <= -delta" and "difference >= delta" are
    rejected at `level`, i.e. |diff| + t_{1 - level} se < delta. Where neither side varies, `exact` (the
    difference is below float resolution) or |diff| < delta decides."""
    with np.errstate(invalid="ignore"):
        bound = np.abs(diff) + _t_isf(level, df) * se
    return np.where(se > 0, bound < delta, exact | (np.abs(diff) < delta))


def spp_factor(diff: np.ndarray, se: np.ndarray, df: np.ndarray, delta: np.ndarray, level: float,
               power: float = POWER) -> float:
    """The smallest factor on the samples per pass at which TOSTs at `level` (`tost`) all pass with
    probability at least `power`, if the true differences were `diff` (0: an unbiased renderer) and the
    standard errors fell as 1/sqrt(samples) from `se`: the TOST's bound |D| + t se < delta inverted for the
    margin, as the detectable bias inverts the test of difference for its bias (GUIDE section 7). The
    probability that some TOST fails is bounded by the sum of each one's (Bonferroni), each taken with D
    normal about `diff`: P(|D| >= delta - t se). Solved by bisection on the factor; inf where a difference lies
    at or beyond its margin; tests without variance (`se` 0) are decided exactly and do not count."""
    varies = se > 0
    if not varies.any():
        return 1.0
    d, s, m = np.abs(diff[varies]), se[varies], delta[varies]
    if (d >= m).any():
        return float("inf")
    with np.errstate(invalid="ignore"):
        q = np.nan_to_num(_t_isf(level, df[varies]), nan=-special.ndtri(level))

    def failing(factor: float) -> float:    # Bonferroni bound on P(some TOST fails) at factor x the samples
        s_f = s / np.sqrt(factor)
        room = m - q * s_f
        p = special.ndtr((d - room) / s_f) + special.ndtr((-d - room) / s_f)
        return float(np.where(room > 0, p, 1.0).sum())

    lo, hi = -30.0, 60.0             # log2 of the factor
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if failing(2 ** mid) <= 1 - power else (mid, hi)
    return float(2 ** hi)


def resolved(diff: np.ndarray, ma: np.ndarray, mb: np.ndarray) -> np.ndarray:
    """Whether a difference of means exceeds FLOAT_RESOLUTION of the larger: below, two renderers' float32
    arithmetic (texture lookups, summation orders) differs, not their estimates (a constant sky seen
    directly has no variance, and a difference of 5e-7 would otherwise be rejected)."""
    return np.abs(diff) > FLOAT_RESOLUTION * np.maximum(np.abs(ma), np.abs(mb))


def compare(a: np.ndarray, b: np.ndarray, alpha: float, margin: Margin | None = None) -> Comparison:
    """Do block pass means `a` (K, rows, columns, 3), the renderer under test, and `b`, the reference,
    estimate the same image? See the module's docstring.

    Half of `alpha` goes to the blocks (Bonferroni over blocks and channels), half to the image means per
    channel (a bias spread over the whole image, too small for any one block, shows there). With a `margin`,
    the verdict is `equivalent` where the TOST passes at `alpha` on every image mean and every trusted
    block: an intersection-union test, whose false-equivalence rate is at most `alpha` without any
    correction for the number of tests (Berger 1982)."""
    if len(a) < 3 or len(b) < 3:
        raise ValueError("the comparison needs at least three passes of each renderer")
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    t, p = _welch(a, b)
    ma, mb, se, df = _moments(a, b)
    block_level, image_level = alpha / 2 / p.size, alpha / 6
    rejected = (p < block_level) & resolved(ma - mb, ma, mb)
    trusted = ~(rare_sample_blocks(a) | rare_sample_blocks(b) | counted_blocks(a, b) | counted_blocks(b, a))
    ga, gb = a.mean((1, 2)), b.mean((1, 2))          # (K, 3) image means of each pass
    _, p_image = _welch(ga, gb)
    gma, gmb, gse, gdf = _moments(ga, gb)
    image_rejected = (p_image < image_level) & resolved(gma - gmb, gma, gmb)
    image_trusted = ~(rare_sample_blocks(ga) | rare_sample_blocks(gb) | counted_blocks(ga, gb) | counted_blocks(gb, ga))
    n_trusted = int((rejected & trusted).sum() + (image_rejected & image_trusted).sum())
    n_untrusted = int((rejected & ~trusted).sum() + (image_rejected & ~image_trusted).sum())
    verdict = "disagree" if n_trusted else "inconclusive" if n_untrusted else "agree"
    block_scale = np.maximum(np.abs(mb), np.abs(gmb))     # a block's mean, or the image mean where darker
    detectable_image = _relative(detectable_bias(gse, gdf, image_level), np.abs(gmb))
    lit = (a != 0).any(0) | (b != 0).any(0)          # blocks black on both sides tell nothing
    detectable_block = float(np.median(_relative(detectable_bias(se, df, block_level), block_scale)[lit])) \
        if lit.any() else 0.0
    worst = np.unravel_index(int(np.argmin(p)), p.shape)
    result = Comparison(verdict, alpha, p.size, n_trusted, n_untrusted, int((~trusted).sum()), float(p.min()),
                        tuple(int(i) for i in worst), float(t[worst]), float(a.mean()), float(b.mean()),
                        detectable_image, detectable_block, margin, p=p,
                        rejected_map=rejected, trusted=trusted, p_image=p_image, image_rejected=image_rejected)
    if margin is not None:   # a block lit in a few passes, or counted, cannot be shown equivalent
        image_decidable, decidable = (~(sparse_blocks(x) | sparse_blocks(y) | counted_blocks(x, y) | counted_blocks(y, x))
                                      for x, y in ((ga, gb), (a, b)))
        _equivalence(result, (gma - gmb, gse, gdf, margin.image * np.abs(gmb), image_decidable, resolved(gma - gmb, gma, gmb)),
                     (ma - mb, se, df, margin.block * block_scale, decidable, resolved(ma - mb, ma, mb)))
    return result


def _relative(x: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """x / scale, 0 where x is 0, inf where only the scale is."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(x == 0, 0.0, np.where(scale > 0, x / scale, np.inf))


def _equivalence(c: Comparison, image: tuple, blocks: tuple) -> None:
    """Sets c's TOST results, the samples per pass that would decide it (`needed`: if the measured differences
    were the true ones; `needed_unbiased`: for an unbiased renderer; both at c.alpha with POWER, over the tests
    that can be decided), and the verdict with a margin: equivalent (every image mean and every block within its
    margin), else disagree (a difference detected), else inconclusive."""
    passed = []
    for diff, se, df, delta, decidable, differs in (image, blocks):
        passed.append(tost(diff, se, df, delta, c.alpha, ~differs) & decidable)
    c.equivalent_image, c.equivalent_map = passed
    diff, se, df, delta = (np.concatenate([g[i][g[4]] for g in (image, blocks)]) for i in range(4))
    c.needed = spp_factor(diff, se, df, delta, c.alpha)
    c.needed_unbiased = spp_factor(np.zeros_like(diff), se, df, delta, c.alpha)
    if c.equivalent_image.all() and c.equivalent_map.all():
        c.verdict = "equivalent"
    elif c.verdict == "agree":
        c.verdict = "inconclusive"


def compare_passes(a: np.ndarray, b: np.ndarray, alpha: float, block: int = 4,
                   margin: Margin | None = None) -> Comparison:
    """`compare` on (K, H, W, 3) passes, averaged over block x block tiles first."""
    return compare(block_means(a, block), block_means(b, block), alpha, margin)
