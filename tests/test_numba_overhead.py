"""numba's compiler as quadsitl installs it (quadsitl.numba_overhead): the same relations and results, less
bookkeeping. Each mend applies to the numba the project pins, and changes nothing a compile produces."""

import itertools

import numba
import pytest
from numba.core import errors, event
from numba.core.compiler import Flags

import quadsitl.jit  # noqa: F401  (installs the mends, as every compiled module's import does)
from quadsitl import numba_overhead


def test_each_mend_applies_to_this_numba_and_installing_again_changes_nothing():
    assert numba_overhead.install() == {"flags": True, "error_text": True, "lock_events": True}
    assert numba_overhead.install() == {"flags": True, "error_text": True, "lock_events": True}


def flags_of(settings: dict) -> Flags:
    flags = Flags()
    for name, value in settings.items():
        setattr(flags, name, value)
    return flags


# Options set, unset, and set to their default (which must compare equal to unset).
SETTINGS = [
    {},
    {"nrt": True},
    {"nrt": False},  # the default, set
    {"boundscheck": True},
    {"nrt": True, "boundscheck": True},
    {"error_model": "numpy"},
    {"error_model": "python"},  # the default, set
    {"nrt": True, "error_model": "numpy"},
    {"fastmath": True},
]


def test_flags_compare_as_numbas_own_do_and_equal_flags_hash_alike():
    for a, b in itertools.product(SETTINGS, repeat=2):
        fa, fb = flags_of(a), flags_of(b)
        numbas = fa.values() == fb.values()  # numba's relation: every option reads the same
        assert (fa == fb) is numbas, (a, b)
        assert (fa != fb) is not numbas, (a, b)
        if numbas:
            assert hash(fa) == hash(fb), (a, b)
    assert flags_of({"nrt": True}) != flags_of({})  # not everything is equal
    assert flags_of({"nrt": False}) == flags_of({})


def test_a_typing_error_reads_as_plain_text():
    @numba.njit
    def attribute_of(x):
        return x.no_such_attribute

    with pytest.raises(errors.TypingError) as raised:
        attribute_of(1.0)
    text = str(raised.value)
    assert "no_such_attribute" in text
    assert "\x1b[" not in text  # no terminal escapes in a log


def test_compiling_no_longer_announces_llvms_lock_and_still_compiles():
    seen: list[str] = []

    class Count(event.Listener):
        def on_start(self, ev):
            seen.append(ev.kind)

        def on_end(self, ev):
            pass

    @numba.njit
    def poly(x):
        return 3.0 * x * x - 2.0 * x + 1.0

    listener = Count()
    event.register("numba:llvm_lock", listener)
    event.register("numba:compile", listener)
    try:
        assert poly(2.0) == 9.0
    finally:
        event.unregister("numba:llvm_lock", listener)
        event.unregister("numba:compile", listener)
    assert "numba:compile" in seen  # it compiled, and said so
    assert "numba:llvm_lock" not in seen
