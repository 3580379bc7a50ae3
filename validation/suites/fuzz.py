"""`validate fuzz`: a seeded mutation fuzzer over the tracer's inputs (scene XML, the meshes and images scenes
name, command-line arguments), each mutant run through `tracer render` and classified.

A mutant is one of the project's scenes (mitsuba_scenes/) changed by one to three mutations: structural
(an element deleted, duplicated, moved, renamed, nested inside a property, a dangling or wrong-kind <ref>, a
self-include), of a value (zero, negative, huge, tiny, NaN, infinity, empty, wrong arity, 2^64, a 20,000-
character value, singular and sheared transforms, degenerate cameras), of a file the scene names
(truncated, bit-flipped, a lying header, another format's bytes, empty), or of the command line. It is
rendered small (`--size 8x8 --spp 1`) over an earlier good output, and classified:

  rendered         exit 0; the scene is then loaded by Mitsuba 3 too: where Mitsuba refuses it, listed
  user error       exit 1 (2 for argparse), one line per refusal, each naming the scene or the file
  bug              a traceback (exit 70, or any other exit status)
  crash            the process died of a signal
  hang             no answer within the timeout
  lost output      the earlier good output changed or removed by a run that failed
  malformed error  a refusal of more than one line per problem, or one that names neither the scene nor the
                   file mutated, or one over MAX_LINE characters

Mutants run in worker processes (`python -m validation.suites.fuzz --worker`), each calling `tracer.cli.main` in
process for one mutant after another (a render of 8 x 8 pixels costs its kernel's compilation, a
refusal milliseconds); a worker that dies or stops answering is a crash or a hang, and is replaced.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import random
import re
import select
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENES = ROOT / "mitsuba_scenes"
REGRESSIONS = ROOT / "tests" / "data" / "fuzz"
ASSETS = ("meshes", "textures", "fragments")        # the folders the scenes name files in
CLASSES = ("rendered", "user error", "bug", "crash", "hang", "lost output", "malformed error")
FAILURES = ("bug", "crash", "hang", "lost output", "malformed error")
MAX_LINE = 1000
FILE_LINE = re.compile(r"\S+\.(xml|obj|ply|serialized|exr|png):\d+: ")
# Rendered mutants that Mitsuba refuses, on purpose (README): (a pattern of Mitsuba's message, why). None yet.
DELIBERATE: list[tuple[str, str]] = []
TIMEOUT = 120.0       # seconds a mutant may take (a kernel's compilation is a few)
BASE_ARGS = ["--size", "8x8", "--spp", "1", "-q"]
PLUGIN_TAGS = ("integrator", "sensor", "film", "rfilter", "sampler", "shape", "bsdf", "emitter", "texture")
PROPERTY_TAGS = ("integer", "float", "boolean", "string", "rgb", "spectrum", "point", "vector", "transform")
LONG = "7" * 20000
VALUES = ["0", "-1", "-0", "1e40", "1e-40", "3.4e38", "nan", "inf", "-inf", "", " ", "1 2", "1 2 3 4", "1,2,3",
          "18446744073709551616", "2147483648", "4294967296", "-2147483649", "1_0", "0x10", "+5", "5.0", "abc",
          "true", "$undeclared", "1e309", LONG, "0 0 0", "1 1 1", "-1 -1 -1", "0.5, 0.5", "400:1, 700:x"]
NAMES = ["filename", "x" * 5000 + ".obj", "", ".", "..", "/", "missing.obj", "meshes", "meshes/cube.ply",
         "textures/sky.exr", "textures/tiles.png", "meshes/cube.serialized", "../../../../etc/passwd", "\u00e9.obj"]
TRANSFORMS = ['<matrix value="0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 1"/>', '<matrix value="1 0.5 0 0 0 1 0 0 0 0 1 0 0 0 0 1"/>',
              '<scale value="0"/>', '<scale value="2"/>', '<scale x="-1"/>', '<scale value="1e-30"/>',
              '<rotate x="0" y="0" z="0" angle="30"/>', '<lookat origin="0 0 0" target="0 0 0"/>',
              '<lookat origin="0 0 1" target="0 0 0" up="0 0 1"/>', '<translate value="1e39 0 0"/>',
              '<matrix value="1 0 0 0 0 1 0 0 0 0 1 0 0 0 0.5 1"/>', '<matrix value="1 2 3"/>',
              '<translate value="1 2 3" x="1"/>', '<rotate y="1" angle="nan"/>']
CLI = [["--spp", "0"], ["--spp", "-1"], ["--spp", "18446744073709551616"], ["--seed", "-1"], ["--seed", "4294967296"],
       ["--max-depth", "-2"], ["--max-depth", "2147483648"], ["--max-depth", "99999999999999999999"],
       ["--report-depth", "-1"], ["--estimator", "report"], ["--estimator", "report", "--direct", "0"],
       ["--estimator", "report", "--indirect", "-3"], ["--direct", "2"], ["--size", "0x0"], ["--size", "8x"],
       ["--size", "99999999999x8"], ["--width", "-4"], ["--filter", "mitchell"], ["--filter", "tent"],
       ["--time-limit", "-1"], ["--time-limit", "nan"], ["--time-limit", "inf"], ["--aov-spp", "0"], ["--aovs"],
       ["--adaptive", "--estimator", "report"], ["-D", "=3"], ["-D", "nothing"], ["-D", "undeclared=1"],
       ["--hemisphere", "uniform"], ["-o", "out.hdr"], ["-o", "keep.exr"], ["-o", "."], ["-o", "nodir/sub/x.exr"],
       ["-o", "k" * 5000 + ".exr"], ["-o", "keep.png"], ["--no-png"], ["--spp", "abc"], ["--bogus"]]


@dataclass
class Mutant:
    """A scene and the files it names (name -> bytes), the extra arguments and what was done to them."""
    index: int
    seed_scene: str
    xml: bytes
    files: dict[str, bytes] = field(default_factory=dict)
    args: list[str] = field(default_factory=list)
    mutations: list[str] = field(default_factory=list)
    target: str = "scene.xml"        # the file a refusal must name (the scene, or the file corrupted)
    command: str = "render"          # or "info": the scene loaded and its kernel's geometry built, no render


@dataclass
class Outcome:
    index: int
    kind: str                        # one of CLASSES
    mutations: list[str]
    seed_scene: str
    exit: int | None
    message: str
    seconds: float
    mitsuba: str = ""                # "refuses: ..." where Mitsuba refuses a rendered mutant


# ---- mutations ---------------------------------------------------------------------------------------
def seed_scenes() -> list[Path]:
    return sorted(SCENES.glob("*.xml"))


def _elements(root: ET.Element) -> list[tuple[ET.Element, ET.Element | None]]:
    """Every element with its parent (None for the root)."""
    out = [(root, None)]
    for parent in root.iter():
        out += [(child, parent) for child in parent]
    return out


def _structural(rng: random.Random, root: ET.Element, m: Mutant) -> None:
    pairs = [(e, p) for e, p in _elements(root) if p is not None]
    if not pairs:
        return
    e, parent = rng.choice(pairs)
    what = rng.choice(["delete", "duplicate", "move", "rename", "nest", "ref-dangling", "ref-kind", "self-include",
                       "include-missing", "include-folder", "version", "attribute", "default-include", "swap"])
    m.mutations.append(f"structural {what} <{e.tag}{' ' + e.get('type') if e.get('type') else ''}>")
    if what == "delete":
        parent.remove(e)
    elif what == "duplicate":
        parent.insert(list(parent).index(e), ET.fromstring(ET.tostring(e)))
    elif what in ("move", "nest"):
        targets = [t for t, _ in _elements(root) if t is not e and e not in list(t.iter())]
        if what == "nest":
            targets = [t for t in targets if t.tag in PROPERTY_TAGS] or targets
        parent.remove(e)
        rng.choice(targets).append(e)
    elif what == "rename":
        e.tag = rng.choice(PLUGIN_TAGS + PROPERTY_TAGS + ("ref", "include", "default", "path", "foo", "scene"))
    elif what == "ref-dangling":
        parent.insert(list(parent).index(e), ET.Element("ref", id=rng.choice(["nowhere", "", "$x"])))
    elif what == "ref-kind":
        ids = [t.get("id") for t, _ in _elements(root) if t.get("id")]
        host = rng.choice([t for t, _ in _elements(root) if t.tag in PLUGIN_TAGS] or [root])
        host.append(ET.Element("ref", id=rng.choice(ids) if ids else "x", name=rng.choice(["", "bsdf", "reflectance"])))
    elif what == "self-include":
        rng.choice([root, parent]).append(ET.Element("include", filename="scene.xml"))
    elif what == "include-missing":
        root.append(ET.Element("include", filename=rng.choice(["missing.xml", "meshes/cube.obj", ""])))
    elif what == "include-folder":
        root.append(ET.Element("include", filename=rng.choice([".", "meshes", "/"])))
    elif what == "version":
        value = rng.choice([None, "", "3", "3.0", "abc", "4.0.0", "3.0.0.0", "-1.0.0"])
        root.attrib.pop("version", None) if value is None else root.set("version", value)
    elif what == "attribute":
        e.set(rng.choice(["foo", "x", "value", "id", "name", "type", "filename"]), rng.choice(VALUES[:12]))
    elif what == "default-include":
        d = ET.Element("default", name="zz", value="1")
        d.append(ET.Element("include", filename="missing.xml"))
        root.insert(0, d)
    elif what == "swap":
        others = [o for o, _ in pairs if o is not e]
        if others:
            o = rng.choice(others)
            e.tag, o.tag = o.tag, e.tag


def _value(rng: random.Random, root: ET.Element, m: Mutant) -> None:
    pairs = [(e, p) for e, p in _elements(root) if e.attrib]
    if not pairs:
        return
    e, parent = rng.choice(pairs)
    if e.tag == "transform" or (rng.random() < 0.15 and any(t.tag == "transform" for t, _ in pairs)):
        t = e if e.tag == "transform" else rng.choice([t for t, _ in pairs if t.tag == "transform"])
        op = rng.choice(TRANSFORMS)
        if rng.random() < 0.5:
            t.clear()
            t.set("name", "to_world")
        t.append(ET.fromstring(op))
        m.mutations.append(f"value transform {op}")
        return
    key = rng.choice(list(e.attrib))
    if key in ("filename",) or (key == "value" and e.get("name") == "filename"):
        value = rng.choice(NAMES)
    elif key == "type":
        value = rng.choice(["", "nonexistent", "path", "diffuse", "sphere", "area", "box", "perspective", "envmap"])
    else:
        value = rng.choice(VALUES)
    e.set(key, value)
    m.mutations.append(f"value <{e.tag}> {key}={value[:20]!r}{'...' if len(value) > 20 else ''}")


def _corrupt(rng: random.Random, data: bytes, name: str) -> tuple[bytes, str]:
    how = rng.choice(["truncate", "flip", "flip", "header", "empty", "garbage", "other format", "append"])
    if how == "truncate" and data:
        return data[:rng.randrange(len(data))], how
    if how == "flip" and data:
        d = bytearray(data)
        for _ in range(rng.randint(1, 8)):
            d[rng.randrange(len(d))] ^= 1 << rng.randrange(8)
        return bytes(d), how
    if how == "header":                      # a lying count or size in the header
        def lie(match: re.Match) -> bytes:
            count = int(match[2])
            return match[1] + str(rng.choice([0, 1, count - 1, count + 1, 2 ** 32, 2 ** 64])).encode()
        out, n = re.subn(rb"(element \w+ )(\d+)", lie, data, count=1)
        if n:
            return out, "ply element count"
        if name.endswith(".serialized") and len(data) > 8:
            d = bytearray(data)
            d[-4:] = rng.choice([0, 2, 255, 2 ** 31]).to_bytes(4, "little")
            return bytes(d), "serialized mesh count"
        if name.endswith(".exr") and len(data) > 40:
            d = bytearray(data)
            at = rng.randrange(8, min(len(d), 400) - 4)
            d[at:at + 4] = rng.choice([0, 2 ** 31 - 1, 2 ** 32 - 1]).to_bytes(4, "little")
            return bytes(d), "exr header field"
        return data + b"\n" + data, "doubled"
    if how == "empty":
        return b"", how
    if how == "garbage":
        return rng.randbytes(rng.randint(1, 512)), how
    if how == "other format":
        other = rng.choice([p for d in ("meshes", "textures") for p in sorted((SCENES / d).iterdir())])
        return other.read_bytes(), f"{how} ({other.name})"
    return data + rng.randbytes(rng.randint(1, 64)), "append"


def _file(rng: random.Random, root: ET.Element, m: Mutant, assets: dict[str, bytes]) -> None:
    refs = [e for e in root.iter() if e.get("name") == "filename" and e.get("value") in assets]
    if not refs:
        return _value(rng, root, m)
    e = rng.choice(refs)
    data, how = _corrupt(rng, assets[e.get("value")], e.get("value"))
    name = f"mutant_{m.index}{Path(e.get('value')).suffix}"
    m.files[name] = data
    e.set("value", name)
    m.target = name
    m.mutations.append(f"file {Path(name).suffix}: {how}")


def _text(rng: random.Random, xml: bytes, m: Mutant) -> bytes:
    how = rng.choice(["truncate", "flip", "insert", "encoding", "entity"])
    m.mutations.append(f"text {how}")
    if how == "truncate":
        return xml[:rng.randrange(len(xml))]
    if how == "flip":
        d = bytearray(xml)
        d[rng.randrange(len(d))] ^= 1 << rng.randrange(8)
        return bytes(d)
    if how == "insert":
        at = rng.randrange(len(xml))
        return xml[:at] + rng.choice([b"<", b"&", b"]]>", b"\0", b"\xff\xfe", b"<!DOCTYPE x [<!ENTITY a 'b'>]>"]) + xml[at:]
    if how == "encoding":
        return b'<?xml version="1.0" encoding="nonsense"?>' + xml
    return xml.replace(b"<scene", b'<!DOCTYPE s [<!ENTITY e SYSTEM "/etc/hostname">]>\n<scene', 1)


def make_mutant(index: int, seed: int, scenes: list[Path], assets: dict[str, bytes], command: str = "render") -> Mutant:
    """Mutant `index` of the run seeded `seed`: the same pair always gives the same mutant. With `command`
    "info", command-line mutations are -D's only."""
    rng = random.Random(seed * 1_000_003 + index)
    scene = rng.choice(scenes)
    m = Mutant(index, scene.name, b"", command=command)
    root = ET.fromstring(scene.read_bytes())
    kinds = rng.choices(["structural", "value", "file", "cli", "text"], [30, 35, 20, 10, 5], k=rng.choice([1, 1, 2, 3]))
    for kind in kinds:
        if kind == "structural":
            _structural(rng, root, m)
        elif kind == "value":
            _value(rng, root, m)
        elif kind == "file":
            _file(rng, root, m, assets)
        elif kind == "cli":
            args = rng.choice(CLI if command == "render" else [a for a in CLI if a[0] == "-D"])
            m.args += args
            m.mutations.append("cli " + " ".join(a[:20] for a in args))
    m.xml = ET.tostring(root)
    if "text" in kinds:
        m.xml = _text(rng, m.xml, m)
    return m


