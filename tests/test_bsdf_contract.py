"""Every BSDF kind and wrapper of tracer/materials/ held to the BSDF contract (materials.bsdf) as the
renderer sees it: through materials.SurfaceBSDF at a point of a loaded scene (one scene, one quad per
material, so that one set of kernels serves every case), in world space, with the wrappers (`twosided`,
`mask`, `blendbsdf`, `normalmap`, `bumpmap`) applied as the dispatcher applies them. The microfacet kinds,
`principled`, `principledthin` and `pplastic` have their own module-level tests (tests/test_microfacet*.py,
test_principled*.py, test_polarized.py); README's "BSDF tests" table lists what tests each module.

- Sampling follows pdf (non-delta lobes): Pearson's chi-square test of SAMPLES directions on the sphere
  against pdf integrated over its cells (tests/chi2.py), delta-lobe samples left out (their share is the
  density's missing mass). Delta kinds: a chi-square test of how often each lobe is chosen against the
  closed-form probabilities (Fresnel's reflectance; a thin slab's 2R / (1 + R)).
  Level: LEVEL family-wise over the module's CHI2 + DELTA tests (Sidak): a correct BSDF fails a run of
  this module with probability at most LEVEL; the seeds are fixed, so it passes or fails deterministically.
- A sample's weight is eval / pdf at its direction (non-delta lobes; not `blendbsdf`, whose weight is
  the chosen component's f / pdf, as Mitsuba's, equal in expectation), and its pdf is pdf(): exact up to
  float32 rounding (relative 2e-3).
- White furnace: the mean sample weight (times eta^2 across an interface) of a white material is at most
  1 + Z standard errors, and equal to 1 within Z standard errors where the material loses no energy (a
  Lambertian, a mirror, a dielectric, a thin slab, null, a mask or blend of those). Z = 4.5 for a normal
  mean: P(|z| > 4.5) = 7e-6 per test, 3e-4 over the module's FURNACE cases and channels.
- Reciprocity f(wi, wo) / |cos wo| = f(wo, wi) / |cos wi| for the reflecting kinds where it holds
  (not the normal and bump maps: the shadowing term and the tilted frame break it, in Mitsuba too).

Each family is shown to fail on a realistic mistake: a diffuse pdf without its cosine, a mask whose pdf
ignores the opacity, a normal map's pdf in the untilted frame, a Lambertian eval without the cosine, a
plastic without the exit Fresnel factor (furnace and reciprocity), a thin slab's reflectance without the
internal reflections."""
from __future__ import annotations

from pathlib import Path

import drjit as dr
import numpy as np
import pytest
from scipy import stats

import tracer
from tracer.geometry import SceneGeometry
from tracer.jit import INF, NO_PRIM, Array2f, Array3f, Float, UInt32
from tracer.materials import SurfaceBSDF, dispatch, diffuse, fresnel, plastic, thindielectric
from tracer.materials.bsdf import DELTA, has_flag

from .chi2 import chi2_sphere, floats, sidak
from .microfacet_cases import direction
from .test_xml_loader import write_scene

LEVEL = 0.01
Z = 4.5
SAMPLES = 200_000      # per chi-square test: 4 to 10 times fewer than test_microfacet_chi2's, at 24 x 48 cells
RES = 24
N = 20_000             # lanes of the weight, furnace and reciprocity tests
TEXTURES = Path(__file__).resolve().parent.parent / "mitsuba_scenes" / "textures"
WHITE = '<rgb name="reflectance" value="1"/>'
ROUGH_MIRROR = ('<bsdf type="roughconductor"><string name="material" value="none"/>'
                '<float name="alpha" value="{a}"/></bsdf>')
ROUGH_PLASTIC = ('<bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="1"/>'
                 '<float name="alpha" value="{a}"/></bsdf>')
