"""``quadsitl fly``: plant, autopilot and ground station as separate OS processes on free loopback ports.

It waits for the ground station to finish the flight, then writes metrics.json and the figures from
the Zenoh-logged telemetry.csv, exactly as ``quadsitl sim`` does. If any child fails, it exits non-zero
naming the process. Every child is torn down on exit, Ctrl-C and SIGTERM (SIGTERM, then SIGKILL after
3 s for a child that hangs), and each child asks the kernel to end it if the launcher itself dies.
"""

from __future__ import annotations

import contextlib
import json
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundstation.figures import write_figures
from groundstation.metrics import outputs_from_columns, run_metrics
from groundstation.telemetry_csv import read_csv
from quadsitl.config import Preset


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port the OS says is free on 127.0.0.1 now (UDP by default, TCP with SOCK_STREAM)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Children:
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)

    def start(self, name: str, args: list[str]) -> None:
        self.procs[name] = subprocess.Popen([sys.executable, "-m", *args])

    def first_failure(self, done: str) -> tuple[str, int] | None:
        """(name, status) of a child that exited when it should not have; ``done`` may exit with 0."""
        for name, p in self.procs.items():
            rc = p.poll()
            if rc is not None and not (name == done and rc == 0):
                return name, rc
        return None

    def stop(self, grace: float = 3.0) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.terminate()
        end = time.monotonic() + grace
        for p in self.procs.values():
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(max(0.0, end - time.monotonic()))
        for p in self.procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()


def describe(name: str, status: int) -> str:
    if status < 0:
        return f"the {name} process was killed by signal {-status} ({signal.Signals(-status).name})"
    return f"the {name} process exited with status {status}"


def fly(preset_name: str, preset: Preset, args) -> int:
    """Run one flight; returns the exit status for the ``quadsitl fly`` command."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plant_port, gcs_port, zenoh_port = free_port(), free_port(), free_port(socket.SOCK_STREAM)
    zenoh_ep = f"tcp/127.0.0.1:{zenoh_port}"
    quiet = ["--quiet"] if args.quiet else []
    children = Children()

    def on_signal(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_signal)
    try:
        ap = ["autopilot", "--preset", preset_name, "--plant-listen", f"127.0.0.1:{plant_port}",
              "--api-listen", f"127.0.0.1:{gcs_port}", "--api-remote", "none", "--gcs-listen",
              f"127.0.0.1:{free_port()}", "--gcs-remote", "none", "--zenoh-listen", zenoh_ep]  # fmt: skip
        if args.controller:
            ap += ["--controller", args.controller]
        children.start("autopilot", ap)
        plant = [
            "sitl",
            "--preset",
            preset_name,
            "--autopilot",
            f"127.0.0.1:{plant_port}",
            "--speed",
            str(args.speed),
        ]
        if args.integrator:
            plant += ["--integrator", args.integrator]
        children.start("plant", plant)
        gcs = ["groundstation", "--preset", preset_name, "--connect", f"127.0.0.1:{gcs_port}",
               "--zenoh-connect", zenoh_ep, "--trajectory", args.trajectory, "--out", str(out), *quiet]  # fmt: skip
        if args.duration:
            gcs += ["--duration", str(args.duration)]
        children.start("gcs", gcs)
        while True:
            failure = children.first_failure(done="gcs")
            if failure:
                print(f"quadsitl fly: error: {describe(*failure)}; stopping the others", file=sys.stderr)
                return 1
            if children.procs["gcs"].poll() == 0:
                break
            time.sleep(0.05)
    except KeyboardInterrupt:
        print("quadsitl fly: interrupted; stopping plant, autopilot and ground station", file=sys.stderr)
        return 130
    finally:
        children.stop()
        signal.signal(signal.SIGTERM, old)
    write_report(out, preset, args)
    return 0


def write_report(out: Path, preset: Preset, args) -> None:
    """metrics.json and the figures from telemetry.csv."""
    data = read_csv(out / "telemetry.csv")
    t = data["t"]
    y = outputs_from_columns(data["altitude"], data["roll"], data["pitch"], data["yaw"])
    ref = np.column_stack([data[c] for c in ("altitude_ref", "roll_ref", "pitch_ref", "yaw_ref")])
    u = np.column_stack([data[c] for c in ("u1", "u2", "u3", "u4")])
    kind = args.controller or preset.controller.type
    metrics = {kind: run_metrics(t, y, ref, u)}
    settings = {"mode": "lockstep", "speed": args.speed, "duration": float(len(t) * preset.sim.period),
                "period": preset.sim.period, "trajectory": args.trajectory}  # fmt: skip
    (out / "metrics.json").write_text(json.dumps({"preset": preset.name, **settings, "runs": metrics}, indent=2) + "\n")
    if not args.no_figures:
        write_figures({kind: {"t": t, "outputs": y, "reference": ref, "inputs": u}}, out, f"preset {preset.name}, fly")
    if not args.quiet:
        from groundstation.metrics import format_table

        print(format_table(metrics))
        print(f"wrote {out}/telemetry.csv, flight.tlog, metrics.json and figures")
