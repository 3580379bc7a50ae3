"""Mitsuba's `cube` (tracer.shapes.cube): mitsuba_scenes/cube.xml, a checkered cube, a box scaled unevenly and
an emitting cube, against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA; the same test failing with each face's texture coordinates turned
by a quarter."""
import numpy as np

import tracer.shapes.cube as cube
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "cube.xml"


def compared(seed: int):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=3)
    return compare_passes(plugin_passes(SCENE, "path", 3, seed), ref, ALPHA)


def test_cubes_agree_with_mitsuba():
    result = compared(10300)
    assert result.verdict == "agree", result.summary()


def test_fails_with_texture_coordinates_turned(monkeypatch):
    monkeypatch.setattr(cube, "FACE_UV", cube.FACE_UV[1:] + cube.FACE_UV[:1])
    result = compared(10400)
    assert result.verdict == "disagree", result.summary()


def test_the_cube_is_closed_and_outward():
    vertices, faces, _ = cube.local_mesh()
    v = vertices[faces]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert np.all(np.einsum("ij,ij->i", normals, v.mean(axis=1)) > 0)     # every face points away from the centre
    assert np.isclose(0.5 * np.linalg.norm(normals, axis=1).sum(), 24.0)  # area of [-1, 1]^3


def test_a_cube_with_a_filename_is_refused(tmp_path):
    (error,) = scene_errors(write_scene(tmp_path, '<shape type="cube"><string name="filename" value="a.obj"/></shape>'))
    assert "filename" in error
