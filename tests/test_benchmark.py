"""The benchmark's machinery (not its timings, which are benchmark output, never asserted)."""
import numpy as np

from validation.benchmark import bench as benchmark


def test_measure_runs_a_job_in_a_child_and_reports_memory(tmp_path):
    job = benchmark._tracer("path", size=16, spp=2, max_depth=3)
    job["repeats"] = 2
    job["save_image"] = str(tmp_path / "image.npy")
    result = benchmark.measure(job)
    assert len(result["seconds"]) == 2 and result["median"] > 0
    assert result["rays"] >= 16 * 16 * 2          # at least one ray per sample
    assert result["peak_mb"] > 50                 # a Python process with Dr.Jit loaded
    image = np.load(job["save_image"])
    assert image.shape == (16, 16, 3) and np.isfinite(image).all()


def test_sphere_scene_has_the_requested_triangle_count(tmp_path):
    scene = benchmark._sphere_scene(tmp_path, 1000)
    n = benchmark._triangles(scene)
    assert 2 * 900 <= n <= 2 * 1100                 # two blocks, each a sphere of about 1000 triangles


def test_mesh_scene_has_three_smooth_meshes_of_mixed_materials(tmp_path):
    import tracer
    from validation.benchmark.mesh_scene import write_mesh_scene

    scene_file = write_mesh_scene(tmp_path, 6000)
    scene = tracer.load_scene(scene_file)
    assert len(scene.meshes) == 3 and all(m.normals is not None for m in scene.meshes)
    assert {m.bsdf.kind for m in scene.meshes} == {"diffuse", "conductor", "dielectric"}
    assert 0.9 * 6000 <= sum(len(m.faces) for m in scene.meshes) <= 6000
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.glob("*.obj")}
    write_mesh_scene(tmp_path, 6000)                      # meshes written once, then reused
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("*.obj")} == stamps
    assert not list(tmp_path.glob(".*"))                  # no temporary left behind


def test_bench_sections_are_checked_before_running(tmp_path):
    import pytest
    from tracer.errors import UserError

    with pytest.raises(UserError, match="unknown bench sections"):
        benchmark.run(tmp_path, ["meshes", "nonsense"])
    with pytest.raises(UserError, match="performance.json has no"):   # nothing to keep the others from
        benchmark.run(tmp_path, ["meshes"])


def test_mesh_profile_counts_on_a_small_mesh(monkeypatch, tmp_path):
    import tracer
    from tracer.geometry import SceneGeometry
    from tracer.shapes.bvh_build import TRAVERSAL_COST
    from validation.benchmark import mesh_profile

    monkeypatch.setattr(mesh_profile, "RAYS", 4096)
    monkeypatch.setattr(mesh_profile, "LAUNCHES", 1)
    scene = tracer.load_scene(benchmark._sphere_scene(tmp_path, 500))
    p = mesh_profile.profile_tracer(SceneGeometry(scene))
    assert p["rays"] == 4096 and 0 < p["hit_fraction"] <= 1
    assert p["closest_seconds"] > 0 and p["shadow_seconds"] > 0 and p["bvh_build_seconds"] > 0
    assert TRAVERSAL_COST <= p["bvh_sah_cost"] < 500    # a root's step at least; less than one leaf of all
    assert p["closest_batch_seconds"] > 0 and p["shadow_batch_seconds"] > 0
    assert 1 <= p["steps_mean"] <= p["bvh_rows"] and p["tests_mean"] > 0
    assert 1 / mesh_profile.PACKET <= p["packet_busy"] < 1   # walks of different lengths leave lanes idle


