"""``facestats.core.processes.available_memory``: MemAvailable and the memory limits of control groups."""

import os

from facestats.core.processes import available_memory

GiB = 2**30


def _files(root, files):
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def _meminfo(gib):
    return f"MemTotal:       {int(gib * 2 * GiB / 1024)} kB\nMemAvailable:   {int(gib * GiB / 1024)} kB\n"


def test_a_cgroup_v2_limit_bounds_the_memory_available(tmp_path):
    """In a container MemAvailable is the host's (64 GiB here): the 2 GiB limit of the process's group, less its
    working set (usage 1.5 GiB minus 0.5 GiB of inactive file cache, which the kernel reclaims first), leaves 1 GiB;
    a group above it with less room (1.2 GiB limit, 1.0 GiB used) bounds it further."""
    group = "sys/fs/cgroup/user.slice/job"
    root = _files(
        tmp_path,
        {
            "proc/meminfo": _meminfo(64),
            "proc/self/cgroup": "0::/user.slice/job\n",
            f"{group}/memory.max": f"{2 * GiB}\n",
            f"{group}/memory.current": f"{int(1.5 * GiB)}\n",
            f"{group}/memory.stat": f"anon 123\ninactive_file {GiB // 2}\nactive_file 7\n",
            "sys/fs/cgroup/user.slice/memory.max": "max\n",
            "sys/fs/cgroup/user.slice/memory.current": f"{5 * GiB}\n",
        },
    )
    assert available_memory(root) == 1 * GiB
    _files(root, {"sys/fs/cgroup/user.slice/memory.max": f"{int(1.2 * GiB)}\n"})
    _files(root, {"sys/fs/cgroup/user.slice/memory.current": f"{1 * GiB}\n"})
    assert abs(available_memory(root) - 0.2 * GiB) < 1
    _files(root, {f"{group}/memory.max": "max\n", "sys/fs/cgroup/user.slice/memory.max": "max\n"})
    assert available_memory(root) == 64 * GiB  # no limit: the machine's


def test_a_cgroup_v1_limit_and_a_namespaced_path(tmp_path):
    """cgroup v1 (memory.limit_in_bytes, usage, total_inactive_file); in a container's own namespace the path in
    /proc/self/cgroup does not exist under the mount, which is the container's group: the mount's files count.
    v1 writes "no limit" as 2^63 rounded to a page."""
    mount = "sys/fs/cgroup/memory"
    root = _files(
        tmp_path,
        {
            "proc/meminfo": _meminfo(64),
            "proc/self/cgroup": "9:pids:/x\n4:memory,hugetlb:/docker/abc\n0::/\n",
            f"{mount}/memory.limit_in_bytes": f"{3 * GiB}\n",
            f"{mount}/memory.usage_in_bytes": f"{2 * GiB}\n",
            f"{mount}/memory.stat": f"cache 5\ntotal_inactive_file {GiB}\n",
        },
    )
    assert available_memory(root) == 2 * GiB
    _files(root, {f"{mount}/memory.limit_in_bytes": "9223372036854771712\n"})
    assert available_memory(root) == 64 * GiB


def test_missing_or_malformed_proc_files_fall_back_to_the_physical_memory(tmp_path):
    """No /proc at all, or a MemAvailable line that is no number (ValueError escaped): the physical memory."""
    physical = float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    assert available_memory(tmp_path) == physical
    _files(tmp_path, {"proc/meminfo": "MemAvailable: lots kB\n", "proc/self/cgroup": "garbage\n0::\n"})
    assert available_memory(tmp_path) == physical
    _files(tmp_path, {"proc/meminfo": "MemAvailable:\n"})
    assert available_memory(tmp_path) == physical
    assert 0 < available_memory() <= physical  # this machine
