"""Mitsuba's `checkerboard` texture as a diffuse reflectance, on a rectangle's texture coordinates, a
serialized mesh's stored ones and a mesh's barycentric ones: mitsuba_scenes/checkerboard.xml rendered by
the path estimator against Mitsuba (Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA per comparison), the same test failing with u and v swapped;
to_uv as Mitsuba reads it; a texture on a flipped mesh without texture coordinates refused."""
import numpy as np
import pytest

import tracer
from tracer.materials.textures import TextureTables
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import mi, scene_errors  # noqa: F401  (mi: the fixture)
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "checkerboard.xml"


def tracer_passes(max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, "path", max_depth, 7000)


@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, 6])
def test_checkerboard_agrees_with_mitsuba(max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_with_u_and_v_swapped(monkeypatch):
    lookup = TextureTables.eval
    monkeypatch.setattr(TextureTables, "eval", lambda self, index, uv, active, *args, **kwargs:
                        lookup(self, index, uv[::-1], active, *args, **kwargs))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(tracer_passes(2), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


def test_to_uv_as_mitsuba(mi):
    scene = tracer.load_scene(SCENES / SCENE)
    params = mi.traverse(mi.load_file(str(SCENES / SCENE)))
    floor = next(r for r in scene.rectangles if r.name == "floor")
    assert np.allclose(floor.bsdf.texture.to_uv, np.array(params["tiles.to_uv"].matrix), atol=1e-6)


def test_texture_on_a_flipped_mesh_without_texture_coordinates_is_refused(tmp_path):
    """A mesh without texture coordinates takes a triangle's barycentric ones (as Mitsuba); flipped, its
    triangles' corners are reordered, which would change them: refused."""
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    bsdf = '<bsdf type="diffuse"><texture type="checkerboard" name="reflectance"/></bsdf>'
    shape = f'<shape type="obj"><string name="filename" value="t.obj"/>{bsdf}{{}}</shape>'
    assert len(tracer.load_scene(write_scene(tmp_path, shape.format(""))).meshes) == 1
    (error,) = scene_errors(write_scene(tmp_path, shape.format('<boolean name="flip_normals" value="true"/>')))
    assert "flip_normals with a texture on a mesh without texture coordinates" in error


def test_report_estimator_refuses_textures():
    (line,) = tracer.load_scene(SCENES / SCENE).estimator_refusals("report")
    assert "checkerboard" in line and "--estimator path" in line
