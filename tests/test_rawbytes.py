"""The codecs' byte-level helpers: numbers stored and read at any offset (quadsitl.rawbytes) and MAVLink's CRC eight
bytes at a time (quadsitl.codec.crc16), against numpy's and pymavlink's own, compiled and as plain Python."""

import numpy as np
import pytest
from pymavlink.generator.mavcrc import x25crc

from quadsitl import codec
from quadsitl.jit import jit
from quadsitl.rawbytes import get, put
from tests.both_runtimes import outputs

DTYPES = (np.uint8, np.uint16, np.int16, np.uint32, np.int32, np.uint64, np.int64, np.float32, np.float64)


@jit
def _round_trip_f32(buf: np.ndarray, at: int, value: float) -> float:
    put(buf, at, np.float32(value))
    return np.float64(get(buf, at, np.float32))


@jit
def _round_trip_i64(buf: np.ndarray, at: int, value: int) -> int:
    put(buf, at, np.int64(value))
    return get(buf, at, np.int64)


@jit
def _put_u16(buf: np.ndarray, at: int, value: int) -> None:
    put(buf, at, np.uint16(value))


def test_compiled_stores_are_numpys_little_endian_bytes_at_every_offset():
    rng = np.random.default_rng(7)
    for at in range(0, 17):
        value = float(rng.normal() * 1e3)
        buf = np.zeros(32, dtype=np.uint8)
        assert _round_trip_f32(buf, at, value) == float(np.float32(value))
        assert buf[at : at + 4].tobytes() == np.float32(value).astype("<f4").tobytes()
        assert not buf[:at].any() and not buf[at + 4 :].any()  # nothing else written
        n = int(rng.integers(-(2**62), 2**62))
        buf[:] = 0
        assert _round_trip_i64(buf, at, n) == n
        assert buf[at : at + 8].tobytes() == np.int64(n).astype("<i8").tobytes()
    buf = np.zeros(4, dtype=np.uint8)
    _put_u16(buf, 1, 0xABCD)
    assert buf.tolist() == [0, 0xCD, 0xAB, 0]


def test_a_field_past_the_end_of_the_buffer_is_an_index_error_not_a_stray_write():
    guard = np.zeros(64, dtype=np.uint8)
    buf = guard[8:16]  # the bytes after it belong to someone else
    with pytest.raises(IndexError):
        _round_trip_i64(buf, 1, -1)  # would write buf[1:9]: one byte past the end
    with pytest.raises(IndexError):
        _round_trip_f32(buf, -1, 1.0)
    assert not guard.any()
    assert _round_trip_i64(buf, 0, -1) == -1  # the last offset that fits


def test_every_type_reads_back_the_same_compiled_and_as_plain_python():
    code = f"""
import numba
import numpy as np
from quadsitl.rawbytes import get, put
jit = numba.njit  # (numba's cache needs a file: this snippet has none)
DTYPES = ({", ".join(f"np.{d.__name__}" for d in DTYPES)},)

@jit
def fill(buf, a, b, c, d, e, f, g, h, i):
    at = 3
    put(buf, at, a); at += 1
    put(buf, at, b); at += 2
    put(buf, at, c); at += 2
    put(buf, at, d); at += 4
    put(buf, at, e); at += 4
    put(buf, at, f); at += 8
    put(buf, at, g); at += 8
    put(buf, at, h); at += 4
    put(buf, at, i)
    return (get(buf, 3, np.uint8), get(buf, 4, np.uint16), get(buf, 6, np.int16), get(buf, 8, np.uint32),
            get(buf, 12, np.int32), get(buf, 16, np.uint64), get(buf, 24, np.int64), get(buf, 32, np.float32),
            get(buf, 36, np.float64))

buf = np.zeros(48, dtype=np.uint8)
values = [dt(v) for dt, v in zip(DTYPES, (200, 65000, -30000, 4e9, -2e9, 2**63 + 5, -(2**62), 1.1, -2.5e-300))]
back = fill(buf, *values)
print(buf.tobytes().hex(), [np.array(v, dtype=dt).tobytes().hex() for v, dt in zip(back, DTYPES)])
print(all(np.array(v, dtype=dt) == w for v, dt, w in zip(back, DTYPES, values)))
"""
    compiled, python = outputs(code)
    assert compiled == python
    assert compiled.splitlines()[1] == "True"  # every number read back as it was stored


def test_crc16_is_pymavlinks_x25_for_any_length_and_start():
    rng = np.random.default_rng(3)
    for _ in range(600):
        n, start = int(rng.integers(0, 300)), int(rng.integers(0, 9))
        buf = rng.integers(0, 256, start + n + 3).astype(np.uint8)
        extra = int(rng.integers(0, 256))
        reference = x25crc(buf[start : start + n].tobytes())
        reference.accumulate(bytes([extra]))
        assert codec.crc16(buf, start, start + n, extra) == reference.crc, (n, start)


def test_crc16_is_the_same_compiled_and_as_plain_python():
    code = """
import numpy as np
from quadsitl import codec
rng = np.random.default_rng(5)
print([codec.crc16(rng.integers(0, 256, n).astype(np.uint8), 0, n, n % 256) for n in range(0, 70)])
"""
    compiled, python = outputs(code)
    assert compiled == python
