"""The one compiler every equation goes through: numba in nopython mode, with its on-disk cache.

The equations (dynamics, mixer, actuators, integrators, controllers, the per-tick wire codec) are plain
Python functions on plain numbers, decorated with :func:`jit`. numba compiles each one to machine code the
first time it is called with a new combination of argument types and keeps the result on disk, so every
later process loads it instead of compiling.

numba checks a cached function against its own file only, not against the functions it calls (a kernel
in one module inlines equations from others). The cache therefore lives in a folder named by a hash of
every source file of the three packages (:func:`cache_dir`): change any equation and everything is
compiled afresh, once; folders no checkout has used for a week are removed.

One source serves every runtime: the plant and autopilot processes, ``quadsitl sim`` and the batch
engine call the same compiled functions, and ``NUMBA_DISABLE_JIT=1`` runs the very same source as
ordinary Python (the reference the tests compare the compiled code with, and the "pure Python" figure of
``quadsitl bench``). The processes run one tick on made-up data before their first real one, so no
compilation ever happens on the per-tick path.

Settings, the same for every function: no ``fastmath`` (IEEE semantics, so results equal Python's to the
last bit or nearly: the tests allow 1e-12), and numpy's error model (a division by zero gives inf or NaN
instead of raising; inputs are validated before they get here, see :mod:`quadsitl.config`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TypeVar

import numba
import numpy as np

from quadsitl import numba_inlining, numba_overhead
from quadsitl.compile_cache import cache_dir

F = TypeVar("F", bound=Callable)
T = TypeVar("T")

DISABLED = os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")
"""True when ``NUMBA_DISABLE_JIT=1``: every :func:`jit` function runs as ordinary Python."""


numba.config.CACHE_DIR = str(cache_dir())
numba_inlining.install()  # numba's inliner copies an inlined function's IR in linear time (see the module)
numba_overhead.install()  # and spends less of a first compile in its own bookkeeping (see the module)

PROCESS_OPT = 2
"""LLVM's optimisation level for the code the plant and autopilot processes compile (:func:`favour_compile_time`)."""


def favour_compile_time() -> None:
    """Compile at LLVM's ``-O2`` (:data:`PROCESS_OPT`) instead of numba's default ``-O3`` from now on, unless the user
    chose a level (``NUMBA_OPT``): for the plant and autopilot processes, whose first run compiles faster at ``-O2``
    with ticks as quick (docs/performance.md#compiling-on-first-run). The batch engine's loops, which ``-O3``
    makes quicker, compile in processes that keep the default. The results are the same to the bit either way: no
    fast-math, so LLVM keeps every floating-point operation as written. Call before the first compile."""
    if "NUMBA_OPT" not in os.environ:
        numba.config.OPT = type(numba.config.OPT)(PROCESS_OPT)  # numba's own level type, read at each compile


def jit(fn: F | None = None, *, inline: bool = False, nogil: bool = False) -> F | Callable[[F], F]:
    """Compile ``fn`` in nopython mode, cached on disk (see the module's docstring). ``@jit(inline=True)``: the
    function's body is also inlined into every compiled caller (numba's ``inline="always"``), for the equations
    of one control tick, which the per-tick kernels and the sweeps' batch engine call millions of times; the
    results are the same to the bit, and only callers' compile times grow. Also for the codec's small byte helpers
    (:mod:`quadsitl.codec`, :mod:`quadsitl.hil`): compiled code calls them with constant offsets and sizes, and numba
    compiles a function called from compiled code once per combination of constant arguments (13 versions of one
    four-byte read); inlined, they compile with their caller, which shortened both the autopilot's compile and its
    tick (docs/performance.md#compiling-on-first-run). ``@jit(nogil=True)``: the function runs without Python's global
    lock, for the compiled loops that wait on a socket (:func:`autopilot.plant_loop.serve_unlocked`), so that the other
    threads of a process hosting several vehicles (:mod:`autopilot.host`) run meanwhile."""

    def compile_(f: F) -> F:
        inlined = "always" if inline else "never"
        return numba.njit(cache=True, error_model="numpy", inline=inlined, nogil=nogil)(f)  # type: ignore[return-value]

    return compile_ if fn is None else compile_(fn)


