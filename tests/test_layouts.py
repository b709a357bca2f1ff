"""Records handed to compiled code (quadsitl.layout): each declared once, its constants generated from it."""

import importlib
from pathlib import Path

import pytest

from quadsitl import layout

MODULES = ["autopilot.commander_state"]


@pytest.mark.parametrize("module_name", MODULES)
def test_every_generated_block_is_what_its_declaration_generates(module_name):
    module = importlib.import_module(module_name)
    source = Path(module.__file__).read_text(encoding="utf-8")
    for name, declaration in module.LAYOUTS.items():
        assert layout.block_of(source, name) == layout.generate(name, declaration), (
            f"{module_name}: run python -m quadsitl.layout {module_name}"
        )


def test_names_are_numbered_in_order_and_groups_and_spans_bound_them():
    ns: dict = {}
    exec(layout.generate("T", "a: P Q\nb: R\nc: S T U\nab = a + b"), ns)
    assert [ns[n] for n in "PQRSTU"] == list(range(6)) and ns["SIZE"] == 6
    assert (ns["B_FIRST"], ns["B_END"]) == (2, 3) and (ns["AB_FIRST"], ns["AB_END"]) == (0, 3)


def test_a_span_over_groups_that_are_not_neighbours_is_refused():
    with pytest.raises(ValueError, match="span ac: a and c are not consecutive"):
        layout.generate("T", "a: P\nb: Q\nc: R\nac = a + c")


def test_regenerate_rewrites_a_stale_block(tmp_path):
    path = tmp_path / "m.py"
    path.write_text(f"X = 1\n{layout.generate('T', 'a: P Q')}\nY = 2\n")
    assert not layout.regenerate(path, "T", "a: P Q")
    assert layout.regenerate(path, "T", "a: P Q R")
    ns: dict = {}
    exec(path.read_text(), ns)
    assert (ns["R"], ns["SIZE"], ns["X"], ns["Y"]) == (2, 3, 1, 2)
