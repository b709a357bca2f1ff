"""``scripts/installed.py``: how ``./scripts/test`` decides whether it must run ``pip install -e ".[test]"``.
It must name the first requirement that is missing or too old, follow the project's own extras that an
extra names ("quadsitl[docs]"), and honour environment markers."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
spec = importlib.util.spec_from_file_location("installed", ROOT / "scripts" / "installed.py")
installed = importlib.util.module_from_spec(spec)
spec.loader.exec_module(installed)

PYTEST = metadata.version("pytest")


def project(dependencies: list[str], test: list[str], docs: list[str]) -> dict:
    return {"name": "quadsitl", "dependencies": dependencies,
            "optional-dependencies": {"test": test, "docs": docs}}  # fmt: skip


def test_nothing_missing_when_every_requirement_is_satisfied():
    never = "quadsitl-never-installed; python_version < '3'"  # a marker that is false here
    assert installed.missing_requirement(project(["pytest>=1"], ["PyTest", "quadsitl[docs]"], [never])) is None


def test_names_a_requirement_of_an_extra_named_by_the_test_extra():
    p = project(["pytest"], ["quadsitl[docs]"], ["quadsitl-never-installed>=1"])
    assert installed.missing_requirement(p) == "quadsitl-never-installed is not installed"
    assert installed.missing_requirement(project(["pytest"], [], ["quadsitl-never-installed"])) is None  # not asked


def test_names_a_requirement_installed_at_a_version_that_does_not_satisfy_it():
    p = project(["pytest>=999"], [], [])
    assert installed.missing_requirement(p) == f"pytest {PYTEST} is installed, quadsitl needs pytest>=999"


def test_the_command_line_says_what_is_missing_and_exits_1_in_an_environment_without_the_project(tmp_path):
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(tmp_path / "venv")], check=True)
    r = subprocess.run([str(tmp_path / "venv" / "bin" / "python"), str(ROOT / "scripts" / "installed.py")],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 1 and r.stdout.strip() == "quadsitl is not installed", r
