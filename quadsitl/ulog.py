"""PX4's ULog file format, written (https://docs.px4.io/main/en/dev_log/ulog_file_format): the header, the
definitions (flag bits, formats, information, parameters) and the data (subscriptions, the topics' samples in time
order, logged strings). Plain Python and numpy; what a flight's topics hold is :mod:`autopilot.flight_log`'s.

A topic is a format (``name:type field;type field;...``, the first field ``uint64_t timestamp`` [µs]) and its
samples as columns; the samples of all topics are written interleaved by timestamp, as PX4's logger writes them,
each a data message packed without padding (little endian)."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1
# ULog's types: their numpy equivalents (little endian)
TYPES = {"int8_t": "<i1", "uint8_t": "<u1", "int16_t": "<i2", "uint16_t": "<u2", "int32_t": "<i4", "uint32_t": "<u4",
         "int64_t": "<i8", "uint64_t": "<u8", "float": "<f4", "double": "<f8", "bool": "<u1", "char": "S1"}  # fmt: skip
LOG_LEVELS = {"emergency": 0, "alert": 1, "critical": 2, "error": 3, "warning": 4, "notice": 5, "info": 6, "debug": 7}


def _message(kind: bytes, body: bytes) -> bytes:
    """One ULog message: its size (uint16, the body's), its type, its body."""
    if len(body) > 0xFFFF:
        raise ValueError(f"a ULog message of {len(body)} bytes: at most 65535")
    return struct.pack("<HB", len(body), kind[0]) + body


def _field(spec: str) -> tuple[str, str, int]:
    """``type name`` or ``type[n] name`` → (type, name, n)."""
    kind, name = spec.split()
    n = 1
    if "[" in kind:
        kind, count = kind[:-1].split("[")
        n = int(count)
    if kind not in TYPES:
        raise ValueError(f"ULog field {spec!r}: type {kind!r} is not one of {', '.join(TYPES)}")
    return kind, name, n


@dataclass
class Topic:
    """A logged topic: its name (PX4's uORB name), its fields (``type name``, ``type[n] name``; the first is
    ``uint64_t timestamp``), and its samples: {field: values} (arrays of one value per sample, or of n per sample
    for an array field), every field given, as many samples each."""

    name: str
    fields: Sequence[str]
    samples: dict[str, np.ndarray]
    multi_id: int = 0

    def dtype(self) -> np.dtype:
        parts = []
        for spec in self.fields:
            kind, name, n = _field(spec)
            parts.append((name, TYPES[kind]) if n == 1 else (name, TYPES[kind], (n,)))
        return np.dtype(parts)  # packed: numpy's structured types have no padding unless asked

    def format(self) -> str:
        return f"{self.name}:" + "".join(f"{spec};" for spec in self.fields)

    def rows(self) -> np.ndarray:
        """The samples as packed records."""
        if _field(self.fields[0])[:2] != ("uint64_t", "timestamp"):
            raise ValueError(f"ULog topic {self.name}: the first field must be 'uint64_t timestamp'")
        dt = self.dtype()
        n = len(self.samples["timestamp"])
        out = np.zeros(n, dtype=dt)
        for name in dt.names:
            out[name] = self.samples[name]
        return out


@dataclass
class Log:
    """What a ULog file holds: information (``type name`` → value: ``char[n]`` strings and numbers), parameters
    (name → float, or int for an ``int32_t`` parameter), topics, and logged strings ((timestamp [µs], level name,
    text))."""

    info: dict[str, object] = field(default_factory=dict)
    parameters: dict[str, float | int] = field(default_factory=dict)
    topics: list[Topic] = field(default_factory=list)
    strings: list[tuple[int, str, str]] = field(default_factory=list)
    start_us: int = 0


def _info(key: str, value: object) -> bytes:
    kind, name = key.split()
    if kind.startswith("char"):
        data = str(value).encode("utf-8")
        key = f"char[{len(data)}] {name}"
    else:
        data = np.asarray(value, dtype=TYPES[kind]).tobytes()
    k = key.encode("ascii")
    return _message(b"I", struct.pack("<B", len(k)) + k + data)


def _parameter(name: str, value: float | int) -> bytes:
    if isinstance(value, int):
        key, data = f"int32_t {name}", struct.pack("<i", value)
    else:
        key, data = f"float {name}", struct.pack("<f", value)
    k = key.encode("ascii")
    return _message(b"P", struct.pack("<B", len(k)) + k + data)


def _definitions(log: Log) -> list[bytes]:
    """The header, the definitions and the subscriptions of ``log``'s topics (topic i is msg_id i)."""
    out = [MAGIC, bytes([VERSION]), struct.pack("<Q", log.start_us)]
    out.append(_message(b"B", bytes(8) + bytes(8) + bytes(24)))  # flag bits: none set, no appended data
    for topic in log.topics:
        out.append(_message(b"F", topic.format().encode("ascii")))
    for key, value in log.info.items():
        out.append(_info(key, value))
    for name, value in log.parameters.items():
        out.append(_parameter(name, value))
    for msg_id, topic in enumerate(log.topics):
        out.append(_message(b"A", struct.pack("<BH", topic.multi_id, msg_id) + topic.name.encode("ascii")))
    return out


def _data(topics: Sequence[Topic], strings: Sequence[tuple[int, str, str]], ids: dict[tuple[str, int], int]
          ) -> list[bytes]:  # fmt: skip
    """The samples of ``topics`` (each subscribed as ``ids[name, multi_id]``) and the logged ``strings``, in time
    order (a topic's own order kept at equal times)."""
    stamps, records = [], []
    for topic in topics:
        rows = topic.rows()
        head = struct.pack("<H", ids[topic.name, topic.multi_id])
        stamps.append(rows["timestamp"].astype(np.int64))
        records.extend(_message(b"D", head + r) for r in (rows.tobytes()[i : i + rows.itemsize]
                                                           for i in range(0, rows.nbytes, rows.itemsize)))  # fmt: skip
    for t, level, text in strings:
        stamps.append(np.array([t], dtype=np.int64))
        body = struct.pack("<BQ", ord("0") + LOG_LEVELS[level], t) + text.encode("utf-8")
        records.append(_message(b"L", body))
    if not records:
        return []
    order = np.argsort(np.concatenate(stamps), kind="stable")
    return [records[i] for i in order.tolist()]


def _ids(topics: Sequence[Topic]) -> dict[tuple[str, int], int]:
    return {(topic.name, topic.multi_id): msg_id for msg_id, topic in enumerate(topics)}


def encode(log: Log) -> bytes:
    """The ULog file of ``log``, as bytes."""
    return b"".join(_definitions(log) + _data(log.topics, log.strings, _ids(log.topics)))


def write(path: Path, log: Log) -> None:
    """Write ``log`` to ``path`` as a ULog file."""
    path.write_bytes(encode(log))


class Writer:
    """A ULog file written as a flight goes, as PX4's logger writes it: the definitions of ``log`` (its information,
    parameters and topics' formats; its samples and strings, if any, go first) when opened, then each
    :meth:`append`'s samples and strings. A file written in one append equals :func:`encode`'s."""

    def __init__(self, path: Path, log: Log) -> None:
        self.path = path
        self.ids = _ids(log.topics)
        self.file = open(path, "wb")  # noqa: SIM115 -- open for the flight, closed by close()
        self.file.writelines(_definitions(log))
        self.append(log.topics, log.strings)

    def append(self, topics: Sequence[Topic], strings: Sequence[tuple[int, str, str]] = ()) -> None:
        """More samples of the log's topics (by name and multi_id), and logged strings ((timestamp [µs], level name,
        text)), written in time order among themselves."""
        self.file.writelines(_data(topics, strings, self.ids))

    def flush(self) -> None:
        self.file.flush()

    def close(self) -> None:
        self.file.close()
