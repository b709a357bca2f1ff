"""``quadsitl sweep --cluster``: a real Dask scheduler and workers as processes on loopback (``dask scheduler``,
``dask worker``), the table the same as a local run's to the byte, also when a worker is killed mid-sweep, and
the one-line refusals."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from quadsitl.process_util import free_port
from tests.conftest import run_cli

pytestmark = [pytest.mark.timeout(120), pytest.mark.usefixtures("batch_engine")]  # ~25 s on the 2-core machine

DASK = [str(Path(sys.executable).parent / "dask")]  # distributed's console script
QUADSITL = str(Path(sys.executable).parent / "quadsitl")
TRIALS, CHUNK = 2400, 200  # 12 chunks of 200 five-second trials: about 0.2 s each on one core
SWEEP = ("sweep", "paper-mass-mismatch", "--trials", str(TRIALS), "--chunk", str(CHUNK))


@dataclass
class Cluster:
    """A scheduler and its workers, each ``dask`` command a process group of its own, killed at the end."""

    address: str
    logs: Path
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)

    def start(self, name: str, *argv: str) -> subprocess.Popen:
        log = open(self.logs / f"{name}.log", "wb")  # noqa: SIM115 - the process writes it until it is stopped
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.procs[name] = subprocess.Popen([*DASK, *argv], stdout=log, stderr=subprocess.STDOUT, env=env,
                                            start_new_session=True)  # fmt: skip
        log.close()
        return self.procs[name]

    def worker(self, name: str) -> subprocess.Popen:
        return self.start(name, "worker", self.address, "--name", name, "--nworkers", "1", "--nthreads", "1",
                          "--no-nanny", "--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0",
                          "--local-directory", str(self.logs / name))  # fmt: skip

    def alive(self) -> None:
        """Fail with the log of the first process that ended (the worker killed on purpose aside)."""
        for name, proc in self.procs.items():
            if proc.poll() is not None and proc.returncode != -signal.SIGKILL:
                log = (self.logs / f"{name}.log").read_text(errors="replace")[-2000:]
                raise AssertionError(f"dask {name} ended with status {proc.returncode}:\n{log}")

    def client(self):  # -> distributed.Client, once the scheduler answers
        from distributed import Client

        deadline = time.monotonic() + 60
        while True:
            self.alive()
            try:
                return Client(self.address, timeout=2, set_as_default=False)
            except OSError:
                assert time.monotonic() < deadline, f"the scheduler at {self.address} never answered"

    def wait_for_workers(self, client, n: int) -> None:
        deadline = time.monotonic() + 60
        while len(client.nthreads()) < n:
            self.alive()
            assert time.monotonic() < deadline, f"{n} workers never joined"
            time.sleep(0.1)

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        proc = self.procs[name]
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, sig)

    def stop(self) -> None:
        """The workers, then the scheduler (a worker whose scheduler went first can take seconds to end)."""
        workers = [name for name in self.procs if name != "scheduler"]
        for names in (workers, ["scheduler"]):
            for name in names:
                self.kill(name, signal.SIGTERM)
            deadline = time.monotonic() + 5.0
            for name in names:
                try:
                    self.procs[name].wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    self.kill(name)
                    self.procs[name].wait()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """``dask scheduler`` and two ``dask worker`` on free loopback ports, and the same sweep run locally
    (``--workers 1``) while they start: (the cluster, a client of it for the tests to watch it, the local run's
    folder)."""
    tmp = tmp_path_factory.mktemp("cluster")
    c = Cluster(f"tcp://127.0.0.1:{free_port(socket.SOCK_STREAM)}", tmp)
    try:
        c.start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", c.address.rsplit(":", 1)[1],
                "--dashboard-address", "127.0.0.1:0")  # fmt: skip
        for name in ("w1", "w2"):
            c.worker(name)
        local = tmp / "local"
        r = run(*SWEEP, "--workers", "1", "--out", str(local), "-q")
        assert r.returncode == 0, r.stderr
        client = c.client()
        try:
            c.wait_for_workers(client, 2)
            yield c, client, local
        finally:
            client.close()
    finally:
        c.stop()


def run(*args: str) -> subprocess.CompletedProcess:
    return run_cli(*args, timeout=90)


def assert_same_sweep(out: Path, local: Path, cluster: str, workers: int) -> None:
    """The table byte for byte (CSV and Parquet), every trial once, and the same summary but where and how fast."""
    for name in ("trials.csv", "trials.parquet"):
        assert (out / name).read_bytes() == (local / name).read_bytes(), name
    rows = (out / "trials.csv").read_text().splitlines()[1:]
    assert [int(row.split(",")[0]) for row in rows] == list(range(TRIALS))
    ours, theirs = (json.loads((d / "summary.json").read_text()) for d in (out, local))
    assert (ours["cluster"], ours["workers"]) == (cluster, workers)
    assert (theirs["cluster"], theirs["workers"]) == (None, 1)
    timing = ("cluster", "workers", "wall_s", "vehicle_steps_per_s")
    assert {k: v for k, v in ours.items() if k not in timing} == {k: v for k, v in theirs.items() if k not in timing}
    assert ours["trials"] == ours["flown"] == TRIALS and ours["vehicle_steps"] == TRIALS * 5000


def test_a_sweep_on_a_cluster_is_the_local_sweep_to_the_byte(cluster, tmp_path):
    c, _client, local = cluster
    out = tmp_path / "on-cluster"
    r = run(*SWEEP, "--cluster", c.address, "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert f"on 2 Dask workers at {c.address}" in r.stdout
    assert "warning" not in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert_same_sweep(out, local, c.address, 2)


def test_a_worker_killed_mid_sweep_loses_no_trial(cluster, tmp_path):
    """A third worker joins and is killed (SIGKILL, its whole process group) while the scheduler has chunks of
    this sweep on it that it cannot have sent back (it is stopped first, SIGSTOP, and they are still there): the
    scheduler flies them again on the others, and the table is the local one."""
    c, client, local = cluster
    c.worker("w3")
    c.wait_for_workers(client, 3)
    w3 = next(a for a, w in client.scheduler_info()["workers"].items() if w["name"] == "w3")

    def on_w3() -> set[str]:
        return {str(k) for k in client.processing([w3]).get(w3, ()) if str(k).startswith("quadsitl-sweep-")}

    out = tmp_path / "killed"
    argv = [QUADSITL, *SWEEP, "--cluster", c.address, "--out", str(out)]
    sweep = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        lost: set[str] = set()
        while not lost:
            assert sweep.poll() is None, "the sweep ended before w3 was caught flying a chunk"
            assert time.monotonic() < deadline, "w3 never flew a chunk"
            if on_w3():
                c.kill("w3", signal.SIGSTOP)
                time.sleep(0.2)  # whatever w3 sent before it stopped has reached the scheduler
                lost = on_w3()
                c.kill("w3", signal.SIGKILL if lost else signal.SIGCONT)
            time.sleep(0.01)
        _, stderr = sweep.communicate(timeout=60)
    finally:
        if sweep.poll() is None:
            sweep.kill()
            sweep.wait()
    assert c.procs["w3"].wait(5) == -signal.SIGKILL
    assert sweep.returncode == 0, stderr
    assert f"warning: 1 of the 3 workers left mid-sweep ({w3})" in stderr, stderr
    assert "Traceback" not in stderr and stderr.count("warning") == 1, stderr
    assert_same_sweep(out, local, c.address, 3)
    story = client.run_on_scheduler(lambda dask_scheduler: [t[:3] for t in dask_scheduler.story(*lost)])
    for key in lost:  # sent to a worker twice (w3, then another), and back from one, once
        assert sum(1 for k, _start, finish in story if k == key and finish == "processing") == 2, story
        assert sum(1 for k, _start, finish in story if k == key and finish == "memory") == 1, story


def test_cluster_addresses_are_read_as_dask_spells_them_or_refused_naming_the_option():
    from groundstation.sweep.cluster import parse_address
    from quadsitl.cli_util import UsageError

    for text, address in (("tcp://10.0.0.5:8786", "tcp://10.0.0.5:8786"), ("node-1.lan:8786", "tcp://node-1.lan:8786"),
                          ("tcp://[::1]:08786", "tcp://[::1]:8786"), (" tcp://h:1 ", "tcp://h:1")):  # fmt: skip
        assert parse_address("--cluster", text) == address
    for text in ("localhost", "tcp://127.0.0.1:0", "tcp://h:65536", "http://h:8786", "tcp://h:8786/x", "tcp://:1",
                 "tls://h:8786", "tcp://::1:8786", ""):  # fmt: skip
        with pytest.raises(UsageError, match=r"^--cluster '.*': expected a Dask scheduler's address tcp://HOST:PORT "
                           r"with PORT in 1\.\.65535 \(what `dask scheduler` prints as 'Scheduler at'\)$"):  # fmt: skip
            parse_address("--cluster", text)


def test_cluster_refusals_in_one_line(cluster, tmp_path):
    """A malformed address and --workers with --cluster (exit 2); nothing listening, a server that accepts and
    never answers (distributed itself would wait for ever) and a worker's address instead of the scheduler's
    (exit 1, within the connection timeout). All at once: two of them wait 5 s."""
    c, client, _local = cluster
    silent = socket.socket()  # listens, so the kernel accepts connections, and never says a word
    silent.bind(("127.0.0.1", 0))
    silent.listen()
    nobody = f"tcp://127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    quiet = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
    worker = next(a for a, w in client.scheduler_info()["workers"].items() if w["name"] == "w1")
    expected = {
        ("tcp://127.0.0.1",): (2, "--cluster 'tcp://127.0.0.1': expected a Dask scheduler's address tcp://HOST:PORT"),
        (c.address, "--workers", "2"): (2, f"--workers 2 with --cluster {c.address}: expected one of them"),
        (nobody,): (1, f"--cluster {nobody}: no Dask scheduler answered within 5 s; start one there"),
        (quiet,): (1, f"--cluster {quiet}: no Dask scheduler answered within 5 s; start one there"),
        (worker,): (1, f"--cluster {worker}: what answers there is a Dask worker, not the scheduler"),
    }
    out = tmp_path / "never"
    start = time.monotonic()
    procs: dict[tuple[str, ...], subprocess.Popen] = {}
    try:
        for args in expected:
            argv = [QUADSITL, "sweep", "paper-mass-mismatch", "--out", str(out), "--cluster", *args]
            procs[args] = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        results = {args: (*p.communicate(timeout=60), p.returncode) for args, p in procs.items()}
    finally:
        silent.close()
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
    took = time.monotonic() - start
    for args, (status, message) in expected.items():
        stdout, stderr, got = results[args]
        assert got == status and stdout == "" and stderr.count("\n") == 1, (args, got, stderr)
        assert stderr.startswith(f"quadsitl sweep: error: {message}"), (args, stderr)
    assert took < 20
    assert not out.exists()
