"""SpinThenBlock, the lockstep loops' receive: polls while the peer answers fast, blocks when paced, and
stops polling when polling does not pay (the peer waits for a core)."""

import socket
import threading
import time

import pytest

from quadsitl.cli_util import UsageError
from quadsitl.process_util import (
    HOT_AFTER,
    PACED_BELOW,
    PATIENCE,
    SPIN_ENV,
    SPIN_MISSES,
    SPIN_STRIKES,
    SPIN_WINDOW,
    PaceGauge,
    SpinThenBlock,
    spin_budget,
)


@pytest.fixture
def pair():
    a, b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    a.bind(("127.0.0.1", 0))
    b.connect(a.getsockname())
    yield a, b
    a.close()
    b.close()


def test_a_fast_peer_is_polled_and_a_paced_one_is_waited_for(pair):
    a, b = pair
    wait = SpinThenBlock(a.recv, budget=0.05)
    for i in range(HOT_AFTER):  # quick waits, blocking, until HOT_AFTER of them in a row make it hot
        assert not wait.hot
        b.send(b"b%d" % i)
        assert wait() == b"b%d" % i and wait.blocked == i + 1
    assert wait.hot
    for i in range(5):
        b.send(str(i).encode())
        assert wait() == str(i).encode()
    assert wait.polled == 5 and wait.blocked == HOT_AFTER
    # A paced peer: nothing for longer than the budget, so the poll gives up and the wait blocks.
    threading.Timer(0.12, lambda: b.send(b"late")).start()
    assert wait() == b"late" and wait.blocked == HOT_AFTER + 1 and not wait.hot
    b.send(b"next")
    time.sleep(0.01)
    assert wait() == b"next" and wait.blocked == HOT_AFTER + 2  # not hot: blocks (the datagram is there: at once)
    # A paced loop that finds a datagram already waiting (it was late) stays cold: it would poll the whole budget
    # for the next one, a period away.
    assert not wait.hot
    threading.Timer(0.08, lambda: b.send(b"paced")).start()
    assert wait() == b"paced" and wait.polled == 5 and wait.blocked == HOT_AFTER + 3


def test_a_patient_loop_polls_through_a_late_datagram_and_stays_hot(pair):
    a, b = pair
    wait = SpinThenBlock(a.recv, budget=0.02, patience=0.6)
    assert wait.patience == 0.6
    for i in range(HOT_AFTER):
        b.send(b"%d" % i)
        wait()
    assert wait.hot
    # Later than the budget, within the patience: polled for, not blocked on, and the loop is still hot.
    threading.Timer(0.1, lambda: b.send(b"late")).start()
    assert wait() == b"late" and wait.polled == 1 and wait.blocked == HOT_AFTER and wait.hot
    # Without patience (a paced plant's), the same wait gives up polling after the budget and blocks.
    wait.be_patient(None)
    assert wait.patience == 0.02
    threading.Timer(0.1, lambda: b.send(b"later")).start()
    assert wait() == b"later" and wait.polled == 1 and wait.blocked == HOT_AFTER + 1 and not wait.hot
    # Patience is never shorter than the budget, and with polling off there is none.
    assert SpinThenBlock(a.recv, budget=0.02, patience=0.001).patience == 0.02
    assert SpinThenBlock(a.recv, budget=0.0, patience=0.5).patience == 0.0


def test_polling_stops_for_a_while_when_it_does_not_pay():
    calls = {"poll": 0, "block": 0}

    def late_peer(n, flags=0):  # every datagram comes late: after more than half the budget
        if flags:
            calls["poll"] += 1
            time.sleep(0.0012)
            return b"x"
        calls["block"] += 1
        return b"x"

    wait = SpinThenBlock(late_peer, budget=0.002)
    for _ in range(HOT_AFTER):  # quick blocking waits make it hot
        wait()
    for _ in range(SPIN_WINDOW):
        wait()
    assert wait.cooled == 0  # one window of late answers may be a burst (another process's few ms): polling goes on
    for _ in range(SPIN_WINDOW * (SPIN_STRIKES - 1)):
        wait()
    assert wait.cooled == 1
    polls = calls["poll"]
    for _ in range(20):
        wait()
    assert calls["poll"] == polls  # cooling off: every wait blocks
    assert wait.blocked == HOT_AFTER + 20


