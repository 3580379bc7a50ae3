"""Many rectangles and disks go into a BVH over their boxes (tracer.shapes.rectangle.RectangleBVH), and
several emitting ones are sampled from a table (EmitterTable) rather than one unrolled sample per light:
the same images as the unrolled tests and samples, bit for bit for the path tracer (the report
estimator's sums within rounding); a table or a BVH off by a little is caught by the same comparison."""
import random

import numpy as np
import pytest

from pathlib import Path

import tracer
import tracer.shapes.rectangle as rectangle_module
from tracer.geometry import SceneGeometry, uses_bvh
from tracer.rendering import render

ROOT = Path(__file__).resolve().parents[1]

ROOM = """<scene version="3.0.0">
<sensor type="perspective"><float name="fov" value="40"/>
  <transform name="to_world"><lookat origin="0, 0, 3.9" target="0, 0, 0" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="24"/><rfilter type="box"/></film></sensor>
<bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.8"/></bsdf>
<shape type="obj"><string name="filename" value="{cube}"/><transform name="to_world"><scale value="0.2"/></transform><ref id="white"/></shape>
{shapes}
</scene>"""


def many_rectangles(tmp_path, n: int = 40):
    rng = random.Random(3)
    shapes = []
    for k in range(n):
        x, z, s = rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(0.04, 0.15)
        kind = "disk" if k % 3 == 0 else "rectangle"
        body = ('<emitter type="area"><rgb name="radiance" value="4, 3, 2"/></emitter>' if k % 4 == 1 else
                '<ref id="white"/>')
        shapes.append(f'<shape type="{kind}"><transform name="to_world"><scale x="{s}" y="{1.5 * s}"/>'
                      f'<rotate x="1" angle="{rng.uniform(-120, -60)}"/><rotate y="1" angle="{rng.uniform(0, 90)}"/>'
                      f'<translate x="{x}" y="{rng.uniform(-0.9, 0.5)}" z="{z}"/></transform>{body}</shape>')
    path = tmp_path / "rectangles.xml"
    path.write_text(ROOM.format(shapes="\n".join(shapes), cube=ROOT / "mitsuba_scenes" / "meshes" / "cube.obj"))
    return tracer.load_scene(str(path))


def images(scene, threshold: int, monkeypatch, table: bool = True) -> dict:
    with monkeypatch.context() as m:
        m.setattr(rectangle_module, "BVH_THRESHOLD", threshold)
        if not table:
            m.setattr(SceneGeometry, "_emitter_table", property(lambda self: None))
        geometry = SceneGeometry(scene)
        assert bool(geometry.bvhs) == (len(scene.rectangles) > threshold) == uses_bvh(scene)
        assert (geometry._emitter_table is not None) == table
        return {est: render(scene, est, spp=4, seed=11, max_depth=5, geometry=geometry).image
                for est in ("path", "report")}


def test_rectangles_in_a_bvh_sampled_from_a_table_render_as_unrolled(tmp_path, monkeypatch):
    scene = many_rectangles(tmp_path)
    assert sum(r.radiance is not None for r in scene.rectangles) > 5
    unrolled = images(scene, 10 ** 6, monkeypatch, table=False)
    table = images(scene, 10 ** 6, monkeypatch)
    bvh = images(scene, 0, monkeypatch)
    assert unrolled["path"].mean() > 0
    for image in (table, bvh):
        np.testing.assert_array_equal(image["path"], unrolled["path"])
        np.testing.assert_allclose(image["report"], unrolled["report"], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("fault", ["table radiance", "bvh normal"])
def test_a_wrong_table_or_bvh_is_caught(tmp_path, monkeypatch, fault):
    scene = many_rectangles(tmp_path)
    unrolled = images(scene, 10 ** 6, monkeypatch, table=False)["path"]
    cls, width, column = ((rectangle_module.EmitterTable, 20, 12) if fault == "table radiance"
                          else (rectangle_module.RectangleBVH, 16, 12))
    original = cls.__init__

    def wrong(self, *args):
        original(self, *args)
        table = self.rows if cls is rectangle_module.EmitterTable else self.prims
        rows = table.numpy().reshape(-1, width)
        rows[:, column] *= 1.02                   # a radiance or a normal's component 2% off
        setattr(self, "rows" if cls is rectangle_module.EmitterTable else "prims", type(table)(rows.ravel()))

    monkeypatch.setattr(cls, "__init__", wrong)
    with pytest.raises(AssertionError):
        np.testing.assert_array_equal(images(scene, 0, monkeypatch)["path"], unrolled)


def test_describe_names_the_rectangle_bvh(tmp_path, monkeypatch):
    scene = many_rectangles(tmp_path)
    monkeypatch.setattr(rectangle_module, "BVH_THRESHOLD", 20)
    assert "rectangles (ray-plane, eq. 2-4, in a BVH)" in SceneGeometry(scene).describe()[0]


def test_a_rooms_walls_stay_out_of_the_tiles_bvh_and_shadow_rays_skip_the_tiles(tmp_path):
    """The Cornell box with its light cut into 12 x 12 tiles: the five walls, whose boxes would overlap
    every node, are tested one by one and the tiles go into the BVH; shadow rays end in the tiles' plane, so
    none can cross a tile and their kernel walks no BVH."""
    from validation.benchmark.scene_bench import tiled_light_cornell_box

    scene = tracer.load_scene(tiled_light_cornell_box(tmp_path, 12))
    geometry = SceneGeometry(scene)
    walls = [k for k, r in enumerate(scene.rectangles) if r.radiance is None]
    assert len(walls) == 5 and geometry.rectangles.unrolled == walls
    assert len(geometry.rectangles.bvh_prims) == 144 and geometry.bvhs and not geometry.shadow_bvhs
    assert not set(range(geometry.rectangles.count)) & geometry.occluders
