"""Sample warps and their densities (tracer/sampling.py).

Each warp is checked three ways: (1) its pdf integrates to one, by float64 quadrature of the module's pdf
evaluated through Dr.Jit; (2) the density the warp actually produces, 1 / |Jacobian| computed by Dr.Jit's
forward-mode AD, equals that pdf pointwise; (3) a histogram of 10^6 samples agrees with the pdf integrated
over each bin (Pearson chi-square).

Chi-square tests: under a correct warp the statistic follows chi^2(bins - 1), so a test at significance
1e-3 rejects a correct implementation with probability 1e-3 per test (false-positive rate 0.1%; for the
three warp tests here together at most 0.3%). The samples come from a fixed PCG32 seed, so the outcome is
deterministic: a failure means the histogram changed, not bad luck on this run.

The uniform inputs come from NumPy's PCG64, not from Dr.Jit's PCG32: the chi-square test needs independent
samples, and PCG32 lanes seeded with one state and consecutive stream ids (PCG32(n, seed)) are not
independent of each other -- their first outputs are spread more evenly than chance (a 200-bin histogram
of 10^6 of them gives chi^2 ~ 40 for 199 degrees of freedom), and over many seeds the hemisphere tests'
p-values come out far from uniform. With PCG64 inputs they are uniform (checked over 100 seeds).
"""
import importlib

import drjit as dr
import numpy as np
import pytest
from scipy import stats

from tracer import sampling
from tracer.jit import BACKEND, Array3f, Float, UInt32
from validation.verdict.protocol import ALPHA   # family-wise false-positive rate of one comparison

U = 2.0 ** -24
N_SAMPLES = 1_000_000
AD = importlib.import_module(f"drjit.{BACKEND}.ad")   # AD-enabled twins of tracer.jit's array types


def uniforms(n: int, seed: int) -> tuple[Float, Float]:
    """Independent uniform float32 pairs in [0, 1) (multiples of 2^-24), as Dr.Jit arrays."""
    rng = np.random.default_rng(seed)
    return Float(rng.random(n, dtype=np.float32)), Float(rng.random(n, dtype=np.float32))


def pdf_np(pdf, cos_theta: np.ndarray) -> np.ndarray:
    """The module's pdf evaluated in Dr.Jit, returned as float64."""
    return pdf(Float(np.asarray(cos_theta, np.float32))).numpy().astype(np.float64)


HEMISPHERE = {
    "cosine": (sampling.square_to_cosine_hemisphere, sampling.cosine_hemisphere_pdf),
    "uniform": (sampling.square_to_uniform_hemisphere, sampling.uniform_hemisphere_pdf),
}


# ---- (1) the pdfs integrate to one --------------------------------------------------------------------
@pytest.mark.parametrize("name", HEMISPHERE)
def test_hemisphere_pdf_integrates_to_one_over_the_sphere(name):
    _, pdf = HEMISPHERE[name]
    # midpoint rule in (cos theta, phi) over the whole sphere (d omega = d cos_theta d phi); the lower
    # half must contribute nothing. The pdfs are piecewise linear in cos theta with the kink on a cell
    # boundary, so the rule is exact and only the float32 rounding of each pdf value (~u) remains.
    k, m = 4000, 64
    mu = -1 + (np.arange(k) + 0.5) * (2 / k)
    phi = (np.arange(m) + 0.5) * (2 * np.pi / m)
    mu_grid, _ = np.meshgrid(mu, phi, indexing="ij")
    values = pdf_np(pdf, mu_grid.ravel()).reshape(k, m)
    cell = (2 / k) * (2 * np.pi / m)
    total = values.sum() * cell
    upper = values[mu > 0].sum() * cell
    assert total == pytest.approx(1.0, abs=8 * U)
    assert upper == pytest.approx(1.0, abs=8 * U)
    assert np.all(values[mu < 0] == 0) and np.all(values >= 0)


def test_pdf_values():
    mu = np.array([-0.5, 0.0, 0.25, 1.0])
    assert np.allclose(pdf_np(sampling.cosine_hemisphere_pdf, mu), [0, 0, 0.25 / np.pi, 1 / np.pi], rtol=2 * U)
    assert np.allclose(pdf_np(sampling.uniform_hemisphere_pdf, mu), [0, 0, 0.5 / np.pi, 0.5 / np.pi], rtol=2 * U)


