"""tracer/jit.py's host-side facts: the cores a process may use."""
import os

import pytest

from tracer import jit


@pytest.mark.parametrize("files, expected", [
    ({"/sys/fs/cgroup/cpu.max": "150000 100000"}, 2),                       # v2: 1.5 CPUs' worth, rounded up
    ({"/sys/fs/cgroup/cpu.max": "max 100000"}, None),                       # v2, no quota
    ({"/sys/fs/cgroup/cpu/cpu.cfs_quota_us": "100000",
      "/sys/fs/cgroup/cpu/cpu.cfs_period_us": "100000"}, 1),               # v1
    ({"/sys/fs/cgroup/cpu/cpu.cfs_quota_us": "-1",
      "/sys/fs/cgroup/cpu/cpu.cfs_period_us": "100000"}, None),            # v1, no quota
    ({}, None),                                                             # no cgroup files
])
def test_usable_cores_stay_within_the_containers_quota(monkeypatch, files, expected):
    def read(path):
        if path not in files:
            raise FileNotFoundError(path)
        return files[path]

    monkeypatch.setattr(jit, "_read", read)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(64)))
    assert jit.usable_cores() == (64 if expected is None else expected)


def test_usable_cores_are_at_most_those_the_process_may_run_on(monkeypatch):
    monkeypatch.setattr(jit, "_read", lambda path: "800000 100000" if path.endswith("cpu.max") else "")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    assert jit.usable_cores() == 2
