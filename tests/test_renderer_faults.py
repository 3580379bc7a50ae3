"""`validate check` with a faulty renderer under test: one that crashes, exits 0 without writing, writes
NaN or infinite pixels, the wrong size, a truncated EXR or a PNG. Each is refused in one line with exit 2,
and nothing it wrote reaches the reference cache; a damaged cache entry is rendered again
(validation.verdict.references.load). One that hangs past --timeout loses that check only: it is reported
as timed out and the run goes on with the next scene (exit 4)."""
from __future__ import annotations

import json
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from validation import cli
from validation.verdict import references

from .conftest import SCENES

FAKE = textwrap.dedent('''
    import os, signal, sys, time
    import numpy as np
    import OpenEXR
    args = sys.argv[1:]
    fault, output = args[0], args[args.index("-o") + 1]
    size = dict(a.split("=") for a in args if "=" in a)
    w, h = int(size["width"]), int(size["height"])
    image = np.full((h, w, 3), 0.5, np.float32)
    if fault == "hang" or (fault == "hang-slow" and "slow" in args[1]):
        time.sleep(600)
    if fault == "crash":
        os.kill(os.getpid(), signal.SIGSEGV)
    if fault == "silent":
        sys.exit(0)
    if fault == "nan":
        image[0, 0, 1] = np.nan
    if fault == "inf":
        image[1, 2, 0] = np.inf
    if fault == "size":
        image = image[:-1]
    if fault == "png":
        from PIL import Image
        Image.fromarray((image * 255).astype(np.uint8)).save(output, format="PNG")
        sys.exit(0)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": image}) as f:
        f.write(output)
    if fault == "truncated":
        data = open(output, "rb").read()
        open(output, "wb").write(data[:len(data) // 2])
''')


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """One working folder for the cases: Mitsuba's reference (rendered before the renderer under test runs)
    is cached there once."""
    folder = tmp_path_factory.mktemp("check")
    (folder / "renderer.py").write_text(FAKE)
    return folder


