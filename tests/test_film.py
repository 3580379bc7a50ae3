"""The film: reconstruction filters and splatting with Mitsuba's weights (tracer/film.py)."""
import numpy as np
import pytest

from tracer.film import ALIGNED_RUN, Film, ReconstructionFilter
from tracer.jit import Array3f, Float
from validation.verdict.mitsuba_render import mitsuba
from validation.verdict.protocol import ALPHA   # family-wise false-positive rate of one comparison

FILTERS = {"box": ReconstructionFilter("box"), "gaussian": ReconstructionFilter("gaussian"),
           "gaussian stddev 0.8": ReconstructionFilter("gaussian", stddev=0.8),
           "tent": ReconstructionFilter("tent"), "tent radius 1.7": ReconstructionFilter("tent", tent_radius=1.7)}
FIT_ERROR = 1e-3


def _mitsuba_filter(f: ReconstructionFilter) -> dict:
    if f.kind == "gaussian":
        return {"type": "gaussian", "stddev": f.stddev}
    return {"type": "tent", "radius": f.tent_radius} if f.kind == "tent" else {"type": "box"}


def _samples(width, height, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 1, (n, 2)) * [width, height], rng.uniform(0, 2, (n, 3))


def _ours(f, width, height, pos, values, run=1):
    film = Film(width, height, f)
    film.put(Float(pos[:, 0]), Float(pos[:, 1]), Array3f(*(Float(v) for v in values.T)), run=run)
    return film.develop(), film.weights()


def _mitsuba_block(f, width, height, pos, values):
    """Mitsuba's ImageBlock with the same filter and samples, developed as hdrfilm does (divide by weight)."""
    mi = mitsuba()
    rfilter = mi.load_dict(_mitsuba_filter(f))
    block = mi.ImageBlock(size=[width, height], offset=[0, 0], channel_count=4, rfilter=rfilter, border=True)
    block.put(mi.Point2f(pos[:, 0], pos[:, 1]), [mi.Float(values[:, c]) for c in range(3)] + [mi.Float(np.ones(len(pos)))])
    b = block.border_size()
    t = np.array(block.tensor(), dtype=np.float64)[b:b + height, b:b + width]
    w = t[..., 3:]
    return t[..., :3] / np.where(w == 0, 1, w), w[..., 0]


@pytest.mark.parametrize("run", [1, ALIGNED_RUN])
@pytest.mark.parametrize("name", FILTERS)
def test_splatting_matches_mitsubas_image_block(name, run):
    f, (w, h) = FILTERS[name], (9, 6)
    pos, values = _samples(w, h, 400)
    ours, our_w = _ours(f, w, h, pos, values, run)
    theirs, their_w = _mitsuba_block(f, w, h, pos, values)
    # Mitsuba's LLVM Gaussian is a polynomial fit of exp whose error reaches 4.2e-4 of the peak weight
    # (test_filter_values_match_mitsuba): agreement to that, not to float32 epsilon
    np.testing.assert_allclose(our_w, their_w, rtol=FIT_ERROR)
    np.testing.assert_allclose(ours, theirs, rtol=FIT_ERROR)


@pytest.mark.parametrize("name", FILTERS)
def test_filter_values_match_mitsuba(name):
    f = FILTERS[name]
    x = np.linspace(-f.radius - 0.5, f.radius + 0.5, 1001)
    x = x[np.abs(np.abs(x) - 0.5) > 1e-4] if f.kind == "box" else x    # Mitsuba's box has radius 0.5 + 1e-4
    theirs = np.array(mitsuba().load_dict(_mitsuba_filter(f)).eval(mitsuba().Float(x)))
    np.testing.assert_allclose(f.eval(Float(x)).numpy(), theirs, atol=FIT_ERROR)


def test_the_comparison_sees_a_wrong_filter_width():
    pos, values = _samples(9, 6, 400)
    ours, _ = _ours(ReconstructionFilter("gaussian", stddev=0.55), 9, 6, pos, values)
    theirs, _ = _mitsuba_block(ReconstructionFilter("gaussian"), 9, 6, pos, values)
    assert np.abs(ours - theirs).max() > 1e-2


