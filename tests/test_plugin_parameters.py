"""Every parameter Mitsuba 3 reads for each supported plugin (tracer.mitsuba_xml.MITSUBA_PARAMETERS, taken from
Mitsuba's plugin sources) is honoured (it changes the loaded scene), accepted because it cannot change the
image (scheduling, metadata, differentiable rendering), or refused with a line naming it. Nothing is
silently ignored: a parameter whose handling changes fails here."""
import pickle

import numpy as np
import OpenEXR
import pytest

from tracer import SceneError, load_scene
from tracer.mitsuba_xml import MITSUBA_PARAMETERS

from .test_mesh_formats import FACES, VERTICES, serialized_mesh, write_ply, write_serialized
from .test_xml_features import mi  # noqa: F401  (the fixture)
from .test_xml_loader import HEADER, write_scene

# a non-default value for each parameter
VALUES = {
    "max_depth": '<integer name="max_depth" value="3"/>', "rr_depth": '<integer name="rr_depth" value="2"/>',
    "hide_emitters": '<boolean name="hide_emitters" value="true"/>',
    "block_size": '<integer name="block_size" value="8"/>',
    "samples_per_pass": '<integer name="samples_per_pass" value="2"/>',
    "timeout": '<float name="timeout" value="1"/>',
    "use_spectral_mis": '<boolean name="use_spectral_mis" value="false"/>',
    "to_world": '<transform name="to_world"><translate x="0.5"/></transform>',
    "fov": '<float name="fov" value="30"/>', "fov_axis": '<string name="fov_axis" value="y"/>',
    "focal_length": '<string name="focal_length" value="35mm"/>',
    "near_clip": '<float name="near_clip" value="0.5"/>', "far_clip": '<float name="far_clip" value="100"/>',
    "focus_distance": '<float name="focus_distance" value="3"/>',
    "principal_point_offset_x": '<float name="principal_point_offset_x" value="0.1"/>',
    "principal_point_offset_y": '<float name="principal_point_offset_y" value="0.1"/>',
    "shutter_open": '<float name="shutter_open" value="0.1"/>',
    "shutter_close": '<float name="shutter_close" value="0.5"/>',
    "srf": '<spectrum name="srf" value="400:1, 700:1"/>',
    "width": '<integer name="width" value="10"/>', "height": '<integer name="height" value="7"/>',
    "crop_offset_x": '<integer name="crop_offset_x" value="1"/>',
    "crop_offset_y": '<integer name="crop_offset_y" value="1"/>',
    "crop_width": '<integer name="crop_width" value="2"/>', "crop_height": '<integer name="crop_height" value="2"/>',
    "sample_border": '<boolean name="sample_border" value="true"/>',
    "pixel_format": '<string name="pixel_format" value="luminance"/>',
    "component_format": '<string name="component_format" value="float16"/>',
    "file_format": '<string name="file_format" value="rgbe"/>',
    "compensate": '<boolean name="compensate" value="true"/>', "banner": '<boolean name="banner" value="false"/>',
    "stddev": '<float name="stddev" value="0.3"/>', "radius": '<float name="radius" value="0.7"/>',
    "sample_count": '<integer name="sample_count" value="5"/>', "seed": '<integer name="seed" value="5"/>',
    "flip_normals": '<boolean name="flip_normals" value="true"/>',
    "silhouette_sampling_weight": '<float name="silhouette_sampling_weight" value="0.5"/>',
    "center": '<point name="center" x="1" y="2" z="3"/>',
    "face_normals": '<boolean name="face_normals" value="true"/>',
    "flip_tex_coords": '<boolean name="flip_tex_coords" value="false"/>',
    "shape_index": '<integer name="shape_index" value="1"/>',
    "reflectance": '<rgb name="reflectance" value="0.2, 0.3, 0.4"/>',
    "allow_transmission": '<boolean name="allow_transmission" value="true"/>',
    "material": '<string name="material" value="Au"/>', "eta": '<rgb name="eta" value="0.2, 0.9, 1.1"/>',
    "k": '<rgb name="k" value="3.9, 2.4, 2.2"/>',
    "specular_reflectance": '<rgb name="specular_reflectance" value="0.5"/>',
    "specular_transmittance": '<rgb name="specular_transmittance" value="0.5"/>',
    "distribution": '<string name="distribution" value="ggx"/>', "alpha": '<float name="alpha" value="0.3"/>',
    "alpha_u": '<float name="alpha_u" value="0.3"/>', "alpha_v": '<float name="alpha_v" value="0.3"/>',
    "sample_visible": '<boolean name="sample_visible" value="false"/>',
    "int_ior": '<string name="int_ior" value="water"/>', "nonlinear": '<boolean name="nonlinear" value="true"/>',
    "diffuse_reflectance": '<rgb name="diffuse_reflectance" value="0.2, 0.3, 0.4"/>', "ext_ior": '<float name="ext_ior" value="1.1"/>',
    "radiance": '<rgb name="radiance" value="2, 3, 4"/>', "sampling_weight": '<float name="sampling_weight" value="2"/>',
    "scale": '<float name="scale" value="2"/>', "mis_compensation": '<boolean name="mis_compensation" value="true"/>',
    "bitmap": '<ref name="bitmap" id="nothing"/>',
    "color0": '<rgb name="color0" value="0.1"/>', "color1": '<rgb name="color1" value="0.9"/>',
    "to_uv": '<transform name="to_uv"><scale value="2"/></transform>',
    "position": '<point name="position" x="1" y="2" z="3"/>', "p0": '<point name="p0" x="1" y="2" z="3"/>',
    "p1": '<point name="p1" x="1" y="2" z="3"/>', "cutoff_angle": '<float name="cutoff_angle" value="30"/>',
    "beam_width": '<float name="beam_width" value="10"/>', "direction": '<vector name="direction" x="1" y="-2" z="0"/>',
    "irradiance": '<rgb name="irradiance" value="2, 3, 4"/>', "data": '<ref name="data" id="nothing"/>',
    "raw": '<boolean name="raw" value="true"/>', "filter_type": '<string name="filter_type" value="nearest"/>',
    "wrap_mode": '<string name="wrap_mode" value="clamp"/>', "format": '<string name="format" value="fp16"/>',
    "opacity": '<float name="opacity" value="0.3"/>', "weight": '<float name="weight" value="0.3"/>',
    "normalmap": '<texture type="bitmap" name="normalmap"><string name="filename" value="b.png"/></texture>',
    "flip_invalid_normals": '<boolean name="flip_invalid_normals" value="false"/>',
    "use_shadowing_function": '<boolean name="use_shadowing_function" value="false"/>',
    "value": '<vector name="value" value="0.2, 0.3, 0.4"/>', "name": '<string name="name" value="vertex_d"/>',
    "base_color": '<rgb name="base_color" value="0.2, 0.3, 0.4"/>', "roughness": '<float name="roughness" value="0.3"/>',
    **{name: f'<float name="{name}" value="0.4"/>' for name in (
        "anisotropic", "spec_trans", "sheen", "sheen_tint", "flatness", "spec_tint", "metallic", "clearcoat",
        "clearcoat_gloss", "specular", "main_specular_sampling_rate", "clearcoat_sampling_rate",
        "diffuse_reflectance_sampling_rate", "diff_trans", "specular_reflectance_sampling_rate",
        "specular_transmittance_sampling_rate", "diffuse_transmittance_sampling_rate")},
    "shading_samples": '<integer name="shading_samples" value="2"/>',
    "emitter_samples": '<integer name="emitter_samples" value="0"/>',
    "bsdf_samples": '<integer name="bsdf_samples" value="0"/>',
    "aovs": '<string name="aovs" value="dd:depth"/>',
    "aperture_radius": '<float name="aperture_radius" value="0.2"/>',
    "jitter": '<boolean name="jitter" value="false"/>', "theta": '<float name="theta" value="30"/>',
    "transmittance": '<rgb name="transmittance" value="0.5, 0.6, 0.7"/>',
    "polarizing": '<boolean name="polarizing" value="false"/>', "strength": '<integer name="strength" value="3"/>',
    "accel": '<boolean name="accel" value="false"/>',
    "albedo": '<rgb name="albedo" value="0.2, 0.3, 0.4"/>', "sigma_t": '<rgb name="sigma_t" value="0.2, 0.3, 0.4"/>',
    "sample_emitters": '<boolean name="sample_emitters" value="false"/>',
    "has_spectral_extinction": '<boolean name="has_spectral_extinction" value="false"/>',
    "g": '<float name="g" value="0.3"/>',
    "use_grid_bbox": '<boolean name="use_grid_bbox" value="true"/>', "max_value": '<float name="max_value" value="9"/>',
    "grid": '<ref name="grid" id="nothing"/>', "texture": '<texture type="checkerboard" name="texture"/>', "intensity": '<rgb name="intensity" value="2, 3, 4"/>',
}
HONOURED = "honoured"
NO_EFFECT = "no effect on the image"
REFUSED = "refused"
EXPECTED = {
    "integrator": {"max_depth": HONOURED, "rr_depth": HONOURED, "hide_emitters": REFUSED, "block_size": NO_EFFECT,
                   "samples_per_pass": NO_EFFECT, "timeout": REFUSED, "shading_samples": HONOURED,
                   "emitter_samples": HONOURED, "bsdf_samples": HONOURED,
                   "aovs": NO_EFFECT,      # AOV channels beside the image, which the tracer does not write
                   "use_spectral_mis": NO_EFFECT},   # volpathmis's MIS over the channels: the noise, not the image
    "sensor": {"to_world": HONOURED, "fov": HONOURED, "fov_axis": REFUSED,   # fov_axis without fov: unreferenced
               "focal_length": HONOURED, "near_clip": HONOURED, "far_clip": HONOURED, "focus_distance": NO_EFFECT,
               "principal_point_offset_x": REFUSED, "principal_point_offset_y": REFUSED, "shutter_open": REFUSED,
               "shutter_close": NO_EFFECT, "srf": REFUSED, "aperture_radius": HONOURED},
    "film": {"width": HONOURED, "height": HONOURED,
             "crop_offset_x": REFUSED, "crop_offset_y": REFUSED,   # alone: the full-size window no longer fits
             "crop_width": HONOURED, "crop_height": HONOURED, "sample_border": HONOURED, "pixel_format": REFUSED,
             "component_format": REFUSED, "file_format": REFUSED, "compensate": NO_EFFECT, "banner": NO_EFFECT},
    "rfilter": {"stddev": HONOURED, "radius": HONOURED},
    "sampler": {"sample_count": HONOURED, "seed": HONOURED, "jitter": NO_EFFECT, "strength": NO_EFFECT},
    "shape": {"to_world": HONOURED, "flip_normals": HONOURED, "silhouette_sampling_weight": NO_EFFECT,
              "center": HONOURED, "radius": HONOURED, "filename": HONOURED, "face_normals": HONOURED,
              "flip_tex_coords": NO_EFFECT, "shape_index": HONOURED, "p0": HONOURED, "p1": HONOURED},
    "bsdf": {"reflectance": HONOURED, "allow_transmission": REFUSED, "material": HONOURED, "eta": HONOURED,
             "k": HONOURED, "specular_reflectance": HONOURED, "specular_transmittance": REFUSED, "int_ior": HONOURED,
             "ext_ior": HONOURED, "nonlinear": HONOURED, "diffuse_reflectance": HONOURED, "opacity": HONOURED,
             "distribution": HONOURED, "alpha": HONOURED, "alpha_u": REFUSED, "alpha_v": REFUSED,
             "sample_visible": HONOURED, "weight": HONOURED, "normalmap": HONOURED,
             "flip_invalid_normals": HONOURED, "use_shadowing_function": HONOURED, "scale": HONOURED,
             "theta": NO_EFFECT, "transmittance": HONOURED, "polarizing": NO_EFFECT,   # polarizer: unpolarized
             **{name: HONOURED for name in (
                 "base_color", "roughness", "anisotropic", "spec_trans", "sheen", "sheen_tint", "flatness", "spec_tint",
                 "metallic", "clearcoat", "clearcoat_gloss", "specular", "main_specular_sampling_rate",
                 "clearcoat_sampling_rate", "diffuse_reflectance_sampling_rate", "diff_trans",
                 "specular_reflectance_sampling_rate", "specular_transmittance_sampling_rate",
                 "diffuse_transmittance_sampling_rate")}},
    "texture": {"color0": HONOURED, "color1": HONOURED, "to_uv": HONOURED, "filename": HONOURED, "bitmap": REFUSED,
                "data": REFUSED, "raw": HONOURED, "filter_type": HONOURED, "wrap_mode": HONOURED, "format": REFUSED,
                "accel": NO_EFFECT, "value": HONOURED, "name": HONOURED, "scale": HONOURED},
    "emitter": {"radiance": HONOURED, "sampling_weight": NO_EFFECT, "to_world": NO_EFFECT,   # constant: uniform
                "filename": HONOURED, "scale": HONOURED, "mis_compensation": NO_EFFECT, "bitmap": REFUSED,
                "position": HONOURED, "intensity": HONOURED, "cutoff_angle": HONOURED, "beam_width": HONOURED,
                "texture": REFUSED, "direction": HONOURED, "irradiance": HONOURED,
                "fov": HONOURED, "fov_axis": REFUSED, "focal_length": HONOURED},   # fov_axis without fov: unreferenced
    "medium": {"albedo": HONOURED, "sigma_t": HONOURED, "scale": HONOURED, "sample_emitters": HONOURED,
               "has_spectral_extinction": HONOURED},
    "phase": {"g": HONOURED},
    "volume": {"value": HONOURED, "to_world": HONOURED, "filename": HONOURED, "filter_type": HONOURED,
               "wrap_mode": HONOURED, "use_grid_bbox": HONOURED, "raw": NO_EFFECT, "accel": NO_EFFECT,
               "max_value": REFUSED, "grid": REFUSED, "data": REFUSED},
}
SPECIAL = {   # (tag, kind, parameter) whose handling differs from the tag's other plugins
    **{("integrator", kind, "hide_emitters"): HONOURED for kind in ("path", "direct", "ptracer")},
    ("shape", "cylinder", "silhouette_sampling_weight"): NO_EFFECT,
    ("shape", "disk", "silhouette_sampling_weight"): NO_EFFECT,
    ("emitter", "envmap", "to_world"): HONOURED,
    ("emitter", "point", "to_world"): HONOURED,
    ("emitter", "spot", "to_world"): HONOURED,
    ("emitter", "projector", "to_world"): HONOURED,
    ("sensor", "thinlens", "focus_distance"): HONOURED,
    ("emitter", "directional", "to_world"): HONOURED,
    ("shape", "sphere", "flip_normals"): REFUSED,
    ("shape", "obj", "flip_tex_coords"): HONOURED,      # its test file has texture coordinates, the PLY's none
    ("bsdf", "dielectric", "specular_reflectance"): REFUSED,
    ("bsdf", "thindielectric", "specular_transmittance"): HONOURED,
    ("bsdf", "roughdielectric", "specular_transmittance"): HONOURED,
    ("bsdf", "principled", "eta"): REFUSED,
    ("bsdf", "principledthin", "eta"): REFUSED,    # likewise        # a float in Mitsuba's principled: the test's <rgb> is refused
    ("bsdf", "pplastic", "eta"): REFUSED,               # a number, not the conductors' RGB of the table

}


