"""Many cylinders go into a BVH over their boxes (tracer.shapes.cylinder.CylinderBVH), their normals, texture
coordinates and tangents gathered from a table: the same images as the unrolled cylinder tests, bit for bit
(the path tracer; the report estimator renders no textures), textured and anisotropic ones included; and a
BVH with its cylinders' radii off by 1%, or a table with its normals flipped, is caught by the same
comparison."""
import random

import numpy as np
import pytest

import tracer
import tracer.shapes.cylinder as cylinder_module
from tracer.geometry import SceneGeometry, uses_bvh
from tracer.rendering import render

from .test_sphere_bvh import ROOM     # the room both sets of shapes stand in

MATERIALS = """<bsdf type="diffuse" id="checks"><texture type="checkerboard" name="reflectance"/></bsdf>
<bsdf type="roughconductor" id="brushed"><float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.4"/></bsdf>"""


def many_cylinders(tmp_path, n: int = 30, size: int = 24):
    rng = random.Random(7)
    cylinders = []
    for k in range(n):
        x, y, z, r = rng.uniform(-0.8, 0.8), rng.uniform(-0.9, 0.6), rng.uniform(-0.8, 0.8), rng.uniform(0.03, 0.1)
        body = '<ref id="checks"/>' if k % 3 == 0 else '<ref id="brushed"/>' if k % 3 == 1 else '<ref id="white"/>'
        flip = '<boolean name="flip_normals" value="true"/>' if k % 4 == 0 else ""
        cylinders.append(f'<shape type="cylinder"><point name="p0" x="{x}" y="{y}" z="{z}"/>'
                         f'<point name="p1" x="{x + rng.uniform(-0.3, 0.3)}" y="{y + 0.3}" z="{z + rng.uniform(-0.3, 0.3)}"/>'
                         f'<float name="radius" value="{r}"/>{flip}{body}</shape>')
    path = tmp_path / "cylinders.xml"
    path.write_text(ROOM.format(size=size, shapes="\n".join([MATERIALS, *cylinders])))
    return tracer.load_scene(str(path))


def images(scene, threshold: int, monkeypatch) -> dict:
    monkeypatch.setattr(cylinder_module, "BVH_THRESHOLD", threshold)
    geometry = SceneGeometry(scene)
    assert bool(geometry.bvhs) == (len(scene.of_kind(cylinder_module.Cylinder)) > threshold) == uses_bvh(scene)
    return {"path": render(scene, "path", spp=4, seed=11, max_depth=5, geometry=geometry).image}


def test_cylinders_in_a_bvh_render_as_unrolled(tmp_path, monkeypatch):
    scene = many_cylinders(tmp_path)
    unrolled, bvh = images(scene, 10 ** 6, monkeypatch), images(scene, 0, monkeypatch)
    assert unrolled["path"].mean() > 0
    np.testing.assert_array_equal(bvh["path"], unrolled["path"])


@pytest.mark.parametrize("fault", ["radius", "normal"])
def test_a_wrong_bvh_or_table_is_caught(tmp_path, monkeypatch, fault):
    scene = many_cylinders(tmp_path)
    unrolled = images(scene, 10 ** 6, monkeypatch)["path"]
    original = cylinder_module.CylinderSet.__init__

    def wrong(self, shapes, base):
        original(self, shapes, base)
        if self.bvh is None:
            return
        if fault == "radius":     # the inverse map's first two rows 1% too small: radii 1% too large
            rows = self.bvh.prims.numpy().reshape(-1, 16)
            rows[:, [0, 1, 2, 4, 5, 6, 7, 8]] /= 1.01
            self.bvh.prims = type(self.bvh.prims)(rows.ravel())
        else:                     # every normal flipped
            table = self.frames_table.numpy().reshape(-1, 19)
            table[:, 18] *= -1
            self.frames_table = type(self.frames_table)(table.ravel())

    monkeypatch.setattr(cylinder_module.CylinderSet, "__init__", wrong)
    with pytest.raises(AssertionError):
        np.testing.assert_array_equal(images(scene, 0, monkeypatch)["path"], unrolled)


def test_describe_names_the_bvh(tmp_path, monkeypatch):
    scene = many_cylinders(tmp_path)
    monkeypatch.setattr(cylinder_module, "BVH_THRESHOLD", 20)
    assert "30 cylinders (quadratic, in a BVH)" in SceneGeometry(scene).describe()[0]
