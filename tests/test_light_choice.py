"""The choice of a light per shadow ray (tracer.lights.choice) and the densities MIS reads.

Statistics: Pearson's chi-square of the chosen lights' counts against the counts the table (or the MIS
densities) claims, at level LEVEL: a correct choice fails with probability LEVEL per test
(test_false_positive_rate_is_as_stated measures it over 400 seeds); each test is also shown to fail on a
wrong table."""
from pathlib import Path

import drjit as dr
import numpy as np
import pytest
from scipy import stats

import tracer
from tracer.geometry import SceneGeometry, Surface
from tracer.jit import NO_PRIM, Array3f, Float, UInt32
from tracer.lights import POINT_LIGHT
from tracer.lights.choice import LightChoice, power
from tracer.scene import SceneError

from .conftest import ROOT, SCENES
from .test_xml_loader import write_scene

LEVEL = 1e-3
N = 200_000


def chosen_counts(choice: LightChoice, seed: int, n: int = N, copies: int = 1) -> np.ndarray:
    """(copies, lights) counts of the lights `choice` picks for n uniform numbers per copy."""
    u = np.random.default_rng(seed).random(n * copies, dtype=np.float32)
    k = choice.sample(Float(u)).numpy().reshape(copies, n)
    return np.stack([np.bincount(row, minlength=choice.n) for row in k])


def chi2_p(counts: np.ndarray, pmf: np.ndarray) -> float:
    """Pearson's p-value of `counts` against `pmf` over the lights of positive probability; 0 if a light of
    probability 0 was chosen."""
    if np.any(counts[pmf == 0]):
        return 0.0
    keep = pmf > 0
    return float(stats.chisquare(counts[keep], counts.sum() * pmf[keep] / pmf[keep].sum()).pvalue)


WEIGHTS = [3.0, 0.0, 1.0, 6.0, 0.5, 0.0]


def test_frequencies_match_the_table():
    choice = LightChoice(WEIGHTS)
    pmf = np.array([choice.pmf(k) for k in range(choice.n)])
    assert np.allclose(pmf, np.array(WEIGHTS) / sum(WEIGHTS))
    counts = chosen_counts(choice, 1)[0]
    assert counts[1] == counts[5] == 0      # weight 0: never chosen
    assert chi2_p(counts, pmf) > LEVEL


def test_frequencies_fail_on_a_wrong_table():
    """The same counts against a table one weight of which is 10% off."""
    counts = chosen_counts(LightChoice(WEIGHTS), 1)[0]
    wrong = np.array(WEIGHTS)
    wrong[4] *= 1.1
    assert chi2_p(counts, wrong / wrong.sum()) < LEVEL
    assert chi2_p(counts, np.where(np.array(WEIGHTS) > 0, 1.0, 0.0)) < LEVEL    # uniform over the lit ones


def test_false_positive_rate_is_as_stated():
    """At level 0.01 a correct table is rejected in about 1% of 400 seeds (at most 10 of 400: a binomial
    tail of 0.2% for a test whose false-positive rate is as stated)."""
    choice = LightChoice(WEIGHTS)
    pmf = np.array([choice.pmf(k) for k in range(choice.n)])
    counts = chosen_counts(choice, 7, 20_000, 400)
    rejected = sum(chi2_p(c, pmf) < 0.01 for c in counts)
    assert rejected <= 10, rejected


def test_uniform_choice_is_the_count_of_lights():
    """Equal weights: index floor(u n), probability 1 / n, the same arithmetic as before weights existed."""
    choice = LightChoice([2.0] * 5)
    assert choice.uniform and choice.pmf(3) == 1.0 / 5 and choice.pdf_area(1, 3.0) == 1.0 / (5 * 3.0)
    u = np.linspace(0, 1, 1001, endpoint=False, dtype=np.float32)
    assert np.array_equal(choice.sample(Float(u)).numpy(), np.minimum((u * 5).astype(np.uint32), 4))


