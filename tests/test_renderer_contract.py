"""The external renderer's contract (README "validate check: the renderer contract"): the scene as one resolved
Mitsuba XML or as neutral JSON with PLY meshes, {defines} holding the check's plan only, batch calls and
parallel jobs, the "unsupported" exit status, --label and --cache, and the refusal of passes that are not
independent."""
from __future__ import annotations

import json
import sys
import textwrap

import drjit as dr
import numpy as np
import pytest

from validation import cli
from validation.verdict.renderers import EXIT_UNSUPPORTED, ExternalRenderer, RendererError, independence
from validation.verdict.scenefile import ScenePlanError, plan

from .conftest import SCENES

# writes, for each (seed, output), noise around 0.5 drawn from the seed, and logs its arguments
NOISE = textwrap.dedent('''
    import sys, json
    import numpy as np
    import OpenEXR
    log, width, height, seeds, outputs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], sys.argv[5]
    with open(log, "a") as f:
        f.write(json.dumps(sys.argv[6:] + [seeds]) + "\\n")
    for seed, output in zip(seeds.split(","), outputs.split(",")):
        image = np.random.default_rng(int(seed)).uniform(0, 1, (height, width, 3)).astype(np.float32)
        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": image}) as f:
            f.write(output)
''')


def test_resolved_scene_is_self_contained_and_renders_as_the_plan(tmp_path):
    """{scene_resolved}: no parameters, no includes, absolute paths, the plan's size, depth and spp; Mitsuba
    renders it from another folder bit for bit as the plan's scene."""
    from validation.verdict.mitsuba_render import mitsuba

    mi = mitsuba()
    p = plan(SCENES / "mesh_formats.xml", {"max_depth": "3"}, size=8)   # a referenced sampler, meshes in a folder
    text = p.resolved_xml(spp=2)
    assert "$" not in text and "<default" not in text and "<include" not in text
    (tmp_path / "s.xml").write_text(text)
    threads = dr.thread_count()
    dr.set_thread_count(1)    # the film's sums in one order: with several threads they land in any order
    try:
        a = np.array(mi.render(mi.load_file(str(tmp_path / "s.xml")), seed=5))
        b = np.array(mi.render(p.mitsuba_scene(2), seed=5, spp=2))
    finally:
        dr.set_thread_count(threads)
    assert a.shape == (8, 8, 3) and np.array_equal(a, b)


def test_scene_json_describes_the_planned_scene(tmp_path):
    """{scene_json}: camera, film, filter, depth; every shape a PLY whose area is the shape's (spheres and
    disks tessellated to the same area) wound towards its front; materials and emitters with their values."""
    from plyfile import PlyData

    from validation.verdict import scenejson

    p = plan(SCENES / "caustic.xml", {"max_depth": "4"}, size=16)
    scene = p.tracer_scene()
    data = json.loads(scenejson.write(p, tmp_path).read_text())
    assert data["format"] == scenejson.FORMAT and data["integrator"]["max_depth"] == 4
    assert (data["film"]["width"], data["film"]["height"]) == (p.width, p.height)
    assert data["film"]["filter"]["type"] == scene.camera.rfilter.kind
    assert len(data["shapes"]) == len(scene.shapes)
    for shape, entry in zip(scene.shapes, data["shapes"]):
        ply = PlyData.read(tmp_path / entry["mesh"])
        v = np.stack([ply["vertex"][c] for c in "xyz"], 1).astype(float)
        t = v[np.stack(ply["face"]["vertex_indices"])]
        ng = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        assert 0.5 * np.linalg.norm(ng, axis=1).sum() == pytest.approx(shape.area, rel=1e-5), entry["type"]
        if entry["type"] == "sphere":       # outward
            assert np.all(np.einsum("ij,ij->i", ng, t.mean(1) - shape.center) > 0)
        if entry["type"] == "rectangle":
            assert np.all(ng @ shape.normal > 0)
        emitting = shape.radiance is not None
        assert (entry["emitter"] is not None) == emitting
        if emitting:
            assert entry["emitter"]["radiance"] == pytest.approx(list(shape.radiance))
        assert data["materials"][entry["material"]]["type"] == shape.bsdf.kind


def test_defines_carry_the_plan_only():
    """The scene's own <default>s (cornell_box's seed, spp) are not forwarded; the plan and the -D given are."""
    p = plan(SCENES / "cornell_box.xml", {"max_depth": "3"}, size=16)
    assert sorted(p.defines(8)) == ["height=16", "max_depth=3", "spp=8", "width=16"]


def test_batch_calls_in_parallel_jobs(tmp_path):
    """{seeds}/{outputs}: 5 passes in 2 calls (--jobs 2), seeds seed + k in order; the images are the
    renderer's, pass by pass."""
    (tmp_path / "r.py").write_text(NOISE)
    log = tmp_path / "log"
    r = ExternalRenderer(f"{sys.executable} {tmp_path / 'r.py'} {log} 16 16 {{seeds}} {{outputs}} {{defines}}",
                         jobs=2)
    images = r.passes(plan(SCENES / "cornell_box.xml", size=16), 5, 4, 100)
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    assert sorted(c[-1] for c in calls) == ["100,101", "102,103,104"]
    expected = np.random.default_rng(103).uniform(0, 1, (16, 16, 3)).astype(np.float32)
    assert np.array_equal(images[3], expected)


