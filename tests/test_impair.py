"""The link-impairment layer: its statistics, its option, and a real-time flight through it that still
reaches the paper's references (duplicates and reordered messages discarded by time_usec)."""

import math
import re
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import common as M  # noqa: N812 (the MAVLink constants, short)

from quadsitl.cli_util import UsageError
from quadsitl.process_util import free_ports_apart
from sitl.impair import Impairment, ImpairmentSpec, parse_impairment
from tests.mavclient import Client


def test_impairment_statistics():
    im = Impairment(ImpairmentSpec(loss=5, delay=0.001, jitter=0.002, dup=2, reorder=1), seed=7)
    n = 20000
    schedules = [im.schedule(10.0) for _ in range(n)]
    assert im.dropped / n == pytest.approx(0.05, abs=0.01)
    assert im.duplicated / n == pytest.approx(0.02 * 0.95, abs=0.005)
    assert im.reordered / n == pytest.approx(0.01, abs=0.004)
    delays = [t - 10.0 for s in schedules for t in s]
    assert min(delays) >= 0.001 and max(delays) <= 0.001 + 0.002 + 0.001 + 0.002 + 0.002 + 1e-12
    assert sum(len(s) == 0 for s in schedules) == im.dropped and sum(len(s) == 2 for s in schedules) == im.duplicated
    assert Impairment(ImpairmentSpec()).schedule(3.0) == [3.0]


@pytest.mark.parametrize(
    ("text", "message"),
    [("loss=101", "--impair loss=101: expected a number in [0, 100] %"), ("jitter=x", "jitter=x: expected"),
     ("noise=1", "expected KEY=VALUE with KEY one of loss, delay, jitter, dup, reorder"),
     ("delay=2", "delay=2: expected a number in [0, 1] s")],
)  # fmt: skip
def test_impairment_option_errors_name_the_key_and_value(text, message):
    with pytest.raises(UsageError, match=message.replace("[", r"\[").replace("]", r"\]")):
        parse_impairment("--impair", text)
    assert parse_impairment("--impair", "loss=5,jitter=0.002") == ImpairmentSpec(loss=5, jitter=0.002)


def test_realtime_flight_through_5_percent_loss_and_2_ms_jitter_reaches_the_papers_references():
    plant_port, api = free_ports_apart(2)
    ap = subprocess.Popen([sys.executable, "-m", "autopilot", "--no-zenoh", "--plant-listen", f"127.0.0.1:{plant_port}",
                           "--gcs-listen", "127.0.0.1:0", "--gcs-remote", "none", "--api-listen", f"127.0.0.1:{api}",
                           "--api-remote", "none"])  # fmt: skip
    plant = subprocess.Popen([sys.executable, "-m", "sitl", "--mode", "realtime", "--autopilot",
                              f"127.0.0.1:{plant_port}", "--impair", "loss=5,jitter=0.002,dup=1,reorder=1"],
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    c = Client.to(api)
    ref = dict(altitude=5.0, roll=math.pi / 3, pitch=math.pi / 3, yaw=math.pi / 3)
    try:
        c.connect()
        for _ in range(6):
            c.setpoint(**ref)
            c.pump(0.05)
        assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_ACCEPTED
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        end = time.monotonic() + 2.5
        while time.monotonic() < end:
            c.setpoint(**ref)
            c.pump(0.05)
        att, pos = c.latest["ATTITUDE"], c.latest["LOCAL_POSITION_NED"]
        assert (att.roll, att.pitch, att.yaw) == pytest.approx((math.pi / 3,) * 3, abs=1e-3)
        assert -pos.z == pytest.approx(5.0, abs=1e-3)
    finally:
        c.conn.close()
        plant.terminate()
        _, err = plant.communicate(timeout=10)
        ap.terminate()
        ap.wait(10)
    line = next(x for x in err.splitlines() if "link impairment" in x)
    dropped = int(line.split("dropped ")[1].split(",")[0])
    assert dropped > 100  # about 5 % of ~2 × 1000 datagrams per second
    stale = int(re.search(r"; (\d+) stale actuator messages", err).group(1))  # the plant's summary line
    assert stale > 0  # duplicated and reordered answers were discarded by time_usec
