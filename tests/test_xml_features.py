"""Mitsuba's XML as Mitsuba reads it: <include>, <path>, <default>, <spectrum>, top-level declarations used
through <ref>, named indices of refraction, the sensor's focal length, flip_normals, and every refusal of a
scene reported at once, one line each. Values are checked against Mitsuba itself where it has them."""
from pathlib import Path

import numpy as np
import pytest

from tracer import SceneError, load_scene
from tracer.ior import NAMED_IOR

from .test_xml_loader import HEADER, assert_located, line_of, write_scene

TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


@pytest.fixture
def mi():
    """Mitsuba in its scalar RGB variant for the duration of a test (the variant the other tests use is
    restored after it)."""
    from validation.verdict.mitsuba_render import mitsuba

    module = mitsuba()                    # the project's variant, set first so that it can be restored
    previous = module.variant()
    module.set_variant("scalar_rgb")
    yield module
    module.set_variant(previous)


def scene_errors(path: Path, **overrides) -> list[str]:
    """The refusals of a scene: one line each, none of them a traceback."""
    with pytest.raises(SceneError) as info:
        load_scene(path, **overrides)
    lines = str(info.value).split("\n")
    assert all(line.strip() == line and line for line in lines)
    assert "Traceback" not in str(info.value)
    return lines


# ---- <include>, <path>, <default> ---------------------------------------------------------------------
def _include_tree(tmp_path: Path) -> Path:
    (tmp_path / "common" / "meshes").mkdir(parents=True)
    (tmp_path / "common" / "meshes" / "tri.obj").write_text(TRI)
    (tmp_path / "include").mkdir()
    (tmp_path / "include" / "part.xml").write_text("""<scene version="3.0.0">
    <default name="size" value="0.5"/>
    <shape type="obj" id="tri">
        <string name="filename" value="meshes/tri.obj"/>
        <ref id="paint"/>
    </shape>
    <shape type="sphere"><float name="radius" value="$size"/></shape>
</scene>""")
    return write_scene(tmp_path, """
    <path value="common"/>
    <default name="size" value="2"/>
    <bsdf type="diffuse" id="paint"><rgb name="reflectance" value="0.25"/></bsdf>
    <include filename="include/part.xml"/>""", name="main.xml")


def test_include_and_path_as_mitsuba(tmp_path, mi):
    path = _include_tree(tmp_path)
    s = load_scene(path)
    (mesh,), (sphere,) = s.meshes, s.spheres
    assert mesh.bsdf.reflectance == (0.25, 0.25, 0.25)          # the included shape uses the main file's bsdf
    assert mesh.vertices[:, 0].max() == 1.0
    assert sphere.radius == 2.0                                 # the first <default> wins, as in Mitsuba
    assert load_scene(path, size=3).spheres[0].radius == 3.0    # and -D beats both
    params = mi.traverse(mi.load_file(str(path)))
    assert np.allclose(params["tri.vertex_positions"], mesh.vertices.ravel())


def test_missing_include_and_path_are_located(tmp_path):
    path = write_scene(tmp_path, '\n    <path value="nowhere"/>\n    <include filename="gone.xml"/>', name="inc.xml")
    errors = scene_errors(path)
    assert len(errors) == 2
    assert_located(errors[0], path, line_of(path, "nowhere"))
    assert "not found" in errors[0]
    assert_located(errors[1], path, line_of(path, "gone.xml"))
    assert "gone.xml" in errors[1] and "not found" in errors[1]


def test_self_including_file_is_refused(tmp_path):
    path = write_scene(tmp_path, '<include filename="loop.xml"/>', name="loop.xml")
    (error,) = scene_errors(path)
    assert "includes itself (loop.xml -> loop.xml)" in error


# ---- top-level declarations and <ref> -----------------------------------------------------------------
def test_top_level_emitter_and_sampler_referenced(tmp_path):
    header = HEADER.replace('<film type="hdrfilm">', '<ref id="smp"/>\n        <film type="hdrfilm">')
    path = write_scene(tmp_path, """
    <sampler type="independent" id="smp"><integer name="sample_count" value="7"/></sampler>
    <emitter type="area" id="lamp"><rgb name="radiance" value="3, 2, 1"/></emitter>
    <emitter type="area" id="lamp2"><rgb name="radiance" value="3, 2, 1"/></emitter>
    <shape type="rectangle"><ref id="lamp"/></shape>
    <shape type="rectangle"><ref name="emitter" id="lamp2"/></shape>""", header=header)   # one shape each, as Mitsuba
    s = load_scene(path)
    assert s.spp == 7
    assert [r.radiance for r in s.emitters] == [(3.0, 2.0, 1.0)] * 2
    assert all(r.bsdf.reflectance == (0.0, 0.0, 0.0) for r in s.rectangles)   # black, as on any emitter


