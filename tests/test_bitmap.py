"""Mitsuba's `bitmap` texture: texel values as Mitsuba 3.9.1 looks them up (sRGB decoded per texel before
bilinear filtering, texel-centred, repeated, clamped or mirrored, nearest; raw; stored as the variant's
floats), and mitsuba_scenes/bitmap.xml rendered
by the path estimator against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA per comparison; the same test failing when the image is filtered before
its sRGB decoding."""
import numpy as np
import pytest

import tracer
from tracer import bitmap
from tracer.geometry import SceneGeometry
from tracer.materials import textures
from tracer.jit import Float, UInt32
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import mi  # noqa: F401  (the fixture)
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "bitmap.xml"
IMAGE = SCENES / "textures" / "tiles.png"


@pytest.mark.parametrize("options", [{}, {"filter_type": "nearest"}, {"wrap_mode": "clamp"}, {"wrap_mode": "mirror"},
                                     {"raw": True}, {"format": "variant"}])
def test_lookup_is_mitsubas(tmp_path, options, mi):
    props = "".join(f'<boolean name="{k}" value="true"/>' if v is True else f'<string name="{k}" value="{v}"/>'
                    for k, v in options.items())
    path = write_scene(tmp_path, f'<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" '
                                 f'name="reflectance"><string name="filename" value="{IMAGE}"/>{props}</texture>'
                                 '</bsdf></shape>')
    geo = SceneGeometry(tracer.load_scene(path))
    rng = np.random.default_rng(4)
    uv = rng.uniform(-1.5, 2.5, (300, 2)).astype(np.float32)
    index = UInt32(np.ones(len(uv), np.uint32))       # the scene's one texture
    ours = np.asarray(geo.materials.textures.eval(index, (Float(uv[:, 0]), Float(uv[:, 1])), True).numpy()).T
    tex = mi.load_dict({"type": "bitmap", "filename": str(IMAGE), **options})
    ref = []
    for u, v in uv:
        si = mi.SurfaceInteraction3f()
        si.uv = mi.Point2f(float(u), float(v))
        ref.append(np.array(tex.eval(si)))
    assert np.allclose(ours, np.array(ref), atol=2e-6)


def tracer_passes(max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, "path", max_depth, 9400)


@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, 6])
def test_bitmap_agrees_with_mitsuba(max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_when_filtered_before_decoding(monkeypatch):
    """Averaging sRGB values and decoding the average darkens every edge between texels."""
    read = bitmap.read_bitmap

    def blurred(path, raw):
        encoded = read(path, raw=True).astype(np.float64)
        blur = (encoded + np.roll(encoded, 1, 0) + np.roll(encoded, 1, 1) + np.roll(encoded, (1, 1), (0, 1))) / 4
        return (blur if raw else bitmap.srgb_to_linear(blur)).astype(np.float32)

    monkeypatch.setattr(textures, "read_bitmap", blurred)
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(tracer_passes(2), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("wrap", [textures.REPEAT, textures.MIRROR])
@pytest.mark.parametrize("bilinear", [False, True])
def test_repeat_and_mirror_are_exact_at_any_coordinate(wrap, bilinear):
    """Texture coordinates from 1e7 (where u w has no fraction) up to 1e37 (bilinear: 1e14, where float64 holds
    u w - 1/2 exactly): the texels are those of the float32 lookup position's exact remainder over the period
    (the neighbours of a bilinear lookup too, whose weights are 0 there). The remainder r - n * floor(r / n) of
    float32 arithmetic, which the lookup used before, misses on most of them."""
    rng = np.random.default_rng(11)
    h, w, n = 5, 7, 4000
    image = rng.random((h, w, 3)).astype(np.float32)
    top = 14 if bilinear else 37
    u, v = ((rng.choice([-1, 1], n) * 10.0 ** rng.uniform(7, top, n)).astype(np.float32) for _ in range(2))
    t = textures.TextureTables([textures.Bitmap(image, bilinear=bilinear, wrap=wrap)])
    got = t.eval(UInt32(np.ones(n, np.uint32)), (Float(u), Float(v)), True)
    got = np.stack([c.numpy() for c in got], axis=1)

    def wrapped(i: int, m: int) -> int:
        r = i % (m if wrap == textures.REPEAT else 2 * m)
        return r if r < m else 2 * m - 1 - r

    if bilinear:     # texel centres: u w - 1/2 rounded once, as the lookup's fused multiply-add
        x, y = (np.floor((a.astype(np.float64) * m - 0.5).astype(np.float32)) for a, m in ((u, w), (v, h)))
    else:
        x, y = (np.floor(a * np.float32(m)) for a, m in ((u, w), (v, h)))
    expected = np.array([image[wrapped(int(j), h), wrapped(int(i), w)] for i, j in zip(x, y)])
    assert np.array_equal(got, expected)
    naive = x - np.float32(w) * np.floor(x / np.float32(w))
    assert np.mean((naive < 0) | (naive >= w) | (naive != [int(i) % w for i in x])) > 0.5