# one quad per material, named by its key (the quad's position: its index along x)
MATERIALS = {
    "diffuse": f'<bsdf type="diffuse">{WHITE}</bsdf>',
    "plastic": '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="1"/></bsdf>',
    "conductor": '<bsdf type="conductor"><string name="material" value="none"/></bsdf>',
    "dielectric": '<bsdf type="dielectric"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1"/></bsdf>',
    "thindielectric": '<bsdf type="thindielectric"><float name="int_ior" value="1.5"/>'
                      '<float name="ext_ior" value="1"/></bsdf>',
    "null": '<bsdf type="null"/>',
    "polarizer": '<bsdf type="polarizer"/>',
    "twosided": f'<bsdf type="twosided"><bsdf type="diffuse">{WHITE}</bsdf>{ROUGH_PLASTIC.format(a=0.3)}</bsdf>',
    "mask": f'<bsdf type="mask"><float name="opacity" value="0.4"/>{ROUGH_MIRROR.format(a=0.3)}</bsdf>',
    "mask_diffuse": f'<bsdf type="mask"><float name="opacity" value="0.7"/><bsdf type="diffuse">{WHITE}</bsdf></bsdf>',
    "blend": f'<bsdf type="blendbsdf"><float name="weight" value="0.3"/><bsdf type="diffuse">{WHITE}</bsdf>'
             f'{ROUGH_MIRROR.format(a=0.2)}</bsdf>',
    "blend_delta": f'<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse">{WHITE}</bsdf>'
                   '<bsdf type="conductor"><string name="material" value="none"/></bsdf></bsdf>',
    "normalmap": f'<bsdf type="normalmap"><texture type="bitmap" name="normalmap"><string name="filename" '
                 f'value="{TEXTURES / "bumps_normalmap.png"}"/></texture>{ROUGH_PLASTIC.format(a=0.2)}</bsdf>',
    "bumpmap": f'<bsdf type="bumpmap"><texture type="bitmap"><string name="filename" value="{TEXTURES / "tiles.png"}"/>'
               f'</texture><float name="scale" value="0.3"/><bsdf type="diffuse">{WHITE}</bsdf></bsdf>',
}
# the scenes the materials are probed in, each with the kinds of its materials only (smaller kernels)
GROUPS = {"plain": ["diffuse", "plastic", "conductor", "dielectric", "thindielectric", "null", "polarizer"],
          "wrapped": ["twosided", "mask", "mask_diffuse", "normalmap", "bumpmap"],
          "blend": ["blend", "blend_delta"]}
GROUP = {key: group for group, keys in GROUPS.items() for key in keys}
QUAD = ("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\n"
        "vn 0 0 1\nf 1/1/1 2/2/2 3/3/3\nf 1/1/1 3/3/3 4/4/4\n")
POINT = (0.13, -0.31)       # where on its quad each material is probed (the maps tilt the normal there)


@pytest.fixture(scope="module")
def geometry(tmp_path_factory):
    """The scene of a group (built on first use): one quad per material, the i-th of the group at x = 3 i."""
    folder, built = tmp_path_factory.mktemp("contract"), {}
    (folder / "quad.obj").write_text(QUAD)

    def of(group: str) -> SceneGeometry:
        if group not in built:
            shapes = "".join(f'<shape type="obj"><string name="filename" value="quad.obj"/>{MATERIALS[key]}'
                             f'<transform name="to_world"><translate x="{3 * i}"/></transform></shape>'
                             for i, key in enumerate(GROUPS[group]))
            built[group] = SceneGeometry(tracer.load_scene(write_scene(folder, shapes, name=f"{group}.xml")))
        return built[group]
    return of


