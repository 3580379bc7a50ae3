"""The Mitsuba XML loader (tracer/mitsuba_xml.py): the project's scenes, parameters, transforms, errors."""
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tracer import SceneError, load_scene

ROOT = Path(__file__).resolve().parents[1]
HEXAGON = ROOT / "mitsuba_scenes" / "hexagon_room.xml"
CORNELL = ROOT / "mitsuba_scenes" / "cornell_box.xml"

HEADER = """<?xml version="1.0" encoding="utf-8"?>
<scene version="3.0.0">
    <sensor type="perspective">
        <film type="hdrfilm">
            <integer name="width" value="8"/>
            <integer name="height" value="6"/>
            <rfilter type="box"/>
        </film>
    </sensor>
"""


def write_scene(folder: Path, body: str, name: str = "scene.xml", header: str = HEADER) -> Path:
    path = folder / name
    path.write_text(header + body + "\n</scene>\n")
    return path


def line_of(path: Path, snippet: str) -> int:
    """1-based number of the (only) line containing `snippet`."""
    lines = [i for i, line in enumerate(path.read_text().splitlines(), 1) if snippet in line]
    assert len(lines) == 1, (snippet, lines)
    return lines[0]


def scene_error(path: Path, **overrides) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(path, **overrides)
    message = str(info.value)
    assert "\n" not in message and message.strip() == message, "the message must be a single line"
    return message


def assert_located(message: str, path: Path, line: int) -> None:
    assert f"{path.name}:{line}:" in message, message
    assert str(path) in message


# ---- the project's scenes -----------------------------------------------------------------------------
def test_hexagon_room_contents_and_defaults():
    s = load_scene(HEXAGON)
    assert (len(s.rectangles), len(s.meshes), len(s.spheres)) == (7, 3, 2)
    assert s.triangle_count == 12                        # floor and ceiling fans of 4, tetrahedron 4
    assert (s.spp, s.max_depth, s.seed, s.rr_depth) == (64, 4, 0, 5)
    assert (s.camera.width, s.camera.height, s.camera.fov, s.camera.fov_axis) == (600, 600, 90.0, "x")
    assert s.path == HEXAGON
    # the sensor's lookat: +z towards the target, +x to the left of the up vector, origin at the eye
    assert np.allclose(s.camera.to_world[:3, :], [[0, 0, 1, -1], [1, 0, 0, 0], [0, 1, 0, 0]])
    # the one light: x in [2, 6], y in [-1, 1] at z = 4.9, facing down, radiance 32
    (light,) = s.emitters
    assert light.radiance == (32.0, 32.0, 32.0)
    assert np.allclose(light.center, [4, 0, 4.9]) and np.allclose(light.normal, [0, 0, -1])
    assert light.area == pytest.approx(8.0)
    mirror, glass = s.spheres
    assert np.allclose(mirror.center, [6, -2, -1]) and mirror.radius == 2.0 and mirror.bsdf.kind == "conductor"
    assert np.allclose(glass.center, [2, 1, 1]) and glass.radius == 1.0
    assert (glass.bsdf.kind, glass.bsdf.int_ior, glass.bsdf.ext_ior) == ("dielectric", 1.5, 1.0)
    assert {m.name for m in s.meshes} == {"floor", "ceiling", "tetrahedron"}
    assert all(m.normals is None for m in s.meshes)      # face_normals = true
    # walls: each normal points into the room (towards its centre, x = 5)
    for r in s.rectangles[:6]:
        assert np.dot(r.normal, np.array([5.0, 0.0, 0.0]) - r.center) > 0, r.name


def test_cornell_box_contents_and_defaults():
    s = load_scene(CORNELL)
    assert (len(s.rectangles), len(s.meshes), len(s.spheres)) == (6, 2, 0)
    assert s.triangle_count == 24
    assert (s.spp, s.max_depth, s.camera.width, s.camera.height) == (64, 6, 256, 256)
    assert s.camera.fov == pytest.approx(39.3077)
    assert [r.name for r in s.emitters] == ["light"]
    # the blocks are the unit cube scaled, rotated and moved: their vertices stay inside the room
    for m in s.meshes:
        assert np.all(np.abs(m.vertices) <= 1.0 + 1e-9), m.name
    floor = next(r for r in s.rectangles if r.name == "floor")
    assert np.allclose(floor.center, [0, -1, 0]) and np.allclose(floor.normal, [0, 1, 0])


