"""`tracer render` and `tracer info`: nothing lost (outputs probed before the render, written all or none,
modes from the umask), renders that cannot succeed refused before their first ray, outputs by extension,
the options (size, time limit, version, backend), one-line user errors and tracebacks for bugs."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tracer import cli, imageio, plan
from tracer.imageio import read_exr, read_exr_header

ROOT = Path(__file__).resolve().parents[1]
ROOM = ROOT / "mitsuba_scenes" / "hexagon_room.xml"
ARGS = ["render", str(ROOM), "-D", "width=12", "-D", "height=10", "--spp", "2", "-q"]


@pytest.fixture
def no_render(monkeypatch):
    """Fails the test if a render starts (the scene's kernel is built)."""
    import tracer.rendering

    def started(*args, **kwargs):
        raise AssertionError("the render started")

    monkeypatch.setattr(tracer.rendering, "SceneGeometry", started)


def one_line_error(capsys, *fragments: str) -> str:
    err = capsys.readouterr().err
    assert err.startswith("tracer: error: ") and err.count("\n") == 1, err
    for fragment in fragments:
        assert fragment in err, err
    return err


# --- nothing lost -------------------------------------------------------------------------------------------

def test_an_unwritable_folder_is_refused_before_rendering_naming_the_users_path(tmp_path, capsys, no_render):
    (tmp_path / "afile").write_text("")
    out = tmp_path / "afile" / "room.exr"
    assert cli.main(ARGS + ["-o", str(out)]) == 1
    err = one_line_error(capsys, str(out), "is a file, not a folder")
    assert ".tmp" not in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_folder_is_refused_before_rendering(tmp_path, capsys, no_render):
    folder = tmp_path / "ro"
    folder.mkdir(mode=0o555)
    assert cli.main(ARGS + ["-o", str(folder / "room.exr")]) == 1
    one_line_error(capsys, str(folder / "room.exr"), "cannot write into")


def test_a_folder_in_the_way_of_the_png_keeps_the_previous_exr(tmp_path, capsys, no_render):
    (tmp_path / "b.png").mkdir()
    previous = tmp_path / "b.exr"
    previous.write_bytes(b"the previous render")
    assert cli.main(ARGS + ["-o", str(previous)]) == 1
    one_line_error(capsys, "b.png: is a folder")
    assert previous.read_bytes() == b"the previous render"


def test_a_failed_write_leaves_every_previous_file_intact(tmp_path, capsys, monkeypatch):
    """The EXR is written first; the PNG's failure must not have replaced (or removed) the old EXR."""
    exr, png = tmp_path / "b.exr", tmp_path / "b.png"
    exr.write_bytes(b"old exr")
    png.write_bytes(b"old png")

    def broken(path, image, metadata=None):
        raise OSError(f"{path}: disk full")

    monkeypatch.setattr(imageio, "WRITERS", {**imageio.WRITERS, ".png": broken})
    assert cli.main(ARGS + ["-o", str(exr)]) == 1
    one_line_error(capsys, "disk full")
    assert exr.read_bytes() == b"old exr" and png.read_bytes() == b"old png"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.exr", "b.png"]  # no temporaries left


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_file_modes_follow_the_umask(tmp_path, umask):
    out = tmp_path / "room.exr"
    out.write_bytes(b"")
    out.chmod(0o644)
    old = os.umask(umask)
    try:
        assert cli.main(ARGS + ["-o", str(out)]) == 0
    finally:
        os.umask(old)
    for path in (out, out.with_suffix(".png")):
        assert path.stat().st_mode & 0o777 == 0o666 & ~umask, path


# --- plan before work ---------------------------------------------------------------------------------------

def test_the_branching_tree_that_cannot_fit_is_refused_before_the_first_ray(tmp_path, capsys, no_render):
    out = tmp_path / "room.exr"
    assert cli.main(["render", str(ROOM), "--size", "16x16", "-q", "--estimator", "report", "--direct", "1000",
                     "--indirect", "1000", "--report-depth", "3", "-o", str(out)]) == 1
    one_line_error(capsys, "1,000,000,000 rays per camera sample", "GiB", "would fit")
    assert list(tmp_path.iterdir()) == []


def test_a_huge_image_is_refused_before_the_first_ray(tmp_path, capsys, monkeypatch, no_render):
    monkeypatch.setattr(plan, "available_memory", lambda: 4 << 30)
    assert cli.main(["render", str(ROOM), "--size", "15000x15000", "-q", "-o", str(tmp_path / "big.exr")]) == 1
    one_line_error(capsys, "15000 x 15000 needs about", "4.00 GiB available", "fits")
    assert list(tmp_path.iterdir()) == []


def test_report_depth_below_zero_says_what_report_depth_is(tmp_path, capsys):
    assert cli.main(ARGS + ["--estimator", "report", "--report-depth", "-3", "-o", str(tmp_path / "r.exr")]) == 1
    one_line_error(capsys, "--report-depth must be >= 0", "got -3")


# --- outputs ------------------------------------------------------------------------------------------------

def test_outputs_by_extension_in_any_case(tmp_path):
    a, b = tmp_path / "a.EXR", tmp_path / "b.Png"
    assert cli.main(ARGS + ["-o", str(a), "-o", str(b)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.EXR", "b.Png"]  # a .png was asked for: no other
    exr, png = read_exr(a), np.asarray(Image.open(b))
    assert exr.shape == (10, 12, 3) and png.shape == (10, 12, 3) and png.dtype == np.uint8
    expected = np.round(imageio.srgb_encode(exr) * 255).astype(np.uint8)
    assert np.array_equal(png, expected)


def test_a_png_beside_the_exr_unless_no_png(tmp_path):
    assert cli.main(ARGS + ["-o", str(tmp_path / "x.exr")]) == 0
    assert cli.main(ARGS + ["-o", str(tmp_path / "y.exr"), "--no-png"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.exr", "x.png", "y.exr"]


def test_an_unknown_format_is_refused_before_rendering(tmp_path, capsys, no_render):
    assert cli.main(ARGS + ["-o", str(tmp_path / "x.hdr")]) == 1
    one_line_error(capsys, "x.hdr: unknown image format '.hdr'", ".exr and .png")


def test_the_default_output_is_the_scenes_name_beside_it(tmp_path):
    shutil.copy(ROOM, tmp_path / "room.xml")
    (tmp_path / "meshes").symlink_to(ROOM.parent / "meshes")
    assert cli.main(["render", str(tmp_path / "room.xml"), "--size", "8x8", "--spp", "1", "-q"]) == 0
    assert (tmp_path / "room.exr").exists() and (tmp_path / "room.png").exists()


def test_spp_and_seed_in_the_exr_header(tmp_path):
    out = tmp_path / "r.exr"
    assert cli.main(ARGS + ["--seed", "7", "-o", str(out)]) == 0
    header = read_exr_header(out)
    assert (header["spp"], header["seed"], header["estimator"]) == ("2", "7", "path")


# --- options ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("size, shape", [(["--size", "20x6"], (6, 20, 3)),
                                         (["--width", "9", "--height", "5"], (5, 9, 3))])
def test_size_on_any_scene(tmp_path, size, shape):
    out = tmp_path / "r.exr"
    assert cli.main(["render", str(ROOM), "--spp", "1", "-q", "-o", str(out)] + size) == 0
    assert read_exr(out).shape == shape


@pytest.mark.parametrize("size, message", [(["--size", "20"], "expected WIDTHxHEIGHT"),
                                           (["--width", "0"], "--width must be >= 1")])
def test_a_bad_size_is_refused(tmp_path, capsys, size, message):
    assert cli.main(["render", str(ROOM), "-q", "-o", str(tmp_path / "r.exr")] + size) == 1
    one_line_error(capsys, message)


def test_time_limit_writes_the_passes_rendered_with_their_spp(tmp_path, capsys):
    out = tmp_path / "r.exr"
    assert cli.main(ARGS[:-3] + ["--spp", "50", "-q", "--time-limit", "1e-6", "-o", str(out)]) == 0
    assert "(time limit 1e-06 s: 1 of 50 spp)" in capsys.readouterr().out
    assert read_exr_header(out)["spp"] == "1"


def test_info_lists_the_scenes_parameters(capsys):
    assert cli.main(["info", str(ROOM), "-D", "width=10"]) == 0
    out = capsys.readouterr().out
    assert "parameters (-D NAME=VALUE):" in out
    assert "    spp = 64\n" in out and "    width = 600 (given 10)\n" in out


def _python(code: str, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT), **env}, cwd=ROOT)


def test_help_and_version_do_not_import_drjit():
    code = ("import sys\nfrom tracer import cli\nfor a in (['--help'], ['--version'], ['render', '--help']):\n"
            "    try:\n        cli.main(a)\n    except SystemExit as e:\n        assert e.code == 0\n"
            "print('drjit imported:', 'drjit' in sys.modules)")
    run = _python(code, DRJIT_LIBLLVM_PATH="/nonexistent/libLLVM.so")
    assert run.returncode == 0, run.stderr
    assert "tracer 0.1.0" in run.stdout and "--time-limit" in run.stdout and "TRACER_BACKEND" in run.stdout
    assert run.stdout.rstrip().endswith("drjit imported: False")


def test_a_render_without_progress_does_not_import_the_progress_bar():
    code = ("import sys\nimport tracer\nfrom tracer.rendering import render\n"
            f"render(tracer.load_scene({str(ROOM)!r}, width=4, height=4), spp=1)\n"
            "print('tqdm imported:', 'tqdm' in sys.modules)")
    run = _python(code)
    assert run.returncode == 0, run.stderr
    assert run.stdout.rstrip().endswith("tqdm imported: False")


@pytest.mark.parametrize("given, used", [(None, "1"), ("3", "3")])
def test_the_command_line_runs_numpy_with_one_blas_thread_unless_told(given, used):
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    env |= {"PYTHONPATH": str(ROOT)} | ({"OPENBLAS_NUM_THREADS": given} if given else {})
    code = ("import os, sys\nfrom tracer import cli\ntry:\n    cli.main(['--version'])\nexcept SystemExit:\n    pass\n"
            "print('numpy' in sys.modules, os.environ['OPENBLAS_NUM_THREADS'])")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[-2:] == ["False", used]      # set before NumPy (and its OpenBLAS) is loaded


RENDER = "from tracer import cli; raise SystemExit(cli.main(['render', {!r}, '--size', '4x4', '-o', {!r}]))"


@pytest.mark.parametrize("scene, code", [(ROOM, 0), (Path("no_such_scene.xml"), 1)])
def test_the_command_ends_its_process_with_every_line_and_file_delivered(tmp_path, scene, code):
    """`tracer` (cli.run) skips the interpreter's teardown: its lines, exit code and images still arrive."""
    out = tmp_path / "r.exr"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"} | {"PYTHONPATH": str(ROOT)}
    run = subprocess.run([sys.executable, "-m", "tracer.cli", "render", str(scene), "--size", "8x6", "-o", str(out)],
                         capture_output=True, text=True, timeout=120, env=env, cwd=ROOT)   # pipes: block-buffered
    assert run.returncode == code, run.stderr
    if code:
        assert run.stderr.startswith("tracer: error:") and not out.exists()
        return
    assert run.stdout.rstrip().endswith(f"wrote {out}, {out.with_suffix('.png')}"), run.stdout
    from tracer.imageio import read_exr_rgb
    image = read_exr_rgb(out)
    assert image.shape == (6, 8, 3) and image.sum() > 0
    assert out.with_suffix(".png").stat().st_size > 0


LIB = Path("/usr/lib/x86_64-linux-gnu")


@pytest.mark.parametrize("library, says", [
    ("libLLVM-15.so.1", "Dr.Jit found LLVM 15"),
    ("libLLVM-14.so.1", "Dr.Jit's LLVM backend is unavailable"),
    ("no-such-libLLVM.so", "Dr.Jit's LLVM backend is unavailable"),
])
def test_a_missing_or_too_old_llvm_is_one_line_with_the_fix(tmp_path, library, says):
    if library.startswith("libLLVM") and not (LIB / library).exists():
        pytest.skip(f"needs {LIB / library}")
    run = _python(RENDER.format(str(ROOM), str(tmp_path / "r.exr")), DRJIT_LIBLLVM_PATH=str(LIB / library))
    assert run.returncode == 1
    assert run.stderr.startswith(f"tracer: error: {says}") and run.stderr.count("\n") == 1, run.stderr
    assert "libllvm19" in run.stderr and "DRJIT_LIBLLVM_PATH" in run.stderr
    assert list(tmp_path.iterdir()) == []


def test_cuda_without_a_gpu_is_one_line(tmp_path):
    import drjit as dr

    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("this machine has a GPU")
    run = _python(RENDER.format(str(ROOM), str(tmp_path / "r.exr")).replace("'-o'", "'--backend', 'cuda', '-o'"))
    assert run.returncode == 1
    assert run.stderr.startswith("tracer: error: TRACER_BACKEND=cuda") and run.stderr.count("\n") == 1, run.stderr


# --- user errors and bugs -----------------------------------------------------------------------------------

def test_a_bug_shows_its_traceback_and_says_it_is_a_bug(tmp_path, capsys, monkeypatch):
    import tracer.rendering

    def bug(*args, **kwargs):
        raise ValueError("an internal inconsistency")

    monkeypatch.setattr(tracer.rendering, "SceneGeometry", bug)
    assert cli.main(ARGS + ["-o", str(tmp_path / "r.exr")]) == cli.BUG_EXIT
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "ValueError: an internal inconsistency" in err
    assert "is a bug in the tracer" in err
    assert list(tmp_path.iterdir()) == []


def test_a_scene_error_is_one_line(tmp_path, capsys):
    assert cli.main(["render", str(tmp_path / "missing.xml"), "-q", "-o", str(tmp_path / "r.exr")]) == 1
    one_line_error(capsys, "missing.xml: cannot read scene file")
    assert list(tmp_path.iterdir()) == []