def test_a_shared_bad_bsdf_is_reported_once(tmp_path):
    path = write_scene(tmp_path, """
    <bsdf type="diffuse" id="bad"><rgb name="reflectanse" value="0.2"/></bsdf>
    <shape type="rectangle"><ref id="bad"/></shape>
    <shape type="sphere"><ref id="bad"/></shape>""")
    (error,) = scene_errors(path)
    assert_located(error, path, line_of(path, "reflectanse"))
    assert "unreferenced property 'reflectanse'" in error and "supported: reflectance" in error


# ---- <spectrum>, <rgb> and <float> colours -------------------------------------------------------------
PAIRS = "400:0.04, 500:0.3, 550:0.6, 600:0.2, 700:0.9"


@pytest.mark.parametrize("value", [PAIRS, "360:1, 830:1", "0.3", "450:0.1, 460:0.9, 470:0.1"])
def test_spectra_convert_as_mitsubas_rgb_variant(tmp_path, value, mi):
    path = write_scene(tmp_path, f"""
    <shape type="rectangle">
        <bsdf type="diffuse"><spectrum name="reflectance" value="{value}"/></bsdf>
    </shape>
    <shape type="rectangle">
        <emitter type="area"><spectrum name="radiance" value="{value}"/></emitter>
    </shape>""")
    surface, light = load_scene(path).rectangles
    bsdf = mi.load_string(f'<bsdf version="3.0.0" type="diffuse"><spectrum name="reflectance" value="{value}"/></bsdf>')
    lamp = mi.load_string(f'<emitter version="3.0.0" type="area"><spectrum name="radiance" value="{value}"/></emitter>')
    assert np.allclose(surface.bsdf.reflectance, mi.traverse(bsdf)["reflectance.value"], rtol=2e-6, atol=1e-7)
    assert np.allclose(light.radiance, mi.traverse(lamp)["radiance.value"], rtol=2e-6, atol=1e-7)


def test_reflectance_and_radiance_spectra_differ():
    """A flat spectrum is white as a reflectance (weighted by D65) but reddish as a radiance."""
    from tracer.spectra import to_rgb
    assert np.allclose(to_rgb("360:1, 830:1", emitter=False), 1.0, atol=2e-3)
    radiance = to_rgb("360:1, 830:1", emitter=True)
    assert np.allclose(radiance, [1.2049, 0.9483, 0.9093], atol=1e-3)     # xyz_to_srgb(1, 1, 1)
    assert np.allclose(to_rgb("0.5", emitter=True), 0.5 * np.array([1.204794, 0.948292, 0.908916]), rtol=1e-5)


def test_float_radiance_is_grey_as_in_mitsuba(tmp_path):
    path = write_scene(tmp_path, '<shape type="rectangle"><emitter type="area"><float name="radiance" value="2"/>'
                                 '</emitter></shape>')
    assert load_scene(path).emitters[0].radiance == (2.0, 2.0, 2.0)


@pytest.mark.parametrize("value, words", [("400:0.1, 390:0.2", "must increase"), ("400:0.1", "at least two"),
                                          ("a:b", "wavelength:value")])
def test_bad_spectrum_is_located(tmp_path, value, words):
    path = write_scene(tmp_path, f'<shape type="rectangle"><bsdf type="diffuse">\n'
                                 f'        <spectrum name="reflectance" value="{value}"/></bsdf></shape>')
    (error,) = scene_errors(path)
    assert_located(error, path, line_of(path, "<spectrum"))
    assert words in error


# ---- named indices of refraction ----------------------------------------------------------------------
def test_named_iors_are_mitsubas(mi):
    for name, value in NAMED_IOR.items():
        eta = mi.traverse(mi.load_dict({"type": "dielectric", "int_ior": name, "ext_ior": "vacuum"}))["eta"]
        assert np.float32(value) == pytest.approx(eta, rel=1e-7), name