# ---- the densities MIS reads against the choice the samples make --------------------------------------
def light_of_samples(geo: SceneGeometry, n: int, seed: int):
    """n light samples seen from a point inside the scene: (the index of each one's light, its pdf_area,
    the density MIS reads for it, the choice probability that density implies)."""
    rng = np.random.default_rng(seed)
    u = [Float(rng.random(n, dtype=np.float32)) for _ in range(3)]
    ls = geo.sample_light(*u, Array3f(0.0, 0.0, 0.0))
    prim, pdf = ls.prim.numpy(), ls.pdf_area.numpy()
    y = np.stack([c.numpy() for c in (ls.y.x, ls.y.y, ls.y.z)], 1)
    surf = Surface(ls.y, ls.n, ls.n, UInt32(0), ls.prim, ls.prim < geo.n_prims)
    mis = geo.light_pdf_area(surf).numpy().astype(float)
    index, pmf_mis = np.full(n, -1), np.zeros(n)
    for k, e in enumerate(geo.emitters):
        lo, hi = geo.prim_range(e)
        on = (prim >= lo) & (prim < hi)
        index[on], pmf_mis[on] = k, mis[on] * e.area
    if geo.has_environment:
        on = prim == NO_PRIM
        d = Array3f(*(Float(y[on, i]) for i in range(3)))
        mis[on] = np.broadcast_to(np.asarray(geo.environment_pdf(d).numpy() if geo.envmap is not None
                                             else geo.environment_pdf(d)), (on.sum(),))
        on_env = geo.envmap.pdf(d).numpy() if geo.envmap is not None else 1 / (4 * np.pi)
        index[on], pmf_mis[on] = geo.n_lights - 1, mis[on] / on_env
    for k, light in enumerate(geo.points, len(geo.emitters)):
        on = (prim == POINT_LIGHT) & np.all(np.isclose(y, light.position), axis=1)
        index[on], mis[on], pmf_mis[on] = k, pdf[on], pdf[on]    # a delta light: no other strategy finds it
    return index, pdf, mis, pmf_mis


def mis_problems(geo: SceneGeometry, seed: int = 3, n: int = N) -> list[str]:
    """Where the MIS densities differ from the samples': a sample's pdf_area against the density MIS reads
    at its point, and the lights' frequencies against the probabilities that density implies."""
    index, pdf, mis, pmf_mis = light_of_samples(geo, n, seed)
    out = []
    if np.any(index < 0):
        out.append(f"{np.sum(index < 0)} samples on no light")
    if not np.allclose(pdf, mis, rtol=1e-5, atol=0):
        out.append(f"pdf_area and the MIS density differ (worst ratio {np.max(np.abs(pdf / mis - 1)):.3g})")
    claimed = np.array([np.median(pmf_mis[index == k]) if np.any(index == k) else 0.0 for k in range(geo.n_lights)])
    if (p := chi2_p(np.bincount(index[index >= 0], minlength=geo.n_lights), claimed)) < LEVEL:
        out.append(f"the lights' frequencies differ from the MIS density's (chi-square p = {p:.3g})")
    return out


CASES = [(ROOT / "tests" / "data" / "two_lights.xml", "power"), (ROOT / "tests" / "data" / "light_behind_wall.xml", "power"),
         (ROOT / "tests" / "data" / "light_behind_wall.xml", "mixed"), (SCENES / "spot_lights.xml", "mixed"),
         (ROOT / "tests" / "data" / "sampling_weight.xml", "uniform"), (SCENES / "environment_map.xml", "power"),
         (SCENES / "constant_environment.xml", "power"), (SCENES / "point_lights.xml", "power"),
         (SCENES / "sphere_lights.xml", "uniform")]


@pytest.mark.parametrize("path, policy", CASES, ids=[f"{p.stem}-{q}" for p, q in CASES])
def test_mis_density_is_the_sampling_density(path, policy):
    geo = SceneGeometry(tracer.load_scene(path, width=4, height=4), light_choice=policy)
    assert not geo.choice.uniform or policy == "uniform"
    assert mis_problems(geo) == []


def test_mis_check_fails_where_choice_and_density_disagree():
    """Power-proportional choice read by MIS as uniform, and the reverse: both caught."""
    scene = tracer.load_scene(ROOT / "tests" / "data" / "light_behind_wall.xml", width=4, height=4)
    powered, uniform = (SceneGeometry(scene, light_choice=p) for p in ("power", "uniform"))
    powered.prim_emission = uniform.prim_emission     # the same radiance, the uniform choice's pdfs
    assert any("differ" in line for line in mis_problems(powered))
    uniform.choice = SceneGeometry(scene, light_choice="power").choice    # samples by power, pdfs as uniform
    uniform.__dict__.pop("_emitter_table", None)
    assert any("frequencies" in line for line in mis_problems(uniform))


