"""Every reader refuses a malformed or truncated file in one line naming the file and the scene element that
named it, and the loader refuses what Mitsuba 3 refuses structurally (each case checked against Mitsuba's
own loader, `mitsuba_refuses`); found by the fuzzer (validation/suites/fuzz.py), kept here as classes of input."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tracer import SceneError, load_scene
from tracer.cli import main

from .test_xml_features import TRI, scene_errors
from .test_xml_loader import HEADER, write_scene

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT / "mitsuba_scenes" / "meshes"


def mitsuba_refuses(path: Path) -> bool:
    from validation.suites.fuzz import mitsuba_refuses as refuses
    return refuses(path)


def refused(path: Path, *fragments: str, mitsuba: bool = True) -> str:
    """The scene's one refusal, which names the file and holds `fragments`; Mitsuba refuses the scene too."""
    (error,) = scene_errors(path)
    assert str(path) in error or path.name in error, error
    for fragment in fragments:
        assert fragment in error, error
    if mitsuba:
        assert mitsuba_refuses(path), "Mitsuba accepts this scene"
    return error


def mesh_scene(tmp_path: Path, kind: str, data: bytes, name: str | None = None) -> Path:
    file = tmp_path / (name or f"mesh.{kind}")
    file.write_bytes(data)
    return write_scene(tmp_path, f'<shape type="{kind}"><string name="filename" value="{file.name}"/></shape>')


# ---- corrupted and truncated files ----------------------------------------------------------------------
@pytest.mark.parametrize("cut", [9, 30, 60, 90])
def test_truncated_serialized_mesh(tmp_path, cut):
    data = (MESHES / "cube.serialized").read_bytes()
    path = mesh_scene(tmp_path, "serialized", data[:cut])
    error = refused(path, "mesh.serialized", '<shape type="serialized">')
    assert "serialized" in error


def test_serialized_mesh_without_its_offset_table_as_mitsuba(tmp_path):
    """Mitsuba reads the first mesh from the file's start: a cut table does not matter to it, nor here."""
    data = (MESHES / "cube.serialized").read_bytes()
    path = mesh_scene(tmp_path, "serialized", data[:-8])
    assert len(load_scene(path).meshes) == 1 and not mitsuba_refuses(path)


def test_bit_flipped_serialized_meshes_never_raise_anything_else(tmp_path):
    data = (MESHES / "cube.serialized").read_bytes()
    rng = np.random.default_rng(5)
    for i in range(200):
        d = bytearray(data)
        for at in rng.integers(0, len(d), 3):
            d[at] ^= 1 << int(rng.integers(8))
        path = mesh_scene(tmp_path, "serialized", bytes(d), name=f"m{i}.serialized")
        try:
            load_scene(path)
        except SceneError as e:
            assert f"m{i}.serialized" in str(e)


def test_ply_header_undercounting_its_faces(tmp_path):
    data = (MESHES / "cube.ply").read_bytes().replace(b"element face 12", b"element face 10")
    refused(mesh_scene(tmp_path, "ply", data), "than its header declares", "10 face")


def test_ascii_ply_header_undercounting_its_faces(tmp_path):
    text = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
            "3 0 2 1\n")
    refused(mesh_scene(tmp_path, "ply", text.encode()), "1 more lines")


def test_ply_trailing_content_as_mitsuba(tmp_path):
    """Mitsuba refuses any byte after a binary PLY's data and any token after an ASCII one's, not blank lines."""
    binary = mesh_scene(tmp_path, "ply", (MESHES / "cube.ply").read_bytes() + b"\n", name="b.ply")
    refused(binary, "1 more bytes")
    text = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n\n\n")
    blank = mesh_scene(tmp_path, "ply", text.encode(), name="a.ply")
    assert len(load_scene(blank).meshes) == 1 and not mitsuba_refuses(blank)


def envmap_scene(tmp_path: Path, data: bytes) -> Path:
    (tmp_path / "sky.exr").write_bytes(data)
    return write_scene(tmp_path, '<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>')