def test_mesh_profile_asks_both_renderers_the_same_queries(monkeypatch, tmp_path):
    """The same random rays hit, and the same shadow rays are blocked, in both renderers (a shadow ray's
    length once went into Mitsuba's ray time instead of its maxt: every one of its shadow rays was infinite)."""
    import mitsuba as mi
    import tracer
    from tracer.geometry import SceneGeometry
    from validation.benchmark import mesh_profile

    mi.set_variant("llvm_ad_rgb")
    monkeypatch.setattr(mesh_profile, "RAYS", 4096)
    monkeypatch.setattr(mesh_profile, "LAUNCHES", 1)
    path = benchmark._sphere_scene(tmp_path, 500)
    ours = mesh_profile.profile_tracer(SceneGeometry(tracer.load_scene(path)))
    theirs = mesh_profile.profile_mitsuba(mi, mi.load_file(str(path)))
    assert 0.2 < ours["blocked_fraction"] < ours["hit_fraction"] - 0.1     # shadow rays are short: fewer blocked
    for fraction in ("hit_fraction", "blocked_fraction"):
        assert abs(ours[fraction] - theirs[fraction]) < 0.005, fraction


def test_a_renders_time_is_split_into_its_walks_and_the_rest(tmp_path):
    import tracer
    import tracer.shapes.bvh as bvh
    from tracer.geometry import SceneGeometry
    from tracer.rendering import render
    from validation.benchmark import mesh_profile

    scene = tracer.load_scene(benchmark._sphere_scene(tmp_path, 500), width=32, height=32)
    geo = SceneGeometry(scene)
    once = lambda: render(scene, "path", spp=4, max_depth=4, geometry=geo).render_seconds   # noqa: E731
    once()   # as the bench: kernels compiled first (render_seconds leaves compilation out, a timed walk not)
    p = mesh_profile.profile_render(once)
    if not bvh.BATCHED_WALKS:     # the walks run inside the render's kernels: nothing to time apart
        assert p["closest_walk_seconds"] == p["shadow_walk_seconds"] == 0
        return
    assert p["closest_walk_seconds"] > 0 and p["shadow_walk_seconds"] > 0
    assert 0 < p["closest_walked_fraction"] <= 1 and 0 < p["shadow_walked_fraction"] <= 1
    assert 0 < p["rest_seconds"] < p["timed_render_seconds"]
    assert bvh._walk_seconds is None            # timing is off again after the render


def test_setup_from_the_disk_cache_is_timed_apart(tmp_path, monkeypatch):
    from tracer.shapes import bvh_cache

    monkeypatch.setenv(bvh_cache.ENV, "off")
    monkeypatch.setattr(bvh_cache, "DISK_MIN_TRIANGLES", 0)   # the small scene's BVH goes to disk too
    job = {"scene": str(benchmark._sphere_scene(tmp_path, 500)), "params": {}}
    loaded = []
    monkeypatch.setattr(bvh_cache, "_load", lambda *a, real=bvh_cache._load: loaded.append(real(*a)) or loaded[-1])
    assert benchmark._setup_from_disk_cache(job) > 0
    assert len(loaded) == 2 and loaded[0] is None and loaded[1] is not None   # the second read the first's file
    assert bvh_cache.disk_folder() is None              # the variable as it was


def test_mesh_rows_pool_two_processes_renders():
    first = {"seconds": [3.0, 3.2, 3.1], "median": 3.1, "setup_seconds": 1.0, "profile": {}}
    benchmark._pool(first, {"seconds": [2.0, 2.1, 2.2], "median": 2.1, "setup_seconds": 2.0})
    assert first["seconds"] == [3.0, 3.2, 3.1, 2.0, 2.1, 2.2] and first["median"] == 2.6
    assert first["setup_seconds"] == 1.5 and first["setup_runs"] == [1.0, 2.0] and "profile" in first


