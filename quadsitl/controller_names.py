"""The names ``--controller``, a preset's ``[controller] type`` and a sweep's ``controller`` take: a built-in's, or a
controller of your own to load (:mod:`autopilot.plugin`). Plain Python, importing nothing: the command line checks a
name without loading the compiler."""

from __future__ import annotations

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
