"""The built-in peers (`validate check --renderer cycles|luxcore`), for real: each agrees with Mitsuba on the
Cornell box, an injected conversion mistake (one bounce too many) is caught, and what a peer cannot express
is skipped as unsupported in one line before any pass. The peers live in their own environment
(`scripts/setup.sh --peers`; CI installs it): without it these tests skip, saying so."""
from __future__ import annotations

import pytest

from validation import cli
from validation.verdict.peers import PeerRenderer, python

from .conftest import SCENES

needs_peers = pytest.mark.skipif(not python().is_file(), reason=f"the peers' Python {python()} is not installed "
                                 "(bash scripts/setup.sh .venv --peers)")


@needs_peers
@pytest.mark.parametrize("peer", ["cycles", "luxcore"])
def test_peer_agrees_and_an_extra_bounce_is_caught(peer, tmp_path, capsys, monkeypatch):
    """max_depth 2 (direct light), 16 px: the peer agrees; with one bounce too many it disagrees (about 15%
    brighter: far beyond the check's detectable bias, about 5% at this budget)."""
    monkeypatch.setenv("VALIDATE_CACHE", str(tmp_path))
    args = ["check", str(SCENES / "cornell_box.xml"), "--renderer", peer, "--max-depth", "2", "--size", "16",
            "--passes", "8", "--spp", "16", "--max-spp", "16"]
    assert cli.main(args) == 0, capsys.readouterr().out
    assert cli.main(args + ["--mistake", "extra-bounce"]) == 1
    out = capsys.readouterr().out
    assert f"[{peer} (mistake: extra-bounce), max_depth 2]" in out


@needs_peers
def test_what_a_peer_cannot_express_is_skipped_before_any_pass(tmp_path, capsys, monkeypatch):
    """A point light (point_lights.xml) and max_depth 1: skipped with the reason, exit 0; nothing rendered (no
    reference cached)."""
    monkeypatch.setenv("VALIDATE_CACHE", str(tmp_path))
    code = cli.main(["check", str(SCENES / "point_lights.xml"), str(SCENES / "dark.xml"), "--renderer", "cycles",
                     "--max-depth", "1", "--size", "8"])
    out = capsys.readouterr().out
    assert code == 0 and out.count("unsupported:") == 2, out
    assert "max_depth 1" in out and "2 skipped: unsupported" in out
    assert not any(tmp_path.iterdir())


def test_a_missing_peer_environment_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("VALIDATE_PEERS_PYTHON", str(tmp_path / "no-python"))
    assert cli.main(["check", str(SCENES / "cornell_box.xml"), "--renderer", "luxcore"]) == 2
    err = capsys.readouterr().err.strip()
    assert "scripts/setup.sh --peers" in err and "\n" not in err


def test_peer_options_are_checked():
    with pytest.raises(Exception, match="no mistake 'x'"):
        PeerRenderer.named("cycles", mistake="x")


@needs_peers
def test_luxcore_refuses_the_conductors_it_renders_differently(tmp_path, capsys, monkeypatch):
    """LuxCore's conductor Fresnel term is an approximation (reports/peers.md: a gold sphere under uniform light
    disagrees, +2.6%, and metal2 renders that approximation exactly): such scenes are skipped."""
    monkeypatch.setenv("VALIDATE_CACHE", str(tmp_path))
    assert cli.main(["check", str(SCENES / "constant_environment.xml"), "--renderer", "luxcore", "--size", "8"]) == 0
    assert "conductor Fresnel term" in capsys.readouterr().out


def test_the_peers_report_keeps_the_data_scenes_apart_and_names_a_stopped_check():
    """reports/peers.md: mitsuba-renderer/mitsuba-data's scenes in a table of their own; a check stopped by the
    time limit per call is said so, not called a refusal of the check."""
    from validation.suites.peers import DATA_PREFIX, report

    row = {"renderer": "luxcore", "max_depth": 2, "verdict": "agree", "mean": 0.01, "rejected": 0, "tests": 195,
           "detectable": 0.03, "seconds": 12.0}
    stopped = row | {"scene": "mirror.xml", "verdict": "error",
                     "note": "renderer did not finish pass 0 within --timeout 900 s (stopped)"}
    text = report([row | {"scene": "cornell_box.xml"}, row | {"scene": DATA_PREFIX + "scenes/cbox/cbox.xml"},
                   stopped], findings="")
    ours, data = text.split("### The scenes of mitsuba-renderer/mitsuba-data")
    assert "| cornell_box.xml | 2 |" in ours and "cbox.xml" not in ours.split("### What")[0]
    assert f"| {DATA_PREFIX}scenes/cbox/cbox.xml | 2 |" in data
    assert "| mirror.xml | 2 |  | stopped: over the time limit |" in ours
    assert "Refused by the check itself" not in text
