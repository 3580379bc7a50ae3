"""Warps from the unit square to the domains the estimators sample, with their densities, and the inversion
of tabulated CDFs."""
import drjit as dr
import numpy as np

from .jit import HOST_FLOAT, PCG32, Array3f, Float, UInt32, UInt64

INV_PI = 1.0 / dr.pi
GUIDE_DENSITY = 8    # guide-table entries per CDF entry (GuidedCDF)
GUIDE_MAX = 1 << 22  # at most: u * m then rounds (float32) by under a quarter of an entry's bucket


def square_to_cosine_hemisphere(u1: Float, u2: Float) -> Array3f:
    """Cosine-weighted direction about +z (Malley's method); density cos(theta) / pi."""
    r, phi = dr.sqrt(u1), dr.two_pi * u2
    s, c = dr.sincos(phi)
    return Array3f(r * c, r * s, dr.safe_sqrt(1.0 - u1))


def cosine_hemisphere_pdf(cos_theta: Float) -> Float:
    return dr.maximum(cos_theta, 0.0) * INV_PI


def square_to_uniform_hemisphere(u1: Float, u2: Float) -> Array3f:
    """Uniform direction about +z; density 1 / (2 pi).

    The report's eq. 11 maps spherical angles to x, y, z; drawing cos(theta) (not theta) uniformly is
    what makes the directions uniform in solid angle.
    """
    z = u1
    r = dr.safe_sqrt(1.0 - z * z)
    s, c = dr.sincos(dr.two_pi * u2)
    return Array3f(r * c, r * s, z)


def square_to_uniform_sphere(u1: Float, u2: Float) -> Array3f:
    """Uniform direction on the unit sphere; density 1 / (4 pi)."""
    z = 1.0 - 2.0 * u1
    r = dr.safe_sqrt(1.0 - z * z)
    s, c = dr.sincos(dr.two_pi * u2)
    return Array3f(r * c, r * s, z)


def square_to_uniform_disk_concentric(u1: Float, u2: Float) -> tuple[Float, Float]:
    """Shirley and Chiu's concentric map of [0,1)^2 onto the unit disk: uniform in area."""
    a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    first = dr.abs(a) > dr.abs(b)
    r = dr.select(first, a, b)
    phi = dr.select(first, (dr.pi / 4) * (b / a), (dr.pi / 2) - (dr.pi / 4) * (a / b))
    phi = dr.select((a == 0) & (b == 0), 0.0, phi)
    s, c = dr.sincos(phi)
    return r * c, r * s


def uniform_hemisphere_pdf(cos_theta: Float) -> Float:
    return dr.select(cos_theta > 0, 1.0 / dr.two_pi, 0.0)


def square_to_uniform_triangle(u1: Float, u2: Float) -> tuple[Float, Float]:
    """Barycentric coordinates (b1, b2) of a point uniform in area on a triangle."""
    su = dr.sqrt(u1)
    return u2 * su, 1.0 - su


