"""Backstepping, PD, PX4's cascade and the template on the same work: docs/controllers.md's tables and figures.

    python scripts/controller_results.py [OUT_DIR]   (default: docs/figures)

Flies ``quadsitl sim`` (groundstation.offline.run_offline) on the paper's experiment, the x500's circle, and the
x500 holding 5 m on its sensors in a 6 m/s wind from the west with moderate turbulence (wind and sensor seeds 0);
runs the paper-mass-mismatch sweep (200 trials) with each controller; prints Markdown tables and writes
controllers_paper.png (altitude and roll of the paper's step), controllers_circle.png and controllers_hold.png
(the paths from above).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from groundstation.metrics import channel_outputs, run_metrics
from groundstation.offline import run_offline, tracking
from groundstation.sweep.run import run_sweep
from groundstation.sweep.spec import load_spec
from quadsitl.config import SensorParams, WindParams, load_preset

ROOT = Path(__file__).resolve().parent.parent
TEMPLATE = f"{ROOT / 'examples' / 'controllers' / 'template.py'}:Template"
CONTROLLERS = {"backstepping": "backstepping", "pd": "pd", "px4": "px4", "template": TEMPLATE}
STYLE = {"backstepping": "C0", "pd": "C3", "px4": "C2", "template": "C4"}


def paper(out: Path) -> None:
    preset = load_preset("paper")
    runs, _ = run_offline(preset, list(CONTROLLERS.values()))
    print("\n### The paper's experiment\n")
    print("| controller | altitude rise [s] | altitude settle [s] | altitude error at 5 s [m] | roll rise [s] | "
          "roll overshoot | peak u1 [N] |\n|---|---|---|---|---|---|---|")  # fmt: skip
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for name, spec in CONTROLLERS.items():
        r = runs[spec]
        m = run_metrics(r.t, channel_outputs(r.state), r.reference, r.inputs)
        a, ro = m["altitude"], m["roll"]

        def f(v: float | None, fmt: str = ".3f") -> str:
            return "—" if v is None or v != v else format(v, fmt)

        print(f"| {name} | {f(a['rise_time'])} | {f(a['settling_time'])} | {f(a['steady_state_error'])} | "
              f"{f(ro['rise_time'])} | {f(ro['overshoot_pct'], '.1f')} % | {f(a['peak_abs_u'], '.1f')} |")  # fmt: skip
        y = channel_outputs(r.state)
        axes[0].plot(r.t, y[:, 0], color=STYLE[name], label=name)
        axes[1].plot(r.t, np.degrees(y[:, 1]), color=STYLE[name], label=name)
    axes[0].set(xlabel="t [s]", ylabel="altitude [m]", title="the paper's step: altitude (reference 5 m)")
    axes[1].set(xlabel="t [s]", ylabel="roll [deg]", title="roll (reference 60°)")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(out / "controllers_paper.png", dpi=90)
    plt.close(fig)


def paths(title: str, preset, trajectory: str, file: Path) -> None:
    runs, _ = run_offline(preset, list(CONTROLLERS.values()), trajectory=trajectory)
    track = tracking(runs)
    print(f"\n### {title}\n")
    print("| controller | horizontal RMS [m] | horizontal max [m] | altitude RMS [m] |\n|---|---|---|---|")
    fig, ax = plt.subplots(figsize=(5.6, 5.0))
    for name, spec in CONTROLLERS.items():
        t = track[spec]
        print(f"| {name} | {t['horizontal_rms']:.3f} | {t['horizontal_max']:.3f} | {t['altitude_rms']:.3f} |")
        r = runs[spec]
        ax.plot(r.state[:, 1], r.state[:, 0], color=STYLE[name], lw=1.0, label=name)
    r = runs["backstepping"]
    ax.plot(r.position_reference[:, 1], r.position_reference[:, 0], "k--", lw=0.8, label="reference")
    ax.set(xlabel="east [m]", ylabel="north [m]", title=title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(file, dpi=90)
    plt.close(fig)


def sweep() -> None:
    base = load_spec("paper-mass-mismatch").with_trials(200)
    print("\n### The paper's step with the model's mass and inertias off by up to ±20 % (200 trials)\n")
    print("| controller | altitude error at 5 s, p5 / p50 / p95 [m] | roll settle p50 [s] | diverged |")
    print("|---|---|---|---|")
    for name in ("backstepping", "pd", "px4"):
        spec = dataclasses.replace(base, controller=name)
        res = run_sweep(spec, workers=2)
        table = res.table
        sse, settle = table["altitude_steady_state_error"], table["roll_settling_time"]
        p5, p50, p95 = np.nanpercentile(sse, [5, 50, 95])
        settled = f"{np.nanmedian(settle):.3f}" if np.isfinite(settle).any() else "—"
        print(f"| {name} | {p5:.3f} / {p50:.3f} / {p95:.3f} | {settled} | {int(np.nansum(table['diverged']))} |")


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "figures"
    out.mkdir(parents=True, exist_ok=True)
    paper(out)
    x500 = load_preset("x500")
    paths("The x500's circle (truth, calm)", x500, "circle", out / "controllers_circle.png")
    windy = dataclasses.replace(x500, sensors=SensorParams(),
                                wind=dataclasses.replace(WindParams(), speed_m_s=6.0, from_deg=270.0,
                                                         turbulence="moderate"))  # fmt: skip
    paths("The x500 holding 5 m on its sensors, 6 m/s wind, moderate turbulence", windy,
          "hold:altitude=5,duration=30", out / "controllers_hold.png")  # fmt: skip
    sweep()


if __name__ == "__main__":
    main()