@jit(inline=True)
def copy_into(dst: np.ndarray, src: np.ndarray) -> None:
    """``dst[:src.size] = src`` for 1-D arrays, element by element: numba's own slice assignment checks the shapes
    and compiles, for its error, a message formatted with them (string formatting, seconds of a first run's
    compile in each process: docs/performance.md#compiling-on-first-run). IndexError when ``dst`` is shorter."""
    if dst.size < src.size:
        raise IndexError("copy_into: the destination is shorter than the source")
    for i in range(src.size):
        dst[i] = src[i]


def specialized(fn: F, *args: object) -> F:
    """The machine code of the :func:`jit` function ``fn`` for the types of ``args`` (compiled, or loaded from the
    cache, now), callable without numba's dispatch: a call from Python then skips working out the type of every argument
    and choosing among the compiled versions, which for the plant's step (12 arguments) was most of the call
    (docs/performance.md#per-call; what remains is mostly unpacking the arrays: :func:`sitl.plant.step_work` takes
    three). For the objects that call one function on the same arrays every tick (:class:`sitl.plant.Plant`, the
    controllers); they must pass arguments of exactly these types (the same arrays, or arrays of the same dtype,
    dimensions and layout): an array of another dtype is refused with a TypeError, but one of other dimensions is not
    checked, and a number is converted to the type it had here (an int where a float was given becomes a float; a float
    where an int was, an int). With ``NUMBA_DISABLE_JIT=1``, ``fn`` itself."""
    if DISABLED:
        return fn
    return fn.compile(tuple(numba.typeof(a) for a in args))  # type: ignore[attr-defined]


if DISABLED:

    def borrowed(value: T) -> T:
        """``value`` itself (see the compiled version's docstring)."""
        return value

else:
    from numba.core import cgutils, types
    from numba.extending import intrinsic

    def _without_owner(builder, ty, value):
        """The LLVM value of ``value`` (of numba type ``ty``) with every array's meminfo in it NULL."""
        if isinstance(ty, types.Array):  # the array's struct: (meminfo, parent, nitems, itemsize, data, shape, strides)
            return builder.insert_value(value, cgutils.get_null_value(value.type.elements[0]), 0)
        if isinstance(ty, types.BaseTuple):
            for i, t in enumerate(ty.types):
                value = builder.insert_value(value, _without_owner(builder, t, builder.extract_value(value, i)), i)
        return value

    @intrinsic
    def borrowed(typingctx, value):
        """``value`` (an array, or a tuple of them, nested) with no owner: the same data, shape and strides, but
        numba's reference count of its memory is not kept (the meminfo is NULL), so neither its copies nor its slices
        count. Each view of an array numba makes (a slice, an argument, a tuple's element) otherwise takes and drops a
        reference with an atomic instruction, a large share of a per-tick loop's time
        (docs/performance.md#reference-counts). Only for arrays that live longer than the compiled call (its
        arguments), and never returned."""

        def codegen(context, builder, sig, args):
            out = _without_owner(builder, sig.args[0], args[0])
            context.nrt.incref(builder, sig.return_type, out)  # a new reference: its other members counted
            return out

        return value(value), codegen


if DISABLED:

    def constants(values: np.ndarray, size: int) -> tuple:
        """The first ``size`` entries of a parameter array as a tuple (see the compiled version's docstring)."""
        return tuple(values[:size])

else:
    from numba.np.unsafe.ndarray import to_fixed_tuple

    @numba.njit(inline="always")
    def constants(values: np.ndarray, size: int) -> tuple:
        """The first ``size`` entries (a constant) of a parameter array as a tuple, for a compiled loop that reads
        them on every pass (the sweeps' batch engine): the equations index a tuple as they index the array, and
        the compiler then knows no store in the loop can change them, so it computes what depends on them alone
        (1/Ix, l/Ix, ...) once before the loop instead of on every tick. The results are the same to the bit."""
        return to_fixed_tuple(values, size)