# ---- (2) the density each warp produces is its pdf ----------------------------------------------------
def _jacobian_columns(warp, u1: np.ndarray, u2: np.ndarray, monkeypatch):
    """d warp / d u1 and d warp / d u2 by forward-mode AD, each a list of NumPy components."""
    monkeypatch.setattr(sampling, "Array3f", AD.Array3f)    # let the warp build an AD-tracked vector
    cols = []
    for which in (0, 1):
        a, b = AD.Float(u1.astype(np.float32)), AD.Float(u2.astype(np.float32))
        x = (a, b)[which]
        dr.enable_grad(x)
        out = warp(a, b)
        dr.forward_from(x, flags=dr.ADFlag.ClearEdges)   # keep the grad of x itself (z = u1)
        cols.append(np.stack([dr.grad(c).numpy().astype(np.float64) for c in out]))
        values = np.stack([dr.detach(c).numpy().astype(np.float64) for c in out])
    return cols, values


# The Jacobian's entries are a handful of float32 operations on O(1) values (a few u relative each);
# the cross product of the two nearly orthogonal columns and its norm add a few more. 32u covers it.
JAC_RTOL = 32 * U


@pytest.mark.parametrize("name", HEMISPHERE)
def test_hemisphere_warp_density_equals_pdf(name, monkeypatch):
    warp, pdf = HEMISPHERE[name]
    g = np.linspace(0.01, 0.99, 60)                    # stay off the square's edges (infinite Jacobian)
    u1, u2 = (a.ravel() for a in np.meshgrid(g, g))
    (j1, j2), w = _jacobian_columns(warp, u1, u2, monkeypatch)
    solid_angle_per_area = np.linalg.norm(np.cross(j1.T, j2.T), axis=1)
    density = 1 / solid_angle_per_area
    assert np.allclose(density, pdf_np(pdf, w[2]), rtol=JAC_RTOL, atol=0)


def test_triangle_warp_is_area_preserving(monkeypatch):
    g = np.linspace(0.01, 0.99, 60)
    u1, u2 = (a.ravel() for a in np.meshgrid(g, g))
    (j1, j2), b = _jacobian_columns(sampling.square_to_uniform_triangle, u1, u2, monkeypatch)
    det = np.abs(j1[0] * j2[1] - j1[1] * j2[0])
    # |det J| = 1/2, the area of the barycentric triangle, everywhere: the density the warp produces,
    # 1 / |det J| = 2, is the uniform pdf 1 / area, which integrates to one over the triangle (that the
    # samples land inside it is checked below)
    assert np.allclose(det, 0.5, rtol=JAC_RTOL, atol=0)
    u1, u2 = (np.float32(x).astype(np.float64) for x in (u1, u2))
    assert np.allclose(b[0], u2 * np.sqrt(u1), rtol=0, atol=4 * U)      # b1 = u2 sqrt(u1)
    assert np.allclose(b[1], 1 - np.sqrt(u1), rtol=0, atol=4 * U)       # b2 = 1 - sqrt(u1)


# ---- samples lie in the domain ------------------------------------------------------------------------
@pytest.mark.parametrize("name", HEMISPHERE)
def test_hemisphere_samples_unit_and_upper(name):
    warp, _ = HEMISPHERE[name]
    u1, u2 = uniforms(200_000, 1)
    u1 = dr.concat((u1, Float([0.0, 1.0 - 2 ** -24, 0.5])))
    u2 = dr.concat((u2, Float([0.0, 1.0 - 2 ** -24, 0.5])))
    w = warp(u1, u2).numpy().astype(np.float64)
    # sin/cos (a few ulp each) times r, squared and summed: |w|^2 is 1 to within ~8u, |w| to ~4u
    assert np.all(np.abs(np.linalg.norm(w, axis=0) - 1) <= 8 * U)
    assert np.all(w[2] >= 0) and np.all(np.isfinite(w))


def test_triangle_samples_inside():
    u1, u2 = uniforms(200_000, 2)
    u1 = dr.concat((u1, Float([0.0, 1.0 - 2 ** -24, 0.0, 1.0 - 2 ** -24])))
    u2 = dr.concat((u2, Float([0.0, 1.0 - 2 ** -24, 1.0 - 2 ** -24, 0.0])))
    b1, b2 = (x.numpy().astype(np.float64) for x in sampling.square_to_uniform_triangle(u1, u2))
    assert np.all(b1 >= 0) and np.all(b2 >= 0)
    assert np.all(b1 + b2 <= 1 + 2 * U)               # one rounding in b1 + b2


