"""What every command promises its user: --help with examples, one-line errors (never a traceback),
and progress on stderr that --quiet silences."""

import io
import os
import re
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from groundstation.offline import run_offline
from groundstation.progress import FlightProgress, announce_if_slow, format_eta
from quadsitl.config import load_preset

COMMANDS = ["sim", "fly", "up", "presets", "gains", "sweep", "plant", "autopilot", "gcs", "bench", "router"]
# "gcs: flight t = 4.10 / 5 s, 2.0× real time, ETA 1 s"
PROGRESS_LINE = re.compile(r"^gcs: flight t = \d+\.\d\d / 5 s, \d+\.\d× real time, ETA (\d+ s|\d+:\d\d)$", re.M)
DONE_LINE = re.compile(r"^gcs: flight t = 5\.00 / 5 s, \d+\.\d× real time, done in \d+\.\d s$", re.M)


def quadsitl(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """The ``quadsitl`` command as a real process, output captured (so stderr is not a terminal)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "groundstation.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)


# ---- --help ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_has_help_with_examples(command):
    r = quadsitl(command, "--help")
    assert r.returncode == 0, r.stderr
    assert "examples:" in r.stdout
    assert f"quadsitl {command}" in r.stdout.split("examples:", 1)[1]  # the examples are of this command


# ---- one-line errors -------------------------------------------------------------------------------


def assert_one_line_error(r: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


@pytest.mark.parametrize("command", ["sim", "fly", "up", "gcs", "presets"])
def test_unknown_preset_names_the_available_ones(command, tmp_path):
    args = ["nosuch"] if command == "presets" else ["--preset", "nosuch"]
    out = ["--out", str(tmp_path / "out")] if command in ("sim", "fly", "gcs") else []
    r = quadsitl(command, *args, *out, timeout=30)
    assert r.returncode == 2
    line = assert_one_line_error(r)
    assert line.startswith(f"quadsitl {command}: error: ")
    assert "unknown preset 'nosuch'" in line and "paper" in line and "x500" in line
    assert r.stdout == ""


@pytest.mark.parametrize("command", ["sim", "fly", "up", "plant"])
@pytest.mark.parametrize(
    ("option", "message"),
    [
        (("--wind", "60,270"), "--wind 60,270: wind.speed_m_s = 60.0: expected a number in [0, 50] m/s"),
        (("--wind", "5"), "--wind '5': expected 2 comma-separated finite numbers"),
        (("--gust", "3,400,1"), "--gust 3,400,1: wind.gust_from_deg = 400.0: expected a number in [0, 360] deg"),
        (("--gust", "3,90,1,0"), "--gust 3,90,1,0: wind.gust_rise_s = 0.0: expected a number in (0, 100] s"),
        (("--gust", "3"), "--gust '3': expected 2 to 4 comma-separated numbers: SPEED,FROM[,START[,RISE]]"),
        (("--wind-seed", "-3"), "--wind-seed -3: wind.seed = -3: expected an integer in [0, 2**63 - 1]"),
        (("--turbulence", "gale"), "argument --turbulence: invalid choice: 'gale' (choose from 'none', 'light', "
                                   "'moderate', 'severe')"),  # argparse's own: its usage, then this line
    ],
)  # fmt: skip
def test_a_bad_wind_option_is_one_line_naming_the_option_the_key_and_what_is_allowed(command, option, message,
                                                                                      tmp_path):  # fmt: skip
    """Refused before any process starts (the plant: before it binds its port)."""
    extra = {"sim": ["--out", str(tmp_path / "o")], "fly": ["--out", str(tmp_path / "o")],
             "plant": ["--autopilot", "127.0.0.1:9"], "up": []}[command]  # fmt: skip
    r = quadsitl(command, *option, *extra, timeout=30)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert message in (r.stderr.strip().splitlines()[-1] if "choose from" in message else assert_one_line_error(r))
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["fly", "gcs"])
@pytest.mark.parametrize(
    ("trajectory", "message"),
    [
        ("circle:radius=-2", "--trajectory 'circle:radius=-2': radius = -2: expected a number in (0, 1000] m"),
        ("figure8:period=x", "--trajectory 'figure8:period=x': period='x' is not a number; expected figure8[:size=M]"),
        ("helix", "--trajectory 'helix': expected step, ramp, sine, circle[:...], figure8[:...], hold[:...] or an "
                  "existing CSV"),
        ("BAD_CSV", "bad.csv, line 3, column altitude: 'high' is not a number"),
    ],
)  # fmt: skip
def test_a_bad_trajectory_is_one_line_naming_the_option_or_the_file(command, trajectory, message, tmp_path):
    if trajectory == "BAD_CSV":
        trajectory = str(tmp_path / "bad.csv")
        (tmp_path / "bad.csv").write_text("t,x,y,altitude,yaw\n0,0,0,2,0\n5,1,1,high,0\n")
    r = quadsitl(command, "--trajectory", trajectory, "--out", str(tmp_path / "out"), timeout=30)
    assert r.returncode == 2
    line = assert_one_line_error(r)
    assert line.startswith(f"quadsitl {command}: error: ") and message in line, line
    assert r.stdout == ""


@pytest.fixture
def busy_port():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    yield sock.getsockname()[1]
    sock.close()


@pytest.mark.parametrize(
    ("command", "option", "extra"),
    [
        ("autopilot", "--gcs-listen", ["--no-zenoh"]),
        ("autopilot", "--api-listen", ["--no-zenoh"]),
        ("autopilot", "--plant-listen", ["--no-zenoh"]),
        ("plant", "--bind", ["--autopilot", "127.0.0.1:9"]),
    ],
)
def test_busy_port_names_the_port_and_the_option(busy_port, command, option, extra):
    r = quadsitl(command, option, f"127.0.0.1:{busy_port}", *extra, timeout=30)
    assert r.returncode != 0
    line = assert_one_line_error(r)
    assert str(busy_port) in line and option in line and "in use" in line


# ---- progress --------------------------------------------------------------------------------------


def test_short_sim_prints_no_progress_when_piped_and_quiet_prints_nothing(tmp_path):
    r = quadsitl("sim", "--preset", "paper", "--duration", "2", "--no-figures", "--out", str(tmp_path / "a"))
    assert r.returncode == 0, r.stderr
    # plain progress only for runs longer than its 2 s interval of wall time: none for this one (about 0.2 s), unless
    # the machine stalled it past 2 s (a loaded CI machine did once: "0.2× real time, ETA 8 s", then "done in 2.6 s"),
    # and then its closing line says so
    slow = re.search(r"^sim: t = 2\.00 / 2 s, \d+\.\d× real time, done in (\d+\.\d) s$", r.stderr, re.M)
    assert r.stderr == "" or (slow and float(slow.group(1)) >= 2.0), r.stderr
    assert "2000 ticks" in r.stdout
    q = quadsitl("sim", "--preset", "paper", "--duration", "2", "--no-figures", "--quiet", "--out", str(tmp_path / "b"))
    assert q.returncode == 0, q.stderr
    assert (q.stdout, q.stderr) == ("", "")
    assert (tmp_path / "b" / "telemetry.csv").exists()


def test_fly_progress_is_a_plain_line_when_piped_and_quiet_silences_it(tmp_path):
    # --speed 2 caps the pace: 5 simulated seconds take 2.5 s of wall time, so one line every ~2 s shows.
    r = quadsitl("fly", "--duration", "5", "--speed", "2", "--no-figures", "--out", str(tmp_path / "a"), timeout=180)
    assert r.returncode == 0, r.stderr
    assert PROGRESS_LINE.search(r.stderr), r.stderr
    assert len(DONE_LINE.findall(r.stderr)) == 1, r.stderr
    assert "\x1b[" not in r.stderr  # no terminal control codes in a pipe
    # the closing line names what was written: no figures were
    wrote = f"wrote {tmp_path / 'a'}/telemetry.csv, flight.tlog, flight.ulg, metrics.json"
    assert r.stdout.splitlines()[-1] == wrote, r.stdout
    assert not list((tmp_path / "a").glob("*.png"))
    q = quadsitl("fly", "--duration", "1", "--no-figures", "--quiet", "--out", str(tmp_path / "b"), timeout=180)
    assert q.returncode == 0, q.stderr
    assert "real time" not in q.stderr and "gcs:" not in q.stderr
    assert q.stdout == ""


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_progress_plain_lines_are_rate_limited_with_rtf_and_eta():
    clock, buf = FakeClock(), io.StringIO()
    p = FlightProgress(10.0, label="x:", stream=buf, clock=clock, interactive=False)
    for now, sim in [(0.05, 0.1), (1.0, 2.0), (2.0, 4.0), (2.05, 4.1), (3.0, 6.0), (4.0, 8.0), (4.5, 10.0)]:
        clock.now = now
        p.update(sim)
    clock.now = 5.0
    p.close()
    p.close()  # idempotent
    p.update(3.0)  # ignored once closed
    assert buf.getvalue().splitlines() == [
        "x: t = 4.00 / 10 s, 2.0× real time, ETA 3 s",  # 6 s left at 2 s per wall s
        "x: t = 8.00 / 10 s, 2.0× real time, ETA 1 s",  # 2 s after the previous line
        "x: t = 10.00 / 10 s, 2.0× real time, done in 5.0 s",
    ]


def test_progress_is_silent_for_short_runs_when_disabled_and_after_failure():
    for enabled, steps, completed in [(True, [(1.0, 5.0)], True), (False, [(3.0, 5.0)], True), (True, [], False)]:
        clock, buf = FakeClock(), io.StringIO()
        p = FlightProgress(10.0, enabled, stream=buf, clock=clock, interactive=False)
        for now, sim in steps:
            clock.now = now
            p.update(sim)
        clock.now = 4.0
        p.close(completed=completed)
        assert buf.getvalue() == ""
    clock, buf = FakeClock(), io.StringIO()
    with pytest.raises(KeyboardInterrupt), FlightProgress(10.0, stream=buf, clock=clock, interactive=False) as p:
        clock.now = 2.0
        p.update(5.0)
        raise KeyboardInterrupt
    assert buf.getvalue() == "flight t = 5.00 / 10 s, 2.5× real time, ETA 2 s\n"  # no "done" line


def test_progress_rich_bar_ends_with_the_final_numbers():
    clock, buf = FakeClock(), io.StringIO()
    with FlightProgress(4.0, label="sim:", stream=buf, clock=clock, interactive=True) as p:
        clock.now = 1.0
        p.update(2.0)
        clock.now = 2.0
        p.update(4.0)
    out = buf.getvalue()
    assert "sim:" in out and "4.00 / 4 s" in out and "2.0× real time" in out and "done in 2.0 s" in out


def test_format_eta():
    assert [format_eta(s) for s in (0.4, 7, 59.4, 125, 3723)] == ["0 s", "7 s", "59 s", "2:05", "1:02:03"]


def test_sim_progress_observes_without_changing_the_results():
    preset = load_preset("paper")
    seen: list[float] = []
    with_progress, _ = run_offline(preset, ["backstepping", "pd"], 1.2, progress=seen.append)
    without, _ = run_offline(preset, ["backstepping", "pd"], 1.2)
    for kind in without:
        for name in ("t", "state", "reference", "inputs", "forces"):
            assert np.array_equal(getattr(with_progress[kind], name), getattr(without[kind], name)), (kind, name)
    # Cumulative over both runs: every 500 ticks (0.5 s at T = 1 ms) and at the end of each run.
    assert seen == pytest.approx([0.0, 0.5, 1.0, 1.2, 1.2, 1.7, 2.2, 2.4])


def test_a_slow_wait_is_announced_once_with_its_time_and_a_quick_one_not_at_all():
    buf = io.StringIO()
    with announce_if_slow("x: compiling", after=0.05, stream=buf):
        time.sleep(0.3)
    lines = buf.getvalue().splitlines()
    # 0.3 s or more (a loaded machine may oversleep), said with one decimal
    assert lines[0] == "x: compiling ..." and re.fullmatch(r"x: compiling: done in (0\.[3-9]|[1-9]\d*\.\d) s", lines[1])
    for enabled, wait, after in ((True, 0.0, 0.5), (False, 0.3, 0.05)):
        quiet = io.StringIO()
        with announce_if_slow("x: compiling", enabled=enabled, after=after, stream=quiet):
            time.sleep(wait)
        time.sleep(after + 0.1)  # a timer that was not cancelled would have fired by now
        assert quiet.getvalue() == ""


@pytest.mark.parametrize("value", ["-0.1", "nan", "11"])
def test_a_bad_setpoints_ahead_is_refused_in_one_line_before_anything_is_written(value, tmp_path):
    r = quadsitl("gcs", f"--setpoints-ahead={value}", "--out", str(tmp_path / "o"), timeout=30)
    assert r.returncode == 2 and r.stdout == ""
    line = assert_one_line_error(r)
    assert line == f"quadsitl gcs: error: --setpoints-ahead {float(value)!r}: expected a number in [0, 10]"
    assert not (tmp_path / "o").exists()
