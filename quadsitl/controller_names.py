"""The names ``--controller``, a preset's ``[controller] type`` and a sweep's ``controller`` take: a built-in's, or a
controller of your own to load (:mod:`autopilot.plugin`). Plain Python, importing nothing: the command line checks a
name without loading the compiler."""

from __future__ import annotations

from pathlib import Path

BUILT_IN = ("backstepping", "pd")  # compiled into the autopilot's tick
SHIPPED = {"px4": "autopilot.px4:PX4Cascade"}  # shipped controllers that plug in as yours do: name → module:Name
ALLOWED = "backstepping, pd, px4, or a controller of your own: path/to/file.py:Name or package.module:Name"


def is_plugin(name: str) -> bool:
    """``name`` is a controller to load: a shipped one's name (px4), ``path/to/file.py:Name`` or
    ``package.module:Name``."""
    where, _, cls = name.rpartition(":")
    return name in SHIPPED or (name not in BUILT_IN and bool(where) and cls.isidentifier())


def is_controller_name(name: str) -> bool:
    """A built-in's name or a controller to load (whether it loads is checked when it is loaded)."""
    return name in BUILT_IN or is_plugin(name)


def absolute(name: str, base: Path | None = None) -> str:
    """``name`` with a controller file's path made absolute (relative to ``base``, default the working directory),
    for processes and sweeps that run elsewhere; any other name as it is."""
    where, _, cls = name.rpartition(":")
    if not is_plugin(name) or not (where.endswith(".py") or "/" in where or "\\" in where):
        return name
    path = Path(where).expanduser()
    if base is not None and not path.is_absolute():
        path = base / path
    return f"{path.resolve()}:{cls}"
