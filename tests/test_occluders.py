"""Shadow rays skip planar primitives that no segment from the scene to a light crosses strictly: the scene
reaches strictly to one side of the plane only where no light lies strictly on the other (a wall with the
whole scene on one side, a light in its own plane); they can never block one."""
import numpy as np
import pytest

import tracer
from tracer.geometry import SceneGeometry
from tracer.shapes.mesh import Mesh, MeshSet
from tracer.jit import Array3f, Float, UInt32

from .conftest import SCENES

SENSOR = """<sensor type="perspective"><transform name="to_world"><lookat origin="0, 0, 1.9" target="0, 0, 0"
  up="0, 1, 0"/></transform><film type="hdrfilm"><integer name="width" value="8"/><integer name="height"
  value="8"/></film></sensor>"""


def test_convex_room_walls_and_its_light_are_not_occluders():
    """The walls have the room on one side; the light, under the ceiling, has the ceiling above it and the
    room below, but shadow rays end in its plane, so none crosses it strictly."""
    geo = SceneGeometry(tracer.load_scene(SCENES / "hexagon_room.xml"))
    names = {i: r.name for i, r in enumerate(geo.rectangles.shapes)}
    kept = {names.get(i, "mesh or sphere") for i in geo.occluders}
    assert kept == {"mesh or sphere"}
    tetra = set(range(geo.meshes.base + 8, geo.meshes.base + 12))  # floor (4) and ceiling (4) triangles come first
    assert tetra <= geo.occluders and not (set(range(geo.meshes.base, geo.meshes.base + 8)) & geo.occluders)


def test_culled_occluders_change_no_shadow_ray_from_the_scene_to_the_light():
    """Segments from points on the room's surfaces to points on its light: blocked the same with and
    without culling."""
    scene = tracer.load_scene(SCENES / "hexagon_room.xml")
    culled, full = SceneGeometry(scene), SceneGeometry(scene)
    full.occluders = set(range(full.n_prims))
    rng = np.random.default_rng(3)
    n = 20000
    o = Array3f(*(np.array([5, 0, 0]) + rng.uniform(-3, 3, (n, 3))).T)
    d = rng.normal(size=(n, 3))
    d = Array3f(*(d / np.linalg.norm(d, axis=1, keepdims=True)).T)
    none = UInt32(0xFFFFFFFF)
    hit = culled.closest_hit(o, d, 0.0, float("inf"), none)          # points on the room's surfaces
    ok = hit.valid.numpy()
    x = (o + d * hit.t).numpy().T[ok]
    half = len(x)
    light, = scene.emitters
    e1, e2 = light.edges
    ab = rng.uniform(-1, 1, (half, 2))
    y = light.center + ab[:, :1] * e1 + ab[:, 1:] * e2                 # points on the light
    seg = y - x
    dist = np.linalg.norm(seg, axis=1)
    w = Array3f(*(seg / dist[:, None]).T)
    args = (Array3f(*x.T), w, Float(dist), UInt32(hit.prim.numpy()[ok]), UInt32(culled.prim_range(light)[0]))
    a = culled.occluded(*args).numpy()
    b = full.occluded(*args).numpy()
    assert 0.1 < b.mean() < 0.9                                       # both blocked and free segments
    # They may differ only for segments lying in a culled primitive's plane (two points on the floor):
    # the full test then reports a rounding-level graze of a coplanar neighbour, the culled one cannot.
    culled_planes = [(p0, n) for shapes in culled.shape_sets for i, p0, n in shapes.culling_planes()
                     if i not in culled.occluders]
    in_plane = np.zeros(half, bool)
    for p0, n in culled_planes:
        in_plane |= (np.abs((x - p0) @ n) < 1e-5) & (np.abs((y - p0) @ n) < 1e-5)
    differ = a != b
    assert not np.any(differ & ~in_plane), np.flatnonzero(differ & ~in_plane)


def test_mesh_side_bounds_hold_every_side():
    """The bounds from which the culling decides without a mesh's sides hold each side it would compute,
    for planes through or beside its vertices, and decide planes clear of it."""
    rng = np.random.default_rng(5)
    vertices = rng.normal(size=(500, 3)) * [1, 20, 3e-3] + [4, 0, -1]
    meshes = MeshSet([Mesh(vertices, rng.integers(0, 500, (800, 3)), bsdf=None)], base=0)
    axes = [s * np.eye(3)[k] * (1 + 1e-9 * rng.normal(size=3)) for k in range(3) for s in (-1, 1)]
    for _ in range(300):
        n = axes[rng.integers(6)] if rng.random() < 0.3 else rng.normal(size=3)   # the box touches the sides
        n /= np.linalg.norm(n)
        p0 = vertices[np.argmin(vertices @ n) if rng.random() < 0.5 else rng.integers(500)]
        p0 = p0 + n * rng.choice([0, 1e-12, -1e-12, 1e-3])
        side = meshes.sides(p0, n)
        lo, hi = meshes.side_bounds(p0, n)
        assert lo <= side.min() and side.max() <= hi
    assert meshes.side_bounds(np.array([30.0, 0, 0]), np.array([1.0, 0, 0]))[1] < 0


