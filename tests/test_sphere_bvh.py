"""Many spheres go into a BVH over their boxes (tracer.shapes.sphere.SphereBVH): the same images as the
unrolled sphere tests, bit for bit for the path tracer (the report estimator's sums within rounding), an
emitting sphere among them included; and a BVH with its spheres' radii off by 1% is caught by the same
comparison."""
import random

import numpy as np
import pytest

import tracer
import tracer.shapes.sphere as sphere_module
from tracer.geometry import SceneGeometry, uses_bvh
from tracer.rendering import render

ROOM = """<scene version="3.0.0">
<sensor type="perspective"><float name="fov" value="40"/>
  <transform name="to_world"><lookat origin="0, 0, 3.9" target="0, 0, 0" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="{size}"/><integer name="height" value="{size}"/><rfilter type="box"/></film></sensor>
<bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.8"/></bsdf>
<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><translate y="-1"/></transform><ref id="white"/></shape>
<shape type="rectangle"><transform name="to_world"><translate z="-1"/></transform><ref id="white"/></shape>
<shape type="rectangle"><transform name="to_world"><scale x="0.3" y="0.3"/><rotate x="1" angle="90"/><translate y="0.99"/></transform>
  <emitter type="area"><rgb name="radiance" value="10"/></emitter></shape>
{shapes}
</scene>"""


def many_spheres(tmp_path, n: int = 40):
    rng = random.Random(5)
    spheres = []
    for k in range(n):
        x, z, r = rng.uniform(-0.9, 0.9), rng.uniform(-0.9, 0.9), rng.uniform(0.03, 0.15)
        body = ('<emitter type="area"><rgb name="radiance" value="3"/></emitter>' if k == 7 else
                '<bsdf type="dielectric"/>' if k % 5 == 0 else '<ref id="white"/>')
        spheres.append(f'<shape type="sphere"><point name="center" x="{x}" y="{-1 + r}" z="{z}"/>'
                       f'<float name="radius" value="{r}"/>{body}</shape>')
    path = tmp_path / "spheres.xml"
    path.write_text(ROOM.format(size=24, shapes="\n".join(spheres)))
    return tracer.load_scene(str(path))


def images(scene, threshold: int, monkeypatch) -> dict:
    monkeypatch.setattr(sphere_module, "BVH_THRESHOLD", threshold)
    geometry = SceneGeometry(scene)
    assert bool(geometry.bvhs) == (len(scene.of_kind(sphere_module.Sphere)) > threshold) == uses_bvh(scene)
    return {est: render(scene, est, spp=4, seed=11, max_depth=5, geometry=geometry).image
            for est in ("path", "report")}


def test_spheres_in_a_bvh_render_as_unrolled(tmp_path, monkeypatch):
    scene = many_spheres(tmp_path)
    unrolled, bvh = images(scene, 10 ** 6, monkeypatch), images(scene, 0, monkeypatch)
    assert unrolled["path"].mean() > 0
    np.testing.assert_array_equal(bvh["path"], unrolled["path"])
    np.testing.assert_allclose(bvh["report"], unrolled["report"], rtol=1e-5, atol=1e-6)


def test_a_bvh_with_wrong_radii_is_caught(tmp_path, monkeypatch):
    scene = many_spheres(tmp_path)
    unrolled = images(scene, 10 ** 6, monkeypatch)["path"]
    original = sphere_module.SphereBVH.__init__

    def wrong_radii(self, spheres, prim_base):
        original(self, spheres, prim_base)
        rows = self.prims.numpy().reshape(-1, 8)
        rows[:, 4] *= 1.02        # squared radii: radii 1% too large
        self.prims = type(self.prims)(rows.ravel())

    monkeypatch.setattr(sphere_module.SphereBVH, "__init__", wrong_radii)
    with pytest.raises(AssertionError):
        np.testing.assert_array_equal(images(scene, 0, monkeypatch)["path"], unrolled)


def test_describe_names_the_bvh(tmp_path, monkeypatch):
    scene = many_spheres(tmp_path)
    monkeypatch.setattr(sphere_module, "BVH_THRESHOLD", 20)
    geometry = SceneGeometry(scene)
    lines = geometry.describe()
    assert "40 spheres (quadratic, in a BVH)" in lines[0]
    assert any("bounce by bounce" in line for line in lines) == geometry.bounce_by_bounce
