"""A linear copy of an inlined function's IR, for numba's inliner (``inline="always"``).

Before numba inlines a function it deep-copies the function's IR, twice. numba 0.68 copies each block with a
``copy.deepcopy`` of its own, and every block refers to the function's one scope, which lists every variable of
the function: each block's copy copies the whole scope again. The copy grows as blocks × variables, and for the
per-tick kernels, whose inlined callees inline callees of their own, it was a large part of every first compile
(docs/performance.md#the-inliners-copy). numba's own issue: https://github.com/numba/numba/issues/8989.

:func:`install` gives the blocks of one inlining one ``deepcopy`` memo: the scope is copied once, and the copied
blocks share it as the original blocks share theirs. The inliner's steps after the copy are numba's own and
unchanged, and so is the machine code it produces. It applies only where the inliner copies as described
(checked on its source), so another numba version runs its own copy unchanged.
"""

from __future__ import annotations

import contextvars
import copy
import functools
import inspect
from typing import Any

_BLOCK_COPY = "copy.deepcopy(the_ir.blocks[block_label])"  # numba's per-block copy in InlineWorker.inline_ir

_memo: contextvars.ContextVar[dict[int, Any] | None] = contextvars.ContextVar("quadsitl_inline_memo", default=None)


class _SharedMemoCopy:
    """The ``copy`` module as numba's inliner sees it: its ``deepcopy`` uses the current inlining's memo."""

    def __getattr__(self, name: str) -> Any:
        return getattr(copy, name)

    @staticmethod
    def deepcopy(x: Any, memo: dict[int, Any] | None = None) -> Any:
        shared = _memo.get()
        return copy.deepcopy(x, shared if memo is None and shared is not None else memo)


def install() -> bool:
    """Make numba's inliner copy a callee's blocks with one memo per inlining. Returns whether it applies (False,
    changing nothing, when this numba's inliner does not copy as described above). Idempotent."""
    from numba.core import inline_closurecall as icc

    worker = icc.InlineWorker
    if getattr(worker.inline_ir, "_quadsitl_shared_memo", False):
        return True
    try:
        source = inspect.getsource(worker.inline_ir)
    except (OSError, TypeError):
        return False
    if _BLOCK_COPY not in source or getattr(icc, "copy", None) is not copy:
        return False
    numbas = worker.inline_ir

    @functools.wraps(numbas)
    def inline_ir(self: Any, *args: Any, **kwargs: Any) -> Any:
        token = _memo.set({})  # one memo for this inlining: never shared with the next, which may inline the same IR
        try:
            return numbas(self, *args, **kwargs)
        finally:
            _memo.reset(token)

    inline_ir._quadsitl_shared_memo = True  # type: ignore[attr-defined]
    icc.copy = _SharedMemoCopy()  # type: ignore[assignment]
    worker.inline_ir = inline_ir  # type: ignore[method-assign]
    return True