def test_sampling_weights_are_read():
    """The weights in the kernel's order (the rectangle, the mesh, two point lights); the mesh light of weight
    0, never chosen, has MIS density 0 and is still an emitter (hide_emitters passes through it)."""
    geo = SceneGeometry(tracer.load_scene(ROOT / "tests" / "data" / "sampling_weight.xml", width=4, height=4))
    assert list(geo.choice.weights) == [0.25, 0.0, 3.0, 0.0] and geo.choice.policy == "sampling_weight"
    mesh = next(e for e in geo.emitters if e.sampling_weight == 0)
    lo, hi = geo.prim_range(mesh)
    prims = UInt32(np.arange(lo, hi, dtype=np.uint32))
    surf = Surface(Array3f(0.0), Array3f(0.0), Array3f(0.0), UInt32(0), prims, prims < geo.n_prims)
    assert np.all(geo.light_pdf_area(surf).numpy() == 0) and np.all(geo.emits(surf).numpy())


def test_weights_mitsuba_refuses_are_refused(tmp_path):
    light = '<emitter type="point"><point name="position" value="0, 1, 0"/>{}</emitter>'
    for weight in ("-1", "nan", "inf"):
        path = write_scene(tmp_path, light.format(f'<float name="sampling_weight" value="{weight}"/>'))
        with pytest.raises(SceneError, match=r"scene.xml:\d+: .*sampling_weight.*(non-negative|not a finite)"):
            tracer.load_scene(path)
    path = write_scene(tmp_path, light.format('<float name="sampling_weight" value="0"/>') * 2)
    with pytest.raises(SceneError, match="every emitter's sampling_weight is 0"):
        SceneGeometry(tracer.load_scene(path))


def test_power_estimates():
    """pi A L for an area light, 4 pi I for a point light, by luminance; a spot light's cone by quadrature
    against the closed form of its linear falloff's integral."""
    scene = tracer.load_scene(SCENES / "spot_lights.xml", width=4, height=4)
    spot = next(x for x in scene.point_lights if x.spot is not None and x.image is None)
    _, cutoff, beam = spot.spot
    c, b = np.radians(cutoff), np.radians(beam)
    # 2 pi [ (1 - cos b) + int_b^c (c - t) / (c - b) sin t dt ] = 2 pi [1 - (sin c - sin b) / (c - b)]
    exact = 2 * np.pi * (1 - (np.sin(c) - np.sin(b)) / (c - b))
    y = float(np.asarray(spot.intensity) @ [0.212671, 0.715160, 0.072169])
    assert power(spot, 1.0) == pytest.approx(y * exact, rel=1e-5)
    area = next(s for s in tracer.load_scene(SCENES / "cornell_box.xml", width=4, height=4).emitters)
    assert power(area, 1.0) == pytest.approx(np.pi * area.area * float(np.asarray(area.radiance) @ [0.212671, 0.715160, 0.072169]))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sampling_weight.xml", "light_behind_wall.xml"])
def test_agrees_with_mitsuba(name):
    """The same file rendered by Mitsuba (validation.verdict.check: Welch tests per block, family-wise
    false-positive rate ALPHA; its line states the bias it could have missed)."""
    from validation.verdict.check import Settings, check
    from validation.verdict.protocol import ALPHA
    from validation.verdict.renderers import TracerRenderer
    result = check(ROOT / "tests" / "data" / name, TracerRenderer("path"), 4, settings=Settings(alpha=ALPHA),
                   output=ROOT / "out" / "test-light-choice")
    assert result.verdict == "agree", result.line()


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["power", "mixed"])
@pytest.mark.parametrize("path", [ROOT / "tests" / "data" / "light_behind_wall.xml", SCENES / "environment_map.xml",
                                  SCENES / "spot_lights.xml"], ids=lambda p: p.stem)
def test_other_policies_agree_with_mitsuba(monkeypatch, policy, path):
    """The policies the study measured (validation/studies/light_choice.py) are unbiased too."""
    from tracer.lights import choice
    from validation.verdict.check import Settings, check
    from validation.verdict.protocol import ALPHA
    from validation.verdict.renderers import TracerRenderer
    monkeypatch.setattr(choice, "DEFAULT", policy)
    result = check(path, TracerRenderer("path"), 4, settings=Settings(alpha=ALPHA),
                   output=ROOT / "out" / "test-light-choice")
    assert result.verdict == "agree", result.line()
