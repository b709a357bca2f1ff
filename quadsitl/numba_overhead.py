"""Three costs numba 0.68's compiler pays in Python on every first compile that buy quadsitl nothing.

A profile of the autopilot's first compile (docs/performance.md#numbas-own-overhead) found, besides the typing and
lowering a compile needs:

- **Comparing compile flags.** numba looks up every call's typing in a cache keyed by, among others, the compile's
  ``Flags``; each lookup hashes and compares them by building a dict of all their forty options through properties
  (``TargetConfig.values``). Equal flags are those whose options all read the same: :func:`_flags_equal` compares
  only the options set to something other than their default, which is the same relation. numba's hash is already
  the same for all flags of a class (it hashes the sorted option names), and so is this one.
- **Colouring error text.** numba's typing tries templates that fail, and formats each failure's message with
  terminal escapes (colorama, when installed: it is initialised and wound down around every message), even in its
  default ``no_color`` scheme, where the escapes make a message bold at most. With ``NUMBA_COLOR_SCHEME`` unset
  the messages are kept as plain text; a scheme the user chose is left alone.
- **Announcing LLVM's lock.** numba broadcasts an event each time the compiler takes llvmlite's lock, at every call
  into LLVM, so that a compile's metadata can say how long it held the lock
  (``timers["llvm_lock"]``, which then reads 0). numba's other compile events and timers are untouched.

:func:`install` applies each mend only where this numba does what is described (checked on its source, or on the
objects it mends), so another numba version runs unchanged. The machine code is the same: none of this reaches what
numba compiles.
"""

from __future__ import annotations

import functools
import inspect
from typing import Any

_NUMBAS_FLAGS_HASH = "return hash(tuple(sorted(self.values())))"  # TargetConfig.__hash__: the option names only
_NUMBAS_FLAGS_EQUAL = "return self.values() == other.values()"  # TargetConfig.__eq__: every option reads the same


def _differences(flags: Any) -> dict[str, Any]:
    """The options of ``flags`` set to a value other than their default."""
    options = flags.options
    return {name: value for name, value in flags._values.items() if value != options[name].default}


def _flags_equal(self: Any, other: Any) -> Any:
    if type(other) is not type(self):
        return _numbas_flags_equal(self, other)
    return _differences(self) == _differences(other)


def _flags_hash(self: Any) -> int:
    return _class_hash(type(self))


@functools.cache
def _class_hash(config: type) -> int:
    return hash(tuple(sorted(config.options)))  # numba's value: the sorted names of the class's options


_numbas_flags_equal: Any = None


def _mend_flags() -> bool:
    global _numbas_flags_equal
    from numba.core import targetconfig

    config = targetconfig.TargetConfig
    if config.__eq__ is _flags_equal:
        return True
    try:
        if _NUMBAS_FLAGS_HASH not in inspect.getsource(config.__hash__):
            return False
        if _NUMBAS_FLAGS_EQUAL not in inspect.getsource(config.__eq__):
            return False
    except (OSError, TypeError):
        return False
    if any("__eq__" in vars(sub) or "__hash__" in vars(sub) for sub in config.__subclasses__()):
        return False  # a subclass compares in its own way
    _numbas_flags_equal = config.__eq__
    config.__eq__ = _flags_equal  # type: ignore[method-assign,assignment]
    config.__hash__ = _flags_hash  # type: ignore[method-assign,assignment]
    return True


def _plain(msg: str, color: Any = None, style: Any = None) -> str:
    return msg


def _mend_error_text() -> bool:
    from numba.core import config, errors

    scheme = errors.termcolor()
    if config.COLOR_SCHEME != "no_color":
        return False  # the user asked for colours
    if not callable(getattr(scheme, "_markup", None)):
        return scheme.errmsg("x") == "x"  # numba without colorama: plain already
    scheme._markup = _plain  # the instance every numba module holds (errors.termcolor() is a singleton)
    return True


def _mend_lock_events() -> bool:
    from llvmlite.binding import ffi

    lock = getattr(ffi.lib, "_lock", None)
    callbacks = getattr(lock, "_cblist", None)
    if callbacks is None:
        return False
    for acquire, release in list(callbacks):
        if "_initialize_llvm_lock_event" in getattr(acquire, "__qualname__", ""):
            ffi.unregister_lock_callback(acquire, release)
    return True


def install() -> dict[str, bool]:
    """Apply the three mends (see the module); returns which apply to this numba. Idempotent."""
    return {"flags": _mend_flags(), "error_text": _mend_error_text(), "lock_events": _mend_lock_events()}
