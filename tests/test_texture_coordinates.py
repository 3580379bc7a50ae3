"""Texture coordinates on every shape with them, as Mitsuba 3.9.1 computes them: the same rays traced by the
tracer (tracer.geometry's closest hit and surface) and by Mitsuba (`ray_intersect`'s `si.uv`) on one shape
each: an OBJ's `vt` (flipped by default, `flip_tex_coords`), a PLY's `u, v`, a serialized mesh's stored
coordinates, a rotated sphere, disk and cylinder, a rectangle; an OBJ whose corners name coordinates for some
corners only is refused under a texture. mitsuba_scenes/textured_shapes.xml renders textures on all of them
against Mitsuba (Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive
rate ALPHA)."""
from pathlib import Path

import numpy as np
import pytest

import tracer
from tracer.geometry import SceneGeometry
from tracer.jit import INF, NO_PRIM, Array3f, Float, UInt32
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import mi, scene_errors  # noqa: F401  (mi: the fixture)
from .test_xml_loader import HEADER, write_scene

ROOT = Path(__file__).resolve().parents[1]
TEXTURE = '<bsdf type="diffuse"><texture type="checkerboard" name="reflectance"/></bsdf>'
OBJ = ("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0.1 0.2\nvt 0.9 0.1\nvt 0.8 0.7\nvt 0.2 0.95\n"
       "vn 0 0 1\nf 1/1/1 2/2/1 3/3/1 4/4/1\n")
PLY = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
property float u
property float v
element face 2
property list uchar int vertex_indices
end_header
-1 -1 0 0.1 0.2
1 -1 0 0.9 0.1
1 1 0 0.8 0.7
-1 1 0 0.2 0.95
3 0 1 2
3 0 2 3
"""
TURN = '<transform name="to_world"><rotate x="0.6" y="0.8" angle="35"/><scale value="0.8"/><translate z="0.2"/></transform>'
SHAPES = {
    "obj": f'<shape type="obj"><string name="filename" value="quad.obj"/>{TURN}{TEXTURE}</shape>',
    "obj unflipped": ('<shape type="obj"><string name="filename" value="quad.obj"/>'
                      f'<boolean name="flip_tex_coords" value="false"/>{TURN}{TEXTURE}</shape>'),
    "ply": f'<shape type="ply"><string name="filename" value="quad.ply"/>{TURN}{TEXTURE}</shape>',
    "ply flipped": ('<shape type="ply"><string name="filename" value="quad.ply"/>'
                    f'<boolean name="flip_tex_coords" value="true"/>{TURN}{TEXTURE}</shape>'),
    "serialized": (f'<shape type="serialized"><string name="filename" value="{ROOT}/mitsuba_scenes/meshes/'
                   f'quad_uv.serialized"/>{TURN}{TEXTURE}</shape>'),
    "sphere": ('<shape type="sphere"><point name="center" x="0.1" y="0" z="0.1"/><float name="radius" value="0.7"/>'
               f'{TURN}{TEXTURE}</shape>'),
    "disk": f'<shape type="disk">{TURN}{TEXTURE}</shape>',
    "flipped disk": f'<shape type="disk"><boolean name="flip_normals" value="true"/>{TURN}{TEXTURE}</shape>',
    "cylinder": ('<shape type="cylinder"><point name="p0" x="0" y="-0.3" z="-0.5"/><point name="p1" x="0.2" y="0.1" '
                 f'z="0.6"/><float name="radius" value="0.6"/>{TURN}{TEXTURE}</shape>'),
    "rectangle": f'<shape type="rectangle">{TURN}{TEXTURE}</shape>',
}
N = 400


def _rays(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rays from a sphere of radius 4 around the shapes towards points near the origin."""
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(N, 3))
    o = 4.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-0.9, 0.9, (N, 3)) - o
    return o.astype(np.float32), (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


def _ours(path: Path, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    geo = SceneGeometry(tracer.load_scene(path))
    hit = geo.closest_hit(Array3f(*o.T), Array3f(*d.T), 0.0, INF, UInt32(np.full(N, NO_PRIM, np.uint32)))
    surf = geo.surface(hit)
    return np.where(hit.valid.numpy(), hit.t.numpy(), np.inf), np.stack([Float(x).numpy() for x in surf.uv], 1)


def _mitsubas(mi, path: Path, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    scene = mi.load_file(str(path))
    t, uv = np.full(N, np.inf), np.zeros((N, 2))
    for k in range(N):
        si = scene.ray_intersect(mi.Ray3f(mi.Point3f(o[k]), mi.Vector3f(d[k])))
        if si.is_valid():
            t[k], uv[k] = si.t, si.uv
    return t, uv


@pytest.fixture
def mesh_files(tmp_path):
    (tmp_path / "quad.obj").write_text(OBJ)
    (tmp_path / "quad.ply").write_text(PLY)
    return tmp_path


@pytest.mark.parametrize("shape", SHAPES)
def test_texture_coordinates_are_mitsubas(mesh_files, shape, mi):
    path = write_scene(mesh_files, SHAPES[shape])
    o, d = _rays()
    t, uv = _ours(path, o, d)
    t_mi, uv_mi = _mitsubas(mi, path, o, d)
    both = np.isfinite(t) & np.isfinite(t_mi)
    assert both.sum() > N / 5 and (np.isfinite(t) != np.isfinite(t_mi)).sum() <= 2     # grazing rays may differ
    assert np.allclose(t[both], t_mi[both], rtol=1e-4, atol=1e-5)
    du = np.abs(uv[both] - uv_mi[both])
    du[:, 0] = np.minimum(du[:, 0], np.abs(1.0 - du[:, 0])) if shape in ("sphere", "cylinder") else du[:, 0]
    du[:, 1] = np.minimum(du[:, 1], np.abs(1.0 - du[:, 1])) if "disk" in shape else du[:, 1]
    assert du.max() < 2e-4, (shape, du.max())


def test_partial_texture_coordinates_under_a_texture_are_refused(tmp_path):
    (tmp_path / "partial.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.1 0.2\nvt 0.3 0.4\nf 1/1 2/2 3\n")
    shape = f'<shape type="obj"><string name="filename" value="partial.obj"/>{TEXTURE}</shape>'
    (error,) = scene_errors(write_scene(tmp_path, shape))
    assert "some corners only" in error
    plain = write_scene(tmp_path, '<shape type="obj"><string name="filename" value="partial.obj"/></shape>', "b.xml")
    assert len(tracer.load_scene(plain).meshes) == 1          # without a texture they are not used


SCENE = "textured_shapes.xml"


@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, 5])
def test_textured_shapes_agree_with_mitsuba(max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(plugin_passes(SCENE, "path", max_depth, 9100), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_with_the_obj_coordinates_unflipped(monkeypatch):
    def unflipped(scene):
        for m in scene.meshes:
            if m.name == "quad":
                m.uvs = m.uvs * [1.0, -1.0] + [0.0, 1.0]

    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(plugin_passes(SCENE, "path", 2, 9100, edit=unflipped), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()