# ---- running one mutant (in a worker) --------------------------------------------------------------------
GOOD = {"keep.exr": None, "keep.png": None}


def _good_outputs(folder: Path) -> dict[str, bytes]:
    """The earlier good outputs a failing run must leave as they were."""
    if GOOD["keep.exr"] is None:
        import numpy as np

        from tracer.imageio import write_exr, write_png
        image = np.full((8, 8, 3), 0.25, np.float32)
        with tempfile.TemporaryDirectory() as tmp:
            write_exr(Path(tmp) / "k.exr", image)
            write_png(Path(tmp) / "k.png", image)
            GOOD.update({"keep.exr": (Path(tmp) / "k.exr").read_bytes(), "keep.png": (Path(tmp) / "k.png").read_bytes()})
    for name in GOOD:
        (folder / name).write_bytes(GOOD[name])
    return dict(GOOD)


def _malformed(stderr: str, m: Mutant, code: int) -> str:
    """Why a refusal's text is malformed, or '': argparse's ends with its error line; the tracer's is a
    'tracer: error:' line and one line per further problem, each naming the scene or the mutated file unless
    the command line was mutated too, none longer than MAX_LINE."""
    lines = stderr.rstrip("\n").split("\n")
    if code == 2:
        return "" if "error:" in lines[-1] else "an argparse refusal without its error line"
    start = next((i for i, line in enumerate(lines) if line.startswith("tracer: error: ")), None)
    if start is None:
        return "no 'tracer: error:' line"
    refusal = lines[start:]
    if any(len(line) > MAX_LINE for line in refusal):
        return f"a line of {max(map(len, refusal))} characters"
    if not m.args:                  # each line names the scene, the mutated file, or a file and line (an include's)
        unnamed = [line for line in refusal if "scene.xml" not in line and m.target not in line
                   and not FILE_LINE.search(line)]
        if unnamed:
            return f"a refusal naming neither the scene nor {m.target}: {unnamed[0][:200]}"
    return ""