class Probe:
    """The BSDF of material `key` at POINT, seen along wi (theta, phi in degrees; theta > 90: from below)."""

    def __init__(self, geometry, key: str, theta: float, phi: float = 30.0):
        self.geo, self.wi = geometry(GROUP[key]), direction(theta, phi)
        self.point = np.array([3.0 * GROUPS[GROUP[key]].index(key) + POINT[0], POINT[1], 0.0])

    def at(self, n: int) -> tuple[SurfaceBSDF, object]:
        o, d = self.point + self.wi, -self.wi
        o = Array3f(*(dr.opaque(Float, float(x), n) for x in o))      # opaque: the same kernels for every case
        d = Array3f(*(dr.opaque(Float, float(x), n) for x in d))
        surf = self.geo.surface(self.geo.closest_hit(o, d, Float(0.0), Float(INF), UInt32(NO_PRIM)))
        return SurfaceBSDF(self.geo.materials, surf, -d, surf.valid), surf.valid

    def sample(self, u1: Float, u2: Float, u3: Float):
        bsdf, valid = self.at(dr.width(u1))
        bs, weight = bsdf.sample(u1, Array2f(u2, u3), valid)
        return bs, weight, bsdf, valid

    def chi2(self, seed: int = 0, pdf=None):
        def sample(u1, u2, u3):
            bs, weight, _, _ = self.sample(u1, u2, u3)
            return bs.wo, dr.any(weight != 0) & ~has_flag(bs.sampled_type, DELTA)

        def density(d):
            bsdf, valid = self.at(dr.width(d))
            return (pdf or (lambda b, w, v: b.eval_pdf(w, v)[1]))(bsdf, d, valid)

        return chi2_sphere(sample, density, samples=SAMPLES, res=RES, seed=seed)

    def uniforms(self, n: int, seed: int) -> tuple[Float, Float, Float]:
        u = np.random.default_rng(seed).uniform(size=(3, n))
        return floats(u[0]), floats(u[1]), floats(u[2])


CHI2 = [("diffuse", 30.0), ("diffuse", 87.0), ("plastic", 60.0), ("twosided", 130.0), ("mask", 45.0),
        ("blend", 70.0), ("blend_delta", 20.0), ("normalmap", 40.0), ("bumpmap", 80.0)]
DELTA_CASES = [("dielectric", 35.0), ("dielectric", 150.0), ("thindielectric", 60.0), ("thindielectric", 170.0)]
PER_TEST = sidak(LEVEL, len(CHI2) + len(DELTA_CASES))


@pytest.mark.parametrize("key, theta", CHI2)
def test_sampling_follows_pdf(geometry, key, theta):
    result = Probe(geometry, key, theta).chi2()
    assert result.passes(PER_TEST), str(result)
    assert abs(result.mass - result.valid) < 0.01, str(result)


def test_p_values_are_uniform(geometry):
    """The false-positive rate, measured: over 24 seeds on the mask and the blend (200,000 samples each) the
    p-values of the tests above are uniform (Kolmogorov-Smirnov at 0.001) and the fraction below 0.1 lies
    within its binomial range."""
    p_values = np.array([Probe(geometry, key, theta).chi2(seed=100 + s).p_value
                         for key, theta in (("mask", 45.0), ("blend", 70.0)) for s in range(12)])
    assert stats.kstest(p_values, "uniform").pvalue > 1e-3, np.sort(p_values)
    assert np.sum(p_values < 0.1) <= stats.binom.ppf(0.999, len(p_values), 0.1), np.sort(p_values)


def lobe_counts(probe: Probe, n: int = N, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How often the delta kind's sample reflects (wo on wi's side), its weights, and the samples' eta."""
    bs, weight, _, valid = probe.sample(*probe.uniforms(n, seed))
    wo = np.asarray(bs.wo.numpy())
    reflected = np.sign(wo[2]) == np.sign(probe.wi[2])
    return reflected, np.asarray(weight.numpy()), np.broadcast_to(np.asarray(bs.eta.numpy()), (n,))


def reflectance(key: str, theta: float) -> float:
    """The closed form: Fresnel's reflectance of the interface 1 | 1.5 (from either side); a thin slab's
    2R / (1 + R) (Stokes: R + T^2 R / (1 - R^2) summed over the internal reflections)."""
    cos = np.cos(np.radians(theta))
    eta = 1.5 if cos > 0 or key == "thindielectric" else 1 / 1.5
    r = float(fresnel.fresnel_dielectric(Float(abs(cos)), Float(eta))[0].numpy()[0])
    return 2 * r / (1 + r) if key == "thindielectric" else r


@pytest.mark.parametrize("key, theta", DELTA_CASES)
def test_delta_lobes_are_chosen_with_their_probability(geometry, key, theta):
    """Reflection against transmission: Pearson's chi-square on the two counts (1 degree of freedom)."""
    reflected, _, _ = lobe_counts(Probe(geometry, key, theta))
    r = reflectance(key, theta)
    observed, expected = [reflected.sum(), (~reflected).sum()], [N * r, N * (1 - r)]
    assert stats.chisquare(observed, expected).pvalue >= PER_TEST, (observed, expected)


