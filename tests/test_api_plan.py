"""The plan made before a render's first ray (tracer.plan): passes that keep sample indices 32-bit,
memory estimates and what would fit, and the film's developing within its stated multiple of the image."""
import tracemalloc

import numpy as np
import pytest

from tracer.errors import PlanError
from tracer.plan import DEVELOP_MULTIPLE, IMAGE_BYTES, MAX_PASS_SAMPLES, pass_spps, plan_render

GIB = 1 << 30


def test_a_reference_beyond_2_to_the_32_samples_is_planned_in_passes():
    """600 x 600 at 12,000 spp is 4.32e9 samples: two passes, each within 32-bit sample indices."""
    passes = pass_spps(600 * 600, 12000)
    assert sum(passes) == 12000 and len(passes) == 2
    assert all(600 * 600 * spp <= MAX_PASS_SAMPLES for spp in passes)
    assert plan_render(600, 600, 12000, "path", 4, memory=16 * GIB).passes == passes


@pytest.mark.parametrize("pixels, spp", [(1, 1), (7, 2**33 + 5), (600 * 600, 1), (2**20, 4097)])
def test_passes_sum_to_the_spp_and_fit(pixels, spp):
    passes = pass_spps(pixels, spp)
    assert sum(passes) == spp and all(0 < pixels * p <= MAX_PASS_SAMPLES for p in passes)
    assert len(passes) == -(-spp // (MAX_PASS_SAMPLES // pixels))


def test_the_branching_tree_is_refused_with_what_fits():
    with pytest.raises(PlanError) as e:
        plan_render(16, 16, 1, "report", 5, slots=1000, direct=1000, memory=16 * GIB)
    message = str(e.value)
    assert "1,000,000,000 rays per camera sample" in message and "16.00 GiB available" in message
    m = int(message.split("indirect (M) ")[1].split()[0])
    plan_render(16, 16, 1, "report", 5, slots=m, direct=1000, memory=16 * GIB)       # what it says fits, fits
    with pytest.raises(PlanError):
        plan_render(16, 16, 1, "report", 5, slots=m + 1, direct=1000, memory=16 * GIB)


def test_the_default_report_settings_fit_comfortably():
    plan = plan_render(600, 600, 1, "report", 4, slots=8, direct=16, memory=4 * GIB)
    assert plan.peak_bytes < GIB and plan.chunk == 32768


def test_a_huge_image_is_refused_with_a_size_that_fits():
    with pytest.raises(PlanError, match=r"15000 x 15000 needs about .* GiB of memory .* at most about (\d+) x \1 fits"):
        plan_render(15000, 15000, 1, "path", 4, memory=4 * GIB)


def test_the_estimate_counts_the_process_and_the_scene_and_refuses_what_the_scene_leaves_no_room_for():
    from tracer.plan import PROCESS_BYTES, film_bytes

    plan = plan_render(100, 80, 4, "path", 4, memory=16 * GIB, scene_bytes=200 << 20)
    assert plan.peak_bytes == PROCESS_BYTES + (200 << 20) + film_bytes(100, 80, 0, 4, 2) + plan.launch_bytes
    assert "process 120 MiB, scene 200 MiB" in plan.describe()
    assert plan.needed_bytes == plan.peak_bytes - PROCESS_BYTES        # the process is there when it is planned
    with pytest.raises(PlanError, match=r"GiB available besides the scene's 3\.50 GiB; at most about \d+ x \d+ fits"):
        plan_render(8000, 6000, 1, "path", 4, memory=4 * GIB, scene_bytes=GIB * 7 // 2)


def test_a_scenes_triangles_and_texels_enter_the_estimate():
    import tracer
    from tracer.plan import TEXEL_BYTES, TRIANGLE_BYTES
    from tracer.rendering import scene_bytes
    from tracer.sampling import GUIDE_DENSITY

    from .conftest import SCENES

    room = tracer.load_scene(SCENES / "environment_map.xml")
    sky = room.envmap.image      # its texels, and its sampling's guide tables (4 bytes per entry)
    assert scene_bytes(room) == (room.triangle_count * TRIANGLE_BYTES
                                 + sky.shape[0] * sky.shape[1] * (TEXEL_BYTES + 4 * GUIDE_DENSITY))
    textured = tracer.load_scene(SCENES / "bitmap.xml")
    assert scene_bytes(textured) > textured.triangle_count * TRIANGLE_BYTES    # the bitmap's texels


def test_developing_stays_within_its_multiple_of_the_image():
    """The film (16 bytes per pixel, a Dr.Jit array) and the NumPy memory its developing allocates, against
    DEVELOP_MULTIPLE developed images (12 bytes per pixel); the old develop held about 6 images more."""
    from tracer.film import Film, ReconstructionFilter

    film = Film(1000, 800, ReconstructionFilter("box"))
    tracemalloc.start()
    try:
        image = film.develop()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    image_bytes = 1000 * 800 * IMAGE_BYTES
    assert image.shape == (800, 1000, 3) and image.dtype == np.float32
    assert film.size[0] * film.size[1] * 16 + peak <= DEVELOP_MULTIPLE * image_bytes, peak / image_bytes