def run_mutant(m: Mutant, folder: Path, mitsuba_check: bool = True) -> Outcome:
    """Runs `tracer render` on the mutant in this process, in `folder` (emptied first)."""
    from tracer.cli import main

    for p in folder.iterdir():
        if p.name not in ASSETS:
            shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
    scene = folder / "scene.xml"
    scene.write_bytes(m.xml)
    for name, data in m.files.items():
        (folder / name).write_bytes(data)
    good = _good_outputs(folder)
    argv = ["render", str(scene), "-o", str(folder / "keep.exr"), *BASE_ARGS, *m.args] if m.command == "render" \
        else ["info", str(scene), *m.args]
    out, err = io.StringIO(), io.StringIO()
    start = time.perf_counter()
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else 2
    finally:
        os.chdir(cwd)
    seconds = time.perf_counter() - start
    stderr = err.getvalue()
    outcome = Outcome(m.index, "", m.mutations, m.seed_scene, code, stderr.strip()[-2000:], seconds)
    if code == 0:
        outcome.kind = "rendered"
        if mitsuba_check and not any(a.startswith("-D") for a in m.args):
            why = mitsuba_refusal(scene)
            outcome.mitsuba = f"refuses: {why}" if why else ""
        return outcome
    lost = [n for n, data in good.items() if not (folder / n).is_file() or (folder / n).read_bytes() != data]
    if lost:
        outcome.kind, outcome.message = "lost output", f"{', '.join(lost)} changed by a failed run; " + outcome.message
    elif code not in (1, 2) or "Traceback" in stderr:
        outcome.kind = "bug"
    elif why := _malformed(stderr, m, code):
        outcome.kind, outcome.message = "malformed error", f"{why}; " + outcome.message
    else:
        outcome.kind = "user error"
    return outcome