def coordinate_system(n: Array3f) -> tuple[Array3f, Array3f]:
    """Two unit tangents completing n to an orthonormal frame (Duff et al. 2017)."""
    sign = dr.select(n.z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n.z)
    b = n.x * n.y * a
    return (Array3f(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
            Array3f(b, sign + n.y * n.y * a, -n.y))


def to_world(local: Array3f, n: Array3f) -> Array3f:
    s, t = coordinate_system(n)
    return s * local.x + t * local.y + n * local.z


def tea(v0: UInt32, v1: UInt32, rounds: int = 4) -> tuple[UInt32, UInt32]:
    """The tiny encryption algorithm as a hash (Zafar et al. 2010): decorrelates sequential seeds."""
    s = 0
    for _ in range(rounds):
        s = (s + 0x9E3779B9) & 0xFFFFFFFF
        v0 = v0 + (((v1 << 4) + 0xA341316C) ^ (v1 + s) ^ ((v1 >> 5) + 0xC8013EA4))
        v1 = v1 + (((v0 << 4) + 0xAD90777D) ^ (v0 + s) ^ ((v0 >> 5) + 0x7E95761E))
    return v0, v1


def seeded_rng(index: UInt32, seed: int) -> PCG32:
    """One independent PCG32 stream per index: the initial state is TEA(seed, index), as Mitsuba's
    independent sampler does; consecutive indices with one fixed state would give correlated streams."""
    key = dr.opaque(UInt32, seed % 2**32)
    v0, v1 = tea(key, index)
    state = UInt64(v0) | (UInt64(v1) << 32)
    return PCG32(dr.width(index), state, UInt64(index))


def square_to_cosine_hemisphere_concentric(u1: Float, u2: Float) -> Array3f:
    """Mitsuba's cosine-weighted warp: the concentric disk lifted to the hemisphere (density cos(theta) / pi)."""
    x, y = square_to_uniform_disk_concentric(u1, u2)
    return Array3f(x, y, dr.safe_sqrt(1.0 - x * x - y * y))


class GuidedCDF:
    """Rows of n non-decreasing CDF values, inverted with a guide table per row (Chen and Asau, "On
    generating random variates from an empirical distribution", AIIE Transactions 6(2), 1974): entry i of a
    row's table counts its CDF values at most i / m (m = GUIDE_DENSITY * n, at most GUIDE_MAX). A float u
    in [0, 1) lies within a step of bucket b = floor(u m), so the index sought lies between the entries at
    b - 1 and b + 2, and a binary search there takes as many steps as the widest such interval needs
    (`steps`, unrolled), never more than one over the whole row. On mitsuba-data's museum.exr (512 x 256)
    an environment map's sample (its row, then its column) takes 5 steps a search against 9 and 10: 37
    against 45 ns a sample, one thread; a loop of each lane's own steps took 31 ns there but cost the
    bounce kernels around it more. The tables take 4 * GUIDE_DENSITY bytes per CDF value."""

    def __init__(self, cdf: np.ndarray):
        """cdf: (n,) or (rows, n), rounded to Float's precision."""
        held = np.atleast_2d(np.asarray(cdf, HOST_FLOAT))
        self.cdf = Float(held.ravel())
        self.n, self.m = held.shape[1], min(GUIDE_DENSITY * held.shape[1], GUIDE_MAX)
        bounds = np.arange(self.m + 1) / self.m
        guide, widest = np.empty((len(held), self.m + 1), np.uint32), 1
        for row, out in zip(held, guide):      # a row at a time: searchsorted's int64 counts stay small
            count = np.searchsorted(row.astype(np.float64), bounds, side="right")
            widest = max(widest, int(np.max(np.minimum(count[3:], self.n - 1) - count[:-3])))
            out[:] = count
        self.guide = UInt32(guide.ravel())
        self.steps = widest.bit_length()       # a search's interval [lo, hi]: hi - lo <= widest

    def search(self, u: Float, row: UInt32 | int = 0) -> UInt32:
        """In each lane's row, the first index k with cdf[k] > u, or n - 1 if none: what dr.binary_search(0,
        n - 1, cdf[k] <= u) returns."""
        base, at = row * self.n, row * (self.m + 1)
        b = dr.minimum(UInt32(u * self.m), self.m - 1)
        lo = dr.gather(UInt32, self.guide, at + dr.maximum(b, 1) - 1)
        hi = dr.minimum(dr.gather(UInt32, self.guide, at + dr.minimum(b + 2, self.m)), self.n - 1)

        for _ in range(self.steps):     # unrolled: a loop there cost the kernel around it more
            mid = (lo + hi) >> 1
            below = (dr.gather(Float, self.cdf, base + mid) <= u) & (lo < hi)
            lo, hi = dr.select(below, mid + 1, lo), dr.select(below, hi, mid)
        return lo

    def sample(self, u: Float, row: UInt32 | int = 0) -> tuple[UInt32, Float]:
        """In each lane's row, the index `search` finds and u's place within its interval [cdf[k - 1],
        cdf[k]) (cdf[-1] = 0), in [0, 1): a uniform number again, for the sample's next dimension."""
        k = self.search(u, row)
        base = row * self.n
        lo = dr.select(k > 0, dr.gather(Float, self.cdf, base + k - 1, k > 0), 0.0)
        hi = dr.gather(Float, self.cdf, base + k)
        return k, dr.clip((u - lo) / (hi - lo), 0.0, 1.0 - 2.0 ** -24)
