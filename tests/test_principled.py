"""Mitsuba's `principled` (tracer/materials/principled.py) against Mitsuba 3.9.1's own (its eval, pdf and
sample through its Python API, llvm_ad_rgb, same directions and same random numbers) for configurations that
together switch on every lobe (specular, tinted and metallic Fresnel, anisotropy, transmission from both
sides, clearcoat, diffuse with retro-reflection and fake subsurface, sheen with its tint); sampling against
pdf by Pearson's chi-square test (tests/chi2.py, Sidak-corrected to LEVEL over the module's chi-square tests);
energy in a white furnace; the loader's reading of eta and specular. Rendered against Mitsuba's references
by `validate mitsuba-tests` (bsdf_spheres/test_texturedprincipled1 and 2, reports/mitsuba_tests.md)."""
from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

import tracer
from tracer.jit import Array3f, Bool, Float
from tracer.materials import principled
from tracer.materials.principled import PrincipledParams

from .bsdf_properties import assert_weight_is_eval_over_pdf, reciprocity, upper_pairs
from .chi2 import chi2_sphere, sidak
from .microfacet_cases import direction
from .test_microfacet import ATOL, RTOL, N, arrays, close, mi, random_directions  # noqa: F401 (mi: the fixture)
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

LEVEL = 0.01
CONFIGS = [
    dict(base_color=(0.8, 0.3, 0.2), roughness=0.3),
    dict(base_color=(0.2, 0.8, 0.1), roughness=0.15, anisotropic=0.8, metallic=0.7, clearcoat=0.9,
         clearcoat_gloss=0.4, sheen=0.9, spec_tint=0.5, specular=0.7),
    dict(base_color=(0.3, 0.6, 0.8), roughness=0.4, anisotropic=0.2, spec_trans=0.7, clearcoat=0.6,
         sheen=0.2, sheen_tint=0.8, flatness=0.6, specular=0.4),
    dict(base_color=(0.9, 0.9, 0.9), roughness=0.05, spec_trans=1.0, eta=1.33),
]


def params(config: dict, n: int = 1) -> PrincipledParams:
    defaults = dict(principled.WEIGHTS) | dict(principled.RATES)
    w = {k: Float(np.full(n, config.get(k, d), np.float32)) for k, d in defaults.items()}
    eta = config.get("eta", 2.0 / (1.0 - np.sqrt(np.float32(0.08) * np.float32(config.get("specular", 0.5)))) - 1.0)
    w["eta"] = Float(np.full(n, eta, np.float32))
    w["transmits"] = Float(np.full(n, float("spec_trans" in config), np.float32))
    return PrincipledParams(Array3f(*(Float(np.full(n, c, np.float32)) for c in config["base_color"])), w)


def mitsuba_bsdf(mi, config: dict):
    d = {"type": "principled", "base_color": {"type": "rgb", "value": config["base_color"]}}
    return mi.load_dict(d | {k: v for k, v in config.items() if k != "base_color"})


@pytest.mark.parametrize("config", CONFIGS, ids=range(len(CONFIGS)))
def test_bsdf_is_mitsubas(mi, config):
    """eval and pdf at N direction pairs (both sides), and sample with the same random numbers, lane by
    lane (a lane may pick the neighbouring lobe where u1 lies within rounding of a lobe boundary: 0.1%)."""
    wi, wo = random_directions(5, upper=False)
    u = np.random.default_rng(6).uniform(size=(3, N)).astype(np.float32)
    bsdf, ctx = mitsuba_bsdf(mi, config), mi.BSDFContext()
    si = dr.zeros(mi.SurfaceInteraction3f, N)
    si.wi = mi.Vector3f(*wi)
    p, w, o = params(config, N), arrays(wi), arrays(wo)
    assert close(principled.eval(p, w, o, Bool(True)).numpy(), bsdf.eval(ctx, si, mi.Vector3f(*wo)).numpy())
    assert close(principled.pdf(p, w, o, Bool(True)).numpy(), bsdf.pdf(ctx, si, mi.Vector3f(*wo)).numpy())
    bs, weight = principled.sample(p, w, Float(u[0]), _u2(u), Bool(True))
    ref, ref_weight = bsdf.sample(ctx, si, mi.Float(u[0]), mi.Point2f(u[1], u[2]))
    weight, ref_weight = np.asarray(weight.numpy()), np.asarray(ref_weight.numpy())
    same = np.all(np.isclose(weight, ref_weight, rtol=RTOL, atol=ATOL), axis=0)
    assert same.mean() >= 0.999
    live = same & np.any(ref_weight != 0, axis=0)
    assert live.mean() > 0.3
    assert close(np.asarray(bs.wo.numpy())[:, live], np.asarray(ref.wo.numpy())[:, live], atol=1e-4)
    assert close(np.asarray(bs.pdf.numpy())[live], np.asarray(ref.pdf.numpy())[live])
    assert close(np.broadcast_to(bs.eta.numpy(), (N,))[live], np.broadcast_to(ref.eta.numpy(), (N,))[live])


def _u2(u: np.ndarray):
    from tracer.jit import Array2f
    return Array2f(Float(u[1]), Float(u[2]))


def chi2(config: dict, theta: float, seed: int = 0, samples: int = 1_000_000, pdf_of=None):
    p, w = params(config), Array3f(*(float(x) for x in direction(theta)))
    pdf_of = pdf_of or principled.pdf

    def sample(u1, u2, u3):
        from tracer.jit import Array2f
        bs, weight = principled.sample(p, w, u1, Array2f(u2, u3), Bool(True))
        return bs.wo, (weight.x != 0) | (weight.y != 0) | (weight.z != 0)

    return chi2_sphere(sample, lambda d: pdf_of(p, w, d, Bool(True)), samples=samples, seed=seed)