@pytest.mark.parametrize("template, message", [
    ("r {scene}", "must contain {output}"),
    ("r {output} {outputs} {seeds}", "not both"),
    ("r {outputs} {seed}", "{seeds} goes with {outputs}"),
    ("r {output} {sede}", "bad placeholder"),
])
def test_bad_templates_are_refused(template, message):
    with pytest.raises(ScenePlanError, match=message.replace("{", r"\{")):
        ExternalRenderer(template)


def test_unsupported_is_skipped_with_its_reason_and_label(tmp_path, capsys, monkeypatch):
    """Exit status 77: 'skipped: unsupported' with the renderer's last line, under --label, exit 0; the
    reference goes to --cache."""
    (tmp_path / "r.py").write_text(f"import sys\nprint('no spheres here', file=sys.stderr)\nsys.exit({EXIT_UNSUPPORTED})\n")
    monkeypatch.delenv("VALIDATE_CACHE", raising=False)
    cache = tmp_path / "refs"
    code = cli.main(["check", str(SCENES / "dark.xml"), "--renderer", f"{sys.executable} {tmp_path / 'r.py'} "
                     "{scene_json} {output}", "--label", "mine", "--passes", "3", "--spp", "1", "--size", "8",
                     "--cache", str(cache), "--json", str(tmp_path / "out.json")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "skipped" in out and "[mine, max_depth" in out and "unsupported: no spheres here" in out
    assert "1 skipped: unsupported" in out
    assert any(cache.glob("dark-*.npz"))
    assert json.loads((tmp_path / "out.json").read_text())["skipped"][0]["verdict"] == "skipped: unsupported"


def test_dependent_passes_are_refused():
    """Identical passes (a seed ignored) and one pass correlated with another are refused; independent noise
    of any distribution passes (Mitsuba's own passes: reports/peers.md measures the level)."""
    rng = np.random.default_rng(7)
    independent = rng.exponential(1.0, (16, 32, 32, 3)).astype(np.float32) ** 3       # heavy-tailed
    independence(independent)
    same = independent.copy()
    same[5] = same[2]
    with pytest.raises(RendererError, match="passes 2 and 5 are identical"):
        independence(same)
    independence(np.ones((16, 8, 8, 3)), noisy=False)                # noise-free on both sides: not refused
    mixed = independent.copy()
    mixed[9] = 0.5 * (independent[9] + independent[4])
    with pytest.raises(RendererError, match="correlated"):
        independence(mixed)


def test_scene_json_names_parameters_as_mitsuba(tmp_path):
    """A conductor's tint is its specular_reflectance (the loader keeps it in `reflectance`): a peer that read
    the wrong name rendered conductors.xml's tinted conductor untinted (reports/peers.md)."""
    from validation.verdict import scenejson

    data = json.loads(scenejson.write(plan(SCENES / "conductors.xml", size=8), tmp_path).read_text())
    conductors = [m for m in data["materials"] if m["type"] == "conductor"]
    assert [0.9, 0.8, 0.7] in [m["specular_reflectance"] for m in conductors]
    assert all("reflectance" not in m for m in conductors)


NUMPY_RENDERER = (f"{sys.executable} {SCENES.parent / 'examples' / 'numpy_renderer.py'} {{scene_json}} --spp {{spp}} "
                  "--seeds {seeds} --outputs {outputs}")
SMALL = ["--max-depth", "3", "--size", "16", "--passes", "8", "--spp", "16", "--max-spp", "16"]


def test_a_renderer_written_against_scene_json_alone_agrees(tmp_path, capsys, monkeypatch):
    """examples/numpy_renderer.py (no Mitsuba, nothing of the project) through the batch form and two jobs: it
    agrees on spot_lights.xml at max_depth 3 (point and spot lights, an area light, a smooth conductor and
    dielectric; 16 px, 8 x 16 spp), and says 'unsupported' for the tent filter of mesh_formats.xml."""
    monkeypatch.setenv("VALIDATE_CACHE", str(tmp_path))
    code = cli.main(["check", str(SCENES / "spot_lights.xml"), str(SCENES / "mesh_formats.xml"), "--renderer",
                     NUMPY_RENDERER, "--jobs", "2", "--label", "numpy", *SMALL])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "agree        " in out and "unsupported: numpy_renderer: the tent pixel filter" in out


def test_the_scene_json_renderer_is_caught_when_wrong(tmp_path, capsys, monkeypatch):
    """The same renderer and check with its image 25% too bright (--scale 1.25): disagree (this small check
    detects a bias of the image mean of about 10% with 80% power)."""
    monkeypatch.setenv("VALIDATE_CACHE", str(tmp_path))
    code = cli.main(["check", str(SCENES / "spot_lights.xml"), "--renderer", NUMPY_RENDERER + " --scale 1.25",
                     "--jobs", "2", "--label", "numpy", *SMALL])
    out = capsys.readouterr().out
    assert code == 1 and "disagree     " in out, out