def _scene_xml(tag: str, kind: str, param: str) -> tuple[str, str]:
    """(header, body) of a scene with plugin `kind` given parameter `param` (nothing if param is None)."""
    p = VALUES[param] if param else ""
    header, body = HEADER, ""
    if tag == "integrator":
        nested = '<integrator type="path"/>' if kind in ("moment", "aov") else ""
        body = f'<integrator type="{kind}">{p}{nested}</integrator>'
    elif tag == "sensor":
        lens = '<float name="aperture_radius" value="0.1"/>' if kind == "thinlens" and param != "aperture_radius" else ""
        header = HEADER.replace('<sensor type="perspective">', f'<sensor type="{kind}">{lens}{p}')
    elif tag == "film" and param in ("width", "height"):
        header = HEADER.replace(f'<integer name="{param}" value="{8 if param == "width" else 6}"/>', p)
    elif tag == "film":
        header = HEADER.replace('<film type="hdrfilm">', f'<film type="hdrfilm">{p}')
    elif tag == "rfilter":
        header = HEADER.replace('<rfilter type="box"/>', f'<rfilter type="{kind}">{p}</rfilter>')
    elif tag == "sampler":
        header = HEADER.replace('<film type="hdrfilm">', f'<sampler type="{kind}">{p}</sampler><film type="hdrfilm">')
    elif tag == "shape":
        file = {"obj": "a.obj", "ply": "a.ply", "serialized": "a.serialized"}.get(kind)
        if file:
            name = "b" + file[1:] if param == "filename" else file
            p = p.replace(VALUES["filename"], "") if param == "filename" else p
            p += f'<string name="filename" value="{name}"/>'
        body = f'<shape type="{kind}">{p}</shape>'
        if kind == "instance":      # of a group of one sphere
            body = ('<shape type="shapegroup" id="grp"><shape type="sphere"/></shape>'
                    f'<shape type="instance"><ref id="grp"/>{p}</shape>')
    elif tag == "bsdf":
        inner = {"twosided": '<bsdf type="diffuse"/>', "mask": '<bsdf type="diffuse"/>', "normalmap": '<bsdf type="diffuse"/>',
                 "blendbsdf": '<bsdf type="diffuse"/><bsdf type="conductor"/>'}.get(kind, "")
        if kind == "normalmap" and param != "normalmap":
            inner += VALUES["normalmap"].replace("b.png", "a.png")
        if kind == "bumpmap":
            inner = '<bsdf type="diffuse"/>' + VALUES["normalmap"].replace("b.png", "a.png")
            body = f'<shape type="obj"><string name="filename" value="a.obj"/><bsdf type="{kind}">{inner}{p}</bsdf></shape>'
            return header, body
        body = f'<shape type="rectangle"><bsdf type="{kind}">{inner}{p}</bsdf></shape>'
    elif tag == "texture":
        if kind == "bitmap":
            p += f'<string name="filename" value="{"b.png" if param == "filename" else "a.png"}"/>'
            p = p.replace(VALUES["filename"], "") if param == "filename" else p
        if kind == "rawconstant" and param is None:     # Mitsuba requires its value
            p = '<float name="value" value="0.5"/>'
        if kind == "mesh_attribute":                    # Mitsuba requires its name; a PLY file holds attributes
            p += "" if param == "name" else '<string name="name" value="vertex_c"/>'
            return header, ('<shape type="ply"><string name="filename" value="attr.ply"/><bsdf type="diffuse">'
                            f'<texture type="{kind}" name="reflectance">{p}</texture></bsdf></shape>')
        body = (f'<shape type="rectangle"><bsdf type="diffuse"><texture type="{kind}" name="reflectance">{p}'
                '</texture></bsdf></shape>')
    elif tag in ("medium", "phase", "volume"):
        body = _medium_xml(tag, kind, param, p)
    elif kind in ("constant", "point", "spot", "directional", "projector"):
        if kind == "directional" and param == "to_world":   # a translation does not turn it
            p = '<transform name="to_world"><rotate x="1" angle="30"/></transform>'
        body = f'<emitter type="{kind}">{p}</emitter>'
    elif kind == "envmap":
        file = "b.exr" if param == "filename" else "a.exr"
        body = f'<emitter type="{kind}">{p}<string name="filename" value="{file}"/></emitter>'
    else:
        body = f'<shape type="rectangle"><emitter type="{kind}">{p}</emitter></shape>'
    return header, body