def deliberate(o: Outcome) -> str:
    """Why a rendered mutant that Mitsuba refuses is a deliberate difference, or ''."""
    return next((why for pattern, why in DELIBERATE if re.search(pattern, o.mitsuba)), "") if o.mitsuba else ""


def unexplained(outcomes: list[Outcome]) -> list[Outcome]:
    """The failures, and the rendered mutants Mitsuba refuses that are not deliberate differences."""
    return [o for o in outcomes if o.kind in FAILURES or (o.mitsuba and not deliberate(o))]


_REFUSAL = """
import sys
from validation.verdict.mitsuba_render import mitsuba
try:
    mitsuba().load_file(sys.argv[1])
except Exception as e:
    text = str(e).strip()
    print(text.splitlines()[-1][-300:] if text else type(e).__name__)
"""


def mitsuba_refusal(scene: Path) -> str:
    """Mitsuba 3's refusal of a scene file, or '' where it loads it. In a process of its own (its log on
    that process's stderr): Mitsuba 3.9.1 ends the process (std::terminate) on some truncated OpenEXR files,
    an EOFException thrown where it cannot be caught, often only at a later load in the same process; such an
    end counts as a refusal."""
    run = subprocess.run([sys.executable, "-c", _REFUSAL, str(scene)], capture_output=True, text=True, cwd=ROOT)
    if run.returncode:
        died = f"signal {-run.returncode}" if run.returncode < 0 else f"exit status {run.returncode}"
        last = (run.stderr.strip().splitlines() or [""])[-1]
        return f"Mitsuba ended its process ({died}) {last}"[:300]
    return run.stdout.strip()


