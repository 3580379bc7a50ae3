"""The Python API: `tracer.render` is the function, its arguments are checked before the first ray with
messages that name the parameter, any spp works (passes), and the README's example runs as written."""
import re
from pathlib import Path

import numpy as np
import pytest

import tracer
from tracer import PlanError, SettingsError, UserError, plan
from tracer.film import ReconstructionFilter

ROOT = Path(__file__).resolve().parents[1]
ROOM = ROOT / "mitsuba_scenes" / "hexagon_room.xml"


@pytest.fixture(scope="module")
def scene():
    return tracer.load_scene(ROOM, width=8, height=6)


@pytest.fixture
def no_render(monkeypatch):
    import tracer.rendering

    def started(*args, **kwargs):
        raise AssertionError("the render started")

    monkeypatch.setattr(tracer.rendering, "SceneGeometry", started)


def test_tracer_render_is_the_function():
    import tracer.rendering  # noqa: F401  (importing the module must not replace it)

    assert callable(tracer.render) and tracer.render is tracer.rendering.render
    assert tracer.render.__name__ == "render"


@pytest.mark.parametrize("kwargs, message", [
    ({"max_depth": 2.5}, "max_depth must be an integer, got 2.5"),
    ({"spp": True}, "spp must be an integer, got True"),
    ({"spp": 0}, "spp must be >= 1, got 0"),
    ({"seed": 2**70}, "seed must be in [0, 2^32)"),
    ({"seed": -1}, "seed must be in [0, 2^32)"),
    ({"estimator": "bdpt"}, "unknown estimator 'bdpt'"),
    ({"rfilter": "lanczos"}, "rfilter must be a ReconstructionFilter or one of box, gaussian, tent"),
    ({"direct": 4}, "direct: the report estimator's settings; estimator='path' does not use them"),
    ({"indirect": 2, "hemisphere": "uniform"}, "indirect, hemisphere: the report estimator's settings"),
    ({"estimator": "report", "max_depth": -1}, "it needs max_depth >= 0"),
    ({"estimator": "report", "max_depth": 3, "indirect": 0}, "M = 0"),
    ({"estimator": "report", "max_depth": 3, "hemisphere": "sphere"}, "hemisphere must be one of cosine, uniform"),
    ({"time_limit": 0}, "time_limit must be a positive number of seconds"),
])
def test_arguments_are_checked_before_the_first_ray(scene, no_render, kwargs, message):
    with pytest.raises(SettingsError) as e:
        tracer.render(scene, **kwargs)
    assert message in str(e.value)
    assert isinstance(e.value, UserError) and isinstance(e.value, ValueError)


def test_a_scene_that_is_not_one_is_refused(no_render):
    with pytest.raises(SettingsError, match="scene must be a Scene .* or a scene file's path, got int"):
        tracer.render(42)


def test_a_scene_file_path_is_loaded(tmp_path, scene):
    text = ROOM.read_text()
    for name, value in (("width", "8"), ("height", "6"), ("spp", "2")):
        text = re.sub(rf'<default name="{name}" value="\d+"/>', f'<default name="{name}" value="{value}"/>', text)
    (tmp_path / "room.xml").write_text(text)
    (tmp_path / "meshes").symlink_to(ROOM.parent / "meshes")
    from_path = tracer.render(str(tmp_path / "room.xml"))
    from_scene = tracer.render(scene, spp=2)
    assert from_path.image.shape == (6, 8, 3) and from_path.spp == 2
    assert np.array_equal(from_path.image, from_scene.image)


def test_a_filter_by_name_is_mitsubas_default_of_that_kind(scene):
    by_name = tracer.render(scene, spp=2, rfilter="gaussian").image
    by_object = tracer.render(scene, spp=2, rfilter=ReconstructionFilter("gaussian")).image
    # equal up to the order of the Gaussian's overlapping splats (float atomics, several threads)
    np.testing.assert_allclose(by_name, by_object, rtol=1e-5, atol=1e-7)


def test_more_samples_than_a_pass_holds_render_in_passes(scene, monkeypatch):
    """Any spp works: passes of at most MAX_PASS_SAMPLES samples, each with its own random streams. Here a
    pass holds 3 spp of the 48 pixels: 7 spp take passes of 3, 3 and 1, and 6 spp two passes of 3, which
    would develop to the 3 spp image (up to float rounding) if the second pass repeated the first one's
    streams."""
    one_pass = tracer.render(scene, spp=7, seed=5)
    first = tracer.render(scene, spp=3, seed=5)
    monkeypatch.setattr(plan, "MAX_PASS_SAMPLES", 48 * 3)
    passes = tracer.render(scene, spp=7, seed=5)
    two = tracer.render(scene, spp=6, seed=5)
    assert (passes.spp, passes.settings["passes"], one_pass.settings["passes"]) == (7, 3, 1)
    assert (two.spp, two.settings["passes"]) == (6, 2)
    assert not np.array_equal(passes.image, one_pass.image)   # other streams after the first pass
    assert np.abs(two.image - first.image).max() > 1e-3     # the second pass has streams of its own
    assert passes.rays > 2 * first.rays


def test_plan_errors_are_user_errors_before_the_first_ray(scene, monkeypatch, no_render):
    monkeypatch.setattr(plan, "available_memory", lambda: 1024)
    with pytest.raises(PlanError, match="8 x 6 needs about .* available; at most about .* fits"):
        tracer.render(scene, spp=1)


def test_the_readme_example_matches_the_clis_defaults(monkeypatch):
    """The README's Python example renders the report estimator at the CLI's default of 1 spp."""
    readme = (ROOT / "README.md").read_text()
    example = re.search(r"From Python:\n\n```python\n(.*?)```", readme, re.S)[1]
    assert 'tracer.render(scene, "report", spp=1' in example
    small = example.replace("width=200, height=200", "width=10, height=10")
    namespace = {}
    monkeypatch.chdir(ROOT)
    exec(small, namespace)
    assert namespace["result"].image.shape == (10, 10, 3) and namespace["result"].spp == 1


def test_time_limit_stops_before_a_pass_that_would_end_after_it(monkeypatch):
    """With a clock where every pass takes 1 s: a limit of 3.5 s renders 3 passes (the 4th would end at
    4 s); without a limit, all of them."""
    import tracer.rendering as rendering

    clock = [0.0]
    monkeypatch.setattr(rendering.time, "perf_counter", lambda: clock[0])

    def one_second(index, spp):
        clock[0] += 1.0

    assert rendering.run_passes([1] * 10, 3.5, one_second) == ([1, 1, 1], None)
    assert rendering.run_passes([1] * 10, 0.1, one_second) == ([1], None)          # the first pass always runs
    assert rendering.run_passes([2, 2, 1], None, one_second) == ([2, 2, 1], None)


def test_a_time_limit_not_reached_renders_every_sample(scene):
    result = tracer.render(scene, spp=3, time_limit=1e6)
    assert (result.spp, result.settings["passes"]) == (3, 3)
