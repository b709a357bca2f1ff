"""Truth against sensors, closed loop: the README's table and figures of docs/sensors.md's "Closed loop".

    python scripts/sensor_results.py [OUT_DIR]   (default: docs/figures)

For the paper's experiment and an x500 hover at 2 m (10 s), with both controllers, flies ``quadsitl sim`` on the
true state and on the default sensors (seed 0) and prints a Markdown table: settling times (2 %, of the truth),
the tracking RMS and the motor commands' standard deviation over the last 2 s, and the estimate's RMS error. It
writes sensors_paper_forces.png (the paper's motor commands, truth against sensors) and sensors_x500_hover.png
(the hover's altitude and roll, estimate against truth).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

from groundstation.metrics import channel_outputs, run_metrics
from groundstation.offline import run_offline
from quadsitl.config import SensorParams, load_preset
from quadsitl.state import Reference

TAIL = 2.0  # [s]: the steady part the RMS and σ are taken over


def cases():
    paper = load_preset("paper")
    x500 = load_preset("x500")
    hover = dataclasses.replace(x500, reference=Reference(2.0, 0.0, 0.0, 0.0),
                                sim=dataclasses.replace(x500.sim, duration=10.0))  # fmt: skip
    return {"paper's experiment": paper, "x500 hover at 2 m": hover}


def row(name: str, kind: str, state: str, res, preset) -> str:
    m = run_metrics(res.t, channel_outputs(res.state), res.reference, res.inputs)
    tail = res.t >= res.t[-1] - TAIL
    err = channel_outputs(res.state)[tail] - res.reference[tail]
    err[:, 3] = (err[:, 3] + math.pi) % (2 * math.pi) - math.pi
    settle = [m[c]["settling_time"] for c in ("altitude", "roll", "pitch", "yaw")]
    settle_txt = " / ".join("—" if s is None else f"{s:.2f}" for s in settle)
    rms = np.sqrt((err**2).mean(axis=0))
    sigma = res.forces[tail].std(axis=0).mean()
    if res.estimate is None:
        est = "—"
    else:
        e = res.estimate - res.state
        est = (f"{math.sqrt((e[:, 2] ** 2).mean()) * 100:.1f} cm, "
               f"{math.degrees(math.sqrt((e[:, 6:8] ** 2).mean())):.2f}°")  # fmt: skip
    return (f"| {name} | {kind} | {state} | {settle_txt} | {rms[0] * 100:.2f} cm, "
            f"{math.degrees(rms[1:3].mean()):.3f}° | {sigma:.3g} N | {est} |")  # fmt: skip


def main(out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    print(
        "| flight | controller | state | settling [s]: altitude / roll / pitch / yaw | tracking RMS, last 2 s: "
        "altitude, roll & pitch | motor command σ, last 2 s | estimate RMS: altitude, roll & pitch |"
    )
    print("|---|---|---|---|---|---|---|")
    runs = {}
    for name, preset in cases().items():
        for state in ("truth", "sensors"):
            p = dataclasses.replace(preset, sensors=SensorParams() if state == "sensors" else None)
            results, _ = run_offline(p, ["backstepping", "pd"])
            for kind, res in results.items():
                runs[name, kind, state] = res
                print(row(name, kind, state, res, p))
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for ax, kind in zip(axes, ("backstepping", "pd")):
        for state, color in (("sensors", "tab:orange"), ("truth", "tab:blue")):  # the truth drawn over
            res = runs["paper's experiment", kind, state]
            ax.plot(res.t, res.forces[:, 0], color=color, lw=0.8, label=f"{state}")
        ax.set_ylabel(f"{kind}: F1 [N]")
        ax.legend(loc="upper right")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("The paper's experiment: motor 1's command on the true state and on the default sensors")
    fig.tight_layout()
    fig.savefig(out / "sensors_paper_forces.png", dpi=110)
    res = runs["x500 hover at 2 m", "backstepping", "sensors"]
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    axes[0].plot(res.t, -res.state[:, 2], lw=0.9, label="truth")
    axes[0].plot(res.t, -res.estimate[:, 2], lw=0.9, label="estimate")
    axes[0].set_ylabel("altitude [m]")
    axes[1].plot(res.t, np.degrees(res.state[:, 6]), lw=0.9, label="truth")
    axes[1].plot(res.t, np.degrees(res.estimate[:, 6]), lw=0.9, label="estimate")
    axes[1].set_ylabel("roll [deg]")
    axes[1].set_xlabel("t [s] (after 2 s on the ground)")
    for ax in axes:
        ax.legend(loc="lower right")
        ax.grid(alpha=0.3)
    fig.suptitle("x500 hover on the default sensors, backstepping: the estimate it flies on, and the truth")
    fig.tight_layout()
    fig.savefig(out / "sensors_x500_hover.png", dpi=110)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs/figures"))