def mitsuba_refuses(scene: Path) -> bool:
    return bool(mitsuba_refusal(scene))


def worker() -> int:
    """Reads mutants (JSON lines) on stdin, answers outcomes on the original stdout; what the tracer or
    Dr.Jit print on the process's descriptors goes to stderr."""
    os.environ.setdefault("TRACER_BVH_CACHE", "off")
    answer = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    folder = Path(tempfile.mkdtemp(prefix="fuzz-"))
    for asset in ASSETS:
        shutil.copytree(SCENES / asset, folder / asset)
    for line in sys.stdin:
        job = json.loads(line)
        m = Mutant(**{**job["mutant"], "xml": job["mutant"]["xml"].encode("latin-1"),
                      "files": {k: v.encode("latin-1") for k, v in job["mutant"]["files"].items()}})
        outcome = run_mutant(m, folder, job.get("mitsuba", True))
        answer.write(json.dumps(asdict(outcome)) + "\n")
        answer.flush()
    shutil.rmtree(folder, ignore_errors=True)
    return 0


# ---- the pool of workers -----------------------------------------------------------------------------------
class _Worker:
    def __init__(self, log, argv: list[str]):
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
                   OPENBLAS_NUM_THREADS="1")
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=log, env=env, cwd=ROOT, text=True, bufsize=1)
        self.job: Mutant | None = None
        self.since = 0.0

    def send(self, m: Mutant, mitsuba: bool) -> None:
        job = asdict(m)
        job["xml"] = m.xml.decode("latin-1")
        job["files"] = {k: v.decode("latin-1") for k, v in m.files.items()}
        self.job, self.since = m, time.monotonic()
        self.proc.stdin.write(json.dumps({"mutant": job, "mitsuba": mitsuba}) + "\n")
        self.proc.stdin.flush()

    def stop(self) -> None:
        with contextlib.suppress(OSError):
            self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def run_mutants(mutants: list[Mutant], workers: int = 2, timeout: float = TIMEOUT, mitsuba: bool = True,
                progress=None, worker_argv: list[str] | None = None) -> list[Outcome]:
    """Every mutant's outcome, in the order of `mutants`; `worker_argv`: another worker program (a test's)."""
    todo, done = list(reversed(mutants)), {}
    log = tempfile.TemporaryFile("w+")
    argv = worker_argv or [sys.executable, "-m", "validation.suites.fuzz", "--worker"]
    pool = [_Worker(log, argv) for _ in range(min(workers, len(mutants)) or 1)]
    try:
        while len(done) < len(mutants):
            for w in pool:
                if w.job is None and todo:
                    w.send(todo.pop(), mitsuba)
            busy = {w.proc.stdout: w for w in pool if w.job is not None}
            ready, _, _ = select.select(list(busy), [], [], 1.0)
            for stream in ready:
                w = busy[stream]
                line = stream.readline()
                if line:
                    outcome = Outcome(**json.loads(line))
                else:                                   # the worker died on this mutant
                    code = w.proc.wait()
                    outcome = Outcome(w.job.index, "crash" if code < 0 else "bug", w.job.mutations, w.job.seed_scene,
                                      code, f"the process ended with {'signal ' + str(-code) if code < 0 else code}",
                                      time.monotonic() - w.since)
                    pool[pool.index(w)] = w = _Worker(log, argv)
                done[outcome.index] = outcome
                w.job = None
                if progress:
                    progress(outcome)
            for i, w in enumerate(pool):
                if w.job is not None and time.monotonic() - w.since > timeout:
                    w.proc.kill()
                    w.proc.wait()
                    done[w.job.index] = Outcome(w.job.index, "hang", w.job.mutations, w.job.seed_scene, None,
                                                f"no answer in {timeout:g} s", timeout)
                    if progress:
                        progress(done[w.job.index])
                    pool[i] = _Worker(log, argv)
    finally:
        for w in pool:
            w.stop()
    return [done[m.index] for m in mutants]