def small_exr(tmp_path: Path, value: float = 0.5) -> bytes:
    from tracer.imageio import write_exr

    write_exr(tmp_path / "good.exr", np.full((8, 16, 3), value, np.float32))
    return (tmp_path / "good.exr").read_bytes()


@pytest.mark.parametrize("cut", [4, 40, 200, -10])
def test_truncated_environment_map(tmp_path, cut):
    data = small_exr(tmp_path)
    refused(envmap_scene(tmp_path, data[:cut]), "sky.exr", "not a readable OpenEXR image", '<emitter type="envmap">')


def test_bit_flipped_environment_maps_never_raise_anything_else(tmp_path):
    data = small_exr(tmp_path)
    rng = np.random.default_rng(7)
    for i in range(100):
        d = bytearray(data)
        for at in rng.integers(0, len(d), 2):
            d[at] ^= 1 << int(rng.integers(8))
        try:
            load_scene(envmap_scene(tmp_path, bytes(d)))
        except SceneError as e:
            assert "sky.exr" in str(e)


def test_environment_map_with_a_predefined_attribute_of_another_type(tmp_path):
    """OpenEXR's Python binding reads it; its C++ library, Mitsuba's reader, refuses it (found by the fuzzer)."""
    data = small_exr(tmp_path)
    at = data.index(b"compression\0compression\0") + len(b"compression\0")
    corrupt = data[:at] + b"comprXssion" + data[at + len(b"compression"):]
    refused(envmap_scene(tmp_path, corrupt), "sky.exr", "attribute 'compression' has type 'comprXssion'")


def test_environment_scale_that_overflows_float32(tmp_path):
    path = envmap_scene(tmp_path, small_exr(tmp_path, 4.0))
    path.write_text(path.read_text().replace('</emitter>', '<float name="scale" value="3.4e38"/></emitter>'))
    (error,) = scene_errors(path)
    assert "overflows float32" in error and '<emitter type="envmap">' in error


def test_a_render_with_infinite_pixels_names_the_scene(tmp_path, capsys, monkeypatch):
    """A render that overflows float32 (an input near its limit) is refused in one line naming the scene,
    nothing written (found by the fuzzer: the message named a temporary file)."""
    import tracer.rendering

    render = tracer.rendering.render

    def overflowing(*args, **kwargs):
        result = render(*args, **kwargs)
        result.image[0, 0, 0] = np.inf
        return result
    monkeypatch.setattr(tracer.rendering, "render", overflowing)
    path = ROOT / "mitsuba_scenes" / "cornell_box.xml"
    (tmp_path / "out.exr").write_bytes(b"earlier")
    code = main(["render", str(path), "-o", str(tmp_path / "out.exr"), "--size", "8x8", "--spp", "1", "-q"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and f"the render of {path}" in err, err
    assert (tmp_path / "out.exr").read_bytes() == b"earlier"


def test_corrupt_bitmap_texture(tmp_path):
    from PIL import Image

    Image.new("RGB", (4, 4), (10, 200, 30)).save(tmp_path / "tex.png")
    (tmp_path / "tex.png").write_bytes((tmp_path / "tex.png").read_bytes()[:40])
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" '
                                 'name="reflectance"><string name="filename" value="tex.png"/></texture></bsdf></shape>')
    refused(path, "tex.png", "not a readable image")


def test_png_texture_whose_image_data_fails_its_crc(tmp_path):
    """Pillow decodes an IDAT chunk whose CRC fails; libpng, Mitsuba's reader, refuses it (found by the fuzzer)."""
    data = bytearray((ROOT / "mitsuba_scenes" / "textures" / "tiles.png").read_bytes())
    data[data.index(b"IDAT") + 20] ^= 4
    (tmp_path / "tex.png").write_bytes(bytes(data))
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" '
                                 'name="reflectance"><string name="filename" value="tex.png"/></texture></bsdf></shape>')
    refused(path, "tex.png", "'IDAT' fails its CRC")