def _occluders_from_every_side(geo: SceneGeometry) -> set[int]:
    """SceneGeometry._possible_occluders computing every side (no bounds): a plane is kept where a light
    lies strictly below it and the scene strictly above, or the reverse."""
    eps = 1e-6 * geo.scene.extent()
    ends, radii = geo._light_hull()
    keep = set(range(geo.curved_base, geo.n_prims))
    for shapes in geo.shape_sets:
        for i, p0, n in shapes.culling_planes():
            light = (ends - p0) @ n
            side = np.concatenate([s.sides(p0, n) for s in geo.shape_sets if s.count])
            if (np.any(light - radii < -eps) and np.any(side > eps)) or (np.any(light + radii > eps)
                                                                           and np.any(side < -eps)):
                keep.add(i)
    return keep


def test_light_hull_holds_every_emitter_and_point_light(tmp_path):
    """The balls that bound where shadow rays end: a rectangle's corners, a sphere's ball, a mesh's
    vertices and a point light's position."""
    path = tmp_path / "lights.xml"
    path.write_text(f"""<scene version="3.0.0">{SENSOR}
<shape type="rectangle"><transform name="to_world"><scale x="2" y="3"/><translate z="5"/></transform>
  <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
<shape type="sphere"><point name="center" x="0" y="7" z="0"/><float name="radius" value="0.5"/>
  <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
<shape type="obj"><string name="filename" value="{SCENES / 'meshes' / 'cube.obj'}"/>
  <transform name="to_world"><translate x="-9"/></transform>
  <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
<shape type="sphere"><float name="radius" value="40"/></shape>
<emitter type="point"><point name="position" x="1" y="2" z="3"/></emitter>
</scene>""")
    geo = SceneGeometry(tracer.load_scene(path))
    ends, radii = geo._light_hull()
    assert [1, 2, 3] in ends.tolist() and [-2, -3, 5] in ends.tolist() and [2, 3, 5] in ends.tolist()
    assert [0, 7, 0] in ends.tolist() and radii[ends.tolist().index([0, 7, 0])] == 0.5
    assert ends[:, 0].min() == -10 and len(ends) == 1 + 4 + 1 + 8


def test_a_tile_between_the_lights_and_the_scene_still_blocks(tmp_path):
    """Of two tiles in the light's plane, one emitting and one not, both are left out; a tile below the
    light's plane, between it and the floor, is kept; a light below the tiles' plane keeps them all."""
    def occluders(light_z: float) -> set[str]:
        tiles = "".join(f"""<shape type="rectangle" id="{name}"><transform name="to_world"><scale value="0.2"/>
  <rotate x="1" angle="180"/><translate x="{x}" z="{z}"/></transform>{body}</shape>"""
                        for name, x, z, body in [("light", 0, light_z, '<emitter type="area"><rgb name="radiance" value="5"/></emitter>'),
                                                 ("beside", 0.5, 1.5, ""), ("below", 0, 1, "")])
        path = tmp_path / "tiles.xml"
        path.write_text(f"""<scene version="3.0.0">{SENSOR}{tiles}
<shape type="rectangle" id="floor"/><shape type="rectangle" id="ceiling"><transform name="to_world">
  <rotate x="1" angle="180"/><translate z="2"/></transform></shape></scene>""")
        geo = SceneGeometry(tracer.load_scene(path))
        assert geo.occluders == _occluders_from_every_side(geo)
        return {geo.rectangles.shapes[i].name for i in geo.occluders}
    assert occluders(1.5) == {"below"}
    assert occluders(0.5) == {"beside", "below"}


@pytest.mark.parametrize("bvh_threshold", [0, 10 ** 6])
def test_occluders_decided_from_bounds_are_those_of_every_side(bvh_threshold):
    geo = SceneGeometry(tracer.load_scene(SCENES / "hexagon_room.xml"), bvh_threshold=bvh_threshold)
    assert geo.occluders == _occluders_from_every_side(geo)
