"""Mitsuba's `mesh_attribute` texture: a PLY file's extra properties grouped into attributes as Mitsuba 3.9.1
groups them (checked against Mitsuba's own loader on a file written here), a vertex attribute interpolated by
the barycentric coordinates and a face attribute constant over its face (the kernel's lookups against
NumPy), the refusals, and a scene rendered against Mitsuba by the direct integrator (Welch's t-test per 4x4
block and channel, Bonferroni-corrected: family-wise false-positive rate ALPHA = 1e-3 per comparison,
reports/calibration.md) that fails when the barycentric coordinates are permuted or the face index is off
by one."""
import json

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

import tracer
from tracer.meshes import MeshError, read_ply
from tracer.shapes import mesh
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .test_xml_features import mi, scene_errors  # noqa: F401 (mi: Mitsuba in scalar_rgb, restored after)
from .test_xml_loader import write_scene

N = 3                                   # the grid's cells per side
RNG = np.random.default_rng(7)


def grid(n: int = N) -> tuple[np.ndarray, np.ndarray]:
    """A square [-1, 1]^2 in the plane z = 0 of n x n cells, two triangles each, facing -z."""
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    i = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    faces = np.concatenate([np.stack([i, i + n + 1, i + 1], 1), np.stack([i + 1, i + n + 1, i + n + 2], 1)])
    return vertices, faces