def test_the_mesh_table_shows_each_figures_fastest_and_slowest_run():
    row = {"triangles": 1000, "tracer": {"seconds": [2.5, 2.0, 3.25], "setup_runs": [1.0, 1.5]},
           "Mitsuba": {"seconds": [2.2, 2.1], "setup_runs": [0.5, 0.25]},
           "whole": {"tracer": {"seconds": [4.0, 5.0]}, "Mitsuba": {"seconds": [3.0, 3.5, 3.25]}}}
    line = benchmark._mesh_spread(row)
    assert line == ("- 1,000 triangles: render: tracer 2.00–3.25 (3), Mitsuba 2.10–2.20 (2); setup: tracer "
                    "1.00–1.50 (2), Mitsuba 0.25–0.50 (2); whole process: tracer 4.00–5.00 (2), Mitsuba 3.00–3.50 (3).")
    del row["tracer"]["setup_runs"]     # a run from before the setups were kept
    assert "setup" not in benchmark._mesh_spread(row)


def test_a_renders_own_rays_are_replayed_through_both_renderers(tmp_path):
    """The rays one render asks about, recorded and replayed through the tracer's queries and Mitsuba's: as
    many as the render traced, and the same shadow rays blocked on both sides."""
    import mitsuba as mi
    import tracer
    from tracer.geometry import SceneGeometry, recorded_queries
    from tracer.rendering import render
    from validation.benchmark import mesh_profile

    mi.set_variant("llvm_ad_rgb")
    path = benchmark._sphere_scene(tmp_path, 500)
    scene = tracer.load_scene(path, width=32, height=32)
    geo = SceneGeometry(scene)
    traced = []
    once = lambda: traced.append(render(scene, "path", spp=4, max_depth=4, geometry=geo).rays)   # noqa: E731
    with recorded_queries() as queries, mesh_profile.every_bounce_batched():
        once()
    assert [(q, len(o)) for q, o, _, _ in queries[:2]] == [("closest hit", 32 * 32 * 4), ("shadow", len(queries[1][1]))]
    recorded = sum(len(o) for _, o, _, _ in queries)   # shadow rays are traced only towards a light's front
    assert 0.5 * traced[0] < recorded <= traced[0]
    p = mesh_profile.profile_render_rays(geo, once, mi.load_file(str(path), width=32, height=32))
    assert p["replayed_rays"] == recorded
    for key in ("replay_closest_seconds", "replay_shadow_seconds"):
        assert p[key] > 0 and p[key + "_mitsuba"] > 0
    assert 0 < p["replay_blocked_fraction"] < 1
    assert abs(p["replay_blocked_fraction"] - p["replay_blocked_fraction_mitsuba"]) < 0.01
    with recorded_queries() as queries:   # nothing is kept outside a batched render
        geo.closest_hit(*(tracer.jit.Array3f(0.0, 0.0, 0.0),) * 2, 0.0, 1.0, tracer.jit.UInt32(0))
    assert queries == []


def test_the_memory_section_sets_the_plans_estimate_against_the_measured_peak(tmp_path):
    from tracer.plan import PROCESS_BYTES

    scene = benchmark.ROOT / "mitsuba_scenes" / "cornell_box.xml"
    row = benchmark.peak_memory(scene, ["-D", "width=24", "-D", "height=16", "-D", "spp=2"])
    assert row["settings"] == "24 x 16, 2 spp" and row["seconds"] > 0
    assert row["estimate_mib"] >= PROCESS_BYTES / 2**20                # the process is part of the estimate
    assert 50 < row["peak_mib"] < 10 * row["estimate_mib"]              # a Python process with Dr.Jit loaded
    lines = benchmark.memory_markdown({"rows": {"mitsuba_scenes/cornell_box.xml": row}, "docs": False})
    ratio = row["peak_mib"] / row["estimate_mib"]
    assert f"| mitsuba_scenes/cornell_box.xml | 24 x 16, 2 spp | {row['estimate_mib']:.0f} | " \
           f"{row['peak_mib']:.0f} | {ratio:.2f} |" in lines
    assert any("`--mitsuba-data` not given" in line for line in lines)


