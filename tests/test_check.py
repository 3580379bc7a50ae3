"""`validate check`: the verdict's rules on synthetic pass means, its outputs (exit codes, JSON, JUnit) and its
refusals of bad input, each in one line."""
import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from validation import cli
from validation.verdict.check import exit_code, write_json, write_junit
from validation.verdict.scenefile import ScenePlanError, plan
from validation.verdict.stats import compare, grubbs_critical
from validation.verdict.protocol import ALPHA   # family-wise false-positive rate of one comparison

from .conftest import SCENES



def normal_passes(seed: int, mean: float = 1.0, sd: float = 0.1, k: int = 16, shape=(8, 8, 3)) -> np.ndarray:
    return np.random.default_rng(seed).normal(mean, sd, (k, *shape))


def test_grubbs_critical_values_match_published_tables():
    # Grubbs (1950) / NIST two-sided critical values at alpha 0.05: n = 10 -> 2.29, n = 20 -> 2.71
    assert grubbs_critical(10, 0.05) == pytest.approx(2.29, abs=0.01)
    assert grubbs_critical(20, 0.05) == pytest.approx(2.71, abs=0.01)


def test_equal_normal_passes_agree_at_about_the_nominal_rate():
    """200 null comparisons of normal pass means at family-wise alpha 0.1: the disagree count is
    binomial(200, <= 0.1); 40 or more has probability below 1e-4 even at exactly 0.1."""
    disagree = sum(compare(normal_passes(2 * i), normal_passes(2 * i + 1), 0.1).verdict == "disagree"
                   for i in range(200))
    assert disagree < 40


def test_a_one_percent_bias_in_every_block_disagrees():
    result = compare(normal_passes(1, 1.01, 0.02), normal_passes(2), ALPHA)
    assert result.verdict == "disagree", result.summary()


def test_a_bias_too_small_for_any_block_is_caught_by_the_image_mean():
    a, b = normal_passes(3, 1.015, 0.05), normal_passes(4, 1.0, 0.05)
    result = compare(a, b, ALPHA)
    assert result.rejected_map.sum() == 0 and result.image_rejected.any(), result.summary()
    assert result.verdict == "disagree"


def test_a_rejection_decided_by_one_rare_pass_is_inconclusive():
    a, b = normal_passes(5, 1.0, 0.01), normal_passes(6, 1.0, 0.01)
    a[3, 2, 2, 0] = 1.06          # one outlying pass in one block (Grubbs' G about 3.4 > 2.85)
    b[:, 2, 2, 0] -= 0.03         # and a shift that Welch's test alone would reject there
    result = compare(a, b, ALPHA)
    assert result.rejected == 0 and result.untrusted_rejected >= 1, result.summary()
    assert result.verdict == "inconclusive"


def test_a_rejection_resting_on_a_few_distinct_pass_values_is_inconclusive():
    """As the branching estimator's passes with one camera ray per pixel where a few pixels are lit: each pass
    counts the rays that saw the light, and a run whose passes all counted alike has no variance."""
    a, b = normal_passes(9, 1.0, 0.1), normal_passes(10, 1.0, 0.1)      # (the image means then agree)
    a[:, 2, 2, 0] = 6.25                        # every pass the same count
    b[:, 2, 2, 0] = np.random.default_rng(11).normal(6.6, 0.2, len(b))
    result = compare(a, b, ALPHA)
    assert result.rejected == 0 and result.untrusted_rejected == 1, result.summary()
    assert result.verdict == "inconclusive"
    a[:, 2, 2, 0] = np.random.default_rng(12).normal(6.25, 0.05, len(a))   # the same shift, values distinct
    assert compare(a, b, ALPHA).verdict == "disagree"


def test_two_constant_sides_that_differ_disagree():
    """An emitter seen directly has no variance on either side: a wrong radiance there is a disagreement."""
    a, b = normal_passes(13, 1.0, 0.01), normal_passes(14, 1.0, 0.01)
    a[:, 1, 1, :], b[:, 1, 1, :] = 5.0, 5.1
    result = compare(a, b, ALPHA)
    assert result.verdict == "disagree" and result.rejected >= 1, result.summary()


def test_black_images_agree_and_a_black_side_against_light_disagrees():
    black = np.zeros((16, 8, 8, 3))
    assert compare(black, black, ALPHA).verdict == "agree"
    lit = np.ones((16, 8, 8, 3))
    assert compare(black, lit, ALPHA).verdict == "disagree"


