"""The suite runner (validation/suites/runner.py) on Dask: a small calibration suite gives the same arrays, bit
for bit, on one worker and on two; the process that runs it imports neither Dr.Jit nor Mitsuba; a worker killed
mid-suite costs only its units, each unit's result still arrives exactly once."""
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from validation.suites import calibration
from validation.suites.calibration import Cell, Setting, cell_units
from validation.suites.runner import SchedulerError, Unit, check_scheduler, session

ROOT = Path(__file__).resolve().parents[1]
SMALL = Setting(passes=3, size=8, report=(1, 1), old=False)
CELLS = [Cell(scene, "path", spp, depth, 2) for scene in ("room", "dark") for spp, depth in ((1, 2), (4, 3))]

SCRIPT = textwrap.dedent("""
    import sys
    from pathlib import Path
    from validation.suites.calibration import Cell, Setting, run_cells
    from validation.suites.runner import session
    small = Setting(passes=3, size=8, report=(1, 1), old=False)
    cells = [Cell(s, "path", spp, d, 2) for s in ("room", "dark") for spp, d in ((1, 2), (4, 3))]
    for workers in (1, 2):
        with session("local", workers, quiet=True) as runner:
            run_cells([(c, small) for c in cells], runner, Path(sys.argv[1]) / str(workers))
    print("client imported:", sorted(m for m in ("drjit", "mitsuba") if m in sys.modules))
""")


def _arrays(folder: Path) -> dict:
    out = {}
    for f in sorted(folder.glob("*.npz")):
        with np.load(f) as z:
            out[f.name] = {k: z[k] for k in z.files if k != "seconds"}
    return out


@pytest.fixture(scope="module")
def one_and_two(tmp_path_factory):
    """The suite run on a local cluster of one worker and of two (in a fresh interpreter: the client's imports)."""
    out = tmp_path_factory.mktemp("suite")
    run = subprocess.run([sys.executable, "-c", SCRIPT, str(out)], cwd=ROOT, capture_output=True, text=True,
                         env=os.environ | {"PYTHONPATH": str(ROOT)}, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return out, run.stdout


def test_one_and_two_workers_give_the_same_arrays_bit_for_bit(one_and_two):
    out, _ = one_and_two
    one, two = _arrays(out / "1"), _arrays(out / "2")
    assert len(one) == len(CELLS) and one.keys() == two.keys()
    for name in one:
        assert one[name].keys() == two[name].keys() == {"test", "ref"}
        for k in one[name]:
            assert one[name][k].shape == (2, 3, 2, 2, 3)
            assert np.array_equal(one[name][k], two[name][k]), (name, k)
    first = next(iter(one.values()))
    assert not np.array_equal(first["test"], first["ref"])       # independent seeds: the arrays are renders


def test_the_suites_process_imports_neither_drjit_nor_mitsuba(one_and_two):
    assert "client imported: []" in one_and_two[1]


def test_a_worker_killed_mid_suite_costs_only_its_units(one_and_two, tmp_path):
    expected = _arrays(one_and_two[0] / "1")
    arrived, killed = [], []
    units = [u for c in CELLS for u in cell_units(c, SMALL, calibration.cell_path(c, tmp_path, SMALL))]
    with session("local", 2, quiet=True) as runner:
        def on_result(unit: Unit, result) -> None:
            arrived.append(unit.key)
            if not killed:           # the first result: kill a worker that is rendering a unit now
                busy = [w for w, keys in runner.client.processing().items() if keys]
                pids = runner.client.run(os.getpid, workers=busy[:1])
                for pid in pids.values():
                    os.kill(pid, signal.SIGKILL)
                killed.extend(pids)

        results = runner.run(units, "kill test", on_result)
    assert killed, "no worker was busy when the first result arrived"
    assert sorted(arrived) == sorted(u.key for u in units)       # every unit's result once, none twice
    for cell in CELLS:
        path = calibration.cell_path(cell, tmp_path, SMALL)
        data = calibration.assemble(cell_units(cell, SMALL, path), results)
        for k in ("test", "ref"):
            assert np.array_equal(data[k], expected[path.name][k])


@pytest.mark.parametrize("scheduler, workers", [("bogus", None), ("local", 0), ("none", 2), ("tcp://h:1", 2)])
def test_a_bad_scheduler_or_worker_count_is_refused(scheduler, workers):
    with pytest.raises(SchedulerError):
        check_scheduler(scheduler, workers)
