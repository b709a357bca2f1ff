"""Numbers stored in and read from byte buffers at any offset, little-endian, for the compiled codecs.

MAVLink payloads (:mod:`quadsitl.codec`, :mod:`quadsitl.hil`, :mod:`autopilot.stream_frames`) and the telemetry records
(:mod:`autopilot.tick`) put floats and integers at byte offsets that are not multiples of their size. The obvious numba
spelling, ``buf[at : at + 4].view(np.float32)[0] = value``, builds two array objects per field and counts references on
each (an ODOMETRY frame's fields then cost more than its CRC: docs/performance.md#per-call). :func:`put` and :func:`get`
instead compile to one unaligned store or load (x86-64 and AArch64 allow them), after a bounds check that raises
IndexError for a field that does not fit in ``buf``.

With ``NUMBA_DISABLE_JIT=1`` both are the same operations in numpy (the reference the tests compare with).
"""

from __future__ import annotations

import sys

import numpy as np

from quadsitl.jit import DISABLED

if sys.byteorder != "little":  # MAVLink is little-endian, and the stores below write the machine's order
    raise ImportError("quadsitl's codecs need a little-endian machine")


def put(buf: np.ndarray, at: int, value: np.generic) -> None:
    """``value`` at buf[at:]: a numpy scalar, whose type is the field's (``np.float32(x)``, ``np.uint16(n)``; in
    compiled code a plain int is an int64, a float a float64); ``buf`` a contiguous uint8 array."""
    size = value.dtype.itemsize
    if at < 0 or at + size > buf.size:
        raise IndexError("field outside the buffer")
    buf[at : at + size].view(value.dtype)[0] = value


def get(buf: np.ndarray, at: int, dtype: type) -> np.generic:
    """The ``dtype`` number (``np.float32``, ``np.int64``, ...) at buf[at:]; ``buf`` a contiguous uint8 array."""
    size = np.dtype(dtype).itemsize
    if at < 0 or at + size > buf.size:
        raise IndexError("field outside the buffer")
    return buf[at : at + size].view(dtype)[0]


if not DISABLED:  # the compiled versions, used wherever a compiled function calls put or get
    from numba.core import types
    from numba.extending import intrinsic, overload

    def _bytes(buf: types.Type, at: types.Type) -> bool:
        return (isinstance(buf, types.Array) and buf.dtype == types.uint8 and buf.ndim == 1 and buf.layout == "C"
                and isinstance(at, types.Integer))  # fmt: skip

    @intrinsic
    def _store(typingctx, buf, at, value):
        if not (_bytes(buf, at) and isinstance(value, (types.Integer, types.Float))):
            return None

        def codegen(context, builder, signature, args):
            array, offset, number = args
            data = context.make_array(buf)(context, builder, array).data
            pointer = builder.bitcast(builder.gep(data, [offset]), context.get_value_type(value).as_pointer())
            builder.store(number, pointer, align=1)
            return context.get_dummy_value()

        return types.void(buf, at, value), codegen

    @intrinsic
    def _load(typingctx, buf, at, dtype):
        if not (_bytes(buf, at) and isinstance(dtype, types.NumberClass)):
            return None
        number = dtype.instance_type

        def codegen(context, builder, signature, args):
            array, offset, _ = args
            data = context.make_array(buf)(context, builder, array).data
            pointer = builder.bitcast(builder.gep(data, [offset]), context.get_value_type(number).as_pointer())
            return builder.load(pointer, align=1)

        return number(buf, at, dtype), codegen

    @overload(put, inline="always", jit_options={"cache": True})
    def _put(buf, at, value):
        if not (_bytes(buf, at) and isinstance(value, (types.Integer, types.Float))):
            return None
        size = value.bitwidth // 8

        def impl(buf, at, value):
            if at < 0 or at + size > buf.size:
                raise IndexError("field outside the buffer")
            _store(buf, at, value)

        return impl

    @overload(get, inline="always", jit_options={"cache": True})
    def _get(buf, at, dtype):
        if not (_bytes(buf, at) and isinstance(dtype, types.NumberClass)):
            return None
        size = dtype.instance_type.bitwidth // 8

        def impl(buf, at, dtype):
            if at < 0 or at + size > buf.size:
                raise IndexError("field outside the buffer")
            return _load(buf, at, dtype)

        return impl