# ---- (3) chi-square tests -----------------------------------------------------------------------------
K_MU, K_PHI = 10, 20


def hemisphere_histogram(w: np.ndarray) -> np.ndarray:
    mu = w[2]
    phi = np.mod(np.arctan2(w[1], w[0]), 2 * np.pi)
    h, _, _ = np.histogram2d(np.clip(mu, 0, 1), phi, bins=[K_MU, K_PHI], range=[[0, 1], [0, 2 * np.pi]])
    return h.ravel()


def hemisphere_bin_probabilities(pdf) -> np.ndarray:
    """The pdf integrated over each (cos theta, phi) bin: 8-point Gauss-Legendre in each variable
    (exact for pdfs polynomial in cos theta of degree < 16), pdf values from the module in Dr.Jit."""
    x, wt = np.polynomial.legendre.leggauss(8)
    mu_edges = np.linspace(0, 1, K_MU + 1)
    phi_edges = np.linspace(0, 2 * np.pi, K_PHI + 1)
    p = np.zeros((K_MU, K_PHI))
    for i in range(K_MU):
        a, b = mu_edges[i], mu_edges[i + 1]
        mu = (a + b) / 2 + (b - a) / 2 * x
        for j in range(K_PHI):
            c, d = phi_edges[j], phi_edges[j + 1]
            # the pdf does not depend on phi, but integrate over it anyway: the pdf is a density in
            # solid angle, d omega = d cos_theta d phi
            mu_g, _ = np.meshgrid(mu, (c + d) / 2 + (d - c) / 2 * x, indexing="ij")
            vals = pdf_np(pdf, mu_g.ravel()).reshape(8, 8)
            p[i, j] = (b - a) / 2 * (d - c) / 2 * (wt[:, None] * wt[None, :] * vals).sum()
    return p.ravel()


def chi2_pvalue(observed: np.ndarray, probabilities: np.ndarray) -> float:
    assert np.all(probabilities > 0)
    assert np.min(probabilities) * observed.sum() >= 5          # chi-square approximation holds
    expected = probabilities / probabilities.sum() * observed.sum()
    return stats.chisquare(observed, expected).pvalue


_PROB_CACHE: dict = {}


def _probabilities(pdf):
    if pdf not in _PROB_CACHE:
        _PROB_CACHE[pdf] = hemisphere_bin_probabilities(pdf)
    return _PROB_CACHE[pdf]


@pytest.mark.parametrize("name,seed", [("cosine", 11), ("uniform", 12)])
def test_hemisphere_chi_square(name, seed):
    warp, pdf = HEMISPHERE[name]
    w = warp(*uniforms(N_SAMPLES, seed)).numpy().astype(np.float64)
    p = _probabilities(pdf)
    assert p.sum() == pytest.approx(1.0, abs=1e-6)             # bins cover the whole hemisphere
    assert chi2_pvalue(hemisphere_histogram(w), p) > ALPHA


K_TRI = 20


def triangle_histogram(b1: np.ndarray, b2: np.ndarray):
    """Counts in the (b1, b2) grid cells that meet the triangle, the exact probability of each cell
    under the uniform density 2 (full cells h^2, cells cut by the diagonal h^2 / 2), and how many
    samples fell in cells outside the triangle."""
    h, _, _ = np.histogram2d(b1, b2, bins=K_TRI, range=[[0, 1], [0, 1]])
    i, j = np.meshgrid(np.arange(K_TRI), np.arange(K_TRI), indexing="ij")
    area = np.where(i + j <= K_TRI - 2, 1.0, np.where(i + j == K_TRI - 1, 0.5, 0.0)) / K_TRI ** 2
    inside = area > 0
    return h[inside], 2.0 * area[inside], h[~inside].sum()


def test_triangle_chi_square():
    b1, b2 = (x.numpy().astype(np.float64) for x in sampling.square_to_uniform_triangle(*uniforms(N_SAMPLES, 13)))
    counts, p, outside = triangle_histogram(b1, b2)
    assert outside == 0
    assert p.sum() == pytest.approx(1.0, abs=1e-12)
    assert chi2_pvalue(counts, p) > ALPHA


# ---- the chi-square test has power: it rejects wrong pdfs and wrong warps ------------------------------
def test_chi_square_rejects_cosine_samples_against_uniform_pdf():
    w = sampling.square_to_cosine_hemisphere(*uniforms(N_SAMPLES, 11)).numpy().astype(np.float64)
    assert chi2_pvalue(hemisphere_histogram(w), _probabilities(sampling.uniform_hemisphere_pdf)) < ALPHA


