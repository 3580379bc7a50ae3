"""The benchmark's machinery (not its timings, which are benchmark output, never asserted)."""
import numpy as np

from validation import benchmark


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
