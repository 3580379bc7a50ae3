"""The fuzzer (validation/suites/fuzz.py): its fast tier (300 seeded mutants through `tracer info`, every rendered
mutant cross-checked against Mitsuba's loader), the failures of past runs kept as regression cases
(tests/data/fuzz, through `tracer render`), and its classifier shown to catch each kind of failure."""
from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import pytest

from tracer.errors import UserError
from validation.suites import fuzz
from validation.suites.fuzz import FAILURES, Mutant, make_mutant, run_mutant, run_mutants, unexplained

FAST_N, FAST_SEED = 300, 20261201


def _findings(outcomes) -> str:
    return "\n".join(f"{o.index} {o.seed_scene} {o.mutations}: {o.kind} {o.mitsuba} {o.message[-300:]}"
                     for o in unexplained(outcomes))


def test_fast_tier():
    """300 mutants of a fixed seed: no traceback, crash, hang, lost output or malformed error, and no loaded
    mutant that Mitsuba refuses (beyond the deliberate differences)."""
    _, outcomes, _ = fuzz.fuzz(FAST_N, FAST_SEED, workers=2, command="info")
    assert not unexplained(outcomes), _findings(outcomes)
    kinds = {o.kind for o in outcomes}
    assert {"rendered", "user error"} <= kinds          # the mutants reach both ends


def test_past_failures_stay_fixed():
    cases = fuzz.load_regressions()
    assert len(cases) >= 5
    outcomes = run_mutants(cases, workers=2)
    assert not unexplained(outcomes), _findings(outcomes)


def test_mutants_are_seeded():
    scenes, assets = fuzz.seed_scenes(), fuzz.assets()
    a = [make_mutant(i, 7, scenes, assets) for i in range(40)]
    b = [make_mutant(i, 7, scenes, assets) for i in range(40)]
    assert [(m.xml, m.files, m.args) for m in a] == [(m.xml, m.files, m.args) for m in b]
    assert len({m.xml for m in a}) > 30
    kinds = {mu.split(" ")[0] for m in a for mu in m.mutations}
    assert {"file", "cli"} <= kinds


# ---- the classifier catches what it is there to catch ---------------------------------------------------------
def _mutant(tmp_path, args=()) -> Mutant:
    return Mutant(0, "cornell_box.xml", (fuzz.SCENES / "cornell_box.xml").read_bytes(), args=list(args))


@pytest.fixture
def folder(tmp_path):
    for asset in fuzz.ASSETS:
        (tmp_path / asset).symlink_to(fuzz.SCENES / asset)
    return tmp_path


def test_classifies_a_traceback_as_a_bug(folder, monkeypatch):
    monkeypatch.setattr("tracer.mitsuba_xml.load_scene", lambda *a, **k: {}["missing"])
    assert run_mutant(_mutant(folder), folder, False).kind == "bug"


def test_classifies_an_error_that_names_no_file_as_malformed(folder, monkeypatch):
    def refuse(*a, **k):
        raise UserError("something is wrong")
    monkeypatch.setattr("tracer.mitsuba_xml.load_scene", refuse)
    outcome = run_mutant(_mutant(folder), folder, False)
    assert outcome.kind == "malformed error" and "naming neither" in outcome.message


def test_classifies_a_failed_run_that_touched_the_output_as_lost_output(folder, monkeypatch):
    def clobber(scene, args, paths, *rest):
        paths[0].write_bytes(b"partial")
        raise UserError(f"{args.scene}: failed late")
    monkeypatch.setattr("tracer.cli._write_outputs", clobber)
    outcome = run_mutant(_mutant(folder), folder, False)
    assert outcome.kind == "lost output", outcome


def test_classifies_a_rendered_mutant_mitsuba_refuses(folder):
    xml = (fuzz.SCENES / "cornell_box.xml").read_bytes().replace(b"<scene version=\"3.0.0\">", b"<scene version=\"3.0.0\">"
                                                                   b"<integer name=\"zz\" value=\"1\"/>", 1)
    m = Mutant(0, "cornell_box.xml", xml, command="info")
    assert b"zz" in xml
    outcome = run_mutant(m, folder, True)
    # the tracer refuses the stray property as Mitsuba does; a mutant both load is not listed
    assert outcome.kind == "user error"
    good = run_mutant(Mutant(1, "cornell_box.xml", (fuzz.SCENES / "cornell_box.xml").read_bytes(), command="info"),
                      folder, True)
    assert good.kind == "rendered" and good.mitsuba == ""
    assert fuzz.unexplained([fuzz.Outcome(2, "rendered", [], "x", 0, "", 0.0, "refuses: anything")])


@pytest.mark.parametrize("behaviour, kind", [("import os, signal; os.kill(os.getpid(), signal.SIGSEGV)", "crash"),
                                             ("import time; time.sleep(60)", "hang"),
                                             ("raise SystemExit(3)", "bug")])
def test_pool_classifies_a_dying_or_silent_worker(tmp_path, behaviour, kind):
    """A worker that dies of a signal is a crash, one that does not answer in time a hang; the pool goes on
    with a fresh worker (the second mutant is answered)."""
    script = tmp_path / "worker.py"
    script.write_text(textwrap.dedent(f"""
        import json, sys
        for i, line in enumerate(sys.stdin):
            job = json.loads(line)["mutant"]
            if job["xml"] == "bad":
                {behaviour}
            print(json.dumps(dict(index=job["index"], kind="user error", mutations=[], seed_scene="s", exit=1,
                                  message="", seconds=0.0)), flush=True)
    """))
    mutants = [Mutant(0, "s", b"bad"), Mutant(1, "s", b"good")]
    outcomes = run_mutants(mutants, workers=1, timeout=3, worker_argv=[sys.executable, str(script)])
    assert [o.kind for o in outcomes] == [kind, "user error"]
    assert kind in FAILURES


def test_a_mitsuba_that_ends_its_process_refuses_the_scene(monkeypatch, tmp_path):
    """Mitsuba 3.9.1 ends the process on some truncated OpenEXR files (std::terminate, at a later load in the
    same process): its loads run in a process of their own, whose end by a signal is a refusal, not the end of
    the caller."""
    from validation.suites import fuzz

    scene = tmp_path / "s.xml"
    scene.write_text('<scene version="3.0.0"/>')
    assert fuzz.mitsuba_refusal(scene) == ""
    monkeypatch.setattr(fuzz, "_REFUSAL", "import os, sys; print('what(): cut short', file=sys.stderr); os.abort()")
    why = fuzz.mitsuba_refusal(scene)
    assert why.startswith("Mitsuba ended its process (signal 6)") and "cut short" in why
    assert fuzz.mitsuba_refuses(scene)
