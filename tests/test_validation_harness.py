"""The harness's own parts: reference cache (keys, atomic files, checksums), metrics, resumable sweeps, CLI."""
import shutil

import numpy as np
import pytest

from validation import cli
from validation.verdict import references
from validation.reports import sweep
from validation.verdict.metrics import agreement, measure, rmse, ssim
from validation.verdict.references import Reference
from validation.verdict.scenefile import plan

from .conftest import SCENES


def fake_reference(mean: np.ndarray, var: float = 0.0, passes: int = 4) -> Reference:
    blocks = np.repeat(mean[None, ::4, ::4], passes, axis=0)
    return Reference(mean, np.full_like(mean, var), blocks, 64, 1.0, "k")


def test_rmse_subtracts_the_references_variance():
    rng = np.random.default_rng(0)
    truth = np.full((64, 64, 3), 0.5, np.float32)
    noisy_ref = truth + rng.normal(0, 0.1, truth.shape).astype(np.float32)
    ref = fake_reference(noisy_ref, var=0.01)
    assert rmse(truth, ref) < 0.01                   # without the subtraction: about 0.1
    assert rmse(truth + 0.2, ref) == pytest.approx(0.2, rel=0.05)


def test_ssim_bias_and_identity():
    image = np.random.default_rng(1).uniform(0, 1, (32, 32, 3)).astype(np.float32)
    ref = fake_reference(image)
    assert ssim(image, ref) == pytest.approx(1.0)
    m = measure(image + np.float32(0.1), ref)
    assert m.bias == pytest.approx((0.1, 0.1, 0.1), abs=1e-5)
    assert m.ssim < 1.0


def test_agreement_uses_the_references_blocks():
    rng = np.random.default_rng(2)
    passes = rng.normal(1.0, 0.05, (8, 32, 32, 3)).astype(np.float32)
    ref_passes = rng.normal(1.0, 0.05, (8, 32, 32, 3)).astype(np.float32)
    from validation.verdict.stats import block_means
    ref = Reference(ref_passes.mean(0), ref_passes.var(0) / 8, block_means(ref_passes, 4), 8, 0.0, "k")
    assert agreement(passes, ref).passed
    assert not agreement(passes * 1.1, ref).passed


def test_cache_key_follows_scene_meshes_and_parameters(tmp_path):
    scene = tmp_path / "hexagon_room.xml"
    shutil.copy(SCENES / "hexagon_room.xml", scene)
    shutil.copytree(SCENES / "meshes", tmp_path / "meshes")
    def key(max_depth=4, spp=64, **defines):
        return plan(scene, defines, max_depth=max_depth).content_key(passes=16, spp=spp)

    first = key()
    assert key(max_depth=5) != first
    assert key(spp=32) != first
    assert key(width="32") != first
    mesh = tmp_path / "meshes" / "tetrahedron.obj"
    mesh.write_text(mesh.read_text() + "\n# changed\n")
    assert key() != first
    second = key()
    scene.write_text(scene.read_text().replace("<scene", "<!-- an edited light --><scene", 1))
    assert key() != second


def test_cache_round_trip_and_damage_detection(tmp_path):
    ref = fake_reference(np.random.default_rng(3).uniform(0, 1, (16, 16, 3)).astype(np.float32), 0.01)
    path = tmp_path / "ref.npz"
    references.save(path, ref)
    loaded = references.load(path, "k")
    np.testing.assert_array_equal(loaded.mean, ref.mean)
    assert references.load(path, "another key") is None
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF                     # a flipped byte inside the arrays
    path.write_bytes(bytes(data))
    assert references.load(path, "k") is None
    path.write_bytes(bytes(data[:100]))              # a truncated file
    assert references.load(path, "k") is None
    assert list(tmp_path.glob(".*")) == []           # no temporary file left behind


def _record_runs(tmp_path, monkeypatch) -> list:
    """Replaces the sweep's renders by rows that agree; returns the list the run keys are appended to."""
    calls = []

    def fake_execute(scene_file, spec, ref):
        calls.append(spec.key)
        row = {f: 0 for f in sweep.FIELDS} | {"key": spec.key, "test": "agree", "rejected": 0, "min_p": 0.5}
        return row, np.zeros((4, 4, 3), np.float32)

    monkeypatch.setattr(sweep, "execute", fake_execute)
    monkeypatch.setattr(sweep, "IMAGES", tmp_path / "images")
    return calls


def test_sweep_resumes_and_skips_done_runs(tmp_path, monkeypatch):
    calls = _record_runs(tmp_path, monkeypatch)
    specs = [sweep.RunSpec("path", 2, s, 8) for s in (1, 2, 4)]
    results = tmp_path / "runs.csv"
    sweep.sweep(SCENES / "cornell_box.xml", specs[:2], lambda d, s: None, results)
    with results.open("a") as f:
        f.write("path,2,99")                         # a torn line, as an interrupted write leaves
    rows = sweep.sweep(SCENES / "cornell_box.xml", specs, lambda d, s: None, results)
    assert calls == [s.key for s in specs]           # the second sweep ran only the third spec
    assert [r["key"] for r in rows] == [s.key for s in specs]
    assert (tmp_path / "runs.json").exists()


def test_cli_errors_are_one_line(capsys):
    assert cli.main(["report", "no/such/scene.xml"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("validate: error:") and "\n" not in err
    assert cli.main(["report", str(SCENES / "cornell_box.xml"), "--size", "2"]) == 2
    assert "--size" in capsys.readouterr().err


def test_sweep_renders_again_when_the_scene_changes(tmp_path, monkeypatch):
    """Runs are keyed by the scene's content: an edited light is rendered again, not read from the CSV."""
    calls = _record_runs(tmp_path, monkeypatch)
    scene = tmp_path / "cornell_box.xml"
    shutil.copy(SCENES / "cornell_box.xml", scene)
    shutil.copytree(SCENES / "meshes", tmp_path / "meshes")
    specs = [sweep.RunSpec("path", 2, 1, 8)]
    results = tmp_path / "runs.csv"
    sweep.sweep(scene, specs, lambda d, s: None, results)
    sweep.sweep(scene, specs, lambda d, s: None, results)
    assert len(calls) == 1                              # unchanged: read from the CSV
    scene.write_text(scene.read_text().replace("<scene", "<!-- another light --><scene", 1))
    rows = sweep.sweep(scene, specs, lambda d, s: None, results)
    assert len(calls) == 2 and len(rows) == 1           # edited: rendered again, the stale row not reported