def test_chi_square_rejects_uniform_theta_warp():
    # the classic bug the module's docstring warns about: theta (instead of cos theta) drawn uniformly
    u1, u2 = uniforms(N_SAMPLES, 12)
    z = dr.cos(0.5 * dr.pi * u1)
    r = dr.safe_sqrt(1 - z * z)
    w = Array3f(r * dr.cos(dr.two_pi * u2), r * dr.sin(dr.two_pi * u2), z).numpy().astype(np.float64)
    assert chi2_pvalue(hemisphere_histogram(w), _probabilities(sampling.uniform_hemisphere_pdf)) < ALPHA


def test_chi_square_rejects_naive_triangle_warp():
    # (u1, u2 (1 - u1)) lands in the triangle but crowds the b2 = 1 corner
    u1, u2 = (x.numpy().astype(np.float64) for x in uniforms(N_SAMPLES, 13))
    counts, p, outside = triangle_histogram(u1, u2 * (1 - u1))
    assert outside == 0
    assert chi2_pvalue(counts, p) < ALPHA


# ---- coordinate_system --------------------------------------------------------------------------------
def _normals():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(20000, 3))
    special = [[0, 0, -1], [0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0],
               [1e-4, 0, -1], [0, -1e-7, -1], [1e-20, 1e-20, -1], [1, 1, -1e-7], [1, 1, 0], [0.6, 0, -0.8]]
    n = np.vstack([special, n, n * [1, 1, 0] + [0, 0, -1e-3]])   # and a band near the equator
    return np.asarray(n / np.linalg.norm(n, axis=1, keepdims=True), np.float32).astype(np.float64)


def test_coordinate_system_is_orthonormal_and_right_handed():
    n = _normals()
    s, t = sampling.coordinate_system(Array3f(np.ascontiguousarray(n.T.astype(np.float32))))
    s, t = s.numpy().T.astype(np.float64), t.numpy().T.astype(np.float64)
    assert np.all(np.isfinite(s)) and np.all(np.isfinite(t))
    # n itself is a rounded unit vector (|n| - 1 up to ~u); every entry of the frame is a few float32
    # operations on O(1) values (Duff et al. 2017 report errors of a few ulp): allow 16u
    tol = 16 * U
    dot = lambda a, b: np.sum(a * b, axis=1)
    for name, value, want in [("|s|", np.linalg.norm(s, axis=1), 1), ("|t|", np.linalg.norm(t, axis=1), 1),
                              ("s.t", dot(s, t), 0), ("s.n", dot(s, n), 0), ("t.n", dot(t, n), 0),
                              ("(s x t).n", dot(np.cross(s, t), n), 1)]:
        err = np.abs(value - want)
        assert err.max() <= tol, (name, n[np.argmax(err)], err.max() / U)


def test_coordinate_system_south_pole_exactly():
    s, t = sampling.coordinate_system(Array3f(0.0, 0.0, -1.0))
    assert np.allclose(s.numpy().ravel(), [1, 0, 0]) and np.allclose(t.numpy().ravel(), [0, -1, 0])


def test_to_world_maps_local_frame_onto_normal():
    n = _normals()[:2000]
    rng = np.random.default_rng(1)
    local = rng.normal(size=(len(n), 3))
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    nn = Array3f(np.ascontiguousarray(n.T.astype(np.float32)))
    w = sampling.to_world(Array3f(np.ascontiguousarray(local.T.astype(np.float32))), nn).numpy().T
    # an orthonormal change of basis: lengths kept, and the local z component becomes the cosine to n
    assert np.allclose(np.linalg.norm(w, axis=1), 1, atol=32 * U)
    assert np.allclose(np.sum(w * n, axis=1), local[:, 2], atol=32 * U)
    up = sampling.to_world(Array3f(0.0, 0.0, 1.0) + Array3f(0.0) * nn.x, nn).numpy().T
    assert np.allclose(up, n, atol=16 * U)


