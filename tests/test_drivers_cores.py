"""drivers.cores: the cores a process may use, its cgroup's CPU quota included (fake cgroup trees in
tmp_path, laid out as the kernel mounts them: v2 unified, v2 under ``unified/`` beside v1, v1 ``cpu`` and
``cpu,cpuacct`` mounts, a v1 container whose listed path is not under its mount)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from drivers import cores
from drivers.camera.video_file import decoder_threads_per_file


def _tree(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def _limit(tmp_path: Path, listing: str, files: dict[str, str]) -> float | None:
    (tmp_path / "proc_cgroup").write_text(listing)
    _tree(tmp_path / "cg", files)
    return cores.cgroup_cpu_limit(tmp_path / "proc_cgroup", tmp_path / "cg")


@pytest.mark.parametrize(("listing", "files", "expected"), [
    # v2, a Kubernetes container's own limit (1.5 CPU) and its pod's (4 CPU): the tightest binds
    ("0::/kubepods/pod1/ctr\n", {"kubepods/pod1/ctr/cpu.max": "150000 100000\n",
                                 "kubepods/pod1/cpu.max": "400000 100000\n", "cpu.max": "max 100000\n"}, 1.5),
    # v2, the leaf unlimited, its parent (a systemd slice with CPUQuota=100%) limited
    ("0::/system.slice/rig.service\n", {"system.slice/rig.service/cpu.max": "max 100000\n",
                                        "system.slice/cpu.max": "100000 100000\n"}, 1.0),
    # v2 inside a cgroup namespace (Docker --cpus=2): the container's cgroup is the hierarchy's root
    ("0::/\n", {"cpu.max": "200000 100000\n"}, 2.0),
    # hybrid: v1 controllers and v2 under unified/, no quota anywhere
    ("3:cpu:/\n0::/user.slice\n", {"cpu/cpu.cfs_quota_us": "-1\n", "cpu/cpu.cfs_period_us": "100000\n",
                                    "unified/user.slice/cpu.max": "max 100000\n"}, None),
    # v1 mounted apart as cpu/ (this kind of VM), a 2-CPU quota
    ("4:cpu:/\n2:cpuacct:/\n", {"cpu/cpu.cfs_quota_us": "200000\n",
                                "cpu/cpu.cfs_period_us": "100000\n"}, 2.0),
    # v1 Docker without a cgroup namespace: /docker/<id> is listed, the mount is the container's own cgroup
    ("5:cpu,cpuacct:/docker/0123abc\n", {"cpu,cpuacct/cpu.cfs_quota_us": "50000\n",
                                         "cpu,cpuacct/cpu.cfs_period_us": "100000\n"}, 0.5),
    # unreadable values and lines: no quota known, no error
    ("garbage\n0::/x\n", {"x/cpu.max": "lots\n"}, None),
    ("", {}, None),
])
def test_the_tightest_quota_along_the_cgroup_path(tmp_path: Path, listing: str, files: dict[str, str],
                                                  expected: float | None) -> None:
    assert _limit(tmp_path, listing, files) == expected


def test_no_proc_listing_means_no_quota(tmp_path: Path) -> None:
    assert cores.cgroup_cpu_limit(tmp_path / "absent", tmp_path) is None


@pytest.mark.parametrize(("quota", "expected_cap"), [("50000 100000", 1), ("150000 100000", 2),
                                                     ("100000 100000", 1), ("max 100000", None)])
def test_usable_cores_are_the_affinity_capped_by_the_quota_rounded_up(tmp_path: Path, quota: str,
                                                                      expected_cap: int | None) -> None:
    (tmp_path / "proc_cgroup").write_text("0::/\n")
    _tree(tmp_path / "cg", {"cpu.max": quota})
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    usable = cores.usable_cores(tmp_path / "proc_cgroup", tmp_path / "cg")
    assert usable == (affinity if expected_cap is None else min(affinity, expected_cap))


def test_decoders_share_a_containers_quota_not_its_hosts_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 64-core host, a 2-CPU container: two videos get 1 decoder thread each, not 32."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)
    monkeypatch.setattr(cores, "cgroup_cpu_limit", lambda *paths: 2.0)
    assert decoder_threads_per_file(2) == 1
    monkeypatch.setattr(cores, "cgroup_cpu_limit", lambda *paths: None)
    assert decoder_threads_per_file(2) == 32