@pytest.mark.parametrize("fault, message", [
    ("crash", "killed by signal SIGSEGV on pass 0"),
    ("silent", "exited 0 but wrote no {output} file on pass 0"),
    ("nan", "1 pixels with NaN or infinite values on pass 0"),
    ("inf", "1 pixels with NaN or infinite values on pass 0"),
    ("size", "wrote 32 x 31 pixels on pass 0, the plan is 32 x 32"),
    ("truncated", "unreadable OpenEXR image on pass 0"),
    ("png", "wrote a PNG on pass 0"),
])
def test_a_faulty_renderer_is_refused_in_one_line(workdir, monkeypatch, capsys, fault, message):
    monkeypatch.chdir(workdir)               # the reference cache is .cache/references under the working folder
    command = f"{sys.executable} {workdir / 'renderer.py'} {fault} {{scene}} -o {{output}} {{defines}}"
    code = cli.main(["check", str(SCENES / "cornell_box.xml"), "--renderer", command, "--passes", "3",
                     "--timeout", "3"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("validate: error: ") and "\n" not in err, err
    assert message in err, err
    # nothing the renderer wrote is left or cached: the cache holds Mitsuba's references, each passing its checksum
    files = sorted(p.relative_to(workdir) for p in workdir.rglob("*") if p.is_file())
    cached = [workdir / p for p in files if p.parts[:2] == (".cache", "references")]
    assert [p for p in files if workdir / p not in cached] == [Path("renderer.py")], files
    for path in cached:
        assert references.load(path, path.stem.rsplit("-", 1)[-1]) is not None, path


CONSTANT = textwrap.dedent('''
    <scene version="3.0.0">
        <integrator type="path"/>
        <sensor type="perspective">
            <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
        </sensor>
        <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
    </scene>
''')


def test_a_timed_out_check_is_reported_and_the_run_goes_on(tmp_path, monkeypatch, capsys):
    """Two scenes, a renderer that hangs on the first: that check is stopped at --timeout and reported as
    timed out (its line, the summary, the JSON, the JUnit file), the second still gets its verdict, and the
    exit status says the run is incomplete. Both scenes are a constant environment of 0.5, which the fake
    renders exactly."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "renderer.py").write_text(FAKE)
    for stem in ("a_slow", "b_fast"):
        (tmp_path / f"{stem}.xml").write_text(CONSTANT)
    command = f"{sys.executable} {tmp_path / 'renderer.py'} hang-slow {{scene}} -o {{output}} {{defines}}"
    code = cli.main(["check", "a_slow.xml", "b_fast.xml", "--renderer", command, "--label", "fake", "--passes", "3",
                     "--spp", "4", "--size", "8", "--timeout", "3", "--json", "out/c.json", "--junit", "out/c.xml"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert code == 4, lines
    assert lines[0].startswith("timed out    a_slow.xml [fake, max_depth -1]: no verdict: renderer did not finish "
                               "pass 0 within --timeout 3 s (stopped)"), lines
    assert lines[1].startswith("agree        b_fast.xml [fake, max_depth -1]"), lines
    assert lines[2] == "validate check: 2 checks, 1 agree, 0 disagree, 0 inconclusive, 1 timed out (exit 4)", lines
    report = json.loads((tmp_path / "out/c.json").read_text())
    assert report["exit_code"] == 4 and [c["verdict"] for c in report["checks"]] == ["agree"]
    assert [t["scene"] for t in report["timed_out"]] == ["a_slow.xml"]
    suite = ET.parse(tmp_path / "out/c.xml").getroot().find("testsuite")
    assert (suite.get("tests"), suite.get("errors"), suite.get("failures")) == ("2", "1", "0")


def test_the_fake_renderer_itself_is_accepted(tmp_path, monkeypatch):
    """The same renderer without a fault renders its passes (the cases above fail for their fault alone)."""
    from validation.verdict.renderers import ExternalRenderer
    from validation.verdict.scenefile import plan

    script = tmp_path / "renderer.py"
    script.write_text(FAKE)
    renderer = ExternalRenderer(f"{sys.executable} {script} none {{scene}} -o {{output}} {{defines}}", timeout=60)
    passes = renderer.passes(plan(SCENES / "cornell_box.xml", size=32), 2, 4, 0)
    assert passes.shape == (2, 32, 32, 3) and np.all(passes == 0.5)


def test_a_bad_timeout_is_refused(capsys):
    assert cli.main(["check", str(SCENES / "cornell_box.xml"), "--renderer", "r {output}", "--timeout", "0"]) == 2
    assert "--timeout must be a positive number" in capsys.readouterr().err


def test_damaged_cache_entries_are_never_used(tmp_path):
    """Bit flips and truncations anywhere in a cached reference: load gives the reference unchanged or None
    (rendered again), never a wrong array and never an exception (zipfile raised NotImplementedError)."""
    mean = np.random.default_rng(1).uniform(0, 1, (8, 8, 3)).astype(np.float32)
    ref = references.Reference(mean, mean / 100, np.stack([mean[::4, ::4]] * 4), 64, 1.0, "k")
    path = tmp_path / "ref.npz"
    references.save(path, ref)
    data = path.read_bytes()
    rng = np.random.default_rng(2)
    for i in range(600):
        damaged = bytearray(data)
        if i % 3 == 0:
            damaged = damaged[:int(rng.integers(len(data)))]
        else:
            for at in rng.integers(0, len(data), int(rng.integers(1, 4))):
                damaged[at] ^= 1 << int(rng.integers(8))
        path.write_bytes(bytes(damaged))
        loaded = references.load(path, "k")
        assert loaded is None or (np.array_equal(loaded.mean, ref.mean) and np.array_equal(loaded.blocks, ref.blocks))
