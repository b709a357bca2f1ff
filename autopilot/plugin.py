"""Controllers that plug in (:mod:`quadsitl.controller` is the interface they meet): loaded from a file or a module,
checked, compiled, and called by the autopilot's tick (:func:`autopilot.tick.autopilot_step`).

A loaded controller's law is compiled once into a C-callable function of one signature (:data:`SIGNATURE`: the
address of its buffer, the time, the period), and the vehicle's compiled loops take it by its address, an integer:
they are compiled, and cached on disk, once for all controllers; only the law is compiled for each run. The
law works on one float64 buffer (:data:`B_STATE` …): the state and setpoint the autopilot copies in, the command it
reads back, the model, then the parameters and the memory. Every failure to load (no file, a syntax error, no such
class, a malformed declaration, a law that does not compile or commands NaN at hover) is a
:class:`ControllerError` of one line naming the controller and the reason.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import math
import re
import sys
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import types

from quadsitl import controller as api
from quadsitl.controller_names import BUILT_IN, SHIPPED, is_plugin  # noqa: F401 (is_plugin: this module's callers')
from quadsitl.jit import DISABLED
from quadsitl.param_arrays import VEHICLE_SIZE

# The law's buffer: the state (api.STATE_SIZE), the setpoint (api.SETPOINT_SIZE), the command (4), the model
# (VEHICLE_SIZE), then the parameters and the memory (their sizes the controller's).
B_STATE = 0
B_SETPOINT = B_STATE + api.STATE_SIZE
B_COMMAND = B_SETPOINT + api.SETPOINT_SIZE
B_MODEL = B_COMMAND + 4
B_PARAMS = B_MODEL + VEHICLE_SIZE

SIGNATURE = types.void(types.CPointer(types.float64), types.float64, types.float64)
"""What the compiled tick calls: law(buffer's address, t [s], dt [s])."""


class ControllerError(ValueError):
    """A controller that cannot fly: the message is one line naming it and the reason."""


def _no_law(buf, t, dt):
    pass


if DISABLED:
    NO_ENTRY: Callable = _no_law
else:
    from numba import cfunc

    NO_ENTRY = cfunc(SIGNATURE, cache=True)(_no_law)


def call_law(entry: Callable | int, buf: np.ndarray, t: float, dt: float) -> None:
    """The law ``entry`` on its buffer at time ``t`` [s], period ``dt`` [s]: compiled, ``entry`` is the address of the
    law's C function (:data:`SIGNATURE`), called with the buffer's; with NUMBA_DISABLE_JIT, the Python law on the
    buffer itself. (An address, not numba's first-class function type: an int costs the dispatch of a compiled tick
    called from Python nothing, where a function value costs it more than the tick: docs/performance.md#per-call.)"""
    entry(buf, t, dt)


if not DISABLED:
    from llvmlite import ir
    from numba.extending import intrinsic, overload

    @intrinsic
    def _call_address(typingctx, address, buf, t, dt):
        """Call the C function at ``address`` (void(double*, double, double)) with ``buf``'s data, ``t``, ``dt``."""
        if not (isinstance(address, types.Integer) and isinstance(buf, types.Array) and buf.dtype == types.float64):
            return None

        def codegen(context, builder, signature, args):
            addr, arr, tv, dtv = args
            data = context.make_array(buf)(context, builder, arr).data
            fnty = ir.FunctionType(ir.VoidType(), [data.type, ir.DoubleType(), ir.DoubleType()])
            builder.call(builder.inttoptr(addr, fnty.as_pointer()), [data, tv, dtv])
            return context.get_dummy_value()

        return types.void(address, buf, types.float64, types.float64), codegen

    @overload(call_law, inline="always")
    def _call_law(entry, buf, t, dt):
        return lambda entry, buf, t, dt: _call_address(entry, buf, t, dt)


def _handle(entry: Callable) -> Callable | int:
    """What the compiled tick takes for ``entry``: its address (compiled), or the Python law itself."""
    return entry if DISABLED else entry.address


def no_plug() -> tuple:
    """The ``plug`` argument of the tick for a built-in controller (:func:`autopilot.tick.autopilot_step`)."""
    return (_handle(NO_ENTRY), np.zeros(B_PARAMS), B_PARAMS)


@dataclass
class Plugged:
    """A loaded controller: its class, its declared parameters and memory, and its compiled law (``entry``: a
    C-callable function of :data:`SIGNATURE`, or with ``NUMBA_DISABLE_JIT`` the same law as Python)."""

    spec: str
    cls: type
    parameters: tuple[api.Parameter, ...]
    memory: int
    entry: Callable

    def defaults(self) -> dict[str, float]:
        return {p.name: float(p.default) for p in self.parameters}

    def values(self, overrides: Mapping[str, float] | None = None) -> dict[str, float]:
        """The parameters' values: the defaults, ``overrides`` by name or MAVLink name, each checked against its
        range."""
        values = self.defaults()
        by_name = {p.name: p for p in self.parameters}
        by_id = {p.param_id: p for p in self.parameters}
        for name, value in (overrides or {}).items():
            p = by_name.get(name) or by_id.get(name.upper())
            if p is None:
                raise ControllerError(f"controller {self.spec}: no parameter {name!r} (it has: "
                                      f"{', '.join(by_name) or 'none'})")  # fmt: skip
            if not p.accepts(float(value)):
                raise ControllerError(f"controller {self.spec}: {name} = {value!r}: expected {p.allowed()}")
            values[p.name] = float(value)
        return values

    def check(self, values: Mapping[str, float], model: np.ndarray) -> str | None:
        """The controller's own check of a set of values on ``model`` (the autopilot's, :func:`vehicle_array`): why
        they cannot fly, or None."""
        from quadsitl.param_arrays import FIELD_COLUMNS

        check = getattr(self.cls, "check", None)
        if check is None:
            return None
        named = {field: float(model[cols[0]]) for field, cols in FIELD_COLUMNS.items() if len(cols) == 1}
        try:
            why = check(dict(values), named)
        except Exception as exc:  # the user's code: any failure is its answer
            return f"its check raised {type(exc).__name__}: {exc}"
        return None if why is None else str(why)

    def buffer(self, model: np.ndarray, values: Mapping[str, float]) -> np.ndarray:
        """The law's buffer for ``values`` on ``model``; the memory zero. The tick does not copy the model again: a
        new model (a VM_* parameter) builds a new controller and buffer."""
        buf = np.zeros(B_PARAMS + len(self.parameters) + self.memory)
        buf[B_MODEL : B_MODEL + VEHICLE_SIZE] = model
        for i, p in enumerate(self.parameters):
            buf[B_PARAMS + i] = values[p.name]
        return buf

    def plug(self, model: np.ndarray, values: Mapping[str, float] | None = None) -> tuple:
        """The tick's ``plug`` argument: (the compiled law, its buffer, where its memory starts), checked: the
        values and the controller's own check, and a probe of the law at hover, which must command finite values."""
        values = self.values(values)
        why = self.check(values, model)
        if why:
            raise ControllerError(f"controller {self.spec}: {why}")
        buf = self.buffer(model, values)
        probe = buf.copy()
        probe[B_STATE + api.Z] = -5.0
        inf = math.inf
        probe[B_SETPOINT : B_SETPOINT + api.SETPOINT_SIZE] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0, 0.0,
                                                              0.0, 0.0, inf, inf, inf, 0.6)  # fmt: skip
        probe[B_COMMAND : B_COMMAND + 4] = math.nan
        try:
            _call(self.entry, probe, 0.0, 0.001)
        except Exception as exc:
            raise ControllerError(f"controller {self.spec}: its law raised {_one_line(exc)}") from None
        command = probe[B_COMMAND : B_COMMAND + 4]
        if not np.isfinite(command).all():
            raise ControllerError(f"controller {self.spec}: its law commands {command.tolist()} at hover (5 m up, "
                                  "at rest, holding there): expected finite thrust and torques")  # fmt: skip
        return (_handle(self.entry), buf, B_PARAMS + len(self.parameters))