def test_exit_codes_json_and_junit(tmp_path):
    class Fake:
        def __init__(self, verdict):
            self.verdict, self.seconds, self.scene, self.renderer, self.max_depth = verdict, 1.0, "s.xml", "r", 3
            self.note, self.alpha, self.spp, self.passes, self.stage, self.stages = "", ALPHA, 64, 16, 1, 1
            self.comparison = compare(normal_passes(7), normal_passes(8), ALPHA)

        def line(self):
            return f"{self.verdict} line"

        def as_dict(self):
            return {"verdict": self.verdict}

    assert exit_code([Fake("agree")]) == 0
    assert exit_code([Fake("agree"), Fake("inconclusive")]) == 3
    assert exit_code([Fake("inconclusive"), Fake("disagree")]) == 1
    assert exit_code([Fake("inconclusive")], ["timed out"]) == 4      # the run is incomplete
    assert exit_code([Fake("disagree")], ["timed out"]) == 1
    results = [Fake("agree"), Fake("disagree"), Fake("inconclusive")]
    write_json(results, tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["exit_code"] == 1
    write_junit(results, tmp_path / "r.xml")
    suite = ET.parse(tmp_path / "r.xml").getroot().find("testsuite")
    assert (suite.get("tests"), suite.get("failures"), suite.get("skipped")) == ("3", "1", "1")
    assert len(suite.findall("testcase/failure")) == 1
    properties = {p.get("name"): p.get("value") for p in suite.find("testcase/properties")}
    assert float(properties["detectable_bias_median_block"]) > 0 and properties["power"] == "0.8"


def test_film_size_and_depth_override_any_scene(tmp_path):
    """A scene without <default>s: -D width/height/max_depth still apply (to both renderers)."""
    text = (SCENES / "stress" / "glass_sphere.xml").read_text()
    for name, value in (("spp", "16"), ("width", "32"), ("height", "32"), ("max_depth", "-1")):
        text = text.replace(f'<default name="{name}" value="{value}"/>', "").replace(f"${name}", value)
    scene = tmp_path / "no_defaults.xml"
    scene.write_text(text)
    p = plan(scene, {"width": "20", "height": "12", "max_depth": "3"})
    assert (p.width, p.height, p.max_depth) == (20, 12, 3)
    assert p.tracer_scene().camera.width == 20
    assert '<integer name="width" value="20"' in p.mitsuba_xml()
    assert plan(scene, size=16).width == 16
    with pytest.raises(ScenePlanError, match="declares no <default"):
        plan(scene, {"colour": "1"})


@pytest.mark.parametrize("args, message", [
    (["--passes", "1"], "passes must be an integer of at least 3"),
    (["--spp", "0"], "spp must be an integer of at least 1"),
    (["--alpha", "2"], "alpha must lie strictly between 0 and 1"),
    (["-D", "nope"], "expected NAME=VALUE"),
    (["--renderer", "render {scene}"], "must contain {output}"),
    (["--renderer", "render {scene} {output} {nonsense}"], "bad placeholder"),
    (["--report-depth", "-3", "--estimator", "report"], "the report's depth must be >= 0"),
    (["--estimator", "report", "--direct", "0"], "direct (N) and indirect (M) must be >= 1"),
    (["--spp", "4", "-D", "spp=8"], "--spp or -D spp, not both"),
])
def test_bad_arguments_are_refused_in_one_line(args, message, capsys):
    assert cli.main(["check", str(SCENES / "hexagon_room.xml"), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err


def test_missing_scene_and_failing_renderer_are_refused(tmp_path, capsys):
    assert cli.main(["check", str(tmp_path / "none.xml")]) == 2
    assert "not found" in capsys.readouterr().err
    command = f"{sys.executable} -c \"import sys; sys.exit('broken renderer')\" {{output}}"
    assert cli.main(["check", str(SCENES / "hexagon_room.xml"), "--renderer", command, "--passes", "3"]) == 2
    err = capsys.readouterr().err.strip()
    assert "broken renderer" in err and "\n" not in err


def test_check_on_a_black_scene_agrees(capsys):
    code = cli.main(["check", str(SCENES / "stress" / "empty.xml"), "--passes", "4", "-D", "spp=3"])
    out = capsys.readouterr().out
    assert code == 0 and "both images are black" in out and "4 x 3 spp" in out, out


def test_an_interruption_wrapped_by_drjit_is_reported_as_one(monkeypatch, capsys):
    """Dr.Jit re-raises a KeyboardInterrupt from inside its loops as a RuntimeError."""
    def interrupted(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise RuntimeError("dr.while_loop(): encountered an exception (see above)") from e

    monkeypatch.setattr(cli, "_run", interrupted)
    assert cli.main(["check", str(SCENES / "hexagon_room.xml")]) == 130
    assert capsys.readouterr().err.strip() == "validate: interrupted"


def test_a_bug_shows_its_traceback(monkeypatch, capsys):
    def bug(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(cli, "_run", bug)
    with pytest.raises(ZeroDivisionError):
        cli.main(["check", str(SCENES / "hexagon_room.xml")])
    assert "internal error" in capsys.readouterr().err


def test_float32_round_off_is_not_a_disagreement_but_a_real_offset_is():
    """A constant sky seen directly: no variance; a difference of 5e-7 is float32 arithmetic, 1e-3 is not."""
    sky = np.full((16, 8, 8, 3), 0.225)
    assert compare(sky * (1 + 5e-7), sky, ALPHA).verdict == "agree"
    assert compare(sky * (1 + 1e-3), sky, ALPHA).verdict == "disagree"
    noisy = normal_passes(9, 0.225, 1e-9)
    assert compare(noisy * (1 + 5e-7), noisy, ALPHA).verdict == "agree"


def test_a_sensor_in_an_included_file_is_planned(tmp_path):
    """Mitsuba's docs scenes declare their sensor and integrator in included files, with $parameters."""
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "sensor.xml").write_text(
        '<scene version="3.0.0"><integrator type="$integrator"><integer name="max_depth" value="3"/></integrator>'
        '<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="$w"/>'
        '<integer name="height" value="60"/></film></sensor></scene>')
    scene = tmp_path / "main.xml"
    scene.write_text('<scene version="3.0.0"><default name="integrator" value="path"/>'
                     '<default name="w" value="80"/><include filename="parts/sensor.xml"/></scene>')
    p = plan(scene, size=40)
    assert (p.width, p.height, p.max_depth) == (40, 30, 3)
    assert '<integer name="width" value="40"' in p.mitsuba_xml() and "<include" not in p.mitsuba_xml()


def test_coverage_counts_scenes_and_ranks_blockers(tmp_path):
    """validate coverage on a miniature mitsuba-data: one scene both load, one the tracer refuses, one that
    Mitsuba refuses too, an include fragment (no sensor) reported as such, and a refusal naming a file in the
    data's folder by its path relative to the folder."""
    from validation.suites.coverage import markdown, survey

    scenes = tmp_path / "docs" / "scenes"
    scenes.mkdir(parents=True)
    room = (SCENES / "stress" / "glass_sphere.xml").read_text()
    (scenes / "a.xml").write_text(room)
    (scenes / "b.xml").write_text(room.replace('<bsdf type="dielectric">', '<bsdf type="hair">'))
    (scenes / "c.xml").write_text(room.replace("</scene>", "<shape type='nonsense'/></scene>"))
    (scenes / "d.xml").write_text("<scene version='3.0.0'><bsdf type='diffuse' id='white'/></scene>")
    (scenes / "e.xml").write_text(room.replace("</scene>", "<shape type='obj'><string name='filename' "
                                               "value='missing.obj'/></shape></scene>"))
    outcomes = survey(tmp_path, check_scenes=False)
    assert [(o.mitsuba == "loads", o.tracer) for o in outcomes] == [(True, "loads"), (True, "refused"),
                                                                     (False, "refused"), (True, "fragment"),
                                                                     (False, "refused")]
    text = markdown(outcomes, "validate coverage MITSUBA_DATA_DIR")
    assert "| scene files | 5 |" in text and "| Mitsuba loads (of the 4 scenes) | 2 |" in text
    assert "| include fragments (no sensor: parts of other scenes; not counted below) | 1 |" in text
    assert "| docs/scenes/d.xml | loads | fragment | an include fragment: no sensor |" in text
    assert "| bsdf hair | 1 | 1 |" in text
    assert "missing.obj" in outcomes[-1].refusals[0] and "docs/scenes" in outcomes[-1].refusals[0]
    assert str(tmp_path) not in text + str([o.refusals + [o.mitsuba] for o in outcomes])
    unchecked = markdown(outcomes, "validate coverage MITSUBA_DATA_DIR --no-check", checked=False)
    assert "**not checked** in this run" in unchecked and "| ... and agrees" not in unchecked
    assert "| docs/scenes/a.xml | loads | loads | not checked |" in unchecked


def test_the_content_key_covers_files_an_included_fragment_names_through_the_includers_path(tmp_path):
    """Mitsuba's test scenes name their meshes in an included fragment, found through the including file's
    <path>: those meshes are part of the scene's content, so editing one changes the key."""
    from validation.verdict.scenefile import files_digest, referenced_files

    (tmp_path / "common" / "meshes").mkdir(parents=True)
    (tmp_path / "tests" / "fragments").mkdir(parents=True)
    mesh = tmp_path / "common" / "meshes" / "sphere.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "tests" / "fragments" / "grid.xml").write_text(
        '<scene version="3.0.0"><shape type="obj"><string name="filename" value="meshes/sphere.obj"/></shape></scene>')
    scene = tmp_path / "tests" / "scene.xml"
    scene.write_text('<scene version="3.0.0"><path value="../common"/><include filename="fragments/grid.xml"/></scene>')
    assert [f.resolve() for f in referenced_files(scene)][1:] == [mesh, tmp_path / "tests" / "fragments" / "grid.xml"]
    before = files_digest(scene)
    mesh.write_text("v 0 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\n")
    assert files_digest(scene) != before


def test_a_check_names_the_integrator_the_tracer_renders():
    from validation.verdict.renderers import TracerRenderer
    from validation.verdict.scenefile import plan

    scenes = Path(__file__).resolve().parents[1] / "mitsuba_scenes"
    path = TracerRenderer("path")
    assert path.label_for(plan(scenes / "volpathmis.xml")) == "tracer volpathmis"
    assert path.label_for(plan(scenes / "ptracer.xml")) == "tracer ptracer"
    assert path.label_for(plan(scenes / "cube.xml")) == "tracer path"
    assert TracerRenderer("report").label_for(plan(scenes / "cube.xml")).startswith("tracer report")