def test_lobe_test_fails_without_the_slabs_internal_reflections(geometry, monkeypatch):
    """A thin dielectric reflecting only the first interface's R (its internal reflections lost) is caught."""
    monkeypatch.setattr(thindielectric, "slab_reflectance", lambda r: r)
    reflected, _, _ = lobe_counts(Probe(geometry, "thindielectric", 60.0))
    r = reflectance("thindielectric", 60.0)
    assert stats.chisquare([reflected.sum(), (~reflected).sum()], [N * r, N * (1 - r)]).pvalue < PER_TEST


WEIGHTS = [("diffuse", 30.0), ("plastic", 80.0), ("twosided", 120.0), ("mask", 45.0), ("normalmap", 40.0),
           ("bumpmap", 60.0)]


def weight_against_eval(probe: Probe) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """At each non-delta sample of nonzero weight: (weight, eval / pdf, the sample's pdf, pdf())."""
    bs, weight, bsdf, valid = probe.sample(*probe.uniforms(N, 5))
    f, density = bsdf.eval_pdf(bs.wo, valid)
    live = np.asarray((dr.any(weight != 0) & ~has_flag(bs.sampled_type, DELTA)).numpy())
    ratio = np.asarray(f.numpy()) / np.maximum(np.asarray(density.numpy()), 1e-30)
    return (np.asarray(weight.numpy())[:, live], ratio[:, live], np.asarray(bs.pdf.numpy())[live],
            np.asarray(density.numpy())[live])


@pytest.mark.parametrize("key, theta", WEIGHTS)
def test_weight_is_eval_over_pdf(geometry, key, theta):
    weight, ratio, sampled_pdf, density = weight_against_eval(Probe(geometry, key, theta))
    assert weight.shape[1] > N // 10
    assert np.allclose(sampled_pdf, density, rtol=2e-3, atol=1e-6)
    assert np.allclose(weight, ratio, rtol=2e-3, atol=1e-5)


def test_weight_test_fails_without_lamberts_cosine(geometry, monkeypatch):
    honest = diffuse.eval
    monkeypatch.setattr(diffuse, "eval", lambda rho, wi, wo, active: honest(rho, wi, wo, active) / wo.z)
    weight, ratio, _, _ = weight_against_eval(Probe(geometry, "diffuse", 30.0))
    assert not np.allclose(weight, ratio, rtol=2e-3, atol=1e-5)


LOSSLESS, LOSSY = True, False
FURNACE = [("diffuse", 30.0, LOSSLESS), ("diffuse", 88.0, LOSSLESS), ("plastic", 0.0, LOSSY), ("plastic", 85.0, LOSSY),
           ("conductor", 60.0, LOSSLESS), ("dielectric", 40.0, LOSSLESS), ("dielectric", 160.0, LOSSLESS),
           ("thindielectric", 70.0, LOSSLESS), ("null", 50.0, LOSSLESS), ("polarizer", 50.0, LOSSY),
           ("twosided", 110.0, LOSSY), ("mask", 45.0, LOSSY), ("mask_diffuse", 45.0, LOSSLESS),
           ("blend", 60.0, LOSSY), ("blend_delta", 30.0, LOSSLESS), ("normalmap", 40.0, LOSSY),
           ("bumpmap", 75.0, LOSSY)]


def albedo(probe: Probe, n: int = N) -> tuple[np.ndarray, np.ndarray]:
    """The mean sample weight per channel (eta^2 multiplied back: radiance's 1 / eta^2 is not energy) and
    its standard error."""
    bs, weight, _, _ = probe.sample(*probe.uniforms(n, 7))
    energy = np.asarray(weight.numpy()) * np.asarray(bs.eta.numpy()) ** 2
    return energy.mean(axis=1), energy.std(axis=1) / np.sqrt(n)


@pytest.mark.parametrize("key, theta, lossless", FURNACE)
def test_white_furnace(geometry, key, theta, lossless):
    mean, error = albedo(Probe(geometry, key, theta))
    assert np.all(mean <= 1.0 + Z * error + 1e-5), (mean, error)
    assert np.all(mean > 0.05), mean
    if lossless:
        assert np.all(np.abs(mean - 1.0) <= Z * error + 1e-5), (mean, error)