VALUES["filename"] = ""


def _medium_xml(tag: str, kind: str, param: str | None, p: str) -> str:
    """A sphere holding a heterogeneous medium (its sigma_t the volume of kind, its phase function of kind),
    or the medium of kind; rendered by volpath."""
    medium, phase, volume = "heterogeneous", "isotropic", "constvolume"
    if tag == "volume" and param == "value":        # a colour, not the vector of VALUES
        p = '<rgb name="value" value="2, 3, 4"/>'
    if tag == "medium":
        medium, p_medium, p_phase, p_volume = kind, p, "", ""
    else:
        phase, volume = (kind, volume) if tag == "phase" else (phase, kind)
        p_medium, p_phase, p_volume = ("", p, "") if tag == "phase" else ("", "", p)
    if volume == "gridvolume":
        p_volume = p_volume.replace('value="clamp"', 'value="repeat"')   # clamp is its default
        p_volume += f'<string name="filename" value="{"b.vol" if param == "filename" else "a.vol"}"/>'
    sigma = "" if "sigma_t" in p_medium or medium == "homogeneous" else \
        f'<volume type="{volume}" name="sigma_t">{p_volume}</volume>'
    return ('<integrator type="volpath"/>'
            f'<medium type="{medium}" id="fog">{p_medium}{sigma}<phase type="{phase}">{p_phase}</phase></medium>'
            '<shape type="sphere"><bsdf type="null"/><ref name="interior" id="fog"/></shape>')