def _call(entry: Callable, buf: np.ndarray, t: float, dt: float) -> None:
    if DISABLED:
        entry(buf, t, dt)
    else:
        entry.ctypes(buf.ctypes.data_as(entry.ctypes.argtypes[0]), t, dt)


def _one_line(exc: BaseException) -> str:
    """An exception in one line: its type and first line, and where in the user's code it was raised."""
    text = str(exc).strip().splitlines()
    first = next((line.strip() for line in text if line.strip()), "")
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def _user_frame(exc: BaseException, path: str) -> str:
    """'file:line' of the innermost frame of ``exc`` in ``path``, or ''."""
    for frame in reversed(traceback.extract_tb(exc.__traceback__)):
        if frame.filename == path:
            return f"{Path(path).name}:{frame.lineno}: "
    return ""


def _import(spec: str) -> type:
    """The class ``spec`` names (``path/to/file.py:Name`` or ``package.module:Name``)."""
    where, _, name = spec.rpartition(":")
    if not where or not name:
        raise ControllerError(f"controller {spec!r}: expected a built-in ({', '.join(BUILT_IN)}), "
                              "path/to/file.py:Name or package.module:Name")  # fmt: skip
    if where.endswith(".py") or "/" in where or "\\" in where:
        path = Path(where).expanduser()
        if not path.is_file():
            raise ControllerError(f"controller {spec}: no such file {where}")
        module_name = "quadsitl_controller_" + re.sub(r"\W", "_", str(path.resolve()))
        loader_spec = importlib.util.spec_from_file_location(module_name, path)
        assert loader_spec is not None and loader_spec.loader is not None
        module = importlib.util.module_from_spec(loader_spec)
        sys.modules[module_name] = module
        try:
            loader_spec.loader.exec_module(module)
        except SyntaxError as exc:
            raise ControllerError(f"controller {spec}: {Path(exc.filename or where).name}:{exc.lineno}: "
                                  f"SyntaxError: {exc.msg}") from None  # fmt: skip
        except Exception as exc:  # the user's module: any failure to import is its reason
            raise ControllerError(f"controller {spec}: importing it raised "
                                  f"{_user_frame(exc, str(path))}{_one_line(exc)}") from None  # fmt: skip
    else:
        try:
            module = importlib.import_module(where)
        except ModuleNotFoundError as exc:
            raise ControllerError(f"controller {spec}: no module {exc.name!r}") from None
        except Exception as exc:  # the user's module: any failure to import is its reason
            raise ControllerError(f"controller {spec}: importing {where} raised {_one_line(exc)}") from None
    cls = getattr(module, name, None)
    if cls is None:
        found = sorted(k for k, v in vars(module).items() if inspect.isclass(v) and hasattr(v, "law"))
        raise ControllerError(f"controller {spec}: {where} has no {name!r} (controllers in it: "
                              f"{', '.join(found) or 'none'})")  # fmt: skip
    return cls


