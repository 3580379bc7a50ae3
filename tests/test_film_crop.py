"""hdrfilm's crop window (crop_offset_x/y, crop_width/height) and sample_border against Mitsuba 3.9.1: the
image is the crop window of the whole film's projection (Film::set_crop_window, the projective cameras'
sample_to_camera over film size, crop size and offset), and with sample_border camera rays also start in
the filter's border around it (SamplingIntegrator::render: border_size pixels each side). Scenes:
mitsuba_scenes/hide_emitters.xml with its emitters shown and a Gaussian filter, cropped or with a wide
filter. Welch's t-test per 4 x 4 block and channel, Bonferroni-corrected, family-wise false-positive rate
ALPHA per comparison (2 agreements); the same test disagrees with the crop's offset ignored, with the
crop taken for the whole film (its aspect and field of view), and with sample_border ignored."""
import dataclasses
import functools
import subprocess
import sys

import numpy as np
import pytest

import tracer
from tracer.errors import SettingsError
from tracer.rendering import render
from validation.verdict.mitsuba_render import render_passes
from validation.verdict.protocol import ALPHA
from validation.verdict.scenefile import ScenePlanError, plan
from validation.verdict.stats import compare_passes

from .conftest import PASSES, ROOT, SCENES, SPP
from .test_xml_features import scene_errors

FILM = '<rfilter type="box"/>'
CROP = ('<rfilter type="gaussian"/><integer name="crop_offset_x" value="22"/><integer name="crop_offset_y" '
        'value="9"/><integer name="crop_width" value="20"/><integer name="crop_height" value="16"/>')
BORDER = '<rfilter type="gaussian"><float name="stddev" value="1"/></rfilter><boolean name="sample_border" value="true"/>'


def scene_file(tmp_path, film: str, name: str = "scene.xml", size: tuple[int, int] = (48, 36)):
    text = (SCENES / "hide_emitters.xml").read_text().replace(FILM, film)
    text = text.replace('<default name="hide_emitters" value="true"/>', '<default name="hide_emitters" value="false"/>')
    text = text.replace('value="48"/>', f'value="{size[0]}"/>', 1).replace('value="36"/>', f'value="{size[1]}"/>', 1)
    path = tmp_path / name
    path.write_text(text)
    return path


@functools.lru_cache(maxsize=None)
def mitsuba(path) -> np.ndarray:
    return render_passes(path, PASSES, SPP, seed=12345)


def compare(path, seed: int, edit=None):
    scene = tracer.load_scene(path)
    if edit is not None:
        scene.camera = edit(scene.camera)
    ours = np.stack([render(scene, "path", spp=SPP, seed=seed + k).image for k in range(PASSES)])
    theirs = mitsuba(path)
    assert ours.shape == theirs.shape
    return compare_passes(ours, theirs, ALPHA)


@pytest.fixture(scope="module")
def cropped(tmp_path_factory):
    return scene_file(tmp_path_factory.mktemp("crop"), CROP)


def test_a_crop_agrees_with_mitsuba(cropped):
    cam = tracer.load_scene(cropped).camera
    assert (cam.width, cam.height, cam.film_size, cam.crop_x, cam.crop_y) == (20, 16, (48, 36), 22, 9)
    result = compare(cropped, 7800)
    assert result.verdict == "agree", result.summary()


@pytest.mark.parametrize("mistake", [
    lambda cam: dataclasses.replace(cam, crop_x=0, crop_y=0),             # the offset ignored
    lambda cam: dataclasses.replace(cam, film_width=0, film_height=0),     # the crop projected as the whole film
], ids=["offset-ignored", "crop-as-film"])
def test_a_wrong_crop_disagrees(cropped, mistake):
    result = compare(cropped, 7820, mistake)
    assert result.verdict == "disagree", result.summary()


@pytest.fixture(scope="module")
def bordered(tmp_path_factory):
    return scene_file(tmp_path_factory.mktemp("border"), BORDER, size=(16, 12))


def test_sample_border_agrees_with_mitsuba(bordered):
    cam = tracer.load_scene(bordered).camera
    assert (cam.sample_border, cam.border, cam.sampled_size) == (True, 4, (24, 20))
    result = compare(bordered, 7840)
    assert result.verdict == "agree", result.summary()


def test_sample_border_ignored_disagrees(bordered):
    result = compare(bordered, 7860, lambda cam: dataclasses.replace(cam, sample_border=False))
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("film, words", [
    ('<integer name="crop_offset_x" value="40"/><integer name="crop_width" value="10"/>',
     "the crop window (crop_offset_x 40, crop_offset_y 0, crop_width 10, crop_height 36) does not fit the 48 x 36 "
     "film"),
    ('<integer name="crop_height" value="0"/>', "at least 1 x 1 pixels"),
])
def test_bad_crops_are_refused(tmp_path, film, words):
    errors = scene_errors(scene_file(tmp_path, FILM + film))
    assert len(errors) == 1 and words in errors[0] and '<film type="hdrfilm">' in errors[0], errors


def test_resizing_a_crop_and_comparing_it_are_refused(tmp_path, cropped, bordered):
    out = subprocess.run([sys.executable, "-m", "tracer.cli", "render", str(cropped), "--size", "8x8", "-o",
                          str(tmp_path / "x.exr")], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 1 and "crop window of its 48 x 36 pixels" in out.stderr, out.stderr
    with pytest.raises(ScenePlanError, match="crop window"):
        plan(cropped, None, 32, None)
    with pytest.raises(SettingsError, match="sample_border"):
        render(tracer.load_scene(bordered), "path", spp=1, rfilter="box")
