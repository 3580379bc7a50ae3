"""One runner for every suite: a suite is a list of independent units (a scene, a cell of the calibration
grid, ...), each a task whose result is an array or a verdict, run on Dask distributed.

- `--scheduler local` (the default): a `LocalCluster` on this machine, `workers` worker processes of one
  Dr.Jit thread each, as many as the cores (fewer where memory is short: WORKER_BYTES each). A suite's
  units are small renders (32 x 32 images) that keep one thread busy but not several, so the cores are
  better spent on units side by side; and with one thread per worker a unit's floating-point work (the
  film's atomic adds) is the same on any cluster, so a suite's results do not depend on the number of
  workers.
- `--scheduler tcp://HOST:PORT`: the same suite on an existing cluster (`dask scheduler`, `dask worker
  --nthreads 1` on each machine, the project importable there). Workers need no shared disk: every
  result travels to this process, the one writer of the caches and reports.
- `--scheduler none`: in this process, one unit after another (for debugging).

A unit's Dask key is its content key, so a unit submitted twice is computed once. A worker lost mid-suite
costs only the units it held (Dask computes them again elsewhere); a result counts once, when it reaches
this process. Ctrl-C cancels the suite's tasks and raises KeyboardInterrupt (`validate` exits 130);
results are written as they arrive, each file atomically, so nothing is half-written. The tracer and
Mitsuba are imported by the workers only: this process imports neither Dr.Jit nor Mitsuba."""
from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from tracer.errors import UserError

LOCAL, NONE = "local", "none"
PROTOCOLS = ("tcp://", "tls://", "inproc://", "ucx://")
WORKER_BYTES = 2 << 30          # a worker's peak memory, Mitsuba and Dr.Jit loaded, rendering a suite's unit
DRJIT_THREADS = 1               # per worker; see the module's docstring


@dataclass(frozen=True)
class Unit:
    key: str                    # unique within a suite and determined by the unit's content
    fn: Callable                # a module-level function (workers import it by name)
    args: tuple = ()


def cores() -> int:
    return len(os.sched_getaffinity(0))


def available_bytes() -> int:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 1 << 62


def default_workers() -> int:
    """As many workers as cores, each of DRJIT_THREADS thread, fewer where memory would not hold them."""
    return max(1, min(cores() // DRJIT_THREADS, available_bytes() // WORKER_BYTES))


class DrJitThreads(WorkerPlugin):
    """A worker plugin: Dr.Jit's thread pool set to `threads` when the worker starts."""

    name = "drjit-threads"
    idempotent = True

    def __init__(self, threads: int = DRJIT_THREADS):
        self.threads = threads

    def setup(self, worker=None) -> None:
        import drjit as dr

        dr.set_thread_count(self.threads)


class SchedulerError(UserError):
    """A --scheduler that names no scheduler, or one that cannot be reached."""


def check_scheduler(scheduler: str, workers: int | None = None) -> None:
    if scheduler not in (LOCAL, NONE) and not scheduler.startswith(PROTOCOLS):
        raise SchedulerError(f"--scheduler: expected 'local', 'none' or an address such as tcp://HOST:8786, got "
                             f"'{scheduler}'")
    if workers is not None and (workers < 1 or scheduler != LOCAL):
        raise SchedulerError("--workers takes a positive number and goes with --scheduler local only")


@contextmanager
def session(scheduler: str = LOCAL, workers: int | None = None, quiet: bool = False) -> Iterator["Runner"]:
    """A runner on the scheduler named as `--scheduler` names it; the local cluster is shut down after."""
    check_scheduler(scheduler, workers)
    if scheduler == NONE:
        yield Runner(None, quiet)
        return
    from distributed import Client, LocalCluster

    if scheduler == LOCAL:
        n = workers or default_workers()
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                          silence_logs=logging.CRITICAL) as cluster, Client(cluster) as client:
            client.register_plugin(DrJitThreads())
            yield Runner(client, quiet, f"a local cluster of {n} worker{'s' * (n > 1)} x {DRJIT_THREADS} Dr.Jit "
                                        f"thread ({cores()} cores)")
        return
    try:
        client = Client(scheduler, timeout="20s")
    except (OSError, TimeoutError) as e:
        raise SchedulerError(f"--scheduler {scheduler}: no Dask scheduler answers there ({e})") from None
    with client:
        client.register_plugin(DrJitThreads())
        n = len(client.scheduler_info()["workers"])
        yield Runner(client, quiet, f"the cluster at {scheduler} ({n} worker{'s' * (n != 1)} now)")


class Runner:
    def __init__(self, client, quiet: bool = False, where: str = "this process"):
        self.client, self.quiet, self.where = client, quiet, where
        self.seconds: dict[str, float] = {}        # a suite's wall time, by its description

    def dashboard(self) -> str | None:
        """The dashboard's address, where the scheduler runs one (the `bokeh` package installed)."""
        if self.client is None or "dashboard" not in self.client.scheduler_info().get("services", {}):
            return None
        return self.client.dashboard_link

    def run(self, units: Iterable[Unit], desc: str, on_result: Callable[[Unit, Any], None] | None = None) -> dict:
        """Every unit's result by its key, in the units' order; `on_result(unit, result)` runs in this process
        as each arrives (to write it to a cache)."""
        units = list({u.key: u for u in units}.values())
        start = time.perf_counter()
        results = (self._in_process if self.client is None else self._distributed)(units, desc, on_result)
        self.seconds[desc] = time.perf_counter() - start
        if not self.quiet and units:
            print(f"{desc}: {len(units)} tasks in {self.seconds[desc]:.1f} s on {self.where}", file=sys.stderr)
        return {u.key: results[u.key] for u in units}

    def _bar(self, total: int, desc: str):
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit="task", file=sys.stderr, disable=self.quiet or None)

    def _in_process(self, units: list[Unit], desc: str, on_result) -> dict:
        import drjit as dr

        threads = dr.thread_count()
        DrJitThreads().setup()
        results = {}
        try:
            with self._bar(len(units), desc) as bar:
                for u in units:
                    results[u.key] = u.fn(*u.args)
                    if on_result:
                        on_result(u, results[u.key])
                    bar.update()
        finally:
            dr.set_thread_count(threads)
        return results

    def _distributed(self, units: list[Unit], desc: str, on_result) -> dict:
        from distributed import as_completed

        link = self.dashboard()
        if link and not self.quiet:
            print(f"{desc}: {len(units)} tasks on {self.where}; dashboard {link}", file=sys.stderr)
        by_key = {u.key: u for u in units}
        futures = [self.client.submit(u.fn, *u.args, key=f"{desc}-{u.key}", pure=False, retries=0) for u in units]
        names = {f.key: u.key for f, u in zip(futures, units)}
        results = {}
        try:
            with self._bar(len(units), desc) as bar:
                for batch in as_completed(futures, with_results=True).batches():   # all that have arrived
                    for future, result in batch:
                        key = names[future.key]
                        results[key] = result
                        future.release()
                        if on_result:
                            on_result(by_key[key], result)
                        bar.update()
        except BaseException:
            self.client.cancel(futures)          # Ctrl-C or a unit's error: nothing of this suite runs on
            raise
        return results