def write_vol(path, data: np.ndarray, bbox=((0, 0, 0), (1, 1, 1))) -> None:
    """A Mitsuba .vol file (version 3, float32) of data (z, y, x, channels)."""
    nz, ny, nx, c = data.shape
    path.write_bytes(b"VOL\x03" + np.array([1, nx, ny, nz, c], "<i4").tobytes()
                     + np.asarray(bbox, "<f4").tobytes() + data.astype("<f4").tobytes())


def _fingerprint(s) -> bytes:
    cam = s.camera
    return pickle.dumps((cam.to_world.tolist(), cam.fov, cam.fov_axis, cam.near_clip, cam.far_clip, cam.width,
                         cam.projection, cam.aperture_radius, cam.focus_distance, cam.film_size, cam.crop_x,
                         cam.crop_y, cam.sample_border,
                         cam.height, cam.rfilter, s.spp, s.seed, s.max_depth, s.rr_depth, s.shading_samples,
                         [(r.to_world.tolist(), r.bsdf, r.radiance) for r in s.rectangles],
                         [(m.vertices.tolist(), m.faces.tolist(), None if m.normals is None else m.normals.tolist(),
                           m.bsdf, m.radiance, None if m.uvs is None else m.uvs.tolist()) for m in s.meshes],
                         [(x.center.tolist(), x.radius, x.bsdf) for x in s.spheres], s.environment,
                         [(c.to_world.tolist(), c.flipped) for c in s.cylinders],
                         None if s.envmap is None else (s.envmap.image.tolist(), s.envmap.to_world.tolist()),
                         [(light.position.tolist(), light.intensity, light.cone(), light.projection)
                          for light in s.point_lights],
                         [(light.direction.tolist(), light.irradiance) for light in s.directional_lights],
                         [(m.kind, m.scale, m.phase, m.sample_emitters, m.spectral_extinction,
                           *(_volume_print(v) for v in (m.sigma_t, m.albedo))) for m in s.media],
                         sorted(s.shape_media.values()), s.camera_medium, s.hide_emitters))


