"""The BSDF contract's properties for a kind's module called directly in its local frame (materials.bsdf):
a sample's weight is eval / pdf and its pdf is pdf() (non-delta lobes), reciprocity, and the white-furnace
albedo. tests/test_bsdf_contract.py checks the same through the dispatcher for the kinds and wrappers; the
kinds with their own test modules (pplastic, principled, principledthin, the microfacet kinds) use these."""
from __future__ import annotations

import numpy as np

from tracer.jit import Array2f, Array3f, Bool
from tracer.materials.bsdf import DELTA, has_flag

from .chi2 import floats

RTOL, ATOL = 2e-3, 1e-5      # float32 rounding of eval / pdf against the weight computed in another order


def vectors(v: np.ndarray) -> Array3f:
    return Array3f(*(floats(c) for c in v))


def uniforms(n: int, seed: int):
    u = np.random.default_rng(seed).uniform(size=(3, n))
    return floats(u[0]), Array2f(floats(u[1]), floats(u[2]))


def weight_against_eval(module, p, wi: np.ndarray, seed: int = 5):
    """At each non-delta sample of nonzero weight from the incidences `wi` (3 x n): (weight, eval / pdf, the
    sample's pdf, pdf())."""
    w = vectors(wi)
    u1, u2 = uniforms(wi.shape[1], seed)
    bs, weight = module.sample(p, w, u1, u2, Bool(True))
    f, density = module.eval(p, w, bs.wo, Bool(True)), module.pdf(p, w, bs.wo, Bool(True))
    weight, f, density = (np.asarray(x.numpy()) for x in (weight, f, density))
    live = np.any(weight != 0, axis=0) & ~np.asarray(has_flag(bs.sampled_type, DELTA).numpy())
    live = np.broadcast_to(live, (wi.shape[1],))
    return weight[:, live], (f / np.maximum(density, 1e-30))[:, live], np.asarray(bs.pdf.numpy())[live], density[live]


def assert_weight_is_eval_over_pdf(module, p, wi: np.ndarray) -> None:
    weight, ratio, sampled_pdf, density = weight_against_eval(module, p, wi)
    assert weight.shape[1] > wi.shape[1] // 10
    assert np.allclose(sampled_pdf, density, rtol=RTOL, atol=1e-6)
    assert np.allclose(weight, ratio, rtol=RTOL, atol=ATOL)


def reciprocity(module, p, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """f(wi, wo) / |cos wo| and f(wo, wi) / |cos wi| (f cos as eval returns it, divided by its cosine)."""
    forward = np.asarray(module.eval(p, vectors(wi), vectors(wo), Bool(True)).numpy()) / np.abs(wo[2])
    backward = np.asarray(module.eval(p, vectors(wo), vectors(wi), Bool(True)).numpy()) / np.abs(wi[2])
    return forward, backward


def albedo(module, p, wi: np.ndarray, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """The mean sample weight per channel at the incidences `wi` (eta^2 multiplied back: radiance's
    1 / eta^2 across an interface is not energy) and its standard error."""
    u1, u2 = uniforms(wi.shape[1], seed)
    bs, weight = module.sample(p, vectors(wi), u1, u2, Bool(True))
    energy = np.asarray(weight.numpy()) * np.asarray(bs.eta.numpy()) ** 2
    return energy.mean(axis=1), energy.std(axis=1) / np.sqrt(wi.shape[1])


def upper_pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n random direction pairs above the surface."""
    rng = np.random.default_rng(seed)
    wi, wo = (v / np.linalg.norm(v, axis=0) for v in rng.normal(size=(2, 3, n)))
    wi[2], wo[2] = np.abs(wi[2]), np.abs(wo[2])
    return wi, wo