def assets() -> dict[str, bytes]:
    return {f"{d}/{p.name}": p.read_bytes() for d in ASSETS for p in sorted((SCENES / d).iterdir()) if p.is_file()}


def fuzz(n: int, seed: int, workers: int = 2, timeout: float = TIMEOUT, mitsuba: bool = True, progress=None,
         command: str = "render"):
    """Runs mutants 0..n-1 of `seed`: (mutants, outcomes, seconds)."""
    scenes, files = seed_scenes(), assets()
    mutants = [make_mutant(i, seed, scenes, files, command) for i in range(n)]
    start = time.perf_counter()
    outcomes = run_mutants(mutants, workers, timeout, mitsuba, progress)
    return mutants, outcomes, time.perf_counter() - start


# ---- regression cases (tests/data/fuzz) -------------------------------------------------------------------
def save_regression(m: Mutant, outcome: Outcome, folder: Path = REGRESSIONS) -> Path:
    """A failing mutant kept as a case: its scene, its files, its arguments and what it once did."""
    case = folder / f"{m.seed_scene.removesuffix('.xml')}-{m.index}"
    case.mkdir(parents=True, exist_ok=True)
    (case / "scene.xml").write_bytes(m.xml)
    for name, data in m.files.items():
        (case / name).write_bytes(data)
    (case / "case.json").write_text(json.dumps({"args": m.args, "mutations": m.mutations, "target": m.target,
                                                "seed_scene": m.seed_scene, "was": outcome.kind,
                                                "message": outcome.message[:500]}, indent=1) + "\n")
    return case


