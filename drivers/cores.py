"""The CPU cores this process may use: its affinity set, capped by the CPU quota of its cgroup.

A container (Docker ``--cpus``, a Kubernetes CPU limit, a systemd ``CPUQuota``) usually sees every core of
its host, in ``os.cpu_count()`` and in its affinity set; its quota says how much of them it may use. Work
split over more threads or processes than that is throttled, not faster: each extra decoder thread costs
CPU in hand-overs, each extra batch worker the memory of its frames. The quota is read from cgroup v2
(``cpu.max``: "QUOTA PERIOD" or "max PERIOD") and v1 (``cpu.cfs_quota_us`` / ``cpu.cfs_period_us``, −1 for
none), in every directory from the process's own cgroup (``/proc/self/cgroup``) up to the hierarchy's root
(a parent's limit binds its children; inside a container the hierarchy's root is usually the container's
own cgroup). A quota of Q µs of CPU per period of P µs allows ⌈Q / P⌉ cores, rounded up as the JVM and dask
do (a 1.5-CPU container runs 2 threads, each throttled a little). Linux only: elsewhere there is no quota.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path

__all__ = ["cgroup_cpu_limit", "usable_cores"]

PROC_CGROUP = Path("/proc/self/cgroup")
CGROUP_ROOT = Path("/sys/fs/cgroup")


def usable_cores(proc_cgroup: Path = PROC_CGROUP, cgroup_root: Path = CGROUP_ROOT) -> int:
    """Cores this process may use (≥ 1): its affinity set (``os.cpu_count()`` where there is none), at most
    the cgroup quota rounded up (:func:`cgroup_cpu_limit`)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    limit = cgroup_cpu_limit(proc_cgroup, cgroup_root)
    return max(1, cores if limit is None else min(cores, math.ceil(limit)))


def cgroup_cpu_limit(proc_cgroup: Path = PROC_CGROUP, cgroup_root: Path = CGROUP_ROOT) -> float | None:
    """The tightest CPU quota over the process's cgroups (cores, e.g. 1.5), None when none is set or the
    files cannot be read. ``proc_cgroup``: the ``/proc/<pid>/cgroup`` listing; ``cgroup_root``: where the
    hierarchies are mounted (v2 there or in ``unified/``, v1 in ``cpu/`` or a directory named by its
    controller list)."""
    try:
        listing = proc_cgroup.read_text()
    except OSError:
        return None
    limits: list[float] = []
    for line in listing.splitlines():
        fields = line.split(":", 2)
        if len(fields) != 3:
            continue
        _, controllers, path = fields
        if controllers == "":  # the v2 (unified) hierarchy
            limits += _limits_along(path, (cgroup_root, cgroup_root / "unified"), _v2_limit)
        elif "cpu" in controllers.split(","):
            limits += _limits_along(path, (cgroup_root / "cpu", cgroup_root / controllers), _v1_limit)
    return min(limits, default=None)


def _limits_along(path: str, mounts: tuple[Path, ...], read: Callable[[Path], float | None]) -> list[float]:
    """The quotas (cores) found in ``path`` and its ancestors under each existing mount of the hierarchy."""
    found: list[float] = []
    for mount in dict.fromkeys(m for m in mounts if m.is_dir()):  # the same directory once
        directory = mount / path.strip("/")
        while True:
            limit = read(directory) if directory.is_dir() else None
            if limit is not None:
                found.append(limit)
            if directory == mount:
                break
            directory = directory.parent
    return found


def _v2_limit(directory: Path) -> float | None:
    """``cpu.max`` of a v2 cgroup as cores, None for "max", a missing or unreadable file."""
    try:
        quota, period = (directory / "cpu.max").read_text().split()
        return _cores(int(quota), int(period)) if quota != "max" else None
    except (OSError, ValueError):
        return None


def _v1_limit(directory: Path) -> float | None:
    """``cpu.cfs_quota_us`` / ``cpu.cfs_period_us`` of a v1 cgroup as cores, None for −1 (no quota) or
    missing, unreadable files."""
    try:
        quota = int((directory / "cpu.cfs_quota_us").read_text())
        period = int((directory / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None
    return _cores(quota, period)


def _cores(quota_us: int, period_us: int) -> float | None:
    return quota_us / period_us if quota_us > 0 and period_us > 0 else None
