"""Pearson's chi-square goodness-of-fit test of a direction sampler against the density it claims, as
Mitsuba tests its BSDFs (its `chi2` module; the method, not its code).

Directions are binned on the sphere in (phi, cos theta) cells, which have equal solid angle. The expected
count of a cell is the sample count times the claimed density integrated over the cell (Gauss-Legendre,
`ires` x `ires` nodes per cell). Samples of zero weight are not counted (as in Mitsuba's BSDF adapter), so
the density must integrate to the fraction of samples with nonzero weight. Cells are sorted by expected
count and those below 5 pooled (consecutively, until each pool expects 5 or more) so that the statistic's
chi-square approximation holds; quadrature error, where the density is not smooth, widens a cell's variance; the test also fails outright on a sample in a cell of zero expected count
or a density integrating to more than 1.01.

The p-value is uniform on [0, 1] when the sampler follows the density, so a test at level `alpha` rejects
a correct sampler with probability `alpha` (tests/test_microfacet_chi2.py measures this over seeds)."""
from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import numpy as np
from scipy import stats

from tracer.jit import Array3f, Float, UInt32
from tracer.sampling import seeded_rng

MIN_EXPECTED = 5.0


@dataclass
class Chi2Result:
    p_value: float
    statistic: float
    dof: int
    mass: float                  # the density's integral over the sphere
    valid: float                 # fraction of samples of nonzero weight
    problems: list[str] = field(default_factory=list)

    def passes(self, level: float) -> bool:
        return not self.problems and self.p_value >= level

    def __str__(self):
        text = (f"p = {self.p_value:.3g} (chi2 {self.statistic:.1f}, dof {self.dof}), density mass "
                f"{self.mass:.4f}, nonzero-weight samples {self.valid:.4f}")
        return text + "".join(f"; {p}" for p in self.problems)


def sidak(level: float, tests: int) -> float:
    """Per-test level that keeps the family-wise false-positive rate of `tests` independent tests at `level`."""
    return 1.0 - (1.0 - level) ** (1.0 / tests)


def chi2_sphere(sample, pdf, samples: int = 1_000_000, res: int = 48, ires: int = 8, seed: int = 0) -> Chi2Result:
    """sample(u1, u2, u3) -> (directions, nonzero-weight mask); pdf(directions) -> densities (solid angle).
    The grid has `res` rows in cos theta and 2 res columns in phi."""
    rng = seeded_rng(dr.arange(UInt32, samples), seed)
    wo, valid = sample(*(rng.next_float32() for _ in range(3)))
    w = np.asarray(wo.numpy(), dtype=np.float64).reshape(3, -1)
    keep = np.broadcast_to(np.asarray(valid.numpy(), dtype=bool), (w.shape[1],))
    w = w[:, keep]
    density, error = _integrate(pdf, res, ires, samples)
    expected, mass, problems = samples * density, density.sum(), []
    finite = np.isfinite(w).all(axis=0)
    if not finite.all():
        problems.append(f"{np.sum(~finite)} samples are not finite")
        w = w[:, finite]
    phi = np.arctan2(w[1], w[0])
    col = np.clip(((phi + np.pi) / (2 * np.pi) * 2 * res).astype(int), 0, 2 * res - 1)
    row = np.clip(((w[2] + 1.0) / 2.0 * res).astype(int), 0, res - 1)
    observed = np.bincount(row * 2 * res + col, minlength=2 * res * res).astype(np.float64)
    if mass > 1.01:
        problems.append(f"the density integrates to {mass:.4f} > 1")
    if np.any((expected <= 0) & (observed > 0)):
        problems.append(f"{int(observed[expected <= 0].sum())} samples in cells of zero density")
    statistic, dof = _pooled_statistic(observed, expected, (samples * error) ** 2)
    p = float(stats.chi2.sf(statistic, dof)) if dof >= 1 else 0.0
    if dof < 1:
        problems.append("too few degrees of freedom")
    return Chi2Result(p, statistic, dof, mass, keep.mean(), problems)


def _integrate(pdf, res: int, ires: int, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """The density's integral over each cell (row-major: cos theta rows, phi columns) and an estimate of
    its quadrature error, refined per cell (Gauss-Legendre of order 2 ires, 4 ires, ..., at most 16 ires)
    until two orders agree within 0.05 standard deviations of the cell's count. A cell where the density
    jumps or has an integrable singularity may not get there: its error estimate, the last two orders'
    difference, then widens the cell's variance in the statistic."""
    cells = np.arange(2 * res * res)
    coarse = _integrate_cells(pdf, res, ires, cells)
    result, error = np.zeros_like(coarse), np.zeros_like(coarse)
    n = ires
    while len(cells) and n < 16 * ires:
        fine = _integrate_cells(pdf, res, 2 * n, cells)
        result[cells], error[cells] = fine, np.abs(fine - coarse)
        sigma = np.sqrt(np.maximum(fine * samples, 1.0)) / samples
        rough = error[cells] > 0.05 * sigma
        cells, coarse, n = cells[rough], fine[rough], 2 * n
    return result, error


def _integrate_cells(pdf, res: int, n: int, cells: np.ndarray) -> np.ndarray:
    nodes, weights = np.polynomial.legendre.leggauss(n)
    d_phi, d_z = np.pi / res, 2.0 / res
    row, col = cells // (2 * res), cells % (2 * res)
    t = 0.5 * (nodes + 1.0)
    z = -1.0 + (row[:, None, None] + t[None, :, None]) * d_z                 # (cells, n, 1)
    phi = -np.pi + (col[:, None, None] + t[None, None, :]) * d_phi           # (cells, 1, n)
    z, phi = np.broadcast_arrays(z, phi)
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    d = Array3f(floats(s * np.cos(phi)), floats(s * np.sin(phi)), floats(z))
    values = np.asarray(pdf(d).numpy(), dtype=np.float64).reshape(len(cells), n, n)
    values = np.nan_to_num(values, nan=np.inf)      # a NaN density must not pass unnoticed
    w = weights[:, None] * weights[None, :] * 0.25 * d_phi * d_z
    return np.einsum("cij,ij->c", values, w)


def floats(values: np.ndarray) -> Float:
    """A Float holding `values` (flattened) from a 64-byte aligned copy. Dr.Jit maps a NumPy array's memory and
    compiles a kernel for its alignment: arrays of arbitrary alignment would compile a kernel per call."""
    values = np.asarray(values, dtype=np.float32).ravel()
    buffer = np.empty(values.size + 16, dtype=np.float32)
    start = (-buffer.ctypes.data % 64) // 4
    out = buffer[start:start + values.size]
    out[:] = values
    return Float(out)


def _pooled_statistic(observed: np.ndarray, expected: np.ndarray, quadrature_var: np.ndarray) -> tuple[float, int]:
    """Pearson's statistic sum (o - e)^2 / (e + q) over the cells, q the variance of the expected count's
    quadrature error (negligible but where the density is not smooth), cells expecting fewer than
    MIN_EXPECTED pooled in increasing order; and its degrees of freedom."""
    order = np.argsort(expected)
    statistic, cells, pool = 0.0, 0, np.zeros(3)
    for cell in zip(observed[order], expected[order], quadrature_var[order]):
        if cell[1] <= 0:
            continue
        pool += cell
        if pool[1] >= MIN_EXPECTED:
            statistic, cells, pool = statistic + (pool[0] - pool[1]) ** 2 / (pool[1] + pool[2]), cells + 1, 0 * pool
    if pool[1] > 0:
        statistic, cells = statistic + (pool[0] - pool[1]) ** 2 / (pool[1] + pool[2]), cells + 1
    return statistic, cells - 1