def test_the_scenes_section_times_both_renderers_interleaved_and_labels_its_caps(tmp_path, monkeypatch):
    from validation.benchmark import scene_bench

    chosen = scene_bench.candidates(None, ["mitsuba_scenes/cornell_box.xml"])
    assert [n for n, _ in chosen] == ["mitsuba_scenes/cornell_box.xml"]
    order = []
    monkeypatch.setattr(scene_bench, "_timed",       # the tracer's CPU seconds half Mitsuba's
                        lambda command, env: (order.append(command[0]) or 1.0,
                                              4.0 if command[0].endswith("mitsuba") else 2.0, ""))
    section = scene_bench.scenes(lambda _: None, globs=["mitsuba_scenes/cornell_box.xml"], scale=0.1, runs=2)
    row = section["rows"]["mitsuba_scenes/cornell_box.xml"]
    assert row["tracer"]["seconds"] == [1.0, 1.0] and row["ratio"] == 1.0 and row["cpu_ratio"] == 0.5
    mitsuba = [c.endswith("mitsuba") for c in order]
    assert mitsuba == [False, True, False, True, True, False]     # warm-up, then each renderer first in turn
    text = "\n".join(scene_bench.markdown(section, None))
    assert "every film scaled by 0.1" in text and "median ratio **1.00**" in text
    assert "In CPU seconds: median **0.50**" in text


def test_a_scaled_scene_keeps_everything_but_its_film_size():
    from validation.verdict.scenefile import resized_xml

    text = resized_xml(benchmark.ROOT / "mitsuba_scenes" / "cornell_box.xml", 30, 20)
    assert 'name="width" value="30"' in text and 'name="height" value="20"' in text
    assert "<integrator" in text and "<emitter" in text


def test_a_scene_is_rendered_by_both_command_lines():
    from validation.benchmark import scene_bench

    path = benchmark.ROOT / "mitsuba_scenes" / "cornell_box.xml"
    row = scene_bench.measure_scene(path, 0.05, 1, lambda _: None)
    assert row["tracer"]["error"] == "" and row["Mitsuba"]["error"] == "", row
    assert (row["width"], row["height"]) == (13, 13)               # 256 x 256 scaled
    assert row["ratio"] > 0 and row["cpu_ratio"] > 0
    assert all(x["cpu_seconds"][0] > 0 for x in (row["tracer"], row["Mitsuba"]))


def test_the_generated_many_light_scene_cuts_the_light_into_tiles_of_the_same_power(tmp_path):
    import numpy as np
    import tracer
    from validation.benchmark import scene_bench

    one = tracer.load_scene(scene_bench.tiled_light_cornell_box(tmp_path, 1))
    many = tracer.load_scene(scene_bench.tiled_light_cornell_box(tmp_path, 4))
    original = tracer.load_scene(benchmark.ROOT / "mitsuba_scenes" / "cornell_box.xml")
    assert len(many.emitters) == 16 and len(one.emitters) == 1
    np.testing.assert_allclose(one.emitters[0].to_world, original.emitters[0].to_world, atol=1e-12)
    assert np.isclose(sum(e.area for e in many.emitters), original.emitters[0].area)


def test_measure_runs_another_checkouts_tracer(tmp_path):
    import shutil

    other = tmp_path / "other"
    shutil.copytree(benchmark.ROOT / "tracer", other / "tracer", ignore=shutil.ignore_patterns("__pycache__"))
    job = benchmark._tracer("path", size=8, spp=1, max_depth=2) | {"repeats": 1}
    assert benchmark.measure(job, tracer_root=other)["tracer_package"] == str((other / "tracer").resolve())
    assert benchmark.measure(job)["tracer_package"] == str(benchmark.ROOT / "tracer")