def load_regressions(folder: Path = REGRESSIONS) -> list[Mutant]:
    out = []
    for i, case in enumerate(sorted(p for p in folder.iterdir() if (p / "case.json").is_file()) if folder.is_dir() else []):
        meta = json.loads((case / "case.json").read_text())
        files = {p.name: p.read_bytes() for p in case.iterdir() if p.name not in ("scene.xml", "case.json")}
        out.append(Mutant(-1 - i, meta["seed_scene"], (case / "scene.xml").read_bytes(), files, meta["args"],
                          [case.name] + meta["mutations"], meta["target"]))
    return out


# ---- the report ----------------------------------------------------------------------------------------------
def report(outcomes: list[Outcome], n: int, seed: int, seconds: float, workers: int, command: str) -> str:
    counts = Counter(o.kind for o in outcomes)
    refused_by_mitsuba = [o for o in outcomes if o.kind == "rendered" and o.mitsuba]
    findings = unexplained(outcomes)
    lines = ["# Fuzzing the tracer's inputs", "",
             f"`{command}`: {n:,} mutants of the project's scenes (seed {seed}), {workers} worker processes, "
             f"{seconds:.0f} s ({n / max(seconds, 1e-9):.1f} mutants/s). Each mutant is rendered at 8 x 8, 1 spp "
             "over an earlier good output (`validation/suites/fuzz.py` says how mutants are made and classified).", "",
             "| outcome | mutants |", "|---|---:|"]
    lines += [f"| {c} | {counts.get(c, 0):,} |" for c in CLASSES]
    lines += ["", f"Rendered mutants that Mitsuba 3's loader refuses: {len(refused_by_mitsuba)}, of which "
                  f"{sum(bool(deliberate(o)) for o in refused_by_mitsuba)} are deliberate differences (README)"
                  + (":" if DELIBERATE else "; none is declared (`validation.suites.fuzz.DELIBERATE`).")]
    lines += [f"- {why} ({sum(deliberate(o) == why for o in refused_by_mitsuba)} mutants)" for _, why in DELIBERATE]
    kinds = Counter(mu.split(" ")[0] for o in outcomes for mu in o.mutations)
    ops = Counter(" ".join(mu.split(" ")[:2]).rstrip(":") for o in outcomes for mu in o.mutations
                  if mu.startswith(("structural", "file", "text")))
    lines += ["", "Mutations applied (a mutant holds one to three): " +
              ", ".join(f"{k} {v:,}" for k, v in kinds.most_common()) + "; of which " +
              ", ".join(f"{k} {v:,}" for k, v in sorted(ops.items())) + "."]
    scene_counts = Counter((o.seed_scene, o.kind) for o in outcomes)
    lines += ["", "| scene | rendered | user error | other |", "|---|---:|---:|---:|"]
    for s in sorted({o.seed_scene for o in outcomes}):
        other = sum(v for (sc, k), v in scene_counts.items() if sc == s and k not in ("rendered", "user error"))
        lines.append(f"| {s} | {scene_counts[(s, 'rendered')]} | {scene_counts[(s, 'user error')]} | {other} |")
    if findings:
        lines += ["", "## Findings", ""]
        for o in findings:
            what = o.kind if o.kind in FAILURES else f"rendered, but Mitsuba {o.mitsuba}"
            lines.append(f"- mutant {o.index} of {o.seed_scene} ({'; '.join(o.mutations)}): {what}: "
                         f"`{o.message.splitlines()[-1][:300] if o.message else ''}`")
    slow = sorted(outcomes, key=lambda o: -o.seconds)[:3]
    lines += ["", "Slowest mutants: " + ", ".join(f"{o.index} ({o.seed_scene}, {o.kind}) {o.seconds:.1f} s" for o in slow)
              + "."]
    return "\n".join(lines) + "\n"


