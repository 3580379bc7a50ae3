"""Mitsuba's samplers other than `independent` (stratified, multijitter, orthogonal, ldsampler) place samples
in patterns that change the noise, not the expected image: the tracer renders them with its independent
sampler at the sample count each rounds `sample_count` up to, and says so in `tracer info`. The counts are
checked against Mitsuba's own samplers; an image rendered with one agrees with Mitsuba's."""
import numpy as np
import pytest

import tracer
from tracer.cli import main
from tracer.rendering import render
from validation.verdict.mitsuba_render import mitsuba, render_passes
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP
from .test_xml_features import scene_errors

KINDS = ("stratified", "multijitter", "orthogonal", "ldsampler")


def sampler_scene(folder, kind: str, count: int | None, extra: str = "") -> "Path":
    text = (SCENES / "cornell_box.xml").read_text().replace(
        '<sampler type="independent">', f'<sampler type="{kind}">{extra}', 1)
    text = text.replace('<scene version="3.0.0">', f'<scene version="3.0.0"><path value="{SCENES}"/>', 1)
    path = folder / f"{kind}.xml"
    path.write_text(text if count is None else text.replace('value="$spp"', f'value="{count}"', 1))
    return path


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("count", [1, 5, 16, 17, 30])
def test_sample_count_rounds_as_mitsuba(tmp_path, kind, count):
    mi = mitsuba()
    expected = mi.load_dict({"type": kind, "sample_count": count}).sample_count()
    scene = tracer.load_scene(sampler_scene(tmp_path, kind, count), width=8, height=8)
    assert (scene.spp, scene.sampler) == (expected, kind)


def test_info_says_the_sampler_is_replaced(tmp_path, capsys):
    assert main(["info", str(sampler_scene(tmp_path, "ldsampler", 16))]) == 0
    assert "sampler 'ldsampler': rendered with the independent sampler at its 16 spp" in capsys.readouterr().out


def test_a_stratified_scene_agrees_with_mitsuba(tmp_path):
    path = sampler_scene(tmp_path, "stratified", None, '<boolean name="jitter" value="true"/>')
    scene = tracer.load_scene(path, width=SIZE, height=SIZE, max_depth=3, spp=SPP)
    ours = np.stack([render(scene, "path", seed=5100 + k).image for k in range(PASSES)])
    ref = render_passes(path, PASSES, SPP, seed=12345, width=SIZE, height=SIZE, max_depth=3)
    result = compare_passes(ours, ref, ALPHA)
    assert result.verdict == "agree", result.summary()


def test_a_misspelled_sampler_parameter_is_refused(tmp_path):
    (error,) = scene_errors(sampler_scene(tmp_path, "orthogonal", 4, '<integer name="strenght" value="2"/>'))
    assert "strenght" in error and "orthogonal" in error