def test_named_ior_in_a_scene(tmp_path):
    path = write_scene(tmp_path, '<shape type="sphere"><bsdf type="dielectric"><string name="int_ior" value="Water"/>'
                                 '<string name="ext_ior" value="air"/></bsdf></shape>')
    b = load_scene(path).spheres[0].bsdf
    assert (b.int_ior, b.ext_ior) == (1.333, 1.000277)
    bad = write_scene(tmp_path, '<shape type="sphere"><bsdf type="dielectric">\n'
                                '        <string name="int_ior" value="glas"/></bsdf></shape>', name="bad.xml")
    (error,) = scene_errors(bad)
    assert_located(error, bad, line_of(bad, "glas"))
    assert "'glas'" in error and "bk7" in error


# ---- camera: focal length and Mitsuba's default -------------------------------------------------------
@pytest.mark.parametrize("lens", ['<string name="focal_length" value="35mm"/>', "",
                                  '<float name="fov" value="30"/><string name="fov_axis" value="diagonal"/>'])
def test_field_of_view_as_mitsuba(tmp_path, lens, mi):
    header = HEADER.replace('<sensor type="perspective">', f'<sensor type="perspective">{lens}')
    cam = load_scene(write_scene(tmp_path, "", header=header)).camera
    sensor = mi.load_string(header.split("<scene", 1)[1].split(">", 1)[1].replace(
        '<sensor type="perspective">', '<sensor version="3.0.0" type="perspective">'))
    x_fov = mi.traverse(sensor)["x_fov"]
    assert np.degrees(2 * np.arctan(cam.tan_half_fov()[0])) == pytest.approx(float(np.ravel(x_fov)[0]), rel=1e-5)


# ---- flip_normals ------------------------------------------------------------------------------------
def test_flip_normals_on_rectangles_and_meshes(tmp_path):
    (tmp_path / "tri.obj").write_text(TRI)
    body = ('<shape type="rectangle"><boolean name="flip_normals" value="{0}"/></shape>'
            '<shape type="obj"><string name="filename" value="tri.obj"/><boolean name="flip_normals" value="{0}"/>'
            '</shape>')
    plain = load_scene(write_scene(tmp_path, body.format("false"), name="a.xml"))
    flipped = load_scene(write_scene(tmp_path, body.format("true"), name="b.xml"))
    assert np.allclose(flipped.rectangles[0].normal, -plain.rectangles[0].normal)
    assert flipped.rectangles[0].area == plain.rectangles[0].area
    assert np.allclose(flipped.rectangles[0].center, plain.rectangles[0].center)
    assert np.allclose(flipped.meshes[0].normals, -plain.meshes[0].normals)
    v = flipped.meshes[0].vertices[flipped.meshes[0].faces[0]]
    assert np.cross(v[1] - v[0], v[2] - v[0])[2] < 0                  # the winding, hence the face normal


# ---- everything not honoured is refused, all at once ----------------------------------------------------
REFUSED = [
    ('<shape type="rectangle"><bsdf type="diffuse">\n<rgb name="reflectanse" value="0.2"/></bsdf></shape>',
     "reflectanse", "unreferenced property 'reflectanse'"),
    ('<shape type="rectangle"><bsdf type="conductor">\n<rgb name="eta" value="0.2, 0.9, 1.1"/>'
     '<string name="material" value="Au"/></bsdf></shape>', 'type="conductor"', "either eta and k or a material"),
    ('<shape type="rectangle"><bsdf type="conductor">\n<string name="material" value="Gold"/></bsdf></shape>',
     '"Gold"', "no conductor named 'Gold'"),
    ('<shape type="rectangle"><bsdf type="conductor">\n<rgb name="specular_reflectance" value="1.5"/></bsdf>'
     '</shape>', 'type="conductor"', "specular_reflectance must lie in [0, 1]"),
    ('<integrator type="volpath">\n<boolean name="hide_emitters" value="true"/></integrator>', "hide_emitters",
     "hide_emitters = true with volpath"),
    ('<shape type="rectangle"><emitter type="area">\n<float name="scale" value="2"/></emitter></shape>',
     '"scale"', "unreferenced property 'scale'"),
    ('<shape type="sphere">\n<transform name="to_world"><scale x="2"/></transform></shape>', '<shape type="sphere">',
     "scale uniformly"),
    ('<shape type="sphere"><boolean name="flip_normals" value="true"/>\n</shape>', "flip_normals",
     "flip_normals on a sphere"),
    ('<sensor type="perspective">\n</sensor>', '<sensor type="perspective">\n', "a second sensor"),
    ('<shape type="rectangle"><bsdf type="dielectric">\n<rgb name="specular_transmittance" value="0.5"/></bsdf>'
     '</shape>', "specular_transmittance", "other than 1"),
    ('<shape type="rectangle"><bsdf type="diffuse">\n<texture type="volume" name="reflectance"/></bsdf>'
     '</shape>', 'type="volume"', "unsupported texture plugin 'volume'"),
    ('<emitter type="sunsky">\n</emitter>', 'type="sunsky"', "unsupported emitter plugin 'sunsky'"),
]