def _volume_print(v):
    grid = getattr(v, "data", None)
    return (getattr(v, "value", None), v.to_world.tolist(), None if grid is None else grid.tolist(),
            getattr(v, "filter", None), getattr(v, "wrap", None))


def _outcome(tmp_path, tag, kind, param) -> str:
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0.25\nf 1/1 2/1 3/1\n")
    (tmp_path / "b.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")
    write_ply(tmp_path / "a.ply", True)
    write_ply(tmp_path / "b.ply", False, faces=FACES[:2])
    write_ply(tmp_path / "attr.ply", False, extra={"c_0": np.full(len(VERTICES), 0.25), "d_0": np.full(len(VERTICES), 0.5)})
    parts = [serialized_mesh(VERTICES, FACES), serialized_mesh(VERTICES[::-1], FACES[:3])]
    write_serialized(tmp_path / "a.serialized", parts)
    write_serialized(tmp_path / "b.serialized", parts[::-1])
    from PIL import Image
    for name, seed in (("a.png", 1), ("b.png", 2)):
        Image.fromarray(np.random.default_rng(seed).integers(0, 256, (4, 8, 3), dtype=np.uint8)).save(tmp_path / name)
    write_vol(tmp_path / "a.vol", np.arange(8.0).reshape(2, 2, 2, 1), ((0, 0, 0), (2, 1, 1)))
    write_vol(tmp_path / "b.vol", np.arange(8.0)[::-1].reshape(2, 2, 2, 1))
    for name, value in (("a.exr", 1.0), ("b.exr", 2.0)):
        OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": np.full((4, 8, 3), value, np.float32)}).write(
            str(tmp_path / name))
    base = load_scene(write_scene(tmp_path, _scene_xml(tag, kind, None)[1], "base.xml", _scene_xml(tag, kind, None)[0]))
    header, body = _scene_xml(tag, kind, param)
    try:
        scene = load_scene(write_scene(tmp_path, body, "with.xml", header))
    except SceneError as e:
        assert any(s in str(e) for s in (f"'{param}'", f"{param} ", f" {param}:", f'name="{param}"')), str(e)
        assert len(str(e).splitlines()) == 1, str(e)
        return REFUSED
    return HONOURED if _fingerprint(scene) != _fingerprint(base) else NO_EFFECT