LAW_ARGUMENTS = ("t", "dt", "x", "sp", "model", "k", "mem", "u")


def _declared(spec: str, cls: type) -> tuple[tuple[api.Parameter, ...], int, Callable]:
    """The class's parameters, memory and law, checked."""
    law = inspect.getattr_static(cls, "law", None)
    if not isinstance(law, staticmethod):
        raise ControllerError(f"controller {spec}: expected a @staticmethod law({', '.join(LAW_ARGUMENTS)})")
    law = law.__func__
    arguments = tuple(inspect.signature(law).parameters)
    if len(arguments) != len(LAW_ARGUMENTS):
        raise ControllerError(f"controller {spec}: law takes ({', '.join(arguments)}): expected "
                              f"({', '.join(LAW_ARGUMENTS)})")  # fmt: skip
    parameters = tuple(getattr(cls, "parameters", ()))
    seen: set[str] = set()
    for p in parameters:
        if not isinstance(p, api.Parameter):
            raise ControllerError(f"controller {spec}: parameters holds {p!r}: expected quadsitl.controller."
                                  "Parameter")  # fmt: skip
        if not (math.isfinite(p.low) and math.isfinite(p.high) and p.low <= p.high):
            raise ControllerError(f"controller {spec}: parameter {p.name}: range [{p.low}, {p.high}]: expected "
                                  "finite low <= high")  # fmt: skip
        if not p.accepts(p.default):
            raise ControllerError(f"controller {spec}: parameter {p.name}: default {p.default!r}: expected "
                                  f"{p.allowed()}")  # fmt: skip
        if not api.MAVLINK_NAME.fullmatch(p.param_id):
            raise ControllerError(f"controller {spec}: parameter {p.name}: MAVLink name {p.param_id!r}: expected "
                                  "capitals, digits and _, at most 16 characters")  # fmt: skip
        if p.param_id in seen:
            raise ControllerError(f"controller {spec}: parameter {p.param_id} declared twice")
        seen.add(p.param_id)
    memory = getattr(cls, "memory", 0)
    if not isinstance(memory, int) or not 0 <= memory <= 10_000:
        raise ControllerError(f"controller {spec}: memory = {memory!r}: expected an integer in [0, 10000]")
    return parameters, memory, law


