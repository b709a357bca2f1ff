"""tests/alone.py, the plugin that gives a module marked ``alone`` the machine to itself under pytest-xdist: a run of
its own with two workers, each test writing when it ran."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).parent.parent

MODULE = """import json, os, time
from pathlib import Path
import pytest
{mark}

@pytest.mark.parametrize("n", range(2))
def test_runs(n):
    start = time.monotonic()
    time.sleep(0.6)
    with open(Path(__file__).parent / "ran.jsonl", "a") as f:
        f.write(json.dumps([Path(__file__).stem, start, time.monotonic(), os.environ["PYTEST_XDIST_WORKER"]]) + "\\n")
"""


def test_an_alone_module_runs_while_no_other_does(tmp_path):
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    (tmp_path / "test_soaklike.py").write_text(MODULE.format(mark="pytestmark = pytest.mark.alone"))
    for name in ("test_a", "test_b", "test_c"):
        (tmp_path / f"{name}.py").write_text(MODULE.format(mark=""))
    r = subprocess.run([sys.executable, "-m", "pytest", "-c", str(tmp_path / "pytest.ini"), "-p", "tests.alone",
                        "-p", "no:cacheprovider", "-n", "2", "--dist", "loadscope", "-q", str(tmp_path)],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    ran = [json.loads(line) for line in (tmp_path / "ran.jsonl").read_text().splitlines()]
    assert len(ran) == 8
    alone = [(s, e) for name, s, e, _ in ran if name == "test_soaklike"]
    others = [(s, e) for name, s, e, _ in ran if name != "test_soaklike"]
    span = min(s for s, _ in alone), max(e for _, e in alone)
    assert all(e <= span[0] or s >= span[1] for s, e in others), ran  # nothing else ran meanwhile
    assert len({w for *_, w in ran}) == 2  # two workers did run
    assert any(s2 < e1 and s1 < e2 for i, (s1, e1) in enumerate(others) for s2, e2 in others[i + 1 :]), ran
