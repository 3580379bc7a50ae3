"""Participating media against closed forms: a homogeneous slab's transmittance and single scattering, and
an infinite medium of albedo 1 in a white furnace; the loader's reading and refusals of media.

The slab: the medium between two large null rectangles z = 0 and z = T (a volpath scene), seen along -z
through a 1-degree field of view (ray directions within 0.5 degree of the axis: path lengths within 4e-5 of
T). Transmittance (albedo 0, a constant environment of radiance 1 behind): exp(-scale sigma_t T) per
channel, a chromatic sigma_t included (each path samples one channel's distances; the others are weighted
by tr / pdf). Single scattering (max_depth 2: one real collision, its shadow ray; a directional light of
irradiance E travelling at angle theta_l from -z, mu = cos theta_l): the camera sees

    L = albedo sigma_t E p(-mu) (1 - exp(-sigma_t T (1 + 1 / mu))) / (sigma_t (1 + 1 / mu)),

p the phase function at the angle between the light's direction of travel and the direction to the camera
(cos = -mu; pbrt-v4 eq. 11.13 with one scattering event). The furnace: the camera inside a sphere of a
medium of albedo 1 in a constant environment of radiance 1 sees radiance 1 in every direction, whatever the
density (homogeneous, or a grid) and the phase function.

Each comparison is a z-test of the image's mean (its standard error from the 256 pixels' spread, each pixel
the mean of 64 independent paths) at |z| < Z: 8 comparisons of 3 channels, each mean's z a Student t of
255 degrees of freedom (P(|t| > 4.5) = 1e-5), a false-positive rate of 2.5e-4 for the module; each slab
test also shows that the figure a typical mistake predicts (the scale ignored, a phase function's g of the
opposite sign) lies outside it, and the furnace fails when shadow rays cross the medium without its
transmittance. The furnace's last case takes Mitsuba's other weights (has_spectral_extinction
false) and no shadow rays from the medium (sample_emitters false)."""
from __future__ import annotations

import numpy as np
import pytest

import tracer
from tracer.media.phase import INV_FOUR_PI
from tracer.rendering import render

from .test_plugin_parameters import write_vol
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

Z = 4.5
SPP = 64
CAMERA = """<?xml version="1.0" encoding="utf-8"?>
<scene version="3.0.0">
    <integrator type="volpath"><integer name="max_depth" value="{depth}"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 1, 0"/></transform>
        {sensor_medium}
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
            <rfilter type="box"/></film>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
    </sensor>
"""


def _hg(g: float, cos: float) -> float:
    return INV_FOUR_PI * (1 - g * g) / (1 + g * g - 2 * g * cos) ** 1.5


def slab_scene(tmp_path, medium: str, lights: str, depth: int = -1, thickness: float = 1.0):
    header = CAMERA.format(depth=depth, fov=1, origin="0, 0, 5", target="0, 0, 0", sensor_medium="", spp=SPP)
    body = (f'<medium type="homogeneous" id="slab">{medium}</medium>'
            '<shape type="rectangle"><bsdf type="null"/><ref name="interior" id="slab"/><transform name="to_world">'
            f'<scale value="1000"/><translate z="{thickness}"/></transform></shape>'
            '<shape type="rectangle"><bsdf type="null"/><ref name="interior" id="slab"/>'
            '<boolean name="flip_normals" value="true"/><transform name="to_world"><scale value="1000"/></transform>'
            f'</shape>{lights}')
    return write_scene(tmp_path, body, header=header)


