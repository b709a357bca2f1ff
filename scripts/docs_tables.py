"""The documentation's tables of preset keys, generated from their one declaration (:mod:`quadsitl.keys`, the
fields of :mod:`quadsitl.config`): each table sits between two markers in a page,

    <!-- generated: sensors -->
    ...
    <!-- end generated -->

(a preset section's keys, or ``params``: the autopilot's MAVLink parameter table).

    python scripts/docs_tables.py          rewrites the tables in docs/
    python scripts/docs_tables.py --check  exits 1, naming the page, when a table is not what the keys say

``tests/test_docs_tables.py`` runs the check.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from quadsitl.config import IMU_PROFILES, SCHEMA
from quadsitl.keys import markdown_table

ROOT = Path(__file__).resolve().parent.parent
MARK = re.compile(r"(<!-- generated: (\w+) -->\n)(.*?)(<!-- end generated -->)", re.S)


def sensor_defaults() -> dict[str, str]:
    """The IMU figures' defaults: the px4 profile's, and the adis16448 profile's where it differs."""
    px4, adis = IMU_PROFILES["px4"], IMU_PROFILES["adis16448"]
    return {k: f"{v:g}" + (f" (adis16448: {adis[k]:g})" if adis[k] != v else "") for k, v in px4.items()}


def params_table() -> str:
    """The autopilot's MAVLink parameters (:data:`autopilot.params.SPECS`, in index order): name, range, meaning."""
    from autopilot.params import SPECS

    rows = ["| index | parameter | allowed | meaning |", "|---|---|---|---|"]
    rows += [f"| {i} | `{s.name}` | {s.allowed()} | {s.doc} |" for i, s in enumerate(SPECS)]
    return "\n".join(rows) + "\n"


def table(section: str) -> str:
    """The Markdown table of a preset section's keys, or (``params``) of the MAVLink parameters."""
    if section == "params":
        return params_table()
    return markdown_table(SCHEMA[section], sensor_defaults() if section == "sensors" else None)


def generated(text: str) -> str:
    """``text`` with every generated table made anew."""
    return MARK.sub(lambda m: m[1] + table(m[2]) + m[4], text)


def pages() -> list[Path]:
    return sorted((ROOT / "docs").glob("*.md"))


def main(argv: list[str]) -> int:
    stale = []
    for page in pages():
        text = page.read_text(encoding="utf-8")
        new = generated(text)
        if new != text:
            stale.append(page)
            if "--check" not in argv:
                page.write_text(new, encoding="utf-8")
    if stale and "--check" in argv:
        print(f"not what the keys say: {', '.join(str(p.relative_to(ROOT)) for p in stale)}; run "
              "python scripts/docs_tables.py", file=sys.stderr)  # fmt: skip
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
