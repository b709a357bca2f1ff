import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.alone import pytest_collection_modifyitems, pytest_configure, pytest_runtest_protocol  # noqa: F401 (hooks)

# pymavlink's mavutil speaks MAVLink 2 with the common dialect only when told before it is imported.
os.environ.setdefault("MAVLINK20", "1")
os.environ.setdefault("MAVLINK_DIALECT", "common")

# Each xdist worker picks its ports (and so do the processes its tests start) from a part of its own: a vehicle's
# stream to a client's port that is not bound yet must not reach another test's client (quadsitl.process_util).
if "PYTEST_XDIST_WORKER" in os.environ and "QUADSITL_PORTS" not in os.environ:
    _worker, _workers = int(os.environ["PYTEST_XDIST_WORKER"][2:]), int(os.environ["PYTEST_XDIST_WORKER_COUNT"])
    _share = (32768 - 20000) // _workers
    os.environ["QUADSITL_PORTS"] = f"{20000 + _worker * _share}-{20000 + (_worker + 1) * _share - 1}"

BIN = Path(sys.executable).parent


def run_cli(*args: str, timeout: float = 120, module: str | None = None) -> subprocess.CompletedProcess:
    """Run the installed ``quadsitl`` command (or ``python -m <module>``) and capture its output."""
    if module:
        cmd = [sys.executable, "-m", module, *args]
    else:
        exe = BIN / "quadsitl"
        cmd = [str(exe), *args] if exe.exists() else [sys.executable, "-m", "groundstation.cli", *args]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)


def _warm_the_autopilot() -> None:
    from autopilot.tick import warm_up

    warm_up()


def _warm_the_plant() -> None:
    from quadsitl.config import load_preset
    from sitl import process
    from sitl.plant import Plant

    process.warm_up(Plant(load_preset("paper")), (False, True))


def _warm_the_autopilots_loop() -> None:
    """The autopilot's compiled plant loop for both of its modes (its arguments' types differ)."""
    from autopilot.process import warm_up_loops

    warm_up_loops()


def _warm_the_sim() -> None:
    """``sim``'s compiled loop over the whole vehicle, on the true state (its own compile: a test that runs ``sim``
    with a short timeout must not pay it)."""
    from groundstation.api import sim

    sim("paper", duration=0.01)


# What the session compiles into numba's cache, in parts: (name, what it needs in the cache first, how). The
# autopilot's loop calls its tick: compiled after it, it takes the tick from the cache instead of compiling it again.
# A worker starts on the part of its own index, so with three workers the first three parts start at once.
WARM_PARTS = (
    ("autopilot", (), _warm_the_autopilot),
    ("plant", (), _warm_the_plant),
    ("sim", (), _warm_the_sim),
    ("autopilot-loop", ("autopilot",), _warm_the_autopilots_loop),
)


def _warm_the_engine(version: int):
    def warm() -> None:
        from groundstation.sweep.run import VERSIONS, warm_version

        warm_version(*VERSIONS[version])

    return warm


# The sweeps' batch engine, each of its versions one part (about 30 s each on a 2-core guest): only the tests of
# the sweeps need it (the fixture batch_engine), so a worker compiles it while it would otherwise wait for the
# parts above, and no test waits for it but those.
ENGINE_PARTS = (("engine-paper", (), _warm_the_engine(0)), ("engine-general", (), _warm_the_engine(1)))


def _warm_the_sensor_sim() -> None:
    """``sim``'s compiled loop on sensors, the estimator's path in it: minutes cold (docs/performance.md#on-sensors)."""
    from groundstation.api import sim

    sim("x500", state="sensors", duration=0.01)


# sim on sensors, one part: the tests that fly it (the fixture sensor_sim) wait for it. Compiled by the test that came
# first, it was compiled by two or three workers at once when their tests came together, each on a core of two, for
# longer than a test's timeout, while the real-time flights beside them starved.
SENSOR_PARTS = (("sim-sensors", (), _warm_the_sensor_sim),)
LATER_PARTS = SENSOR_PARTS + ENGINE_PARTS  # the longest first


