"""quadsitl.jit.borrowed: an argument's arrays without numba's reference count, for the per-tick loops (each view of
an owned array takes and drops a reference with an atomic instruction: docs/performance.md#reference-counts). The
views must be the same arrays (data, shape, strides: what is written through them reaches the caller's), have no
owner (so neither their copies nor their slices count), and leave every other member's count as it was."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from numba.core import cgutils, types
from numba.core.runtime import _nrt_python, rtsys
from numba.extending import intrinsic
from numba.typed import List

from quadsitl.jit import DISABLED, borrowed

pytestmark = pytest.mark.skipif(DISABLED, reason="compiled code only (NUMBA_DISABLE_JIT=1: borrowed is the identity)")


@intrinsic
def owned(typingctx, arr):
    """Whether the array has an owner numba counts references of (its meminfo is not NULL)."""

    def codegen(context, builder, sig, args):
        meminfo = builder.extract_value(args[0], 0)
        return builder.icmp_unsigned("!=", meminfo, cgutils.get_null_value(meminfo.type))

    return types.boolean(arr), codegen


@numba.njit
def owners(a, b):
    """(a owned, a borrowed, a borrowed slice, b's rows inside a nested tuple borrowed; the scalar passed along)."""
    n, (x, (y, k)) = borrowed((a, (b, (b[1], 7))))
    return owned(a), owned(n), owned(n[2:5]), owned(x), owned(x[0]), owned(y), k


def test_a_borrowed_array_and_its_slices_have_no_owner_and_other_members_pass_as_they_are():
    a, b = np.arange(10.0), np.zeros((3, 4))
    assert owners(a, b) == (True, False, False, False, False, False, 7)


@numba.njit
def write_through(a, b):
    x, y = borrowed((a, b))
    x[3:6] = 1.5  # a slice of a borrowed array
    row = y[2]
    row[1] = -2.0  # a row of a 2-D one
    return x.shape[0], y.shape, y.strides, x[7]


def test_what_is_written_through_a_borrowed_view_reaches_the_callers_array():
    a, b = np.arange(10.0), np.zeros((3, 4), order="F")
    n, shape, strides, seven = write_through(a, b)
    assert (n, shape, strides, seven) == (10, b.shape, b.strides, 7.0)
    assert a.tolist() == [0.0, 1.0, 2.0, 1.5, 1.5, 1.5, 6.0, 7.0, 8.0, 9.0]
    assert b[2, 1] == -2.0 and np.count_nonzero(b) == 1


@numba.njit
def with_a_list(a, times):
    lst = List()
    lst.append(1.0)
    total = 0.0
    for _ in range(times):
        x, q = borrowed((a, lst))  # a list is counted as before: each borrowed tuple holds one more reference
        total += x[0] + q[0]
    return total


def test_members_that_are_not_arrays_keep_their_counts_nothing_leaks_or_is_freed_twice():
    a = np.ones(4)
    with_a_list(a, 1)
    _nrt_python.memsys_enable_stats()
    try:
        before = rtsys.get_allocation_stats()
        assert with_a_list(a, 1000) == 2000.0
        after = rtsys.get_allocation_stats()
    finally:
        _nrt_python.memsys_disable_stats()
    allocated, freed = after.alloc - before.alloc, after.free - before.free
    assert allocated > 0 and allocated == freed  # the list's and its data's, each freed once
    assert after.mi_alloc - before.mi_alloc == after.mi_free - before.mi_free