def _entry(spec: str, law: Callable, n_params: int, memory: int) -> Callable:
    """The law compiled behind :data:`SIGNATURE`, or with NUMBA_DISABLE_JIT the same as Python."""
    s, c, m, p = B_SETPOINT, B_COMMAND, B_MODEL, B_PARAMS
    end_params, end = p + n_params, p + n_params + memory
    if DISABLED:

        def python_entry(buf, t, dt):
            law(t, dt, buf[:s], buf[s:c], buf[m:p], buf[p:end_params], buf[end_params:end], buf[c:m])

        return python_entry
    from numba import carray, cfunc, njit
    from numba.core.errors import NumbaError

    compiled = njit(law)

    def entry(address, t, dt):
        buf = carray(address, (end,))
        compiled(t, dt, buf[:s], buf[s:c], buf[m:p], buf[p:end_params], buf[end_params:end], buf[c:m])

    try:
        return cfunc(SIGNATURE)(entry)
    except NumbaError as exc:
        raise ControllerError(f"controller {spec}: its law does not compile: {_numba_reason(exc)}") from None


def _numba_reason(exc: BaseException) -> str:
    """numba's error in one line: the first line that says what went wrong, and the user's line it points at."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(exc))
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    skip = ("Failed in nopython mode pipeline", "During:", 'File "', "^", "- Resolution failure", "No implementation")
    reason = next((line for line in lines if not line.startswith(skip) and not line.startswith(">")), "")
    where = next((m.group(1, 2) for line in lines if (m := re.search(r'File "([^"]+)", line (\d+)', line))), None)
    place = f" ({Path(where[0]).name}:{where[1]})" if where else ""
    return (reason or type(exc).__name__) + place


_LOADED: dict[tuple[str, float], Plugged] = {}  # this process's loaded controllers, by name and file time


def load(spec: str) -> Plugged:
    """The controller ``spec`` names (a shipped one's name, ``path/to/file.py:Name`` or ``package.module:Name``), its
    law compiled, once per process while its file is unchanged (a sweep flies it trial after trial). Raises
    :class:`ControllerError` (one line) when it cannot be."""
    where = SHIPPED.get(spec, spec).rpartition(":")[0]
    path = Path(where).expanduser()
    key = (spec, path.stat().st_mtime if where.endswith(".py") and path.is_file() else 0.0)
    if key not in _LOADED:
        cls = _import(SHIPPED.get(spec, spec))
        parameters, memory, law = _declared(spec, cls)
        _LOADED[key] = Plugged(spec, cls, parameters, memory, _entry(spec, law, len(parameters), memory))
    return _LOADED[key]