def warm_among_workers(parts: tuple, shared: Path, worker: int, poll: float = 0.1, extra: tuple = ()) -> None:
    """Compile ``parts`` into numba's cache, each once among the pytest-xdist workers that share the directory
    ``shared``: a worker takes a part nobody has taken whose needs are done (worker ``worker`` starts with the part
    of that index, so two workers start on different parts), marks it done, and returns once every part is done.
    While the parts left are all taken by others, or wait on one that is, it takes a part of ``extra`` instead, if
    one is left: work some tests need later, done now instead of waiting."""
    import fcntl

    first = worker % len(parts)
    order = [*parts[first:], *parts[:first], *extra]
    while True:
        done = {name for name, _, _ in order if (shared / f"{name}.done").exists()}
        if all(name in done for name, _, _ in parts):
            return
        for name, needs, warm in order:
            if name in done or not set(needs) <= done:
                continue
            with open(shared / f"{name}.lock", "w") as lock:
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    continue  # another worker is on it
                if not (shared / f"{name}.done").exists():
                    warm()
                    (shared / f"{name}.done").touch()
            break
        else:
            time.sleep(poll)  # every part left is taken, or waits on one that is


def _warm(parts: tuple, tmp_path_factory, extra: tuple = ()) -> None:
    """``parts`` compiled: here, or among the pytest-xdist workers (:func:`warm_among_workers`)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is None:
        for _, _, warm in parts:
            warm()
        return
    shared = tmp_path_factory.getbasetemp().parent / "numba-warm"  # the run's, common to its workers
    shared.mkdir(exist_ok=True)
    warm_among_workers(parts, shared, int(worker.removeprefix("gw")), extra=extra)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile every per-tick function into numba's cache once, before the first test, so that no test's timeout
    counts it (a fresh checkout has no cache; a module whose tests allow 60 s, run alone, timed out in its first test
    while the session compiled). Under pytest-xdist the workers share the parts (:func:`warm_among_workers`): on a
    2-core guest each worker spent about 110 s compiling everything, and both now wait about 70 s (the autopilot's
    tick alone is about 60 s); the worker that would wait for the autopilot compiles the batch engine meanwhile.
    Not in pytest-xdist's controller (it runs no test), nor for ``--collect-only``."""
    config = session.config
    controller = bool(getattr(config.option, "numprocesses", None)) and not hasattr(config, "workerinput")
    if controller or config.option.collectonly:
        return
    _warm(WARM_PARTS, config._tmp_path_factory, extra=LATER_PARTS)
    _WARMED.append(True)
    if "PYTEST_XDIST_WORKER" in os.environ:
        _warm_later_behind(config._tmp_path_factory.getbasetemp().parent / "numba-warm")


_WARMED: list[bool] = []  # pytest_sessionstart compiled them
_BEHIND: list[subprocess.Popen] = []  # the process compiling LATER_PARTS, when this worker started it


def _warm_later_behind(shared: Path) -> None:
    """The parts left of LATER_PARTS compiled from now on by a process of its own at low priority (nice 10), started
    once in the run by the first worker here: the tests that need them (the fixtures batch_engine and sensor_sim)
    find them compiled, or wait for the part under way, instead of compiling it in their own time (sim's loop on
    sensors took longer than a test's timeout on a loaded CI machine). Should it stop, a fixture takes its part over."""
    try:
        (shared / "later.started").touch(exist_ok=False)
    except FileExistsError:
        return
    code = f"from pathlib import Path; from tests.conftest import LATER_PARTS, warm_among_workers; " \
           f"warm_among_workers(LATER_PARTS, Path({str(shared)!r}), 0)"  # fmt: skip
    _BEHIND.append(subprocess.Popen([sys.executable, "-c", code], cwd=Path(__file__).parent.parent,
                                    preexec_fn=lambda: os.nice(10)))  # fmt: skip


def pytest_sessionfinish(session: pytest.Session) -> None:
    for p in _BEHIND:
        if p.poll() is None:
            p.kill()
            p.wait()


@pytest.fixture(scope="session", autouse=True)
def compiled(tmp_path_factory):
    """Every per-tick function in numba's cache: :func:`pytest_sessionstart` compiled them (or, should it not have
    run, here)."""
    if not _WARMED:
        _warm(WARM_PARTS, tmp_path_factory, extra=LATER_PARTS)


@pytest.fixture(scope="session")
def batch_engine(compiled, tmp_path_factory):
    """The sweeps' batch engine in numba's cache (tests that fly it, or start processes that do): compiled here, or
    waited for while another worker compiles it."""
    _warm(ENGINE_PARTS, tmp_path_factory)


@pytest.fixture(scope="session")
def sensor_sim(compiled, tmp_path_factory):
    """``sim``'s loop on sensors in numba's cache (tests that run ``sim`` or the batch engine on sensors): compiled
    here, or waited for while another worker compiles it."""
    _warm(SENSOR_PARTS, tmp_path_factory)


@pytest.fixture
def cli():
    return run_cli
