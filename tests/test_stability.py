"""The fast cases of the numerical-stability suite (validation/suites/stability.py, mitsuba_scenes/stress/).

Statistical cases run at family-wise false-positive rate ALPHA for this file (Bonferroni over its
statistical cases); black and input cases are exact and have no false positives. The slow cases (the
furnace near rho = 1, tiny lights, scaled rooms, glass against Mitsuba) run in
`python -m validation.suites.stability --report reports/stability.md`.
"""
import pytest

import tracer
from validation.suites import stability
from validation.verdict.protocol import ALPHA   # family-wise false-positive rate of one comparison

FAST = [c for c in stability.cases() if c.fast]
CASE_ALPHA = ALPHA / sum(c.statistical for c in FAST)


@pytest.mark.parametrize("case", FAST, ids=lambda c: c.name)
def test_fast_case(case):
    outcome = stability.run_case(case, CASE_ALPHA, mitsuba=False)
    assert outcome.passed, f"{case.name}: ours {outcome.ours}, error {outcome.error}; {outcome.detail}"


def test_exact_check_fails_on_a_biased_value():
    """Power: the furnace check rejects an exact value 1% off (what a lost bounce or leak would cost)."""
    case = next(c for c in FAST if c.name == "furnace rho=0.9 max_depth=5")
    wrong = stability.Case(**{**case.__dict__, "exact": case.exact * 1.01})
    assert not stability.run_case(wrong, CASE_ALPHA, mitsuba=False).passed


def test_black_check_fails_when_the_light_is_inside():
    """Power: the leak check sees light (the edge-on scene rendered from above the light is not black)."""
    case = stability.Case("edge-on, camera moved", "lights", "stress/edge_on.xml", "black")
    scene = tracer.load_scene(case.path, width=8, height=8)
    scene.camera.to_world[2, 3] = 1.0   # lift the camera out of the light's plane
    from tracer.rendering import render
    assert render(scene, "path", spp=4, seed=0).image.max() > 0


def test_furnace_formula():
    assert stability.furnace_value(0.5, 1) == 1.0           # emission seen directly is depth 1
    assert stability.furnace_value(0.5, 2) == 1.5
    assert stability.furnace_value(0.999, -1) == pytest.approx(1000.0)


@pytest.mark.parametrize("bad", ["nan", "1e39"])
def test_bad_numbers_are_refused_or_render_clean(bad):
    """Every number of stress/bad_number_base.xml replaced in turn: one-line refusal or a clean image."""
    result = stability.bad_number_sweep(only=(bad,))[bad]
    assert not result["failed"], result["failed"][:5]
    assert result["refused"] > 0


def test_scaled_rooms_are_up_to_date():
    text = (stability.SCENES / "hexagon_room.xml").read_text()
    for fname, (op, scale) in stability._SCALED_OPS.items():
        assert (stability.STRESS / fname).read_text() == stability.scaled_room(text, op, scale), \
            f"run python -m validation.suites.stability --write-scenes ({fname} is stale)"


@pytest.mark.parametrize("scene_name", stability.LEAK_SCENES)
def test_rays_through_shared_edges_and_vertices_hit(scene_name):
    """Rays from inside a closed enclosure aimed exactly at its corners and along its edges must hit it:
    a miss is a crack a path could leak through (closed by tracer.shapes.planar.EDGE_MARGIN)."""
    missed, total = stability.edge_ray_misses(scene_name)
    assert missed == 0, f"{missed} of {total} rays through edges/vertices slipped through the enclosure"


@pytest.mark.parametrize("scene_name", stability.LEAK_SCENES)
def test_hit_points_on_shared_edges_lie_inside_the_enclosure(scene_name):
    """A hit accepted by the conservative edge test may lie up to 2^-20 beyond the edge, outside the
    neighbouring face's plane; a path continued from there escapes. SceneGeometry.surface keeps every hit
    point inside its primitive, so each lies strictly inside the convex enclosure (float32 exact test)."""
    import numpy as np
    from scipy.spatial import ConvexHull

    for geo, vertices, hit in stability.edge_rays(scene_name):
        p = geo.surface(hit).p.numpy().T.astype(np.float64)
        planes = np.unique(ConvexHull(vertices).equations.round(9), axis=0)   # outward n, offset c: n.x + c <= 0 inside
        dist = np.sort(p @ planes[:, :3].T + planes[:, 3], axis=1)
        assert np.abs(dist[:, -1]).max() < 1e-5                # on its own face's plane
        beyond = dist[:, -2] >= 0                                # on or beyond a neighbouring face's plane
        assert not beyond.any(), f"{beyond.sum()} hit points on or beyond a neighbouring face, up to {dist[:, -2].max():.3g}"


def test_double_precision_mode_renders_the_same_image(tmp_path):
    """TRACER_PRECISION=double (a child process: the kernel types are fixed at import) computes in Float64
    and, with the same seed and so the same random numbers, gives the float32 image up to rounding."""
    import os
    import subprocess
    import sys

    import numpy as np

    from tracer.rendering import render

    code = ("import sys, numpy as np, tracer, tracer.jit as j\n"
            "assert j.Float.__name__ == 'Float64', j.Float\n"
            f"s = tracer.load_scene({str(stability.SCENES / 'hexagon_room.xml')!r}, width=16, height=16)\n"
            "from tracer.rendering import render\n"
            f"np.save({str(tmp_path / 'd.npy')!r}, render(s, 'path', spp=16, seed=3, max_depth=3).image)\n")
    env = {**os.environ, "TRACER_PRECISION": "double", "PYTHONPATH": str(stability.ROOT)}
    subprocess.run([sys.executable, "-c", code], env=env, check=True)
    double = np.load(tmp_path / "d.npy")
    single = render(tracer.load_scene(stability.SCENES / "hexagon_room.xml", width=16, height=16), "path",
                    spp=16, seed=3, max_depth=3).image
    assert np.isfinite(double).all() and (double >= 0).all()
    assert np.median(np.abs(double - single)) < 1e-5 * single.mean()   # most pixels: identical paths
    assert abs(double.mean() - single.mean()) < 0.02 * single.mean()