@pytest.mark.parametrize("name", FILTERS)
def test_constant_radiance_develops_to_itself_up_to_the_border(name):
    pos, _ = _samples(8, 8, 2000, seed=1)
    image, weights = _ours(FILTERS[name], 8, 8, pos, np.full((2000, 3), 0.7))
    assert (weights > 0).all()
    np.testing.assert_allclose(image, 0.7, rtol=1e-5)


def test_box_filter_is_the_mean_of_the_samples_in_each_pixel():
    pos, values = _samples(4, 3, 300, seed=2)
    image, weights = _ours(FILTERS["box"], 4, 3, pos, values)
    px = np.floor(pos).astype(int)
    for y in range(3):
        for x in range(4):
            inside = (px[:, 0] == x) & (px[:, 1] == y)
            assert weights[y, x] == inside.sum()
            np.testing.assert_allclose(image[y, x], values[inside].mean(0), rtol=1e-5)


def test_gaussian_is_mitsubas_windowed_gaussian():
    f = ReconstructionFilter("gaussian")
    x = np.linspace(-2.5, 2.5, 101)
    expected = np.maximum(np.exp(-x ** 2 / (2 * 0.25)) - np.exp(-4.0 / (2 * 0.25)), 0)
    np.testing.assert_allclose(f.eval(Float(x)).numpy(), expected, atol=1e-6)
    assert f.radius == 2.0


# ---- whole images against Mitsuba ------------------------------------------------------------------
PASSES, SPP, SIZE = 16, 64, 32


def _variant(tmp_path, rfilter_xml):
    from validation.verdict.scene_variants import with_filter

    from .conftest import SCENES

    return with_filter(SCENES / "hexagon_room.xml", rfilter_xml, tmp_path, "room")


def _both(scene_file, rfilter=None):
    import tracer
    from tracer.rendering import render
    from validation.verdict.mitsuba_render import render_passes

    scene = tracer.load_scene(scene_file, width=SIZE, height=SIZE)
    ours = np.stack([render(scene, "path", spp=SPP, seed=500 + k, max_depth=3, rfilter=rfilter).image
                     for k in range(PASSES)])
    return ours, render_passes(scene_file, PASSES, SPP, width=SIZE, height=SIZE, max_depth=3)


@pytest.mark.parametrize("rfilter_xml", ["", '<rfilter type="tent"><float name="radius" value="1.5"/></rfilter>'],
                         ids=["no rfilter: Mitsuba's default gaussian", "tent radius 1.5"])
def test_filtered_image_agrees_with_mitsuba(tmp_path, rfilter_xml):
    from validation.verdict.stats import welch_test

    ours, theirs = _both(_variant(tmp_path, rfilter_xml))
    result = welch_test(ours, theirs, alpha=ALPHA)
    assert result.passed, result.summary()


def test_agreement_test_sees_a_box_filter_against_a_gaussian_reference(tmp_path):
    from validation.verdict.stats import welch_test

    ours, theirs = _both(_variant(tmp_path, ""), rfilter=ReconstructionFilter("box"))
    assert not welch_test(ours, theirs, alpha=ALPHA).passed


@pytest.mark.parametrize("name", FILTERS)
def test_a_pixels_footprint_adds_what_each_samples_footprint_adds(name):
    # samples in pixel order, 8 a pixel (as a render's): the footprint shared by a pixel's samples
    # (run >= ALIGNED_RUN) takes the same weights, summed in another order
    w, h, spp = 7, 5, 8
    rng = np.random.default_rng(3)
    pixel = np.repeat(np.arange(w * h), spp)
    pos = np.stack([pixel % w, pixel // w], 1) + rng.uniform(0, 1, (len(pixel), 2))
    values = rng.uniform(0, 2, (len(pixel), 3))
    (a, a_w), (b, b_w) = (_ours(FILTERS[name], w, h, pos, values, run) for run in (1, spp))
    np.testing.assert_allclose(b_w, a_w, rtol=1e-6)
    np.testing.assert_allclose(b, a, rtol=1e-5)
