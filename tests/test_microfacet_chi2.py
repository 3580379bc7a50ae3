"""Sampling follows pdf, for every microfacet BSDF: Pearson's chi-square test (tests/chi2.py) of a
million samples against the pdf integrated over the sphere's cells, as Mitsuba tests its BSDFs. Both
distributions, visible normals and all normals, isotropic and anisotropic roughness from near-smooth to
rough, incidence from normal to grazing, and for the dielectric from inside, under total internal
reflection and from the denser side.

Level: LEVEL family-wise over the module's CONFIGS tests (Sidak: each at sidak(LEVEL, len(CONFIGS))), so a
correct implementation fails a run of this module with probability LEVEL; the test's seeds are fixed, so a
given correct implementation passes or fails deterministically. test_p_values_are_uniform (slow) measures
the harness's false-positive rate over seeds; the last tests show it rejects realistic mistakes."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from tracer.jit import Array3f, Bool
from tracer.materials import roughdielectric
from tracer.materials.microfacet import microfacet

from .chi2 import chi2_sphere, sidak
from .microfacet_cases import Case, direction

LEVEL = 0.01


def run(case: Case, wi: np.ndarray, seed: int = 0, samples: int = 1_000_000, params=None, sample_params=None):
    """The chi-square test of case's sample against its pdf at incidence wi; `sample_params` (default the
    case's) are the parameters the sampler uses, to test a sampler that differs from the pdf."""
    p = params or case.params()
    ps = sample_params or p
    module, w = case.module, Array3f(*(float(x) for x in wi))

    def sample(u1, u2, u3):
        bs, weight = module.sample(ps, w, u1, (u2, u3), Bool(True))
        return bs.wo, (weight.x != 0) | (weight.y != 0) | (weight.z != 0)

    return chi2_sphere(sample, lambda d: module.pdf(p, w, d, Bool(True)), samples=samples, seed=seed)


def configs():
    out = []
    for ggx in ("ggx", "beckmann"):
        for visible in (True, False):
            out += [(Case("roughconductor", ggx, 0.05, visible), (30.0, 20.0)),
                    (Case("roughconductor", ggx, (0.5, 0.1), visible), (60.0, 30.0)),
                    (Case("roughconductor", ggx, 0.6, visible), (88.0, 0.0)),
                    (Case("roughdielectric", ggx, 0.1, visible), (30.0, 20.0)),
                    (Case("roughdielectric", ggx, (0.2, 0.5), visible), (85.0, 45.0)),
                    (Case("roughdielectric", ggx, 0.5, visible), (140.0, 70.0)),     # from inside
                    (Case("roughdielectric", ggx, 0.3, visible), (95.0, 10.0)),      # inside, grazing: TIR
                    (Case("roughdielectric", ggx, 0.4, visible, int_ior=1.0, ext_ior=1.5), (50.0, 0.0)),
                    (Case("roughplastic", ggx, 0.1, visible), (20.0, 0.0)),
                    (Case("roughplastic", ggx, 0.7, visible, nonlinear=True), (86.0, 60.0))]
    return out


CONFIGS = configs()


@pytest.mark.slow
@pytest.mark.parametrize("case, angles", CONFIGS, ids=lambda c: str(c) if isinstance(c, Case) else f"{c[0]:g}deg")
def test_sampling_follows_pdf(case, angles):
    result = run(case, direction(*angles))
    assert result.passes(sidak(LEVEL, len(CONFIGS))), str(result)
    assert abs(result.mass - result.valid) < 0.005, str(result)


@pytest.mark.slow
def test_p_values_are_uniform():
    """The harness's false-positive rate, measured: over 30 seeds on three configurations (the conductor,
    the dielectric from inside, the plastic; 200,000 samples each), the p-values of a correct sampler are
    uniform (Kolmogorov-Smirnov at 0.001) and the fraction below 0.05 is within its binomial range."""
    p_values = []
    for case, angles in (CONFIGS[1], CONFIGS[5], CONFIGS[9]):
        p_values += [run(case, direction(*angles), seed=1000 + s, samples=200_000).p_value for s in range(30)]
    p_values = np.array(p_values)
    print(f"{len(p_values)} p-values: {np.mean(p_values < 0.01):.3f} below 0.01, {np.mean(p_values < 0.05):.3f} "
          f"below 0.05, {np.mean(p_values < 0.1):.3f} below 0.1; KS p = {stats.kstest(p_values, 'uniform').pvalue:.3f}")
    assert stats.kstest(p_values, "uniform").pvalue > 1e-3, np.sort(p_values)
    assert np.sum(p_values < 0.05) <= stats.binom.ppf(0.999, len(p_values), 0.05)


def test_rejects_missing_refraction_jacobian(monkeypatch):
    """A pdf without the refraction Jacobian of the half vector (Walter (17)) is caught."""
    case = Case("roughdielectric", "ggx", 0.3)
    honest = roughdielectric._jacobian

    def reflection_only(wi, wo, m, eta, reflected):
        return honest(wi, wo, m, eta, Bool(True))

    monkeypatch.setattr(roughdielectric, "_jacobian", reflection_only)
    assert not run(case, direction(30.0)).passes(sidak(LEVEL, len(CONFIGS)))


def test_rejects_swapped_alphas():
    """Sampling with alpha_u and alpha_v swapped (the pdf right) is caught."""
    case = Case("roughconductor", "ggx", (0.5, 0.1))
    p = case.params()
    swapped = case.params()
    swapped.distr = microfacet(True, 0.1, 0.5, True)
    assert run(case, direction(60.0, 30.0), params=p).passes(sidak(LEVEL, len(CONFIGS)))
    assert not run(case, direction(60.0, 30.0), params=p, sample_params=swapped).passes(sidak(LEVEL, len(CONFIGS)))