def _exit_fresnel_lost(honest):
    return lambda albedo, fdr_int, nonlinear, inv_eta2, f_i, f_o: honest(albedo, fdr_int, nonlinear, inv_eta2, f_i,
                                                                          0.0 * f_o)


def test_furnace_fails_without_the_exit_fresnel_factor(geometry, monkeypatch):
    """A plastic whose diffuse light leaves the coating without its Fresnel loss (1 - F(wo)) reflects more
    than it receives."""
    monkeypatch.setattr(plastic, "diffuse_layer", _exit_fresnel_lost(plastic.diffuse_layer))
    mean, error = albedo(Probe(geometry, "plastic", 0.0))
    assert np.any(mean > 1.0 + Z * error), (mean, error)


RECIPROCAL = [("diffuse", 1.0), ("plastic", 1.0), ("twosided", -1.0), ("mask", 1.0), ("blend", 1.0)]


def reciprocity(geo, key: str, side: float) -> tuple[np.ndarray, np.ndarray]:
    """f(wi, wo) / |cos wo| and f(wo, wi) / |cos wi| for N random pairs on one side (z of sign `side`)."""
    rng = np.random.default_rng(11)
    wi, wo = (v / np.linalg.norm(v, axis=0) for v in rng.normal(size=(2, 3, N)))
    wi[2], wo[2] = side * np.abs(wi[2]), side * np.abs(wo[2])
    out = []
    for a, b in ((wi, wo), (wo, wi)):
        probe = Probe(geo, key, 0.0)
        probe.wi = a[:, 0]
        bsdf, valid = _probe_many(probe, a)
        f = np.asarray(bsdf.eval(Array3f(*(floats(c) for c in b)), valid).numpy())
        out.append(f / np.abs(b[2]))
    return out[0], out[1]


def _probe_many(probe: Probe, wi: np.ndarray) -> tuple[SurfaceBSDF, object]:
    """The BSDF at POINT seen along each column of wi (one lane each)."""
    d = Array3f(*(floats(-c) for c in wi))
    o = Array3f(*(floats(probe.point[k] + wi[k]) for k in range(3)))
    surf = probe.geo.surface(probe.geo.closest_hit(o, d, Float(0.0), Float(INF), UInt32(NO_PRIM)))
    return SurfaceBSDF(probe.geo.materials, surf, -d, surf.valid), surf.valid


@pytest.mark.parametrize("key, side", RECIPROCAL)
def test_reciprocity(geometry, key, side):
    forward, backward = reciprocity(geometry, key, side)
    assert np.count_nonzero(forward) > N // 10
    assert np.allclose(backward, forward, rtol=2e-3, atol=1e-5)


def test_reciprocity_fails_without_the_exit_fresnel_factor(geometry, monkeypatch):
    monkeypatch.setattr(plastic, "diffuse_layer", _exit_fresnel_lost(plastic.diffuse_layer))
    forward, backward = reciprocity(geometry, "plastic", 1.0)
    assert not np.allclose(backward, forward, rtol=2e-3, atol=1e-5)


@pytest.mark.parametrize("key, wrong", [
    ("diffuse", lambda b, d, v: dr.select(dr.dot(d, b.n) > 0, Float(0.5 / np.pi), 0.0)),   # no cosine
    ("mask", lambda b, d, v: b._eval_pdf_local(b.to_local(d), v)[1]),                     # opacity ignored
    ("normalmap", lambda b, d, v: b._eval_pdf_local(_untilted(b, d), v)[1]),              # the untilted frame
])
def test_chi2_fails_on_a_realistic_mistake(geometry, key, wrong):
    theta = dict(CHI2)[key]
    result = Probe(geometry, key, theta).chi2(pdf=wrong)
    assert not result.passes(PER_TEST), str(result)


def _untilted(bsdf: SurfaceBSDF, d: Array3f) -> Array3f:
    s, t = dispatch.shading_tangents(bsdf.n0, None)
    return Array3f(dr.dot(d, s), dr.dot(d, t), dr.dot(d, bsdf.n0))
