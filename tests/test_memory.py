"""A render's memory: it does not grow from launch to launch (a scene with the ingredients of the one that grew
without bound, an environment map and meshes in a BVH so that the path tracer goes bounce by bounce, rendered
in many small launches, the process's heap measured between them), and a render that runs out of memory all
the same stops in one line and keeps the passes it completed."""
import ctypes

import numpy as np
import pytest

import tracer
import tracer.film
import tracer.launch
import tracer.plan
from tracer import cli, memory_guard
from tracer.errors import OutOfMemory
from tracer.geometry import SceneGeometry
from tracer.imageio import read_exr, read_exr_header, write_exr
from validation.benchmark.mesh_scene import sphere, torus, write_obj

from .conftest import SCENES

LAUNCH = 2048           # samples per launch: many launches in a second or two
LAUNCHES = 40
SETTLE = 4              # launches that may still fill caches (Dr.Jit's allocations, the kernels)
GROWTH = 8 << 20        # heap growth allowed over the launches after SETTLE (the leak: about 40 MB here)

SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="8"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 1.5, 4" target="0, 0.3, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
    </sensor>
    <emitter type="envmap"><string name="filename" value="sky.exr"/><float name="scale" value="2"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"/>
    </shape>
    <shape type="obj">
        <string name="filename" value="ball.obj"/>
        <transform name="to_world"><scale value="0.5"/><translate x="0.4" y="0.5"/></transform>
        <bsdf type="dielectric"/>
    </shape>
    <shape type="obj">
        <string name="filename" value="ring.obj"/>
        <transform name="to_world"><rotate x="1" angle="90"/><translate x="-0.7" y="0.15"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.4, 0.2"/></bsdf>
    </shape>