CHI2 = [(0, 30.0), (1, 70.0), (2, 45.0), (2, 150.0), (3, 85.0), (3, 150.0), (3, 120.0)]   # 120: inside, TIR


@pytest.mark.slow
@pytest.mark.parametrize("config, theta", CHI2)
def test_sampling_follows_pdf(config, theta):
    result = chi2(CONFIGS[config], theta)
    assert result.passes(sidak(LEVEL, len(CHI2))), str(result)
    assert abs(result.mass - result.valid) < 0.005, str(result)


@pytest.mark.slow
def test_chi2_fails_without_the_refraction_jacobian():
    """The transmission pdf without dwh/dwo's refraction form (the reflection one used throughout)."""
    def wrong(p, wi, wo, active):
        reflected = wi.z * wo.z > 0
        h, _, _, eta_path = principled._half_vector(wi, wo, p.w["eta"])
        right = dr.abs(dr.square(eta_path) * dr.dot(wo, h) / dr.square(dr.dot(wi, h) + eta_path * dr.dot(wo, h)))
        return principled.pdf(p, wi, wo, active) * dr.select(reflected, 1.0, dr.abs(dr.rcp(4.0 * dr.dot(wo, h))) / right)
    result = chi2(CONFIGS[3], 45.0, pdf_of=wrong)
    assert not result.passes(sidak(LEVEL, len(CHI2))), str(result)


@pytest.mark.parametrize("roughness", [0.05, 0.5])
def test_white_furnace(roughness):
    """A white principled conductor (metallic 1) and a white clear dielectric (spec_trans 1) reflect and
    transmit at most all the energy (the mean sample weight, eta^2 multiplied back across the interface;
    bound 1 + 4 standard errors). The Disney diffuse is not energy-conserving by design (its retro-reflection
    exceeds 1 at grazing roughness): not held to it."""
    n = 200_000
    rng = np.random.default_rng(9)
    for config in (dict(base_color=(1.0, 1.0, 1.0), metallic=1.0, roughness=roughness),
                   dict(base_color=(1.0, 1.0, 1.0), spec_trans=1.0, roughness=roughness)):
        for theta in (0.0, 45.0, 80.0) + ((120.0, 170.0) if "spec_trans" in config else ()):
            p, wi = params(config, n), arrays(np.repeat(direction(theta)[:, None], n, axis=1))
            u = rng.uniform(size=(3, n)).astype(np.float32)
            bs, weight = principled.sample(p, wi, Float(u[0]), _u2(u), Bool(True))
            energy = np.asarray(weight.numpy())[0] * np.asarray(bs.eta.numpy()) ** 2
            mean, error = energy.mean(), energy.std() / np.sqrt(n)
            assert 0.1 < mean <= 1.0 + 4 * error, f"{config} at {theta}: {mean:.4f} +- {error:.4f}"


@pytest.mark.parametrize("config", CONFIGS, ids=range(len(CONFIGS)))
def test_weight_is_eval_over_pdf(config):
    """From above and (where it transmits) below: a non-delta sample's weight is eval / pdf, its pdf pdf()."""
    wi, _ = random_directions(11, upper="spec_trans" not in config)
    assert_weight_is_eval_over_pdf(principled, params(config, N), wi)


@pytest.mark.parametrize("config", [0, 1])
def test_reflection_is_reciprocal(config):
    """The reflecting configurations (every lobe but transmission: diffuse with retro-reflection, sheen,
    clearcoat, anisotropic metal) are symmetric in wi and wo."""
    wi, wo = upper_pairs(N, 12)
    forward, backward = reciprocity(principled, params(CONFIGS[config], N), wi, wo)
    assert np.count_nonzero(forward) > N // 2 and np.allclose(backward, forward, rtol=2e-3, atol=1e-5)


def test_eta_and_specular(tmp_path):
    def bsdf(props):
        path = write_scene(tmp_path, f'<shape type="sphere"><bsdf type="principled">{props}</bsdf></shape>')
        return dict(tracer.load_scene(path).spheres[0].bsdf.extra)["eta"]
    assert bsdf("") == pytest.approx(1.5, abs=1e-6)
    assert bsdf('<float name="specular" value="0.7"/>') == pytest.approx(2 / (1 - np.sqrt(0.056)) - 1, rel=1e-6)
    assert bsdf('<float name="eta" value="1.0"/><float name="spec_trans" value="0.5"/>') == 1.001
    (error,) = scene_errors(write_scene(tmp_path, '<shape type="sphere"><bsdf type="principled"><float name="eta" '
                                                  'value="1.2"/><float name="specular" value="0.3"/></bsdf></shape>'))
    assert "either eta or specular" in error


SCENE = "principled.xml"


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 5), ("report", 4)])
def test_principled_agrees_with_mitsuba(estimator, max_depth):
    """mitsuba_scenes/principled.xml (principled and principledthin) by both estimators against Mitsuba (Welch's
    t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per
    comparison)."""
    from validation.verdict.protocol import ALPHA
    from validation.verdict.stats import compare_passes

    from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(plugin_passes(SCENE, estimator, max_depth, 9100), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_with_the_anisotropy_turned(monkeypatch):
    """alpha_x and alpha_y exchanged (the anisotropy turned by 90 degrees about the normal)."""
    from tracer.materials.microfacet import microfacet
    from validation.verdict.protocol import ALPHA
    from validation.verdict.stats import compare_passes

    from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
    honest = principled._distribution
    monkeypatch.setattr(principled, "_distribution", lambda w: (lambda d: microfacet(True, d.alpha_v, d.alpha_u))(honest(w)))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=4)
    result = compare_passes(plugin_passes(SCENE, "report", 4, 9100), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()
