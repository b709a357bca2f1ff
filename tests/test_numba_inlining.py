"""numba's inliner, as quadsitl installs it (quadsitl.numba_inlining): an inlined function's scope is copied once per
copy of its IR, not once per block, and the inlined code computes what the function computes."""

from __future__ import annotations

import copy

import numba
from numba.core import ir

import quadsitl.jit  # noqa: F401  (installs the linear copy, as every process does)
from quadsitl import numba_inlining


def branches(x: float) -> float:
    """Twenty-four blocks and as many variables: each ``if`` is a block of its own."""
    a = x
    if a > 1.0:
        a = a * 0.5
    if a > 2.0:
        a = a - 0.25
    if a < -1.0:
        a = -a
    if a > 3.0:
        a = a / 3.0
    if a < 0.0:
        a = a + 1.0
    if a > 0.75:
        a = a * a
    if a < 0.1:
        a = a + 0.1
    if a > 5.0:
        a = 5.0
    b = a + 1.0
    if b > 2.0:
        b = b - 1.0
    if b < 1.5:
        b = b * 2.0
    return a * b


def test_an_inlined_functions_scope_is_copied_once_per_ir_copy_not_per_block(monkeypatch):
    assert numba_inlining.install()  # this numba's inliner is the one the module mends
    copies = []

    def counted(self, memo):  # the default deepcopy of an object, counted for a function's scope (not its parent)
        if self.parent is not None:
            copies.append(self)
        new = type(self).__new__(type(self))
        memo[id(self)] = new
        new.__dict__.update(copy.deepcopy(self.__dict__, memo))
        return new

    monkeypatch.setattr(ir.Scope, "__deepcopy__", counted, raising=False)
    inlined = numba.njit(inline="always")(branches)

    @numba.njit
    def caller(x):
        return inlined(x) + inlined(x + 1.0)

    values = (-7.0, -0.5, 0.0, 0.3, 1.5, 2.5, 9.0)
    assert [caller(x) for x in values] == [branches(x) + branches(x + 1.0) for x in values]
    blocks = len(numba.core.compiler.run_frontend(branches).blocks)
    assert blocks > 10
    # Two inlinings, each copying the callee's IR twice (numba's working copy and the copy it keeps): one scope each.
    # numba's own per-block copy copies it once per block: 4 × blocks.
    assert len(copies) == 4, f"{len(copies)} copies of the scope for two inlinings of {blocks} blocks"