@pytest.mark.parametrize("cut", [3, 12, 14, 20])
def test_png_texture_cut_short_as_libpng(tmp_path, cut):
    """A PNG cut inside its image data is refused as libpng (Mitsuba) refuses it, where Pillow may decode it
    (found by the fuzzer); one cut after its image data (in IEND) is read, as Mitsuba reads it."""
    data = (ROOT / "mitsuba_scenes" / "textures" / "tiles.png").read_bytes()
    (tmp_path / "tex.png").write_bytes(data[:-cut])
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" '
                                 'name="reflectance"><string name="filename" value="tex.png"/></texture></bsdf></shape>')
    if cut <= 12:
        assert load_scene(path) and not mitsuba_refuses(path)
    else:
        refused(path, "tex.png", "truncated PNG")


def test_an_area_emitter_attached_to_two_shapes(tmp_path):
    path = write_scene(tmp_path, '<emitter type="area" id="lamp"><rgb name="radiance" value="1"/></emitter>'
                                 '<shape type="rectangle"><ref id="lamp"/></shape>'
                                 '<shape type="disk"><ref id="lamp"/></shape>')
    refused(path, "attached to the shape at", '<shape type="disk">')


def test_underscores_in_spectra(tmp_path):
    for value in ("1_0", "400:0.5, 7_00:0.5"):
        path = write_scene(tmp_path, f'<shape type="sphere"><bsdf type="diffuse"><spectrum name="reflectance" '
                                     f'value="{value}"/></bsdf></shape>')
        refused(path, value)


def test_a_file_included_twice_says_so(tmp_path):
    (tmp_path / "part.xml").write_text('<scene version="3.0.0"><bsdf type="diffuse" id="paint"/></scene>')
    path = write_scene(tmp_path, '<include filename="part.xml"/><include filename="part.xml"/>')
    (error,) = scene_errors(path)
    assert "part.xml:1: <bsdf" in error and "(the file is included twice)" in error and mitsuba_refuses(path)


def test_too_long_file_name_names_the_element(tmp_path):
    path = mesh_scene(tmp_path, "obj", TRI.encode())
    path.write_text(path.read_text().replace("mesh.obj", "m" * 5000 + ".obj"))
    error = refused(path, '<shape type="obj">', "File name too long")
    assert len(error) < 600


def test_long_values_are_clipped_in_messages(tmp_path):
    path = write_scene(tmp_path, f'<shape type="sphere"><float name="radius" value="{"9" * 20000}x"/></shape>')
    error = refused(path, '<float name="radius">', "characters)")
    assert len(error) < 600


# ---- numbers within Mitsuba's bounds --------------------------------------------------------------------
@pytest.mark.parametrize("value", ["18446744073709551616", "9223372036854775808", "+5", "5.0", "1_0"])
def test_integers_mitsuba_cannot_parse(tmp_path, value):
    path = write_scene(tmp_path, f'<integrator type="path"><integer name="max_depth" value="{value}"/></integrator>')
    refused(path, "is not an integer")


@pytest.mark.parametrize("name, value", [("max_depth", 2 ** 31), ("rr_depth", 2 ** 32), ("max_depth", 2 ** 63 - 1)])
def test_integrator_integers_beyond_32_bits(tmp_path, name, value):
    path = write_scene(tmp_path, f'<integrator type="path"><integer name="{name}" value="{value}"/></integrator>')
    refused(path, "out of bounds")


def test_sample_count_of_32_bits_and_beyond(tmp_path):
    sampler = '<sampler type="independent"><integer name="sample_count" value="{}"/></sampler>\n    </sensor>'
    path = write_scene(tmp_path, "", header=HEADER.replace("</sensor>", sampler.format(2 ** 32)))
    refused(path, "sample_count = 4294967296 is out of bounds")
    path = write_scene(tmp_path, "", header=HEADER.replace("</sensor>", sampler.format(2 ** 32 - 1)))
    assert load_scene(path).spp == 2 ** 32 - 1


def test_underscores_in_floats(tmp_path):
    refused(write_scene(tmp_path, '<shape type="sphere"><float name="radius" value="1_0"/></shape>'), "not a number")


