"""Modules that need the machine to themselves, under pytest-xdist. A module marked ``pytest.mark.alone`` asserts
real time's pace on the whole machine (the soak), so it runs while no other worker runs a module. It is collected
last, so that it tends to wait for fewer (pytest-xdist's loadscope orders modules by their number of tests first).
Two locks among the workers, files in the run's directory: every module holds MACHINE shared while it runs, an alone
module holds it exclusive; GATE stops new modules from starting while an alone module waits for those under way. A
plugin of its own (``pytest -p tests.alone``), loaded by tests/conftest.py."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

import pytest

_HELD: dict[str, object] = {}  # this worker's module that holds the machine, and the lock files it holds


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "alone: the module runs while no other test runs (tests/alone.py)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("alone") is not None)  # stable: the others keep their order


def _lock_dir(config: pytest.Config) -> Path:
    return config._tmp_path_factory.getbasetemp().parent  # the run's, common to its workers


def _hold(item: pytest.Item, exclusive: bool) -> None:
    folder = _lock_dir(item.config)
    gate, machine = open(folder / "alone.gate", "a"), open(folder / "alone.machine", "a")  # noqa: SIM115
    fcntl.flock(gate, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
    fcntl.flock(machine, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
    if not exclusive:
        gate.close()  # through the gate: an alone module waiting behind it now waits for this one to end
    _HELD.update(module=item.module, files=(gate, machine))


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    """The module's hold on the machine, taken before its first test's timeout starts (pytest-timeout's is an inner
    wrapper of this hook) and let go after its last test's teardown, its module's fixtures with it."""
    if "PYTEST_XDIST_WORKER" in os.environ and _HELD.get("module") is not item.module:
        _hold(item, exclusive=item.get_closest_marker("alone") is not None)
    yield
    if _HELD.get("module") is item.module and (nextitem is None or nextitem.module is not item.module):
        for f in _HELD.pop("files"):
            f.close()  # closing the file lets go of its lock
        _HELD.clear()