def test_against_interleaves_two_checkouts_and_refuses_a_folder_without_the_tracer(tmp_path, monkeypatch):
    import pytest
    from tracer.errors import UserError
    from validation.benchmark import ab

    with pytest.raises(UserError, match="no tracer package"):
        ab.against(lambda _: None, tmp_path, 1)
    (tmp_path / "tracer").mkdir()
    (tmp_path / "tracer" / "__init__.py").write_text("")
    calls = []

    def fake(job, tracer_root=None):
        calls.append("other" if tracer_root else "this")
        package = (tracer_root.resolve() if tracer_root else benchmark.ROOT) / "tracer"
        seconds = [2.0] * 3 if tracer_root else [1.0] * 3   # this checkout twice as fast
        return {"seconds": seconds, "cpu_seconds": [s * 1.5 for s in seconds], "rays": 10,
                "tracer_package": str(package)}
    monkeypatch.setattr(ab, "measure", fake)
    section = ab.against(lambda _: None, tmp_path, 2)
    assert calls == ["this", "other", "other", "this"] * len(ab.JOBS)   # the first alternates round by round
    for row in section["rows"].values():
        assert row["wall"]["ratio"] == 0.5 and row["cpu"]["ratio"] == 0.5 and len(row["seconds"]["this"]) == 6
    text = "\n".join(ab.markdown(section))
    assert "| hexagon_room | wall |" in text and "**0.500**" in text
    monkeypatch.setattr(ab, "measure", lambda job, tracer_root=None: fake(job, None))   # the wrong tracer ran
    with pytest.raises(RuntimeError, match="imported"):
        ab.against(lambda _: None, tmp_path, 1)


def test_against_names_a_checkout_with_uncommitted_changes_to_its_tracer(tmp_path):
    """The A/B section labels a tree by its commit, and says so where its tracer differs from that commit."""
    import subprocess
    from validation.benchmark import ab

    git = ["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(git[:3] + ["init", "-q"], check=True)
    (tmp_path / "tracer").mkdir()
    (tmp_path / "tracer" / "a.py").write_text("x = 1\n")
    subprocess.run(git + ["add", "-A"], check=True)
    subprocess.run(git + ["commit", "-qm", "a"], check=True)
    assert "uncommitted" not in ab._commit(tmp_path)
    (tmp_path / "tracer" / "a.py").write_text("x = 2\n")
    assert ab._commit(tmp_path).endswith(" with uncommitted changes")


def test_the_rooms_phases_add_up_to_its_render():
    from validation.benchmark.room_profile import phases

    profile = {"variants": {"full": {"cpu": [1.0, 0.9], "rays": 100}, "unblocked": {"cpu": [0.8], "rays": 100},
                            "no_nee": {"cpu": [0.6], "rays": 60}, "camera": {"cpu": [0.2], "rays": 20}},
               "ceiling": {"rays_per_cpu_second": 400.0}}
    t = phases(profile)
    assert abs(sum(x for name, x in t.items() if name != "full") - 0.9) < 1e-12
    assert t["shadow-ray queries"] == 0.9 - 0.8 and t["closest-hit queries"] == 60 / 400


def test_cold_start_writes_the_light_scenes_compile_times_where_measured():
    """The cold-start section's many-light scenes: each one's first compile and render, as measured; no line
    from a run that did not measure them."""
    scenes = [{"lights": 144, "first_compile": 3.32, "median": 3.21}, {"lights": 256, "first_compile": 0.04, "median": 3.28}]
    text = " ".join(benchmark._light_scene_lines(scenes))
    assert "144 then 256 rectangles" in text and "compiles for 3.32 s" in text and "for 0.04 s (its render 3.28 s)" in text
    assert benchmark._light_scene_lines(None) == []


def test_the_report_keeps_no_folder_of_the_machine_that_ran_it():
    """A child's tracer_package (its folder, for --against's check) stays out of performance.json, at any depth."""
    results = {"cold": {"first_compile": 1.0, "tracer_package": "/x/tracer",
                        "light_scenes": [{"lights": 144, "tracer_package": "/x/tracer"}]}, "runs": [1, 2]}
    assert benchmark.without_paths(results) == {"cold": {"first_compile": 1.0, "light_scenes": [{"lights": 144}]},
                                                "runs": [1, 2]}