def write_ply(path, vertex_fields: dict, face_fields: dict, text: bool = False):
    """A PLY of the grid with extra vertex and face properties (name: values, in order)."""
    vertices, faces = grid()
    vertex = np.empty(len(vertices), [(k, "f4") for k in "xyz"] + [(k, v.dtype.str) for k, v in vertex_fields.items()])
    for i, k in enumerate("xyz"):
        vertex[k] = vertices[:, i]
    for k, v in vertex_fields.items():
        vertex[k] = v
    face = np.empty(len(faces), [("vertex_indices", "i4", (3,))] + [(k, v.dtype.str) for k, v in face_fields.items()])
    face["vertex_indices"] = faces
    for k, v in face_fields.items():
        face[k] = v
    PlyData([PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")], text=text).write(str(path))
    return path


def attribute_file(path):
    """Vertex properties tint_r/g/b (vertex_tint_color), temp_0 (vertex_temp), dir_x/y/z (vertex_dir),
    pair_0/1 (two channels: dropped), plain (no postfix: dropped); face properties red/green/blue as bytes
    (face_color, not normalised), weight_1 (face_weight)."""
    nv, nf = (N + 1) ** 2, 2 * N * N
    f = lambda n, k=1: RNG.random(n * k).astype(np.float32).reshape(n, k).squeeze()   # noqa: E731
    vertex = {"tint_r": f(nv), "tint_g": f(nv), "tint_b": f(nv), "temp_0": f(nv), "dir_x": f(nv), "dir_y": f(nv),
              "dir_z": f(nv), "pair_0": f(nv), "pair_1": f(nv), "plain": f(nv)}
    face = {"red": RNG.integers(0, 256, nf).astype(np.uint8), "green": RNG.integers(0, 256, nf).astype(np.uint8),
            "blue": RNG.integers(0, 256, nf).astype(np.uint8), "weight_1": f(nf)}
    return write_ply(path, vertex, face)


EXPECTED = {"vertex_tint_color": 3, "vertex_temp": 1, "vertex_dir": 3, "face_color": 3, "face_weight": 1}


def test_attributes_are_grouped_as_mitsuba_groups_them(tmp_path, mi):
    path = attribute_file(tmp_path / "a.ply")
    attributes = read_ply(path)[4]
    assert {k: v.shape[1] for k, v in attributes.values.items()} == EXPECTED and not attributes.unread
    theirs = mi.load_dict({"type": "ply", "filename": str(path)})
    names = {k for k in mi.traverse(theirs).keys() if k.startswith(("vertex_", "face_"))}
    assert names - {"vertex_positions", "vertex_normals", "vertex_texcoords", "faces"} == set(EXPECTED)
    for name, values in attributes.values.items():
        assert np.array_equal(np.array(theirs.attribute_buffer(name), np.float32), values.ravel()), name
    assert attributes.values["face_color"].max() > 1      # bytes as numbers, as Mitsuba (which warns)


@pytest.mark.parametrize("vertex, face", [
    (["red", "green", "blue", "alpha", "q_1", "q_2", "q_3"], ["s_w"]),
    (["r", "g", "b", "a", "alpha", "k_x", "k_y"], ["a_0", "a_1", "a_2"]),
    (["foo_r", "foo_g", "foo_b", "bar_0", "long_xy", "bar_z"], ["t_0", "t_1", "t_2", "t_3"]),
])
def test_more_groupings_as_mitsuba(tmp_path, mi, vertex, face):
    """Four-channel colours, red/green/blue renamed, groups of 2 and 4 (dropped), postfixes starting no row, a
    postfix of two letters closing a group."""
    n = (N + 1) ** 2, 2 * N * N
    path = write_ply(tmp_path / "b.ply", {k: RNG.random(n[0]).astype(np.float32) for k in vertex},
                     {k: RNG.random(n[1]).astype(np.float32) for k in face})
    attributes = read_ply(path)[4]
    theirs = mi.load_dict({"type": "ply", "filename": str(path)})
    names = {k for k in mi.traverse(theirs).keys() if k.startswith(("vertex_", "face_"))}
    assert names - {"vertex_positions", "vertex_normals", "vertex_texcoords", "faces"} == set(attributes.values)
    for name, values in attributes.values.items():
        assert np.array_equal(np.array(theirs.attribute_buffer(name), np.float32), values.ravel()), name


def test_ascii_and_binary_files_give_the_same_attributes(tmp_path):
    fields = {"c_x": np.arange(16, dtype=np.float32), "c_y": np.ones(16, np.float32), "c_z": np.zeros(16, np.float32)}
    a, b = (read_ply(write_ply(tmp_path / f"{t}.ply", fields, {}, text=t))[4].values for t in (True, False))
    assert list(a) == ["vertex_c"] and np.array_equal(a["vertex_c"], b["vertex_c"])


@pytest.mark.parametrize("vertex, face, words", [
    (("r", "g", "b", "color_0", "color_1", "color_2"), (), "attribute 'vertex_color'"),
    ((), ("a_0", "i0"), "face property named 'i0'")])
def test_files_mitsuba_refuses_are_refused(tmp_path, mi, vertex, face, words):
    """r, g, b and color_0, color_1, color_2 both make vertex_color; a face property named as a face index."""
    n = (N + 1) ** 2, 2 * N * N
    path = write_ply(tmp_path / "refused.ply", {k: np.zeros(n[0], np.float32) for k in vertex},
                     {k: np.zeros(n[1], np.float32) for k in face})
    with pytest.raises(MeshError, match=words):
        read_ply(path)
    with pytest.raises(RuntimeError):
        mi.load_dict({"type": "ply", "filename": str(path)})


def test_kernel_interpolates_vertex_and_holds_face_attributes(tmp_path):
    """AttributeTable.eval at random barycentric coordinates of every triangle: a vertex attribute is
    b0 v0 + b1 v1 + b2 v2 of its corners' values, a face attribute its face's value, times the scale."""
    from tracer.jit import Float, UInt32
    from tracer.materials.textures import MeshAttribute, TextureTables

    path = write_scene(tmp_path, '<shape type="ply"><string name="filename" value="a.ply"/><bsdf type="diffuse">'
                                 '<texture type="mesh_attribute" name="reflectance"><string name="name" '
                                 'value="vertex_dir"/><float name="scale" value="0.5"/></texture></bsdf></shape>')
    attribute_file(tmp_path / "a.ply")
    scene = tracer.load_scene(path)
    m = scene.meshes[0]
    sets = mesh.MeshSet([m], 0)
    table = sets.attribute_table({"vertex_dir", "face_color", "vertex_temp"})
    faces = np.repeat(np.arange(len(m.faces)), 20)
    b = RNG.dirichlet(np.ones(3), len(faces))
    hit = (UInt32(faces), Float(b[:, 1]), Float(b[:, 2]))
    values = m.attributes.values
    cases = {("vertex_dir", 0.5): (values["vertex_dir"][m.faces[faces]] * b[:, :, None]).sum(1) * 0.5,
             ("face_color", 1.0): values["face_color"][faces],
             ("vertex_temp", 2.0): np.repeat((values["vertex_temp"][m.faces[faces], 0] * b).sum(1)[:, None] * 2, 3, 1)}
    for (name, scale), expected in cases.items():
        textures = TextureTables([MeshAttribute(name, scale)], table)
        got = textures.eval(UInt32(np.ones(len(faces), np.uint32)), (Float(0), Float(0)), True, hit=hit)
        assert np.allclose(np.stack([c.numpy() for c in got], 1), expected, rtol=1e-6, atol=1e-6), name
    face = TextureTables([MeshAttribute("face_color")], table).eval(UInt32(1), (Float(0), Float(0)), True, hit=hit)
    assert np.array_equal(face.x.numpy().reshape(-1, 20), np.repeat(face.x.numpy()[::20, None], 20, 1))


# ---- refusals: one line naming the file, line, element and what is supported ------------------------------
def _scene(tmp_path, shape: str, texture: str, bsdf: str = "diffuse", slot: str = "reflectance") -> str:
    attribute_file(tmp_path / "a.ply")
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    files = {"ply": "a.ply", "obj": "a.obj"}
    filename = f'<string name="filename" value="{files[shape]}"/>' if shape in files else ""
    inner = '<bsdf type="diffuse"/><bsdf type="diffuse"/>' if bsdf == "blendbsdf" else \
        '<bsdf type="diffuse"/>' if bsdf in ("normalmap", "bumpmap") else ""
    name = f' name="{slot}"' if bsdf != "bumpmap" else ""
    path = write_scene(tmp_path, f'<shape type="{shape}">{filename}\n<bsdf type="{bsdf}">{inner}\n<texture '
                                 f'type="mesh_attribute"{name}>{texture}</texture></bsdf></shape>')
    (error,) = scene_errors(path)
    assert error.startswith(f"{path}:"), error
    return error


NAME = '<string name="name" value="{}"/>'


@pytest.mark.parametrize("shape", ["rectangle", "sphere", "obj"])
def test_a_shape_without_attributes_is_refused(tmp_path, shape):
    error = _scene(tmp_path, shape, NAME.format("vertex_tint_color"))
    assert f"on a '{shape}'" in error and "supported shapes: ply" in error and "<bsdf" in error


@pytest.mark.parametrize("texture, bsdf, slot, words", [
    (NAME.format("vertex_nothing"), "diffuse", "reflectance",
     ["<shape type=\"ply\">", "no such attribute", "vertex_tint_color (3 channels)", "vertex_temp (1 channel)"]),
    (NAME.format("vertex_tint_color"), "blendbsdf", "weight", ["3 channels where a float", "supported: 1"]),
    (NAME.format("vertex_temp"), "normalmap", "normalmap", ["1 channel where a color3", "supported: 3"]),
    (NAME.format("vertex_temp"), "bumpmap", "", ["bumpmap of a mesh_attribute", "supported: bitmap"]),
    (NAME.format("tint_color"), "diffuse", "reflectance",
     [":12: <string name=\"name\">", "starting with 'vertex_' or 'face_'"]),
    ("", "diffuse", "reflectance", ["<texture type=\"mesh_attribute\">", "needs a <string name=\"name\">"]),
])
def test_what_is_not_honoured_is_refused(tmp_path, texture, bsdf, slot, words):
    error = _scene(tmp_path, "ply", texture, bsdf, slot)
    assert all(w in error for w in words), error


def test_fields_mitsuba_groups_astray_are_refused_where_read(tmp_path):
    """a_0, b_0, a_1: Mitsuba 3.9.1 skips fields after the repeated prefix; the tracer does not guess."""
    v = {k: np.zeros(16, np.float32) for k in ("a_0", "b_0", "a_1")}
    write_ply(tmp_path / "astray.ply", v, {})
    assert read_ply(tmp_path / "astray.ply")[4].unread
    path = write_scene(tmp_path, '<shape type="ply"><string name="filename" value="astray.ply"/><bsdf type="diffuse">'
                                 f'<texture type="mesh_attribute" name="reflectance">{NAME.format("vertex_b")}'
                                 '</texture></bsdf></shape>')
    (error,) = scene_errors(path)
    assert "groups astray" in error and "'a_1'" in error


# ---- agreement with Mitsuba ---------------------------------------------------------------------------------
AGREEMENT_SCENE = """<scene version="3.0.0">
    <default name="spp" value="16"/>
    <integrator type="direct"/>
    <sensor type="perspective">
        <float name="fov" value="62"/>
        <transform name="to_world"><lookat origin="0, 0, -4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="16"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="directional">
        <vector name="direction" value="0.2, -0.3, 1"/><rgb name="irradiance" value="3"/></emitter>
    <shape type="ply">
        <string name="filename" value="a.ply"/>
        <transform name="to_world"><scale value="0.95"/><translate x="1"/></transform>
        <bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance">
            <string name="name" value="vertex_tint_color"/><float name="scale" value="0.9"/></texture></bsdf>
    </shape>
    <shape type="ply">
        <string name="filename" value="a.ply"/>
        <transform name="to_world"><scale value="0.95"/><translate x="-1"/></transform>
        <bsdf type="blendbsdf">
            <texture type="mesh_attribute" name="weight"><string name="name" value="face_weight"/></texture>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.9, 0.2, 0.1"/></bsdf>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.3, 0.9"/></bsdf>
        </bsdf>
    </shape>
</scene>
"""
PASSES, SPP = 16, 16


@pytest.fixture(scope="module")
def agreement(tmp_path_factory):
    """The scene (a vertex colour on the right square, a blend weighted by a face attribute on the left) and
    Mitsuba's passes of it."""
    from validation.verdict.mitsuba_render import render_passes

    folder = tmp_path_factory.mktemp("agreement")
    attribute_file(folder / "a.ply")
    path = folder / "scene.xml"
    path.write_text(AGREEMENT_SCENE)
    return path, render_passes(path, PASSES, SPP, seed=12345)


def _tracer_passes(path) -> np.ndarray:
    from tracer.rendering import render

    scene = tracer.load_scene(path)
    return np.stack([render(scene, "path", seed=9000 + k, spp=SPP).image for k in range(PASSES)])


def permuted(original):
    """AttributeTable.eval reading b2 for b1 and b1 for b2."""
    return lambda self, row, hit, active: original(self, row, (hit[0], hit[2], hit[1]), active)


def off_by_one(original):
    """AttributeTable.eval reading the next triangle."""
    return lambda self, row, hit, active: original(self, row, (hit[0] + 1, hit[1], hit[2]), active)


@pytest.mark.slow
@pytest.mark.parametrize("mistake", [None, permuted, off_by_one])
def test_agrees_with_mitsuba_and_fails_on_a_mistake(monkeypatch, agreement, mistake):
    path, ref = agreement
    if mistake is not None:
        monkeypatch.setattr(mesh.AttributeTable, "eval", mistake(mesh.AttributeTable.eval))
    result = compare_passes(_tracer_passes(path), ref, ALPHA)
    assert result.verdict == ("agree" if mistake is None else "disagree"), result.summary()


def test_scene_json_carries_the_attributes(tmp_path):
    """{scene_json}'s PLY files hold each mesh's attributes under names Mitsuba's ply reads back as the same."""
    from validation.verdict import scenejson
    from validation.verdict.scenefile import plan

    attribute_file(tmp_path / "a.ply")
    (tmp_path / "scene.xml").write_text(AGREEMENT_SCENE)
    p = plan(tmp_path / "scene.xml", {}, size=8)
    data = json.loads(scenejson.write(p, tmp_path / "json").read_text())
    assert data["materials"][0]["texture"]["name"] == "vertex_tint_color"
    for shape, written in zip(p.tracer_scene().shapes, data["shapes"]):
        back = read_ply(tmp_path / "json" / written["mesh"])[4].values
        assert set(back) == set(EXPECTED) and all(np.array_equal(back[k], shape.attributes.values[k]) for k in back)


def test_an_instanced_mesh_reads_its_attributes(tmp_path):
    """A PLY mesh inside a shapegroup, drawn by an instance, shows the attributes it shows placed directly."""
    from tracer.rendering import render

    attribute_file(tmp_path / "a.ply")
    texture = ('<bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance"><string name="name" '
               'value="face_color"/><float name="scale" value="0.003"/></texture></bsdf>')
    placed = '<transform name="to_world"><translate x="0.2"/></transform>'
    ply = f'<shape type="ply"><string name="filename" value="a.ply"/>{texture}{{}}</shape>'
    body = AGREEMENT_SCENE[:AGREEMENT_SCENE.index("<shape")] + "{}</scene>"
    direct = body.format(ply.format(placed))
    group = body.format(f'<shape type="shapegroup" id="g">{ply.format("")}</shape>'
                        f'<shape type="instance"><ref id="g"/>{placed}</shape>')
    images = []
    for name, xml in (("direct.xml", direct), ("group.xml", group)):
        (tmp_path / name).write_text(xml)
        images.append(render(tracer.load_scene(tmp_path / name), "path", seed=3, spp=4).image)
    assert images[0].mean() > 0.05 and np.mean(np.abs(images[0] - images[1]) < 1e-4) > 0.99


def test_report_estimator_refuses_mesh_attributes(tmp_path):
    attribute_file(tmp_path / "a.ply")
    (tmp_path / "scene.xml").write_text(AGREEMENT_SCENE)
    (line,) = tracer.load_scene(tmp_path / "scene.xml").estimator_refusals("report")
    assert "mesh_attribute" in line and "--estimator path" in line


@pytest.mark.parametrize("pairs", [("texture_s", "texture_t"), ("s", "t", "texture_u", "texture_v"),
                                   ("u", "v", "s", "t")])
def test_texture_coordinates_are_the_pair_mitsuba_reads(tmp_path, mi, pairs):
    """u, v, else texture_u, texture_v, else s, t (Mitsuba 3.9.1 reads no texture_s, texture_t)."""
    fields = {k: RNG.random((N + 1) ** 2).astype(np.float32) for k in pairs}
    path = write_ply(tmp_path / "uv.ply", fields, {})
    ours = read_ply(path)[3]
    theirs = mi.load_dict({"type": "ply", "filename": str(path)})
    if not theirs.has_vertex_texcoords():
        assert ours is None
    else:
        assert np.array_equal(np.array(mi.traverse(theirs)["vertex_texcoords"]), ours.astype(np.float32).ravel())
