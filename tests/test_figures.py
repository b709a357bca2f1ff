"""The x–y path figure: what it draws, read back from the PNG's pixels."""

from __future__ import annotations

import numpy as np
from matplotlib import colors, image

from groundstation.figures import write_path_figure


def pixels_of(png: np.ndarray, color: str, tol: float = 0.06) -> int:
    """How many pixels of the image are ``color`` (an RGB within ``tol``)."""
    rgb = np.array(colors.to_rgb(color))
    return int(np.count_nonzero(np.all(np.abs(png[:, :, :3] - rgb) < tol, axis=2)))


def test_the_path_figure_draws_the_measured_path_the_reference_and_home(tmp_path):
    th = np.linspace(0, 2 * np.pi, 500)
    x_ref, y_ref = 5 * np.sin(th), 5 * (1 - np.cos(th))
    x, y = 1.05 * x_ref, 1.05 * y_ref
    x_ref[:50] = np.nan  # the climb: not controlled yet
    path = write_path_figure(tmp_path, x, y, x_ref, y_ref, "test")
    assert path == tmp_path / "fig_xy_path.png"
    png = image.imread(path)
    assert pixels_of(png, "C0") > 1000  # the measured path (and its end)
    assert pixels_of(png, "C3") > 50  # home's star
    assert pixels_of(png, "k", tol=0.15) > 1000  # the dashed reference (and the axes)
    assert pixels_of(png, "C1") == 0  # no "commanded" stand-in when the telemetry has a reference


def test_without_a_reference_in_the_telemetry_the_commanded_path_stands_in(tmp_path):
    th = np.linspace(0, 2 * np.pi, 500)
    nan = np.full_like(th, np.nan)
    planned = (5 * np.sin(th), 5 * (1 - np.cos(th)))
    with_plan = image.imread(write_path_figure(tmp_path, 0 * th, 0 * th, nan, nan, "test", planned=planned))
    without = image.imread(write_path_figure(tmp_path, 0 * th, 0 * th, nan, nan, "test"))
    assert pixels_of(with_plan, "C1") > 200 and pixels_of(without, "C1") == 0