def mean_and_error(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pixels = image.reshape(-1, 3).astype(np.float64)
    return pixels.mean(0), pixels.std(0, ddof=1) / np.sqrt(len(pixels))


def assert_close(image, expected, wrong=None):
    mean, error = mean_and_error(image)
    z = (mean - expected) / np.maximum(error, 1e-7)
    assert np.all(np.abs(z) < Z), (mean, expected, z)
    if wrong is not None:
        assert np.all(np.abs((mean - np.asarray(wrong)) / np.maximum(error, 1e-7)) > Z), (mean, wrong, error)


ENVIRONMENT = '<emitter type="constant"><rgb name="radiance" value="1"/></emitter>'


def test_slab_transmittance(tmp_path):
    sigma, scale = np.array([0.5, 1.0, 2.0]), 0.8
    medium = ('<volume type="constvolume" name="sigma_t"><rgb name="value" value="0.5, 1.0, 2.0"/></volume>'
              '<rgb name="albedo" value="0"/>'
              f'<float name="scale" value="{scale}"/>')
    image = render(tracer.load_scene(slab_scene(tmp_path, medium, ENVIRONMENT))).image
    assert_close(image, np.exp(-scale * sigma), wrong=np.exp(-sigma))


@pytest.mark.parametrize("phase, g", [("isotropic", 0.0), ("hg", 0.6), ("hg", -0.5)])
def test_slab_single_scattering(tmp_path, phase, g):
    sigma, albedo, irradiance, theta = 1.5, np.array([0.8, 0.5, 0.3]), 2.0, np.radians(40)
    mu = np.cos(theta)
    inner = f'<float name="g" value="{g}"/>' if phase == "hg" else ""
    medium = (f'<float name="sigma_t" value="{sigma}"/><rgb name="albedo" value="0.8, 0.5, 0.3"/>'
              f'<phase type="{phase}">{inner}</phase>')
    light = (f'<emitter type="directional"><vector name="direction" x="{np.sin(theta)}" y="0" z="{-mu}"/>'
             f'<rgb name="irradiance" value="{irradiance}"/></emitter>')
    image = render(tracer.load_scene(slab_scene(tmp_path, medium, light, depth=2))).image
    k = 1 + 1 / mu

    def expected(g):
        return albedo * sigma * irradiance * _hg(g, -mu) * (1 - np.exp(-sigma * k)) / (sigma * k)

    assert_close(image, expected(g), wrong=expected(-g) if g else expected(0.5))


def furnace_scene(tmp_path, medium: str, phase: str):
    header = CAMERA.format(depth=-1, fov=60, origin="0, 0, 0", target="0, 0, -1", spp=SPP,
                           sensor_medium='<ref name="medium" id="fog"/>')
    body = (f'<medium id="fog" {medium}<rgb name="albedo" value="1"/>{phase}</medium>'
            '<shape type="sphere"><float name="radius" value="2"/><bsdf type="null"/>'
            f'<ref name="interior" id="fog"/></shape>{ENVIRONMENT}')
    return write_scene(tmp_path, body, header=header)


FURNACES = [
    ('type="homogeneous"><float name="sigma_t" value="1.5"/>', ""),
    ('type="homogeneous"><volume type="constvolume" name="sigma_t"><rgb name="value" value="0.5, 1, 2"/></volume>',
     '<phase type="hg"><float name="g" value="0.7"/></phase>'),
    ('type="heterogeneous"><volume type="gridvolume" name="sigma_t"><string name="filename" value="density.vol"/>'
     '<transform name="to_world"><translate value="-0.5, -0.5, -0.5"/><scale value="4"/></transform></volume>',
     '<phase type="hg"><float name="g" value="-0.4"/></phase>'),
    ('type="heterogeneous"><boolean name="has_spectral_extinction" value="false"/>'
     '<boolean name="sample_emitters" value="false"/><volume type="gridvolume" name="sigma_t">'
     '<string name="filename" value="density.vol"/><transform name="to_world"><translate value="-0.5, -0.5, -0.5"/>'
     '<scale value="4"/></transform></volume>', ""),
]


@pytest.mark.parametrize("medium, phase", FURNACES, ids=["homogeneous", "chromatic-hg", "grid-hg",
                                                          "grid-no-spectral-no-nee"])
def test_white_furnace(tmp_path, medium, phase):
    write_vol(tmp_path / "density.vol", np.random.default_rng(1).uniform(0, 3, (6, 5, 4, 1)))
    image = render(tracer.load_scene(furnace_scene(tmp_path, medium, phase))).image
    assert_close(image, np.ones(3))


def test_furnace_fails_when_shadow_rays_ignore_the_medium(tmp_path, monkeypatch):
    """Power: shadow rays that cross the fog without its transmittance (ratio tracking left out: the light
    reached through a medium as through vacuum) brighten the furnace beyond its bound."""
    from tracer.integrators import volpath

    monkeypatch.setattr(volpath, "_segment", volpath._vacuum)
    image = render(tracer.load_scene(furnace_scene(tmp_path, FURNACES[0][0], FURNACES[0][1]))).image
    mean, error = mean_and_error(image)
    assert np.all((mean - 1.0) / np.maximum(error, 1e-7) > Z), (mean, error)


def test_media_are_read_as_mitsuba_reads_them(tmp_path):
    write_vol(tmp_path / "grid.vol", np.arange(24.0).reshape(2, 3, 4, 1), ((1, 1, 1), (3, 2, 2)))
    body = ('<integrator type="volpath"/><medium type="heterogeneous" id="m">'
            '<volume type="gridvolume" name="sigma_t"><string name="filename" value="grid.vol"/>'
            '<boolean name="use_grid_bbox" value="true"/></volume><float name="scale" value="2"/></medium>'
            '<medium type="homogeneous" id="h"><phase type="hg"/></medium>'
            '<shape type="sphere"><ref name="interior" id="m"/><ref name="exterior" id="h"/></shape>')
    scene = tracer.load_scene(write_scene(tmp_path, body))
    m, h = scene.media
    assert (m.kind, m.scale, m.majorant, m.sigma_t.data.shape) == ("heterogeneous", 2.0, 46.0, (2, 3, 4, 1))
    assert np.allclose(m.sigma_t.to_world @ [0, 0, 0, 1], [1, 1, 1, 1])     # the grid's own box
    assert np.allclose(m.sigma_t.to_world @ [1, 1, 1, 1], [3, 2, 2, 1])
    assert (h.sigma_t.value, h.albedo.value, h.phase.g) == ((1.0, 1.0, 1.0), (0.75, 0.75, 0.75), 0.8)   # defaults
    assert list(scene.shape_media.values()) == [(1, 2)] and scene.camera_medium == 0


@pytest.mark.parametrize("body, words", [
    ('<medium type="homogeneous" id="m"><volume type="gridvolume" name="sigma_t"/></medium>'
     '<shape type="sphere"><ref name="interior" id="m"/></shape>', "a gridvolume needs a 'filename'"),
    ('<medium type="homogeneous" id="m"><phase type="hg"><float name="g" value="1"/></phase></medium>'
     '<shape type="sphere"><ref name="interior" id="m"/></shape>', "must lie in (-1, 1)"),
    ('<medium type="homogeneous" id="m"><phase type="rayleigh"/></medium>'
     '<shape type="sphere"><ref name="interior" id="m"/></shape>', "unsupported phase plugin 'rayleigh'"),
    ('<medium type="homogeneous" id="m"/><shape type="sphere"><ref name="inside" id="m"/></shape>',
     "supported names: interior, exterior"),
    ('<medium type="homogeneous" id="m"><float name="sigma_t" value="-1"/></medium>'
     '<shape type="sphere"><ref name="interior" id="m"/></shape>', "must not be negative"),
    ('<medium type="homogeneous" id="m"><rgb name="sigma_t" value="3, 2, 1"/></medium>'      # as Mitsuba 3.9.1
     '<shape type="sphere"><ref name="interior" id="m"/></shape>', "an <rgb> sigma_t must lie in [0, 1]"),
    ('<medium type="heterogeneous" id="m"><rgb name="albedo" value="1.2, 0.5, 0.5"/></medium>'
     '<shape type="sphere"><ref name="interior" id="m"/></shape>', "an <rgb> albedo must lie in [0, 1]"),
])
def test_refusals(tmp_path, body, words):
    errors = scene_errors(write_scene(tmp_path, body))
    assert len(errors) == 1 and words in errors[0], errors


def test_the_branching_estimator_refuses_media(tmp_path):
    body = ('<integrator type="volpath"><integer name="max_depth" value="3"/></integrator>'
            '<medium type="homogeneous" id="m"/><shape type="sphere"><ref name="interior" id="m"/></shape>')
    scene = tracer.load_scene(write_scene(tmp_path, body))
    with pytest.raises(tracer.SceneError, match="does not render participating media"):
        render(scene, "report", spp=1)
    scene = tracer.load_scene(write_scene(tmp_path, '<integrator type="volpath"/><shape type="sphere"/>'))
    with pytest.raises(tracer.SceneError, match="does not render the volpath integrator"):
        render(scene, "report", spp=1, max_depth=3)


def test_a_medium_takes_values_above_one_where_mitsuba_does(tmp_path):
    body = ('<integrator type="volpath"/><medium type="homogeneous" id="m"><float name="sigma_t" value="3"/>'
            '<volume type="constvolume" name="albedo"><rgb name="value" value="0.5, 0.5, 0.5"/></volume></medium>'
            '<medium type="homogeneous" id="n"><volume type="constvolume" name="sigma_t">'
            '<rgb name="value" value="3, 2, 1"/></volume></medium>'
            '<shape type="sphere"><ref name="interior" id="m"/><ref name="exterior" id="n"/></shape>')
    m, n = tracer.load_scene(write_scene(tmp_path, body)).media
    assert m.sigma_t.value == (3.0, 3.0, 3.0) and n.sigma_t.value == (3.0, 2.0, 1.0)
