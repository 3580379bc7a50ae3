"""Phase functions sample what they evaluate: Pearson's chi-square test (tests/chi2.py) of SAMPLES
directions drawn by tracer.media.phase.sample against phase.eval integrated over the sphere's cells, for
the isotropic phase function and Henyey-Greenstein at g from strongly backward to strongly forward, the
incident direction oblique to the grid's axis. Level: LEVEL family-wise over the CASES (Sidak), seeds
fixed (the harness's false-positive rate over seeds is measured by tests/test_microfacet_chi2.py's
test_p_values_are_uniform). The last tests show it rejects realistic mistakes: a sampler of the opposite g
(forward and backward confused) and one of a nearby g (0.8 for 0.7); the density integrates to 1."""
from __future__ import annotations

import numpy as np
import pytest

from tracer.jit import Array2f, Array3f
from tracer.media import phase
from tracer.media.phase import Phase

from .chi2 import chi2_sphere, sidak

LEVEL = 0.01
SAMPLES = 400_000
D = np.array([0.3, -0.5, -0.8]) / np.linalg.norm([0.3, -0.5, -0.8])   # the direction of travel before scattering
CASES = [Phase(), Phase("hg", -0.7), Phase("hg", -0.2), Phase("hg", 0.3), Phase("hg", 0.8), Phase("hg", 0.95)]


def run(sampled: Phase, evaluated: Phase, d=D, seed: int = 0):
    v = Array3f(*(float(x) for x in d))

    def sample(u1, u2, u3):
        wo, pdf = phase.sample(sampled, v, Array2f(u2, u3))
        return wo, pdf > 0

    return chi2_sphere(sample, lambda w: phase.eval(evaluated, v, w), samples=SAMPLES, seed=seed)


@pytest.mark.parametrize("p", CASES, ids=lambda p: f"{p.kind}{p.g:+}")
def test_sampling_follows_the_density(p):
    result = run(p, p)
    assert result.passes(sidak(LEVEL, len(CASES))), str(result)
    assert abs(result.mass - 1.0) < 2e-3, str(result)


def test_sample_reports_the_density_it_evaluates():
    """sample's pdf is eval's value at the sampled direction (the weight p / pdf is 1, as in Mitsuba)."""
    from tracer.sampling import seeded_rng
    import drjit as dr
    from tracer.jit import UInt32
    for p in CASES:
        rng = seeded_rng(dr.arange(UInt32, 1000), 3)
        v = Array3f(*(float(x) for x in D))
        wo, pdf = phase.sample(p, v, Array2f(rng.next_float32(), rng.next_float32()))
        assert np.allclose(pdf.numpy(), phase.eval(p, v, wo).numpy(), rtol=1e-4), p


def test_forward_scattering_is_along_the_direction_of_travel():
    """g > 0 peaks at wo = d (Mitsuba's hg: its wi is -d)."""
    v = Array3f(*(float(x) for x in D))
    forward = phase.eval(Phase("hg", 0.8), v, v).numpy()[0]
    backward = phase.eval(Phase("hg", 0.8), v, -v).numpy()[0]
    assert forward == pytest.approx((1 + 0.8) / (1 - 0.8) ** 2 / (4 * np.pi), rel=1e-5)
    assert backward < forward / 100


@pytest.mark.parametrize("sampled, evaluated", [(Phase("hg", -0.3), Phase("hg", 0.3)),
                                                 (Phase("hg", 0.8), Phase("hg", 0.7))])
def test_rejects_a_wrong_sampler(sampled, evaluated):
    assert not run(sampled, evaluated).passes(sidak(LEVEL, len(CASES)))
