"""AOVs (albedo, normal through mirrors and glass), Open Image Denoise, and `tracer render --aovs/--denoise`."""
from pathlib import Path

import numpy as np
import pytest

import tracer
from tracer import cli
from tracer.aov import render_aovs
from tracer.denoise import DenoiseError, denoise
from tracer.imageio import read_exr
from tracer.rendering import render

SCENES = Path(__file__).resolve().parents[1] / "mitsuba_scenes"

# Camera at the origin looking along +x; a wall 2 m in front (FRONT) and a red wall 2 m behind.
BOX = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="1, 0, 0" up="0, 0, 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale value="20"/><rotate y="1" angle="-90"/><translate x="2"/></transform>
        {front}
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="20"/><rotate y="1" angle="90"/><translate x="-2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.1, 0.1"/></bsdf>
    </shape>
    {extra}
</scene>"""
GREEN = '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.7, 0.3"/></bsdf>'
MIRROR = '<bsdf type="conductor"><string name="material" value="none"/></bsdf>'
GLASS_PANE = """<shape type="rectangle">
        <transform name="to_world"><scale value="20"/><rotate y="1" angle="-90"/><translate x="1"/></transform>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1.0"/></bsdf>
    </shape>"""


def _box(tmp_path, front, extra="", fov=60):
    path = tmp_path / "box.xml"
    path.write_text(BOX.format(front=front, extra=extra, fov=fov))
    return tracer.load_scene(path)


def test_albedo_of_a_directly_seen_diffuse_wall_is_its_reflectance(tmp_path):
    aov = render_aovs(_box(tmp_path, GREEN), spp=4)
    np.testing.assert_allclose(aov.albedo, np.broadcast_to([0.2, 0.7, 0.3], aov.albedo.shape), rtol=1e-6)


def test_normals_are_unit_length_and_face_the_camera(tmp_path):
    aov = render_aovs(_box(tmp_path, GREEN), spp=4)
    np.testing.assert_allclose(np.linalg.norm(aov.normal, axis=-1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(aov.normal, np.broadcast_to([-1.0, 0.0, 0.0], aov.normal.shape), atol=1e-6)


def test_aovs_through_a_mirror_show_the_reflected_surface(tmp_path):
    aov = render_aovs(_box(tmp_path, MIRROR), spp=4)
    np.testing.assert_allclose(aov.albedo, np.broadcast_to([0.6, 0.1, 0.1], aov.albedo.shape), rtol=1e-6)
    np.testing.assert_allclose(aov.normal, np.broadcast_to([1.0, 0.0, 0.0], aov.normal.shape), atol=1e-6)


def test_aovs_through_glass_blend_reflection_and_refraction_by_fresnel(tmp_path):
    """A glass pane before the green wall, seen almost head-on: F = ((1.5 - 1) / (1.5 + 1))^2 = 0.04 of the
    samples reflect to the red wall behind the camera, the rest refract to the green wall."""
    aov = render_aovs(_box(tmp_path, GREEN, GLASS_PANE, fov=8), spp=256)
    f = 0.04
    expected = (1 - f) * np.array([0.2, 0.7, 0.3]) + f * np.array([0.6, 0.1, 0.1])
    np.testing.assert_allclose(aov.albedo.mean(axis=(0, 1)), expected, atol=0.004)


def test_aovs_of_the_room_are_in_range_and_misses_are_zero():
    scene = tracer.load_scene(SCENES / "hexagon_room.xml", width=16, height=16)
    aov = render_aovs(scene, spp=2)
    assert aov.albedo.shape == aov.normal.shape == (16, 16, 3)
    assert aov.albedo.min() >= 0 and aov.albedo.max() <= 1
    assert np.linalg.norm(aov.normal, axis=-1).max() <= 1 + 1e-6
    assert (aov.albedo.max(-1) == 1.0).any()  # the light, seen directly: its colour, white


@pytest.fixture(scope="module")
def room64():
    """The room at 64 x 64: a noisy 4 spp image, its AOVs, and a 1024 spp tracer render as the target."""
    scene = tracer.load_scene(SCENES / "hexagon_room.xml", width=64, height=64)
    noisy = render(scene, "path", spp=4, seed=3, max_depth=4).image
    target = render(scene, "path", spp=1024, seed=4, max_depth=4).image
    return noisy, render_aovs(scene, spp=8), target


def test_denoising_lowers_the_error_of_a_noisy_image(room64):
    """Off the light and its reflections (whose HDR edges OIDN alters; see the improvements report), the
    denoised 4 spp image's RMSE must be at most 0.6 of the noisy one's; SSIM must rise by at least 0.1."""
    from skimage.metrics import structural_similarity

    from tracer.imageio import srgb_encode

    noisy, aov, target = room64
    out = denoise(noisy, aov.albedo, aov.normal)
    assert out.dtype == np.float32 and out.shape == noisy.shape
    assert np.isfinite(out).all() and out.min() >= 0
    off_light = target.max(axis=-1) < 4.0

    def err(x):
        return np.sqrt(np.mean((x - target)[off_light] ** 2))

    def ssim(x):
        return structural_similarity(srgb_encode(x), srgb_encode(target), channel_axis=-1, data_range=1.0)

    assert err(out) <= 0.6 * err(noisy), (err(out), err(noisy))
    assert ssim(out) >= ssim(noisy) + 0.1, (ssim(out), ssim(noisy))
    colour_only = denoise(noisy)
    assert err(colour_only) <= 0.6 * err(noisy)


def test_denoise_refuses_bad_input(room64):
    noisy, aov, _ = room64
    with pytest.raises(ValueError, match="needs an albedo"):
        denoise(noisy, normal=aov.normal)
    with pytest.raises(ValueError, match="shape"):
        denoise(noisy, aov.albedo[:32])
    with pytest.raises(ValueError, match="NaN"):
        denoise(np.full_like(noisy, np.nan))


def test_a_failing_binding_raises_a_clear_error(room64, monkeypatch):
    import pyoidn

    def broken(*args, **kwargs):
        raise RuntimeError("OIDN filter execution failed (error 1): boom")

    monkeypatch.setattr(pyoidn, "denoise", broken)
    with pytest.raises(DenoiseError, match="Open Image Denoise failed: RuntimeError: OIDN filter execution"):
        denoise(room64[0])


ARGS = ["render", str(SCENES / "hexagon_room.xml"), "-D", "width=16", "-D", "height=16", "--spp", "2", "-q"]


def test_cli_aovs_writes_exactly_the_promised_files(tmp_path):
    assert cli.main(ARGS + ["-o", str(tmp_path / "room.exr"), "--aovs", "--aov-spp", "2"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room.albedo.exr", "room.exr", "room.normal.exr",
                                                          "room.png"]
    normal = read_exr(tmp_path / "room.normal.exr")
    assert normal.min() < 0 and np.abs(normal).max() <= 1  # stored in [-1, 1], not remapped


def test_cli_denoise_keeps_the_noisy_image_and_the_aovs(tmp_path, capsys):
    assert cli.main(ARGS + ["-o", str(tmp_path / "room.exr"), "--denoise"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room.albedo.exr", "room.exr", "room.noisy.exr",
                                                          "room.normal.exr", "room.png"]
    assert not np.array_equal(read_exr(tmp_path / "room.exr"), read_exr(tmp_path / "room.noisy.exr"))
    printed = capsys.readouterr().out
    assert "AOVs (albedo, normal) 8 spp" in printed and "denoise (Open Image Denoise" in printed


def test_cli_denoise_failure_leaves_no_file(tmp_path, monkeypatch, capsys):
    import tracer.denoise

    def broken(*args, **kwargs):
        raise DenoiseError("Open Image Denoise failed: boom")

    monkeypatch.setattr(tracer.denoise, "denoise", broken)
    assert cli.main(ARGS + ["-o", str(tmp_path / "out" / "room.exr"), "--denoise"]) == 1
    assert "tracer: error: Open Image Denoise failed: boom" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_cli_write_failure_removes_what_was_written(tmp_path, monkeypatch, capsys):
    import tracer.imageio

    def broken(path, image):
        raise OSError(f"{path}: disk full")

    monkeypatch.setattr(tracer.imageio, "write_normal_exr", broken)
    assert cli.main(ARGS + ["-o", str(tmp_path / "room.exr"), "--aovs"]) == 1
    assert "disk full" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_refuses_a_bad_aov_spp(tmp_path, capsys):
    assert cli.main(ARGS + ["-o", str(tmp_path / "room.exr"), "--aovs", "--aov-spp", "0"]) == 1
    assert "--aov-spp must be >= 1" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
