"""The machine a benchmark ran on, named so that figures from two machines are never confused."""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
from pathlib import Path


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _hypervisor() -> str:
    """The virtualisation the machine runs under: the virtual machine's kind and any container inside it
    ("none" on bare metal), as systemd-detect-virt tells, else from the CPU's hypervisor flag."""
    found = []
    if shutil.which("systemd-detect-virt"):
        for flag in ("--vm", "--container"):
            out = subprocess.run(["systemd-detect-virt", flag], capture_output=True, text=True).stdout.strip()
            if out and out != "none":
                found.append(out)
    try:
        cpu_flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        cpu_flags = ""
    if not any(kind != "docker" and kind != "lxc" for kind in found) and " hypervisor" in cpu_flags:
        kind = Path("/sys/hypervisor/type")
        found.insert(0, kind.read_text().strip() if kind.exists() else "a hypervisor (CPU flag)")
    return " + ".join(found) or "none"


def describe() -> dict[str, object]:
    """CPU model, cores, hypervisor, kernel, Python: for the report's header and its JSON."""
    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "hypervisor": _hypervisor(),
        "kernel": platform.release(),
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def cpu_times() -> tuple[int, int]:
    """(steal, total) of all CPUs since boot [clock ticks] from /proc/stat: steal is the time the hypervisor ran
    something else while this machine had work for its virtual CPU. (0, 0) where /proc/stat is not there."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    except OSError:
        return 0, 0
    ticks = [int(f) for f in fields[1:9]]  # user nice system idle iowait irq softirq steal
    return ticks[7], sum(ticks)


def process_cpu_seconds(pid: int) -> float:
    """User + system CPU time [s] that the live process ``pid`` has used (``/proc/PID/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def steal_ratio(before: tuple[int, int], after: tuple[int, int]) -> float:
    """The share of CPU time the hypervisor stole between two :func:`cpu_times` readings (0 on bare metal)."""
    total = after[1] - before[1]
    return (after[0] - before[0]) / total if total > 0 else 0.0


def one_line(m: dict[str, object]) -> str:
    return f"{m['cpu']}, {m['cores']} cores, hypervisor {m['hypervisor']}, Linux {m['kernel']}, Python {m['python']}"
