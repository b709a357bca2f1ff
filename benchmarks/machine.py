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
    """The virtualisation the machine runs under ("none" on bare metal), as systemd-detect-virt tells, else
    from the CPU's hypervisor flag and the kernel's name for it."""
    if shutil.which("systemd-detect-virt"):
        out = subprocess.run(["systemd-detect-virt"], capture_output=True, text=True).stdout.strip()
        if out:
            return out
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "unknown"
    if " hypervisor" not in flags:
        return "none"
    kind = Path("/sys/hypervisor/type")
    return kind.read_text().strip() if kind.exists() else "yes (unnamed)"


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


def one_line(m: dict[str, object]) -> str:
    return f"{m['cpu']}, {m['cores']} cores, hypervisor {m['hypervisor']}, Linux {m['kernel']}, Python {m['python']}"