</scene>
"""


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                       "fsmblks", "uordblks", "fordblks", "keepcost")]


def heap_in_use():
    """The bytes malloc has handed out and not had back, all arenas and mmapped blocks (glibc's mallinfo2):
    the process's memory less what the allocator keeps free, so a measure that does not wait for the
    allocator to return pages to the system."""
    try:
        mallinfo2 = ctypes.CDLL(None).mallinfo2
    except (AttributeError, OSError):
        pytest.skip("needs glibc >= 2.33 (mallinfo2)")
    mallinfo2.restype = _Mallinfo2
    info = mallinfo2()
    return info.uordblks + info.hblkhd


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("memory")
    theta, phi = np.meshgrid(np.linspace(0, np.pi, 32), np.linspace(0, 2 * np.pi, 64), indexing="ij")
    sky = np.stack([1 + np.cos(theta), 1 + 0.5 * np.sin(phi), 2 - np.cos(theta)], -1) * 0.5
    sky[4:7, 10:14] = 200.0                                              # a sun
    write_exr(folder / "sky.exr", sky.astype(np.float32))
    write_obj(folder / "ball.obj", *sphere(1200))
    write_obj(folder / "ring.obj", *torus(800))
    path = folder / "scene.xml"
    path.write_text(SCENE.format(spp=LAUNCH * LAUNCHES // (32 * 32)))
    return path


def test_heap_is_flat_over_many_launches_bounce_by_bounce(scene_file, monkeypatch):
    scene = tracer.load_scene(scene_file)
    geometry = SceneGeometry(scene)
    assert geometry.bounce_by_bounce            # the code path that grew: meshes in a BVH, batched walks
    heap, chunks = [], tracer.launch.chunks

    def measured(*args):
        for launch in chunks(*args):
            yield launch
            heap.append(heap_in_use())          # after the launch, its arrays dropped or overwritten

    monkeypatch.setattr(tracer.plan, "WAVEFRONT_CHUNK", LAUNCH)
    monkeypatch.setattr(tracer.launch, "chunks", measured)
    result = tracer.render(scene, geometry=geometry)
    assert len(heap) == LAUNCHES and result.spp == LAUNCHES * LAUNCH // 1024
    assert np.isfinite(result.image).all() and result.image.mean() > 0.05
    growth = max(heap[SETTLE:]) - heap[SETTLE]
    assert growth < GROWTH, f"the heap grew {growth / 2**20:.1f} MiB over {LAUNCHES - SETTLE} launches: " + \
        ", ".join(f"{h / 2**20:.1f}" for h in heap)


# --- running out of memory ------------------------------------------------------------------------------------
CORNELL = SCENES / "cornell_box.xml"
PASSES = 6     # one launch each: --time-limit's passes of one sample per pixel


def exhausted_in_pass(monkeypatch, failing: int) -> None:
    """The machine has almost no memory left once pass `failing` (from 1) has launched (memory_guard.check runs
    after every launch; here one per pass)."""
    checks = iter(range(1, 10**6))
    monkeypatch.setattr(memory_guard, "available_memory", lambda: 1 << 20 if next(checks) >= failing else 1 << 40)


def dr_jit_fails_in_pass(monkeypatch, failing: int) -> None:
    """Dr.Jit's allocation fails in pass `failing`: its error, raised by the launch's splat into the film."""
    calls, put = iter(range(1, 10**6)), tracer.film.Film.put

    def failing_put(self, *args, **kwargs):
        if next(calls) >= failing:
            raise RuntimeError("jit_malloc(): out of memory! Could not allocate 1073741824 bytes (backend=llvm, shared=0).")
        return put(self, *args, **kwargs)

    monkeypatch.setattr(tracer.film.Film, "put", failing_put)


@pytest.mark.parametrize("fail", [exhausted_in_pass, dr_jit_fails_in_pass])
def test_a_render_out_of_memory_keeps_the_passes_it_completed(monkeypatch, fail):
    scene = tracer.load_scene(CORNELL, width=16, height=12)
    three = tracer.render(scene, spp=3, time_limit=1e9)             # the first three passes, uninterrupted
    fail(monkeypatch, 4)
    with pytest.raises(OutOfMemory) as stopped:
        tracer.render(scene, spp=PASSES, time_limit=1e9)
    message = str(stopped.value)
    assert message.startswith("out of memory in pass 4 of 6 (") and "\n" not in message
    assert "the 3 passes done fit: 3 of 6 spp" in message and "the plan estimated a peak of" in message
    partial = stopped.value.partial
    assert partial.spp == 3 and partial.settings["passes"] == 3
    np.testing.assert_array_equal(partial.image, three.image)      # the film as the three passes left it


def test_a_render_out_of_memory_in_its_first_pass_has_nothing_to_keep(monkeypatch):
    scene = tracer.load_scene(CORNELL, width=16, height=12)
    exhausted_in_pass(monkeypatch, 1)
    with pytest.raises(OutOfMemory, match=r"^out of memory in pass 1 of 1 \(.*no pass was complete") as stopped:
        tracer.render(scene, spp=2)
    assert stopped.value.partial is None


def test_the_command_writes_the_passes_done_and_says_so_in_one_line(tmp_path, capsys, monkeypatch):
    out = tmp_path / "cbox.exr"
    exhausted_in_pass(monkeypatch, 3)
    args = ["render", str(CORNELL), "--size", "16x12", "--spp", str(PASSES), "--time-limit", "1e9", "-q"]
    assert cli.main(args + ["-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("tracer: error: out of memory in pass 3 of 6 (") and err.count("\n") == 1, err
    assert f"2 of 6 spp; wrote them to {out}, {out.with_suffix('.png')}" in err
    assert read_exr_header(out)["spp"] == "2" and read_exr(out).mean() > 0

    lost = tmp_path / "lost.exr"
    exhausted_in_pass(monkeypatch, 1)
    assert cli.main(args + ["-o", str(lost)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("tracer: error: out of memory in pass 1 of 6") and err.count("\n") == 1, err
    assert err.rstrip().endswith("nothing written") and not lost.exists()
