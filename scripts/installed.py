"""Is this checkout installed, with everything its tests need, in the Python that runs this file?

Exit status 0 when the project is installed from this checkout in editable mode, at the version in
pyproject.toml, with every requirement of its dependencies and of its test extra (and the extras that one
names, such as docs) installed at a version that satisfies it; otherwise 1, with one line on stdout saying
the first thing that is missing. ``scripts/test`` runs it to skip ``pip install -e ".[test]"`` (a few
seconds even when there is nothing to do) when nothing is missing. Requirements of requirements are not
followed: pip checked them when it installed these.
"""

from __future__ import annotations

import json
import re
import sys
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXTRA = "test"


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def requirement_class():
    """packaging's Requirement: from packaging if it is installed (mkdocs needs it), else pip's own copy."""
    try:
        from packaging.requirements import Requirement
    except ImportError:
        from pip._vendor.packaging.requirements import Requirement
    return Requirement


def missing_requirement(project: dict, extra: str = EXTRA) -> str | None:
    """The first of ``project``'s dependencies and ``extra``'s requirements (following the project's own
    extras that it names, as in "quadsitl[docs]") that is not installed at a version that satisfies it, in
    one line; None when all are. ``project`` is pyproject.toml's [project] table."""
    requirement = requirement_class()
    name = project["name"]
    extras = project.get("optional-dependencies", {})
    pending: list[tuple[str, str]] = [(text, "") for text in project.get("dependencies", [])]
    pending += [(text, extra) for text in extras.get(extra, [])]
    done_extras = {extra}
    while pending:
        text, in_extra = pending.pop(0)
        req = requirement(text)
        if req.marker is not None and not req.marker.evaluate({"extra": in_extra}):
            continue
        if canonical(req.name) == canonical(name):  # an extra naming other extras of the project
            for more in sorted(set(req.extras) - done_extras):
                done_extras.add(more)
                pending += [(t, more) for t in extras.get(more, [])]
            continue
        try:
            version = metadata.version(req.name)
        except metadata.PackageNotFoundError:
            return f"{req.name} is not installed"
        if req.specifier and not req.specifier.contains(version, prereleases=True):
            return f"{req.name} {version} is installed, {name} needs {req.name}{req.specifier}"
    return None


def first_missing(root: Path = ROOT, extra: str = EXTRA) -> str | None:
    """What is missing, in one line, or None when nothing is."""
    try:
        import tomllib
    except ImportError:  # Python 3.10: tomli is one of the project's dependencies
        try:
            import tomli as tomllib
        except ImportError:
            return "tomli is not installed"
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    name = project["name"]
    try:
        dist = metadata.distribution(name)
    except metadata.PackageNotFoundError:
        return f"{name} is not installed"
    url = json.loads(dist.read_text("direct_url.json") or "{}")
    if not url.get("dir_info", {}).get("editable") or url.get("url") != root.as_uri():
        return f"{name} is installed, but not from {root} in editable mode"
    if dist.version != project["version"]:
        return f"{name} {dist.version} is installed, pyproject.toml says {project['version']}"
    return missing_requirement(project, extra)


if __name__ == "__main__":
    why = first_missing()
    if why:
        print(why)
    sys.exit(1 if why else 0)
