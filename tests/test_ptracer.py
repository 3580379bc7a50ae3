"""Mitsuba's `ptracer` (a light tracer), rendered with the path estimator where both estimate the same
image (tracer/integrators/ptracer.py), and refused where the images differ by design.

mitsuba_scenes/ptracer.xml (diffuse and rough surfaces, an area light and a sphere light seen directly,
point and spot lights, the box filter) against Mitsuba 3's own ptracer: Welch's t-test per 4 x 4 block and
channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison (2 comparisons). The
same test disagrees when the path estimator renders ptracer on the scene with a mirror sphere (the mistake
the refusal prevents: a light tracer never connects a mirror to the camera)."""
import numpy as np
import pytest

import tracer
from tracer.rendering import render
from validation.verdict.mitsuba_render import render_passes
from validation.verdict.protocol import ALPHA
from validation.verdict.scenefile import plan
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SPP, mitsuba_passes

SIZE = 16     # pixels on a side (the plugin tests take 32): keeps the four renders of 16 passes short
from .test_xml_features import scene_errors

SCENE = "ptracer.xml"
MATTE = '<bsdf type="roughplastic">\n            <rgb name="diffuse_reflectance" value="0.3, 0.6, 0.8"/>\n' \
        '            <float name="alpha" value="0.2"/>\n        </bsdf>'


def edited(tmp_path, old: str, new: str):
    text = (SCENES / SCENE).read_text()
    assert old in text
    path = tmp_path / SCENE
    path.write_text(text.replace(old, new, 1))
    return path


def test_agrees_with_mitsubas_ptracer():
    assert "ParticleTracer" in str(plan(SCENES / SCENE, None, SIZE, None).mitsuba_scene(4).integrator())
    scene = tracer.load_scene(SCENES / SCENE, width=SIZE, height=SIZE)
    ours = np.stack([render(scene, "path", spp=SPP, seed=7400 + k).image for k in range(PASSES)])
    result = compare_passes(ours, mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE), ALPHA)
    assert result.verdict == "agree", result.summary()


def test_a_mirror_is_refused_and_the_check_sees_why(tmp_path):
    """With the sphere a smooth conductor, Mitsuba's ptracer shows no mirror image; path does."""
    path = edited(tmp_path, MATTE, '<bsdf type="conductor"/>')
    (error,) = scene_errors(path)
    line = next(i for i, text in enumerate(path.read_text().splitlines(), 1) if '<integrator type="ptracer">' in text)
    assert error.startswith(f"{path}:{line}: <integrator type=\"ptracer\">: ptracer's image differs")
    assert "bsdf 'conductor' has a delta lobe" in error
    as_path = tmp_path / "as_path.xml"
    as_path.write_text(path.read_text().replace('<integrator type="ptracer">', '<integrator type="path">'))
    scene = tracer.load_scene(as_path, width=SIZE, height=SIZE)
    ours = np.stack([render(scene, "path", spp=SPP, seed=7500 + k, max_depth=4).image for k in range(PASSES)])
    result = compare_passes(ours, render_passes(path, PASSES, SPP, seed=12345, width=SIZE, height=SIZE), ALPHA)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("old, new, words", [
    (MATTE, '<bsdf type="dielectric"/>', "bsdf 'dielectric' has a delta lobe"),
    (MATTE, '<bsdf type="plastic"/>', "bsdf 'plastic' has a delta lobe"),
    (MATTE, '<bsdf type="twosided"><bsdf type="diffuse"/><bsdf type="conductor"/></bsdf>',
     "bsdf 'conductor' has a delta lobe"),
    (MATTE, '<bsdf type="mask"><float name="opacity" value="0.5"/><bsdf type="diffuse"/></bsdf>',
     "a mask's pass-through"),
    (MATTE, '<bsdf type="blendbsdf"><float name="weight" value="0.3"/><bsdf type="diffuse"/>'
            '<bsdf type="conductor"/></bsdf>', "bsdf 'conductor' has a delta lobe"),
    (MATTE, '<bsdf type="roughdielectric"/>', "bsdf 'roughdielectric' transmits"),
    ('<rfilter type="box"/>', '<rfilter type="tent"/>', "rfilter 'tent'"),
    ('<rfilter type="box"/>', '', "rfilter 'gaussian'"),
    ('<sensor type="perspective">', '<sensor type="thinlens"><float name="aperture_radius" value="0.1"/>',
     "a thinlens sensor"),
    ('<emitter type="point">', '<emitter type="constant"/><emitter type="point">', "emitter 'constant'"),
    ('<rfilter type="box"/>', '<rfilter type="box"/><integer name="crop_width" value="32"/>', "a film crop window"),
])
def test_what_makes_the_images_differ_is_refused(tmp_path, old, new, words):
    path = edited(tmp_path, old, new)
    errors = scene_errors(path)
    assert len(errors) == 1 and '<integrator type="ptracer">' in errors[0] and words in errors[0], errors


def test_info_says_how_ptracer_is_rendered():
    scene = tracer.load_scene(SCENES / SCENE)
    assert (scene.integrator, scene.max_depth) == ("ptracer", 4)
    assert any("ptracer (a light tracer): rendered with the path estimator" in n for n in scene.notes())


PANEL = '<shape type="rectangle" id="panel">'


@pytest.mark.parametrize("mesh, face_normals, refused", [
    ("cube.obj", False, True),     # no normals in the file: Mitsuba's smooth vertex normals
    ("cube.obj", True, False),
    ("quad_uv.obj", False, False),  # flat: its vertex normals are its triangles'
])
def test_an_emitting_mesh_with_interpolated_normals_is_refused(tmp_path, mesh, face_normals, refused):
    path = edited(tmp_path, PANEL, f'<shape type="obj" id="panel"><string name="filename" '
                                   f'value="{SCENES / "meshes" / mesh}"/><boolean name="face_normals" '
                                   f'value="{str(face_normals).lower()}"/>')
    if refused:
        (error,) = scene_errors(path)
        assert "the emitting mesh 'panel' has interpolated normals" in error
    else:
        assert tracer.load_scene(path).integrator == "ptracer"


@pytest.mark.parametrize("outer", ["moment", "aov"])
def test_a_wrapped_ptracer_is_refused_as_by_mitsuba(tmp_path, outer):
    aovs = '<string name="aovs" value="d:depth"/>' if outer == "aov" else ""
    path = edited(tmp_path, '<integrator type="ptracer">', f'<integrator type="{outer}">{aovs}<integrator type="ptracer">')
    path.write_text(path.read_text().replace("</integrator>", "</integrator></integrator>", 1))
    (error,) = scene_errors(path)
    assert f'<integrator type="{outer}">: a {outer} around ptracer' in error
