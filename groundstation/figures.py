"""Figures that reproduce the paper's Figures 2–4: outputs against references, errors, inputs."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

LABELS = ("altitude h [m]", "roll φ [rad]", "pitch θ [rad]", "yaw ψ [rad]")
ERROR_LABELS = ("e1 = h − h_d [m]", "e3 = φ − φ_d [rad]", "e5 = θ − θ_d [rad]", "e7 = ψ − ψ_d [rad]")
INPUT_LABELS = ("u1 [N]", "u2 [N]", "u3 [N]", "u4 [N·m]")
STYLES = {"backstepping": dict(color="C0", lw=1.6), "pd": dict(color="C3", lw=1.2, ls="--")}


def write_figures(runs: dict[str, dict[str, np.ndarray]], out: Path, title: str) -> list[Path]:
    """``runs``: {controller: {"t", "outputs", "reference", "inputs"}}. Writes three PNGs into ``out``."""
    paths = []
    specs = [
        ("fig2_outputs.png", "Outputs and references (paper Fig. 2)", LABELS, "outputs"),
        ("fig3_errors.png", "Tracking errors (paper Fig. 3)", ERROR_LABELS, "errors"),
        ("fig4_inputs.png", "Control inputs (paper Fig. 4)", INPUT_LABELS, "inputs"),
    ]
    for filename, heading, labels, what in specs:
        fig, axes = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
        for name, run in runs.items():
            y = run["outputs"]
            ref = run["reference"]
            series = {"outputs": y, "errors": y - ref, "inputs": run["inputs"]}[what]
            if what == "errors":
                series[:, 3] = np.angle(np.exp(1j * series[:, 3]))
            for i, ax in enumerate(axes.flat):
                ax.plot(run["t"], series[:, i], label=name, **STYLES.get(name, {}))
                if what == "outputs" and name == next(iter(runs)):
                    ax.plot(run["t"], ref[:, i], color="k", lw=0.9, ls=":", label="reference")
        for i, ax in enumerate(axes.flat):
            ax.set_ylabel(labels[i])
            ax.grid(True, alpha=0.3)
            if i >= 2:
                ax.set_xlabel("t [s]")
        axes.flat[0].legend(loc="best", fontsize=8)
        fig.suptitle(f"{heading} — {title}")
        fig.tight_layout()
        path = out / filename
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths
