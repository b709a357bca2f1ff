"""Declared keys: each preset key is declared once, as the dataclass field that holds it (:func:`key`), with its
default, unit, range or allowed values, doc and, for a tunable one, the MAVLink parameter(s) it is (:class:`Param`).

From that one declaration come the check a preset's value goes through and the words of its refusal
(:attr:`Spec.allowed`: ``vehicle.mass = -2.0: expected a finite number > 0``), the [section]'s schema
(:func:`section_of`), the autopilot's MAVLink parameter table entries (:func:`params_of`, used by
:mod:`autopilot.params`) and the tables of the documentation (:func:`markdown_table`). As PX4 declares a module's
parameters once in its ``module.yaml``.

Plain Python, importing nothing of the project: the command line checks values without loading the compiler.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

REQUIRED: Any = dataclasses.MISSING  # a key without a default: a preset must give it
INF = math.inf
# Bounds said by name in a refusal, not as digits.
NAMED_BOUNDS = {"π/2": math.pi / 2, "π": math.pi, "2**63 - 1": 2**63 - 1}
SEED_MAX = 2**63 - 1  # a seed is a non-negative int64
_KEEP: Any = object()


def bound_text(value: float) -> str:
    """A bound as a refusal says it: π/2, π and 2**63 - 1 by name (−π/2 with a minus sign), an int in digits, a
    float power of ten from 1e5 up as one (1e5, 1e6), other floats as ``:g`` writes them, with no ``+`` and no
    leading zero in an exponent (1e-5)."""
    for name, named in NAMED_BOUNDS.items():
        if value == named:
            return name
        if value == -named and isinstance(value, float):
            return f"−{name}"
    if isinstance(value, int):
        return str(value)
    if value >= 1e5 and math.isfinite(value) and math.log10(value).is_integer():
        return f"1e{round(math.log10(value))}"
    return re.sub(r"e([+-])0*(\d+)", lambda m: "e" + ("-" if m[1] == "-" else "") + m[2], f"{value:g}")


@dataclass(frozen=True)
class Param:
    """The MAVLink parameter(s) a key is: one name per element (a list key's elements are parameters of their own),
    one doc each (default: the key's doc), and, where the parameter table's range or unit differs from the key's
    (a parameter is always bounded: a key's infinite bound is capped there), its own. ``to_param`` converts a
    key's value to the parameter's (and ``from_param`` back): MPC_TILTMAX_AIR is in degrees, as PX4's."""

    names: tuple[str, ...]
    docs: tuple[str, ...] = ()
    low: float | None = None
    high: float | None = None
    low_open: bool | None = None
    units: tuple[str, ...] = ()
    to_param: Callable[[float], float] | None = None
    from_param: Callable[[float], float] | None = None


def mavlink(
    names: str | Sequence[str],
    docs: str | Sequence[str] = (),
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool | None = None,
    unit: str | Sequence[str] = (),
    to_param: Callable[[float], float] | None = None,
    from_param: Callable[[float], float] | None = None,
) -> Param:
    """A :class:`Param`; a single name, doc or unit may be given as a string."""

    def many(v: str | Sequence[str]) -> tuple[str, ...]:
        return (v,) if isinstance(v, str) else tuple(v)

    return Param(many(names), many(docs), low, high, low_open, many(unit), to_param, from_param)


@dataclass(frozen=True)
class Spec:
    """What a key accepts, and the words that say so (:attr:`allowed`). ``kind``: "number" (a float), "int",
    "string" or "numbers" (``length`` of them, each checked). A number is in [low, high] (an end open with
    ``low_open``/``high_open``; an infinite end: any finite number that side); a string is one of ``choices``. An
    irregular key gives its own ``check`` (of one value) and its own words (``says``). ``note`` is said in brackets
    after the range; a ``{unit}`` in it places the unit there. ``unit_in_text`` False: the refusal leaves the unit
    out (the [vehicle] keys', whose units the documentation gives)."""

    kind: str
    default: Any = REQUIRED
    unit: str = ""
    low: float = -INF
    high: float = INF
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    length: int | None = None
    note: str = ""
    doc: str = ""
    mavlink: Param | None = None
    check_one: Callable[[Any], bool] | None = None
    says: str = ""
    unit_in_text: bool = True

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def check(self, value: Any) -> bool:
        """One value (an element of a list key) is allowed: in the range, or one of the choices."""
        if self.check_one is not None:
            return self.check_one(value)
        if self.kind == "string":
            return not self.choices or value in self.choices
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below and (self.kind == "int" or math.isfinite(value))

    @property
    def allowed(self) -> str:
        """What is allowed, in words: the end of a refusal (``...: expected <allowed>``)."""
        return self.describe()

    def describe(self, bracket_unit: bool = False) -> str:
        """:attr:`allowed`; ``bracket_unit``: a range's unit in brackets, ``[rad]`` (as a sweep's refusals say it)."""
        if self.says:
            return self.says
        if self.kind == "string":
            return "one of: " + ", ".join(self.choices)
        if self.kind == "int":
            if not math.isfinite(self.high):
                return f"an integer >= {bound_text(self.low)}"
            return f"an integer in [{bound_text(self.low)}, {bound_text(self.high)}]"
        unit = self.unit if self.unit_in_text and "{unit}" not in self.note else ""
        note = f" ({self.note.format(unit=self.unit)})" if self.note else ""
        n = f"{self.length} " if self.kind == "numbers" else ""
        if math.isfinite(self.low) and math.isfinite(self.high):
            left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
            span = f"{left}{bound_text(self.low)}, {bound_text(self.high)}{right}"
            unit = (f" [{unit}]" if bracket_unit else f" {unit}") if unit else ""
            return f"{n or 'a '}number{'s' if n else ''} in {span}{unit}{note}"
        side = ""
        if math.isfinite(self.low):
            side = f" {'>' if self.low_open else '>='} {bound_text(self.low)}"
        unit = f" [{unit}]" if unit else ""
        return f"{n or 'a '}finite number{'s' if n else ''}{side}{note}{unit}"

    def with_default(self, default: Any) -> Spec:
        """The same key with another default (None: optional, filled in elsewhere)."""
        return dataclasses.replace(self, default=default)

    def field(self, default: Any = _KEEP, **changes: Any) -> Any:
        """This key as a dataclass field (``default`` and ``changes`` over its own, when given): a key declared once
        and held by two sections (an angle in [initial] and [reference]) is one Spec made into two fields."""
        s = dataclasses.replace(self, **({} if default is _KEEP else {"default": default}), **changes)
        if s.required:
            return dataclasses.field(metadata={"key": s})
        return dataclasses.field(default=s.default, metadata={"key": s})


def spec(
    default: Any = REQUIRED,
    *,
    unit: str = "",
    low: float = -INF,
    high: float = INF,
    low_open: bool = False,
    high_open: bool = False,
    choices: Sequence[str] = (),
    length: int | None = None,
    integer: bool = False,
    kind: str | None = None,
    note: str = "",
    doc: str = "",
    mavlink: Param | None = None,
    check: Callable[[Any], bool] | None = None,
    says: str = "",
    unit_in_text: bool = True,
) -> Spec:
    """A key's :class:`Spec`. The kind follows from what is given: ``choices`` a string, ``length`` a list of
    numbers, ``integer`` (or an int default) an integer, else a number; ``kind`` says it outright (a string with its
    own ``check``)."""
    if kind is None:
        if choices:
            kind = "string"
        elif length is not None:
            kind = "numbers"
        elif integer or (isinstance(default, int) and not isinstance(default, bool)):
            kind = "int"
        else:
            kind = "number"
    return Spec(kind, default, unit, low, high, low_open, high_open, tuple(choices), length, note, doc, mavlink,
                check, says, unit_in_text)  # fmt: skip


def key(default: Any = REQUIRED, **kw: Any) -> Any:
    """A preset key declared as the dataclass field holding it: ``field(default=..., metadata={"key": Spec})``,
    the Spec from :func:`spec` (same arguments)."""
    return spec(default, **kw).field()


def declared(cls: type) -> dict[str, Spec]:
    """The keys a dataclass declares ({field name: Spec}), in field order; fields without a key are left out."""
    return {f.name: f.metadata["key"] for f in dataclasses.fields(cls) if "key" in f.metadata}


def section_of(cls: type, rename: dict[str, str] | None = None, only: Sequence[str] | None = None) -> dict[str, Spec]:
    """A preset [section]'s schema from the dataclass declaring its keys: {key: Spec} in field order; ``rename``
    gives a field's key in the TOML where it differs (pd_kp → kp), ``only`` the fields the section holds."""
    rename = rename or {}
    return {rename.get(name, name): spec for name, spec in declared(cls).items() if only is None or name in only}


def grouped(specs: Sequence[Spec], note: str, default: Any = REQUIRED) -> Spec:
    """One list key made of several declared number keys with one range (the [vehicle] ``inertia``: ixx, iyy,
    izz): their range and unit, ``note`` naming the elements."""
    first = specs[0]
    assert all((s.low, s.high, s.low_open, s.high_open) == (first.low, first.high, first.low_open, first.high_open)
               for s in specs)  # fmt: skip
    return dataclasses.replace(first, kind="numbers", length=len(specs), note=note, default=default, mavlink=None,
                               doc=", ".join(s.doc for s in specs))  # fmt: skip


@dataclass(frozen=True)
class ParamEntry:
    """One row of the MAVLink parameter table a declared key makes: the field it sets (``element`` of a list key,
    else None), the parameter's name, range [lo, hi] (open at lo with ``lo_open``), unit and doc, and the
    conversions between the key's value and the parameter's."""

    field: str
    element: int | None
    name: str
    lo: float
    hi: float
    unit: str
    doc: str
    lo_open: bool
    to_param: Callable[[float], float] | None = None
    from_param: Callable[[float], float] | None = None
    integer: bool = False  # the key is an int: the parameter's values must be whole


def params_of(cls: type, only: Sequence[str] | None = None, doc_prefix: str = "") -> tuple[ParamEntry, ...]:
    """The MAVLink parameters a dataclass's keys are (``only``: those fields, in that order; default every key with
    a :class:`Param`, in field order). Each takes the key's range, unit and doc where its Param gives none; every
    doc after ``doc_prefix``."""
    specs = declared(cls)
    names = [n for n in specs if specs[n].mavlink is not None] if only is None else list(only)
    out: list[ParamEntry] = []
    for name in names:
        spec = specs[name]
        p = spec.mavlink
        assert p is not None, name
        for i, param_name in enumerate(p.names):
            low = spec.low if p.low is None else p.low
            lo_open = spec.low_open if p.low_open is None else p.low_open
            high = spec.high if p.high is None else p.high
            assert math.isfinite(low) and math.isfinite(high), f"{param_name}: a parameter's range is finite"
            unit = p.units[i] if len(p.units) > 1 else p.units[0] if p.units else spec.unit
            doc = doc_prefix + (p.docs[i] if len(p.docs) > 1 else p.docs[0] if p.docs else spec.doc)
            element = i if spec.kind == "numbers" else None
            out.append(ParamEntry(name, element, param_name, low, high, unit, doc, lo_open, p.to_param, p.from_param,
                                  spec.kind == "int"))  # fmt: skip
    return tuple(out)


def param_values(obj: Any, entries: Sequence[ParamEntry]) -> dict[str, float]:
    """The parameters' values for ``obj`` (an instance of the dataclass the entries were made from)."""
    out: dict[str, float] = {}
    for e in entries:
        value = getattr(obj, e.field)
        value = value[e.element] if e.element is not None else value
        out[e.name] = e.to_param(value) if e.to_param else float(value) if e.integer else value
    return out


def fields_from_params(values: dict[str, float], entries: Sequence[ParamEntry]) -> dict[str, Any]:
    """The fields the parameters' ``values`` set ({field: value}; a list key's as a tuple), for
    ``dataclasses.replace``."""
    out: dict[str, Any] = {}
    for e in entries:
        value = values[e.name]
        value = e.from_param(value) if e.from_param else int(value) if e.integer else value
        if e.element is None:
            out[e.field] = value
        else:
            out[e.field] = (*out.get(e.field, ()), value)
    return out


def default_text(spec: Spec) -> str:
    """A key's default as the documentation's tables give it ("" for none: a required key, or one filled in
    another way)."""
    value = spec.default
    if spec.required or value is None:
        return ""
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, tuple):
        return "[" + ", ".join(f"{v:g}" for v in value) + "]"
    return f"{value:g}" if isinstance(value, float) else str(value)


def markdown_table(specs: dict[str, Spec], defaults: dict[str, str] | None = None) -> str:
    """A section's keys as a Markdown table (key, default, allowed, meaning with the MAVLink parameter), for the
    documentation; ``defaults``: a key's default in words where the section fills it in another way."""
    rows = ["| key | default | allowed | meaning |", "|---|---|---|---|"]
    for name, s in specs.items():
        default = (defaults or {}).get(name) or default_text(s) or ("required" if s.required else "")
        param = f" (`{'`, `'.join(s.mavlink.names)}`)" if s.mavlink else ""
        rows.append(f"| `{name}` | {default} | {s.allowed} | {s.doc}{param} |")
    return "\n".join(rows) + "\n"