def test_waits_made_by_a_compiled_loop_count_as_its_own():
    wait = SpinThenBlock(lambda *a: b"x", budget=0.001)
    assert not wait.polling()
    wait.tally(0, 0, False, blocked=HOT_AFTER, short=HOT_AFTER)  # blocking waits, each short: hot
    assert wait.polling() and wait.blocked == HOT_AFTER and wait.short == HOT_AFTER
    wait.tally(SPIN_WINDOW - 1, 0, ran_out=True, blocked=0, short=0)  # a poll ran out: blocks next, as __call__
    assert not wait.polling() and wait.polled == SPIN_WINDOW - 1 and wait.cooled == 0
    wait.tally(0, 0, False, blocked=HOT_AFTER, short=HOT_AFTER)
    for _ in range(SPIN_STRIKES):  # windows with too many late datagrams, in a row: polling stops for a while
        wait.tally(SPIN_WINDOW, SPIN_MISSES + 1, False, 0, 0)
    assert wait.cooled == 1 and wait.hot and not wait.polling()


def test_a_compiled_loops_polls_counted_at_once_are_counted_as_one_by_one():
    """tally counts a loop's thousands of polls window by window: the verdicts (windows judged, polling stopped,
    its doubling pause) are those of one _verdict per poll, the first ``late`` of each report missing."""
    import random

    rng = random.Random(7)
    bulk, single = SpinThenBlock(lambda *a: b"x", budget=0.001), SpinThenBlock(lambda *a: b"x", budget=0.001)
    pauses = set()
    for _ in range(400):
        polled = rng.choice([0, 1, 5, SPIN_WINDOW - 1, SPIN_WINDOW, 3 * SPIN_WINDOW + 17, rng.randrange(2000)])
        late = rng.choice([0, 0, polled, rng.randrange(polled + 1), SPIN_MISSES + 1])
        bulk.tally(polled, late, False, 0, 0)
        single.polled += polled
        for i in range(polled):
            single._verdict(miss=i < late)
        state = lambda w: (w.polled, w._polls, w._misses, w._strikes, w._cool, w.cooled)  # noqa: E731
        assert state(bulk) == state(single)
        pauses.add(bulk._cool)
    assert bulk.cooled > 3 and pauses == {0.25, 0.5, 1.0, 2.0, 4.0}  # polling stopped, its pause doubled, and reset


def test_the_pace_gauge_tells_a_paced_peer_from_one_nothing_paces():
    gauge = PaceGauge(period=0.001, window=0.125)  # (times in binary fractions: exact sums)
    assert gauge.update(0, 10.0) is None  # the first window begins
    assert gauge.update(60, 10.0625) is None  # still open
    assert gauge.update(125, 10.125) == pytest.approx(1.0)  # real time: 125 ticks of 1 ms in 0.125 s
    # A real-time plant's catch-up burst (ticks back to back) inside a window leaves it paced: the window counts.
    assert gauge.update(250, 10.25) == pytest.approx(1.0)
    assert gauge.update(4000, 10.375) == pytest.approx(30.0)  # lockstep, unpaced
    assert gauge.update(0, 10.5) < 0  # a new plant run, its ticks from 0 again
    assert PaceGauge.patience(1.0) is None and PaceGauge.patience(-1.0) is None
    assert PaceGauge.patience(PACED_BELOW - 0.01) is None
    assert PaceGauge.patience(PACED_BELOW) == PaceGauge.patience(30.0) == PATIENCE


def test_the_budget_comes_from_the_environment_and_is_checked(monkeypatch):
    monkeypatch.setenv(SPIN_ENV, "0")
    assert spin_budget() == 0.0
    monkeypatch.setenv(SPIN_ENV, "150")
    assert spin_budget() == pytest.approx(150e-6)
    for bad in ("abc", "-1", "1e9", "nan"):
        monkeypatch.setenv(SPIN_ENV, bad)
        with pytest.raises(UsageError, match=rf"\${SPIN_ENV} = '{bad}': expected microseconds in \[0, 100000\]"):
            spin_budget()


def test_a_bad_budget_is_one_line_from_the_plant(cli, monkeypatch):
    monkeypatch.setenv(SPIN_ENV, "fast")
    r = cli("plant", "--ticks", "1", timeout=60)
    assert r.returncode == 2 and f"${SPIN_ENV} = 'fast'" in r.stderr and "Traceback" not in r.stderr