# ---- structure ----------------------------------------------------------------------------------------
def test_plugin_inside_a_property(tmp_path):
    path = write_scene(tmp_path, '<shape type="sphere"><point name="center" x="0" y="0" z="0">'
                                 '<shape type="rectangle"/></point></shape>')
    refused(path, "<shape", "cannot be a child of <point>")


@pytest.mark.parametrize("element", ['<default name="r" value="1"/>', '<include filename="missing.xml"/>',
                                     '<float name="a" value="1"/>'])
def test_directive_or_property_inside_a_transform(tmp_path, element):
    path = write_scene(tmp_path, f'<shape type="sphere"><transform name="to_world">{element}</transform></shape>')
    errors = scene_errors(path)      # the missing include is a second refusal
    assert any("inside <transform>" in e and path.name in e for e in errors), errors
    assert mitsuba_refuses(path)


def test_self_include_inside_properties_is_a_cycle_not_a_hang(tmp_path):
    """Two self-includes inside properties once expanded 2^32 times (found by the fuzzer: a hang)."""
    path = write_scene(tmp_path, '<shape type="sphere"><float name="radius" value="1"><include filename="scene.xml"/>'
                                 '</float><rgb name="x" value="1"><include filename="scene.xml"/></rgb></shape>')
    errors = scene_errors(path)
    assert any("includes itself (scene.xml -> scene.xml)" in e for e in errors), errors
    assert mitsuba_refuses(path)


def test_include_inside_a_default(tmp_path):
    path = write_scene(tmp_path, '<default name="a" value="1"><include filename="missing.xml"/></default>')
    refused(path, "<include", "cannot be a child of <default>")


@pytest.mark.parametrize("attribute, fragment", [("", "missing attribute 'version'"),
                                                 (' version="abc"', "invalid version 'abc'"),
                                                 (' version="3.0"', "invalid version '3.0'"),
                                                 (' version="0.5, 0.5"', "invalid version '0.5, 0.5'"),
                                                 (' version="3.0.99999999999999999999"', "invalid version")])
def test_scene_version(tmp_path, attribute, fragment):
    path = write_scene(tmp_path, "", header=HEADER.replace('<scene version="3.0.0">', f"<scene{attribute}>"))
    refused(path, fragment)


@pytest.mark.parametrize("version", ["2.0.0", "3.6.0", "99.0.0", "3.0.0-rc", " 3.0.0 ", "3 0 0", "-1.0.0"])
def test_versions_mitsuba_accepts(tmp_path, version):
    path = write_scene(tmp_path, "", header=HEADER.replace('"3.0.0"', f'"{version}"'))
    assert load_scene(path).camera.width == 8 and not mitsuba_refuses(path)


def test_included_scene_without_version(tmp_path):
    (tmp_path / "part.xml").write_text('<scene><shape type="sphere"/></scene>')
    refused(write_scene(tmp_path, '<include filename="part.xml"/>'), "part.xml", "missing attribute 'version'")


@pytest.mark.parametrize("element", ['<translate value="1 2 3" x="1"/>', '<rotate value="0 1 0" y="1" angle="3"/>'])
def test_value_mixed_with_xyz(tmp_path, element):
    path = write_scene(tmp_path, f'<shape type="sphere"><transform name="to_world">{element}</transform></shape>')
    refused(path, "cannot mix 'value' and 'x'/'y'/'z'")


def test_rotation_angles_beyond_mitsubas_float32_sine(tmp_path):
    mesh = '<shape type="ply"><string name="filename" value="{}"/><transform name="to_world">' \
           '<rotate y="1" angle="{}"/></transform></shape>'
    refused(write_scene(tmp_path, mesh.format(MESHES / "cube.ply", "1.8e19")), "beyond +-1e+10 degrees")
    path = write_scene(tmp_path, mesh.format(MESHES / "cube.ply", "1e10"))
    assert len(load_scene(path).meshes) == 1 and not mitsuba_refuses(path)


def test_an_object_inside_a_transform_operation_is_no_object(tmp_path):
    """Mitsuba ignores elements inside <translate>: a <bsdf id> there cannot be referenced (found by the fuzzer)."""
    path = write_scene(tmp_path, '<shape type="sphere"><transform name="to_world"><translate x="1">'
                                 '<bsdf type="diffuse" id="red"/></translate></transform></shape>'
                                 '<shape type="sphere"><ref id="red"/></shape>')
    refused(path, "no object with id 'red'")