@pytest.mark.parametrize("body, snippet, words", REFUSED)
def test_refused_by_name(tmp_path, body, snippet, words):
    path = write_scene(tmp_path, body)
    errors = scene_errors(path)
    assert any(words in e for e in errors), errors
    lines = path.read_text().split("\n")
    line = next(i for i, text in enumerate(lines, 1) if snippet.split("\n")[0] in text
                and (not snippet.endswith("\n") or i > 3))
    assert any(f"{path.name}:{line}:" in e and words in e for e in errors), (line, errors)


def test_a_crop_outside_the_film_is_refused(tmp_path):
    header = HEADER.replace('<rfilter type="box"/>', '<rfilter type="box"/>\n<integer name="crop_width" value="9"/>')
    path = write_scene(tmp_path, "", header=header)
    (error,) = scene_errors(path)
    assert_located(error, path, line_of(path, '<film type="hdrfilm">'))
    assert "crop_width 9" in error and "does not fit the 8 x 6 film" in error


def test_obj_with_a_zero_length_normal_is_refused(tmp_path):
    (tmp_path / "n.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nf 1//1 2//1 3//1\n")
    path = write_scene(tmp_path, '<shape type="obj"><string name="filename" value="n.obj"/></shape>')
    (error,) = scene_errors(path)
    assert "zero length" in error


def test_all_refusals_listed_at_once(tmp_path):
    body = "\n".join(f"    {b}" for b, _, _ in REFUSED[:6] + REFUSED[-1:])
    header = HEADER.replace('<rfilter type="box"/>', '<rfilter type="box"/>\n<integer name="crop_width" value="9"/>')
    path = write_scene(tmp_path, body, header=header)
    errors = scene_errors(path)
    assert len(errors) == 8, errors
    for (_, _, words) in REFUSED[:6] + REFUSED[-1:]:
        assert sum(words in e for e in errors) == 1, (words, errors)
    assert all(f"{path.name}:" in e for e in errors)


def test_rotated_sphere_is_accepted(tmp_path):
    """A rotation leaves off-diagonal round-off in to_world's Gram matrix: still a uniform scale."""
    path = write_scene(tmp_path, '<shape type="sphere"><transform name="to_world"><rotate z="1" angle="225"/>'
                                 '<scale value="0.5"/><translate z="1"/></transform></shape>')
    (sphere,) = load_scene(path).spheres
    assert sphere.radius == pytest.approx(0.5) and np.allclose(sphere.center, [0, 0, 1])


def test_parameter_used_before_its_default_is_refused(tmp_path):
    """Mitsuba substitutes parameters while reading: the <default> must come first (or -D)."""
    header = HEADER.replace('<integer name="width" value="8"/>', '<integer name="width" value="$w"/>')
    path = write_scene(tmp_path, '\n    <default name="w" value="8"/>', header=header)
    (error,) = scene_errors(path)
    assert_located(error, path, line_of(path, "$w"))
    assert "$w is used before a <default>" in error
    assert load_scene(path, w=5).camera.width == 5


def test_include_of_a_plugin_file_and_paths_of_included_scenes(tmp_path):
    """An included file whose root is a plugin becomes that plugin; a <path> inside an included scene
    serves that file's own includes, not the including scene's meshes (as in Mitsuba)."""
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "paint.xml").write_text('<bsdf type="diffuse" version="3.0.0">'
                                                '<rgb name="reflectance" value="0.1, 0.2, 0.3"/></bsdf>')
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text(TRI)
    (tmp_path / "lib" / "part.xml").write_text('<scene version="3.0.0"><path value="../meshes"/>'
                                               '<shape type="rectangle"><include filename="paint.xml"/></shape>'
                                               '</scene>')
    ok = write_scene(tmp_path, '<include filename="lib/part.xml"/>', name="ok.xml")
    assert load_scene(ok).rectangles[0].bsdf.reflectance == (0.1, 0.2, 0.3)
    bad = write_scene(tmp_path, '<include filename="lib/part.xml"/>\n    <shape type="obj">'
                                '<string name="filename" value="tri.obj"/></shape>', name="bad.xml")
    (error,) = scene_errors(bad)
    assert "'tri.obj' not found" in error
