"""Mitsuba's `volpathmis` (volpath with spectral MIS over the channels' free-flight distances, Miller et al.
2019): in Mitsuba's RGB variants it estimates volpath's image with other noise; the tracer renders it with
its volpath and the same spectral MIS (tracer info says so; tests/test_spectral_mis.py checks the MIS).
mitsuba_scenes/volpathmis.xml (a chromatic medium, sigma_t 0.4 to 4 per unit by channel, in a null sphere)
against Mitsuba 3's own volpathmis: Welch's t-test per 4 x 4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA."""
import numpy as np

import tracer
from tracer.rendering import render
from validation.verdict.protocol import ALPHA
from validation.verdict.scenefile import plan
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, mitsuba_passes

SCENE, SIZE, SPP = "volpathmis.xml", 16, 32


def test_agrees_with_mitsubas_volpathmis():
    assert "VolumetricMisPath" in str(plan(SCENES / SCENE, None, SIZE, None).mitsuba_scene(4).integrator())
    scene = tracer.load_scene(SCENES / SCENE, width=SIZE, height=SIZE)
    assert scene.volumetric and scene.media
    ours = np.stack([render(scene, "path", spp=SPP, seed=7600 + k).image for k in range(PASSES)])
    result = compare_passes(ours, mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE), ALPHA)
    assert result.verdict == "agree", result.summary()


def test_info_says_how_volpathmis_is_rendered(tmp_path):
    scene = tracer.load_scene(SCENES / SCENE)
    assert (scene.integrator, scene.max_depth) == ("volpathmis", 6)
    assert scene.spectral_mis
    assert any("volpathmis: the tracer's volpath with spectral MIS" in n for n in scene.notes())
    path = tmp_path / SCENE
    path.write_text((SCENES / SCENE).read_text().replace(
        '<integer name="max_depth" value="$max_depth"/>',
        '<integer name="max_depth" value="$max_depth"/><boolean name="use_spectral_mis" value="false"/>'))
    plain = tracer.load_scene(path)
    assert plain.integrator == "volpathmis" and not plain.spectral_mis
    assert any("use_spectral_mis = false: rendered with the tracer's volpath" in n for n in plain.notes())