def test_parameter_overrides_take_effect():
    s = load_scene(HEXAGON, spp=3, width=10)
    assert (s.spp, s.camera.width, s.camera.height, s.max_depth) == (3, 10, 600, 4)
    s = load_scene(CORNELL, max_depth="2", height="5", seed=7)  # -D passes strings
    assert (s.max_depth, s.camera.height, s.seed, s.spp) == (2, 5, 7, 64)


def test_unknown_override_is_named():
    message = scene_error(HEXAGON, spp=3, bogus_param=1)
    assert "bogus_param" in message and HEXAGON.name in message
    assert "spp" in message                       # and it lists the parameters the scene does use


def test_override_to_invalid_value_is_reported():
    message = scene_error(HEXAGON, spp="many")
    assert "'many' is not an integer" in message
    assert_located(message, HEXAGON, line_of(HEXAGON, 'name="sample_count"'))


# ---- transforms ---------------------------------------------------------------------------------------
def _rect_to_world(tmp_path, ops: str) -> np.ndarray:
    path = write_scene(tmp_path, f'<shape type="rectangle"><transform name="to_world">{ops}</transform></shape>')
    (r,) = load_scene(path).rectangles
    return r.to_world


def _affine(linear=np.eye(3), offset=(0, 0, 0)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = linear, offset
    return m


RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # right-handed: x -> y


def test_rotate_then_translate(tmp_path):
    m = _rect_to_world(tmp_path, '<rotate z="1" angle="90"/><translate x="1" y="2"/>')
    expected = _affine(offset=(1, 2, 0)) @ _affine(RZ90)     # later operations on the left
    assert np.allclose(m, expected, atol=1e-12)
    assert np.allclose(m[:3, 3], [1, 2, 0])                # the centre only moves by the translation


def test_translate_then_rotate(tmp_path):
    m = _rect_to_world(tmp_path, '<translate x="1" y="2"/><rotate z="1" angle="90"/>')
    assert np.allclose(m, _affine(RZ90) @ _affine(offset=(1, 2, 0)), atol=1e-12)
    assert np.allclose(m[:3, 3], [-2, 1, 0])               # the translation is rotated too


def test_scale_then_rotate_about_an_oblique_axis(tmp_path):
    m = _rect_to_world(tmp_path, '<scale x="2" y="3"/><rotate x="1" y="-2" z="0.5" angle="-33"/>'
                                 '<scale value="0.5"/>')
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    rot = Rotation.from_rotvec(np.radians(-33.0) * axis).as_matrix()
    expected = _affine(0.5 * np.eye(3)) @ _affine(rot) @ _affine(np.diag([2.0, 3.0, 1.0]))
    assert np.allclose(m, expected, atol=1e-12)


def test_matrix_is_row_major_and_composes(tmp_path):
    values = [1, 2, 0, 4, 0, 1, 0, 5, 0, 0, 3, 6, 0, 0, 0, 1]
    m = _rect_to_world(tmp_path, f'<matrix value="{" ".join(map(str, values))}"/><translate z="-1"/>')
    assert np.allclose(m, _affine(offset=(0, 0, -1)) @ np.array(values, float).reshape(4, 4))
    m3 = _rect_to_world(tmp_path, '<matrix value="0 -1 0  1 0 0  0 0 1"/>')   # 9 values: linear part
    assert np.allclose(m3, _affine(RZ90))


def test_lookat_camera_and_composition(tmp_path):
    header = HEADER.replace('<sensor type="perspective">',
                            '<sensor type="perspective"><transform name="to_world">'
                            '<lookat origin="1, 2, 3" target="1, 2, -7" up="0, 1, 0"/>'
                            '<translate x="10"/></transform>')
    s = load_scene(write_scene(tmp_path, "", header=header))
    m = s.camera.to_world
    # forward (+z) is the viewing direction, +y is up, +x = up x forward points left (Mitsuba)
    forward, up = np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
    assert np.allclose(m[:3, 2], forward) and np.allclose(m[:3, 1], up)
    assert np.allclose(m[:3, 0], np.cross(up, forward))
    assert np.allclose(m[:3, 3], [11, 2, 3])               # the eye, then moved by the later translate


def test_sphere_transform_moves_centre_and_scales_radius(tmp_path):
    path = write_scene(tmp_path, '''
    <shape type="sphere">
        <point name="center" x="1" y="0" z="0"/>
        <float name="radius" value="0.5"/>
        <transform name="to_world"><scale value="3"/><translate y="4"/></transform>
    </shape>''')
    (sp,) = load_scene(path).spheres
    assert np.allclose(sp.center, [3, 4, 0]) and sp.radius == pytest.approx(1.5)


# ---- errors: one line naming the file and the line --------------------------------------------------
def test_malformed_xml(tmp_path):
    path = write_scene(tmp_path, '<shape type="rectangle">\n    </shap>\n', name="broken.xml")
    message = scene_error(path)
    assert_located(message, path, line_of(path, "</shap>"))
    assert "malformed XML" in message


def test_missing_scene_file(tmp_path):
    message = scene_error(tmp_path / "nowhere.xml")
    assert "nowhere.xml" in message


@pytest.mark.parametrize("body,snippet,words", [
    ('<shape type="bsplinecurve"/>', 'type="bsplinecurve"', ["bsplinecurve", "supported", "rectangle"]),
    ('<shape type="rectangle">\n        <bsdf type="hair"/>\n    </shape>', 'type="hair"',
     ["hair", "supported", "diffuse"]),
    ('<shape type="rectangle">\n        <emitter type="spot"/>\n    </shape>', 'type="spot"', ["spot", "supported"]),
    ('<integrator type="prbvolpath"/>', 'type="prbvolpath"', ["prbvolpath", "supported", "path"]),
])
def test_unsupported_plugin(tmp_path, body, snippet, words):
    path = write_scene(tmp_path, body, name="plugins.xml")
    message = scene_error(path)
    assert_located(message, path, line_of(path, snippet))
    for w in words:
        assert w in message


def test_unsupported_bsdf_through_a_reference_points_at_its_definition(tmp_path):
    path = write_scene(tmp_path, '''
    <bsdf type="hair" id="shiny"/>
    <shape type="rectangle">
        <ref id="shiny"/>
    </shape>''', name="refs.xml")
    message = scene_error(path)
    assert_located(message, path, line_of(path, 'type="hair"'))
    assert "hair" in message and "supported" in message


def test_missing_mesh_file(tmp_path):
    path = write_scene(tmp_path, '''
    <shape type="obj">
        <string name="filename" value="meshes/gone.obj"/>
    </shape>''', name="mesh.xml")
    message = scene_error(path)
    assert_located(message, path, line_of(path, 'type="obj"'))
    assert "meshes/gone.obj" in message and "not found" in message


def test_malformed_mesh_file(tmp_path):
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    path = write_scene(tmp_path, '<shape type="obj"><string name="filename" value="bad.obj"/></shape>')
    message = scene_error(path)
    assert_located(message, path, line_of(path, 'type="obj"'))
    assert "bad.obj:4" in message                          # and the OBJ's own line


def test_binary_mesh_file(tmp_path):
    (tmp_path / "blob.obj").write_bytes(bytes(range(256)))
    path = write_scene(tmp_path, '<shape type="obj"><string name="filename" value="blob.obj"/></shape>')
    message = scene_error(path)
    assert_located(message, path, line_of(path, 'type="obj"'))
    assert "blob.obj" in message and "not a text" in message


def test_a_shared_mesh_file_is_read_once_until_it_changes(tmp_path):
    from tracer.meshes import _read_obj

    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    shape = '<shape type="obj"><string name="filename" value="tri.obj"/></shape>'
    path = write_scene(tmp_path, shape + shape)
    misses = _read_obj.cache_info().misses
    a, b = load_scene(path).meshes
    assert _read_obj.cache_info().misses == misses + 1 and not a.faces.flags.writeable
    mesh.write_text("v 0 0 0\nv 2.5 0 0\nv 0 1 0\nf 1 2 3\n")   # another size, whatever the clock
    assert load_scene(path).meshes[0].vertices[:, 0].max() == 2.5


def test_mesh_files_read_together_keep_the_shapes_order_and_each_error_its_element(tmp_path):
    """The loader reads a scene's mesh files together, on threads, after checking every element: the
    meshes keep their places among the other shapes, and each broken file is refused at its own element."""
    (tmp_path / "one.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "two.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 2 0\nv 0 0 2\nf 1 2 3\nf 1 2 4\n")
    (tmp_path / "binary.obj").write_bytes(bytes(range(256)))
    (tmp_path / "empty.obj").write_text("v 0 0 0\n")
    shape = '\n    <shape type="obj"><string name="filename" value="{}"/></shape>'.format
    good = shape("two.obj") + '\n    <shape type="sphere"/>' + shape("one.obj")
    s = load_scene(write_scene(tmp_path, good))
    assert [type(x).__name__ for x in s.shapes] == ["Mesh", "Sphere", "Mesh"]
    assert [len(m.faces) for m in s.meshes] == [2, 1]
    path = write_scene(tmp_path, good + shape("binary.obj") + shape("empty.obj"), name="broken.xml")
    from .test_xml_features import scene_errors

    binary, empty = scene_errors(path)
    assert_located(binary, path, line_of(path, "binary.obj"))
    assert_located(empty, path, line_of(path, "empty.obj"))
    assert "not a text" in binary and "no faces" in empty


@pytest.mark.parametrize("body,snippet,bad", [
    ('<shape type="sphere">\n        <float name="radius" value="nan"/>\n    </shape>', 'value="nan"', "nan"),
    ('<shape type="rectangle"><transform name="to_world">\n        <translate x="inf"/>\n'
     '    </transform></shape>', 'x="inf"', "inf"),
    ('<shape type="sphere">\n        <point name="center" value="0, 1e999, 0"/>\n    </shape>', "1e999", "1e999"),
    ('<shape type="rectangle">\n        <emitter type="area"><rgb name="radiance" value="1, -nan, 1"/>'
     '</emitter>\n    </shape>', "-nan", "-nan"),
])
def test_non_finite_number(tmp_path, body, snippet, bad):
    path = write_scene(tmp_path, body, name="numbers.xml")
    message = scene_error(path)
    assert_located(message, path, line_of(path, snippet))
    assert f"'{bad}' is not a finite number" in message


def test_undefined_parameter(tmp_path):
    header = HEADER.replace('<film type="hdrfilm">',
                            '<sampler type="independent">\n'
                            '            <integer name="sample_count" value="$samples"/>\n'
                            '        </sampler>\n        <film type="hdrfilm">')
    path = write_scene(tmp_path, "", header=header, name="params.xml")
    message = scene_error(path)
    assert_located(message, path, line_of(path, "$samples"))
    assert "$samples" in message
    # and supplying it fixes the scene
    assert load_scene(path, samples=5).spp == 5


# ---- reconstruction filters ---------------------------------------------------------------------------
def _with_filter(tmp_path, rfilter: str) -> Path:
    return write_scene(tmp_path, "", header=HEADER.replace('<rfilter type="box"/>', rfilter))


@pytest.mark.parametrize("rfilter, expected", [
    ('<rfilter type="box"/>', ("box", 0.5)),
    ("", ("gaussian", 2.0)),                                   # Mitsuba's default: gaussian, stddev 0.5
    ('<rfilter type="gaussian"><float name="stddev" value="0.25"/></rfilter>', ("gaussian", 1.0)),
    ('<rfilter type="tent"/>', ("tent", 1.0)),
    ('<rfilter type="tent"><float name="radius" value="1.5"/></rfilter>', ("tent", 1.5)),
])
def test_rfilter_kind_and_radius(tmp_path, rfilter, expected):
    f = load_scene(_with_filter(tmp_path, rfilter)).camera.rfilter
    assert (f.kind, f.radius) == expected


@pytest.mark.parametrize("rfilter, words", [
    ('<rfilter type="mitchell"/>', "supported: box, gaussian, tent"),
    ('<rfilter type="tent"><float name="stddev" value="1"/></rfilter>', "supported: radius"),
    ('<rfilter type="gaussian"><float name="stddev" value="0"/></rfilter>', "must lie in (0, 8]"),
])
def test_bad_rfilter_is_refused_with_its_line(tmp_path, rfilter, words):
    path = _with_filter(tmp_path, rfilter)
    message = scene_error(path)
    assert words in message
    assert_located(message, path, line_of(path, "<rfilter"))