def command_line(args, command: str) -> int:
    """`validate fuzz`: runs the mutants, prints each finding and a summary, writes the report; exit 1 on
    any failure."""
    for name, value in (("n", args.n), ("workers", args.workers)):
        if value < 1:
            raise SystemExit(f"validate fuzz: error: --{name} must be >= 1, got {value}")
    seen = Counter()

    def progress(o: Outcome) -> None:
        seen[o.kind] += 1
        if o.kind in FAILURES or o.mitsuba:
            print(f"mutant {o.index} of {o.seed_scene} ({'; '.join(o.mutations)}): {o.kind} {o.mitsuba}: "
                  f"{o.message.splitlines()[-1][:300] if o.message else ''}", flush=True)
        if sum(seen.values()) % 500 == 0:
            print(f"  {sum(seen.values()):,} of {args.n:,}: " + ", ".join(f"{k} {v}" for k, v in seen.items()),
                  flush=True)

    mutants, outcomes, seconds = fuzz(args.n, args.seed, args.workers, args.timeout, not args.no_mitsuba, progress,
                                      args.run)
    if args.save:
        found = {o.index for o in unexplained(outcomes)}
        for m, o in zip(mutants, outcomes):
            if o.index in found:
                save_regression(m, o)
    text = report(outcomes, args.n, args.seed, seconds, args.workers, command)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text)
    failures = len(unexplained(outcomes))
    print(f"validate fuzz: {args.n:,} mutants in {seconds:.0f} s: " + ", ".join(
        f"{c} {sum(o.kind == c for o in outcomes)}" for c in CLASSES) + f"; wrote {args.output}")
    return 1 if failures else 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--worker"]:
        return worker()
    raise SystemExit("usage: validate fuzz --n N --seed S (the worker: python -m validation.suites.fuzz --worker)")


if __name__ == "__main__":
    sys.exit(main())
