"""Mitsuba's `shapegroup` and `instance`, which the tracer expands into copies of the group's shapes (each
member's to_world preceded by the instance's). mitsuba_scenes/instancing.xml against Mitsuba: Welch's
t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA; the same test
failing with the two transforms composed in the wrong order."""
import numpy as np
import pytest

import tracer
import tracer.mitsuba_xml as loader
from tracer.cli import main
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "instancing.xml"


def compared(seed: int):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=3)
    return compare_passes(plugin_passes(SCENE, "path", 3, seed), ref, ALPHA)


def test_instances_agree_with_mitsuba():
    result = compared(9500)
    assert result.verdict == "agree", result.summary()


def test_fails_with_the_transforms_composed_the_wrong_way(monkeypatch):
    add = loader._add_shape

    def swapped(ctx, scene, node, outer=None, prefix=""):
        if outer is None:
            return add(ctx, scene, node)
        before = len(scene.shapes)
        add(ctx, scene, node, np.eye(4), prefix)          # the member as in the group ...
        for shape in scene.shapes[before:]:               # ... then the instance's transform after it
            if hasattr(shape, "to_world"):
                shape.to_world = shape.to_world @ outer
            elif hasattr(shape, "center"):
                shape.center = (np.linalg.inv(outer) @ np.append(shape.center, 1.0))[:3]

    monkeypatch.setattr(loader, "_add_shape", swapped)
    result = compared(9600)
    assert result.verdict == "disagree", result.summary()


def test_instances_are_expanded_and_said_so(capsys):
    scene = tracer.load_scene(SCENES / SCENE)
    assert (scene.instances, len(scene.meshes), len(scene.spheres), len(scene.rectangles)) == (3, 3, 3, 5)
    assert main(["info", str(SCENES / SCENE)]) == 0
    assert "3 instance(s) of shapegroups expanded" in capsys.readouterr().out


GROUP = '<shape type="shapegroup" id="g"><shape type="sphere"/></shape>'


@pytest.mark.parametrize("body, words", [
    ('<shape type="shapegroup" id="g"><shape type="sphere"><emitter type="area"/></shape></shape>'
     '<shape type="instance"><ref id="g"/></shape>', "emitter on a shape inside a shapegroup"),
    ('<shape type="sphere" id="s"/><shape type="instance"><ref id="s"/></shape>', "exactly one shapegroup"),
    (GROUP + '<shape type="shapegroup" id="h"><shape type="instance"><ref id="g"/></shape></shape>',
     "inside a shapegroup"),
    (GROUP + '<shape type="instance"><ref id="g"/><float name="scale" value="2"/></shape>', "unreferenced"),
])
def test_bad_instancing_is_refused(tmp_path, body, words):
    errors = scene_errors(write_scene(tmp_path, body))
    assert any(words in e for e in errors), errors