def test_a_default_inside_a_transform_operation_declares_nothing(tmp_path):
    """Mitsuba ignores what a <lookat> or <translate> holds: a <default> there leaves its parameter undeclared
    (found by the fuzzer: the tracer declared it)."""
    path = write_scene(tmp_path, '<shape type="sphere"><transform name="to_world"><translate x="1">'
                                 '<default name="r" value="2"/></translate></transform>'
                                 '<float name="radius" value="$r"/></shape>')
    refused(path, "$r is used before a <default> declares it")


def test_unexpected_attribute(tmp_path):
    path = write_scene(tmp_path, '<shape type="sphere"><float name="radius" value="1" foo="2"/></shape>')
    refused(path, "unexpected attribute 'foo'")


@pytest.mark.parametrize("transform", ['<scale value="2"/>', '<scale z="1.01"/>',
                                       '<matrix value="1 0.5 0 0 0 1 0 0 0 0 1 0 0 0 0 1"/>'])
def test_camera_with_scale_or_shear(tmp_path, transform):
    header = HEADER.replace('<sensor type="perspective">',
                            f'<sensor type="perspective"><transform name="to_world">{transform}</transform>')
    refused(write_scene(tmp_path, "", header=header), "may not scale or shear")


def test_camera_mirror_and_tiny_scale_as_mitsuba(tmp_path):
    for transform in ('<scale value="-1"/>', '<scale value="1.0001"/>'):
        header = HEADER.replace('<sensor type="perspective">',
                                f'<sensor type="perspective"><transform name="to_world">{transform}</transform>')
        path = write_scene(tmp_path, "", header=header)
        load_scene(path)
        assert not mitsuba_refuses(path)


@pytest.mark.parametrize("what, inside", [("sampler", "</sensor>"), ("film", "</sensor>"), ("rfilter", "</film>")])
def test_duplicate_singletons(tmp_path, what, inside):
    kind = {"sampler": "independent", "film": "hdrfilm", "rfilter": "box"}[what]
    header = HEADER.replace(inside, f'<{what} type="{kind}"/><{what} type="{kind}"/>{inside}')
    refused(write_scene(tmp_path, "", header=header), f"a second {what}")


def test_include_of_a_folder(tmp_path):
    error = refused(write_scene(tmp_path, '<include filename="."/>'), "is a folder")
    assert "not found" not in error


# ---- the command lines ----------------------------------------------------------------------------------
def test_info_into_a_closed_pipe_is_not_an_error():
    scene = ROOT / "mitsuba_scenes" / "cornell_box.xml"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    run = subprocess.run(f"'{sys.executable}' -m tracer.cli info '{scene}' | head -1", shell=True, env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.stdout.strip() == str(scene) and run.stderr == "", run.stderr


def test_cli_refuses_integers_beyond_32_bits(capsys):
    with pytest.raises(SystemExit) as info:
        main(["render", "scene.xml", "--max-depth", str(2 ** 31)])
    assert info.value.code == 2 and "exceeds 2147483647" in capsys.readouterr().err


def test_validate_without_the_validation_extra_says_what_to_install(tmp_path):
    """A `pip install .` without the extra: the harness's imports fail; `validate` says what to install."""
    (tmp_path / "mitsuba").mkdir()
    (tmp_path / "mitsuba" / "__init__.py").write_text("raise ModuleNotFoundError(\"No module named 'mitsuba'\", "
                                                      "name='mitsuba')\n")
    env = dict(os.environ, PYTHONPATH=f"{tmp_path}{os.pathsep}{ROOT}")
    run = subprocess.run([sys.executable, "-m", "validation.cli", "reference", str(ROOT / "mitsuba_scenes" /
                          "cornell_box.xml")], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert run.stderr.count("\n") == 1 and "pip install 'tracer[validation]'" in run.stderr, run.stderr