def test_render_streams_are_independent():
    """Streams of consecutive sample indices must not be correlated: chi-square p-values of their first
    outputs over 30 seeds are uniform (KS test, false-positive rate 1e-3). With a shared PCG32 state and
    sequential stream ids they were not (KS p ~ 3e-11)."""
    from tracer.sampling import seeded_rng
    from tracer.jit import UInt32
    import drjit as dr
    from scipy import stats as st

    pvalues = []
    for seed in range(30):
        x = seeded_rng(dr.arange(UInt32, 20000), seed).next_float32().numpy()
        counts, _ = np.histogram(x, 200, (0, 1))
        pvalues.append(st.chisquare(counts).pvalue)
    assert st.kstest(pvalues, "uniform").pvalue > 1e-3


def _cdfs(rng: np.random.Generator) -> list[np.ndarray]:
    """CDFs of every shape GuidedCDF meets: smooth and peaked (a bright texel among dark ones), with runs of
    zero-probability entries (flat steps), one entry, and one whose last value falls short of 1 (a mesh's
    summed areas, rounded)."""
    peaked = rng.random(300) ** 8
    peaked[[17, 150]] = 500.0
    flat = rng.random(64)
    flat[10:40] = 0.0
    out = [np.cumsum(w) / np.sum(w) for w in (rng.random(1000), peaked, flat, np.ones(1))]
    return out + [np.cumsum(np.full(50, 0.02)) * 0.999]


def _binary_search(cdf: np.ndarray, u: Float) -> np.ndarray:
    """dr.binary_search(0, n - 1, cdf[k] <= u) per lane (an int where the row has one entry)."""
    table = Float(cdf)
    k = dr.binary_search(0, len(cdf) - 1, lambda k: dr.gather(Float, table, k) <= u)
    return np.broadcast_to(k.numpy() if hasattr(k, "numpy") else k, (dr.width(u),))


@pytest.mark.parametrize("case", range(5))
def test_guided_cdf_finds_what_a_binary_search_over_the_row_finds(case):
    """GuidedCDF.search gives the index dr.binary_search(0, n - 1, cdf[k] <= u) gives, for every u, those at
    and next to the CDF's values and its guide buckets' bounds included."""
    rng = np.random.default_rng(case)
    cdf = _cdfs(rng)[case].astype(np.float32)
    guided = sampling.GuidedCDF(cdf)
    edges = np.concatenate([cdf, np.arange(guided.m) / guided.m]).astype(np.float32)
    u = np.concatenate([rng.random(20000), edges, np.nextafter(edges, 0), np.nextafter(edges, 1), [0.0]])
    u = Float(np.clip(u, 0.0, np.nextafter(np.float32(1), 0)).astype(np.float32))
    assert np.array_equal(guided.search(u).numpy(), _binary_search(cdf, u))


def test_guided_cdf_rows_are_searched_apart():
    """Rows of a 2-D table: each lane searches its own row, as a binary search over that row alone would."""
    rng = np.random.default_rng(7)
    rows = np.stack([np.cumsum(w) / np.sum(w) for w in rng.random((6, 40)) ** 4]).astype(np.float32)
    guided = sampling.GuidedCDF(rows)
    row = rng.integers(0, 6, 5000)
    u = rng.random(5000).astype(np.float32)
    expected = [np.minimum(np.searchsorted(rows[r], x, side="right"), 39) for r, x in zip(row, u)]
    got = guided.search(Float(u), UInt32(row)).numpy()
    assert np.array_equal(got, expected)


def test_guided_cdf_search_fails_with_a_step_short():
    """The test above can fail: with one step fewer than the widest bucket needs, some index is wrong."""
    rng = np.random.default_rng(3)
    cdf = _cdfs(rng)[1].astype(np.float32)
    guided = sampling.GuidedCDF(cdf)
    assert guided.steps > 1
    guided.steps -= 1
    u = Float(rng.random(200000).astype(np.float32))
    assert not np.array_equal(guided.search(u).numpy(), _binary_search(cdf, u))


def test_guided_cdf_with_fewer_buckets_than_entries(monkeypatch):
    """Past GUIDE_MAX buckets (a mesh of millions of emitting triangles) a bucket holds several entries; the
    search still finds the binary search's index."""
    monkeypatch.setattr(sampling, "GUIDE_MAX", 16)
    rng = np.random.default_rng(11)
    cdf = _cdfs(rng)[0].astype(np.float32)
    guided = sampling.GuidedCDF(cdf)
    assert guided.m == 16 and guided.steps > 5
    u = Float(np.concatenate([rng.random(50000), cdf[:-1]]).astype(np.float32))
    assert np.array_equal(guided.search(u).numpy(), _binary_search(cdf, u))