CASES = [(tag, kind, p) for (tag, kind), params in MITSUBA_PARAMETERS.items() for p in params]


@pytest.mark.parametrize("tag, kind, param", CASES, ids=[f"{t}-{k}-{p}" for t, k, p in CASES])
def test_parameter_is_honoured_or_refused(tmp_path, tag, kind, param):
    expected = SPECIAL.get((tag, kind, param), EXPECTED[tag][param])
    assert _outcome(tmp_path, tag, kind, param) == expected


def test_every_parameter_has_an_expectation():
    assert all(p in EXPECTED[t] for t, _, p in CASES)
    assert set(VALUES) >= {p for _, _, p in CASES}


OBJECTS = ("bitmap", "srf", "texture", "data", "grid")   # parameters that take objects: not given in the Mitsuba check


def _mitsuba_xml(tmp_path, tag: str, kind: str, param: str) -> str:
    """The plugin alone, given `param`, as Mitsuba reads it (a file where the plugin needs one)."""
    files = {"obj": "a.obj", "ply": "a.ply", "serialized": "a.serialized", "envmap": "a.exr", "bitmap": "a.png",
             "gridvolume": "a.vol"}
    extra = f'<string name="filename" value="{tmp_path / files[kind]}"/>' if kind in files else ""
    value = extra if param == "filename" else VALUES[param] + extra
    value += {"twosided": '<bsdf type="diffuse"/>', "moment": '<integrator type="path"/>',
              "aov": '<integrator type="path"/>'}.get(kind, "")
    if kind == "thinlens" and param != "aperture_radius":
        value += VALUES["aperture_radius"]
    if kind in ("perspective", "thinlens", "projector") and param == "fov_axis":
        value += '<float name="fov" value="40"/>'
    if kind == "conductor" and param in ("eta", "k"):
        value += VALUES["k" if param == "eta" else "eta"]
    if tag == "emitter" and kind == "area":
        return f'<shape version="3.0.0" type="rectangle"><emitter type="area">{value}</emitter></shape>'
    return f'<{tag} version="3.0.0" type="{kind}">{value}</{tag}>'


@pytest.mark.parametrize("tag, kind, param", [c for c in CASES if c[2] not in OBJECTS],
                         ids=[f"{t}-{k}-{p}" for t, k, p in CASES if p not in OBJECTS])
def test_mitsuba_reads_every_listed_parameter(tmp_path, tag, kind, param, mi):
    """The table is Mitsuba's: none of its parameters is one Mitsuba 3.9.1 calls unreferenced (a value it
    refuses for another reason still shows the parameter is read). OBJECTS take objects."""
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    write_ply(tmp_path / "a.ply", True)
    write_serialized(tmp_path / "a.serialized", [serialized_mesh(VERTICES, FACES), serialized_mesh(VERTICES, FACES)])
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": np.ones((4, 8, 3), np.float32)}).write(
        str(tmp_path / "a.exr"))
    from PIL import Image
    Image.fromarray(np.zeros((4, 8, 3), np.uint8)).save(tmp_path / "a.png")
    write_vol(tmp_path / "a.vol", np.ones((2, 2, 2, 1)))
    try:
        mi.load_string(_mitsuba_xml(tmp_path, tag, kind, param))
    except Exception as e:
        assert "unreferenced" not in str(e), str(e)
