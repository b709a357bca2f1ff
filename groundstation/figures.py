"""Figures that reproduce the paper's Figures 2–4: outputs against references, errors, inputs; for a
position trajectory, the x–y path against its reference (:func:`write_path_figure`); for a mission, the x–y
path over the plan's waypoints (:func:`write_mission_figure`)."""

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


def _finish_map(fig, ax, x: np.ndarray, y: np.ndarray, title: str, path: Path, fontsize: float | None = None) -> Path:
    """The part of a map seen from above (x north up, y east right [m]) every map has: the measured path, its end,
    home at the origin, equal scales; saved to ``path``."""
    ax.plot(y, x, color="C0", lw=1.6, label="measured", zorder=3)
    if len(x):
        ax.plot(y[-1], x[-1], marker="o", color="C0", ms=6, ls="none", label="end")
    ax.plot(0.0, 0.0, marker="*", color="C3", ms=14, ls="none", label="home")
    ax.set_xlabel("y (east) [m]")
    ax.set_ylabel("x (north) [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title, fontsize=fontsize)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_path_figure(
    out: Path,
    x: np.ndarray,
    y: np.ndarray,
    x_ref: np.ndarray,
    y_ref: np.ndarray,
    title: str,
    planned: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """``fig_xy_path.png`` in ``out``: the measured path (x north up, y east right [m], local NED, seen from
    above) against the autopilot's reference x_ref, y_ref (where finite), home at the origin marked. When
    the telemetry has no finite reference, ``planned`` (the ground station's commanded x, y) is drawn in its
    place, labelled as such."""
    fig, ax = plt.subplots(figsize=(7, 6.5))
    finite = np.isfinite(x_ref) & np.isfinite(y_ref)
    if finite.any():
        ref_x, ref_y = np.where(finite, x_ref, np.nan), np.where(finite, y_ref, np.nan)
        ax.plot(ref_y, ref_x, color="k", lw=1.0, ls="--", label="reference (x_ref, y_ref)")
    elif planned is not None:
        ax.plot(planned[1], planned[0], color="C1", lw=1.2, ls=":", label="commanded (no x_ref in the telemetry)")
    return _finish_map(fig, ax, x, y, f"x–y path, seen from above — {title}", out / "fig_xy_path.png")


def write_mission_figure(out: Path, data: dict[str, np.ndarray], mission: dict, title: str) -> Path:
    """``fig_mission_path.png`` in ``out``: the measured x–y path (north up, east right [m], local NED from the
    origin, seen from above) over the plan: its items with a position (``mission.json``'s north, east), numbered
    by seq and joined in order from home, home marked."""
    fig, ax = plt.subplots(figsize=(7, 6.5))
    placed = [it for it in mission["items"] if "north" in it]
    if placed:
        north = [0.0] + [it["north"] for it in placed]
        east = [0.0] + [it["east"] for it in placed]
        ax.plot(east, north, color="k", lw=1.0, ls="--", label="plan", zorder=2)
        ax.plot(east[1:], north[1:], marker="s", color="C1", ms=7, ls="none", label="plan items", zorder=4)
        for it in placed:
            ax.annotate(str(it["seq"]), (it["east"], it["north"]), textcoords="offset points", xytext=(6, 6))
    return _finish_map(fig, ax, data["x"], data["y"], f"mission path, seen from above — {title}",
                       out / "fig_mission_path.png", fontsize=10)  # fmt: skip


def write_formation_figure(out: Path, plan, t: np.ndarray, track: np.ndarray, series: dict, title: str) -> Path:
    """``fig_formation.png`` in ``out``: every vehicle's path seen from above (north up, east right [m], from the
    first vehicle's home; :mod:`groundstation.formation`) over its planned path, its start and end marked; and over
    time, the largest formation error among the vehicles and the smallest separation between two, the phases'
    starts marked."""
    fig = plt.figure(figsize=(12, 6.5))
    ax = fig.add_subplot(1, 2, 1)
    planned = plan.along(t[:: max(1, len(t) // 600)])[0]
    for i in range(len(track)):
        color = f"C{i % 10}"
        ax.plot(planned[i, :, 1], planned[i, :, 0], color=color, lw=0.9, ls=":")
        ax.plot(track[i, :, 1], track[i, :, 0], color=color, lw=1.4, label=f"v{i + 1}")
        ax.plot(track[i, 0, 1], track[i, 0, 0], marker="s", color=color, ms=5, ls="none")
        ax.plot(track[i, -1, 1], track[i, -1, 0], marker="o", color=color, ms=5, ls="none")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=7, ncol=2, title="flown (dotted: planned; ■ start, ● end)", title_fontsize=7)
    ax.set_title(f"paths seen from above — {title}", fontsize=10)
    top, bottom = fig.add_subplot(2, 2, 2), fig.add_subplot(2, 2, 4, sharex=None)
    top.plot(series["t"], series["formation_max_m"], color="C3", lw=1.2)
    top.set_ylabel("formation error, worst vehicle [m]")
    bottom.plot(series["t"], series["separation_min_m"], color="C0", lw=1.2)
    bottom.axhline(plan.spacing, color="k", lw=0.8, ls="--", label=f"spacing {plan.spacing:g} m")
    bottom.set_ylabel("smallest separation [m]")
    bottom.set_xlabel("t [s] (0: every vehicle armed)")
    bottom.legend(loc="best", fontsize=8)
    for axis in (top, bottom):
        for name, start in zip(("take off", "form up", "translate", "rotate", "hold", "land"), plan.times,
                               strict=True):  # fmt: skip
            axis.axvline(start, color="0.6", lw=0.7)
            axis.text(start, 1.0, f" {name}", transform=axis.get_xaxis_transform(), fontsize=7, va="top",
                      rotation=90, color="0.4")  # fmt: skip
        axis.grid(True, alpha=0.3)
    fig.tight_layout()
    path = out / "fig_formation.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
