"""``quadsitl bench`` is a benchmark, not a timed test: this only checks that it runs and reports every
figure with a name, a unit and its baseline, in the JSON that tools read."""

import json


def test_bench_costs_report_json_with_names_units_and_baselines(cli):
    r = cli("bench", "--only", "costs", "--json", timeout=120)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert set(report) >= {"lockstep_ratio", "figures", "machine", "elapsed_s"}
    assert report["lockstep_ratio"] is None  # the lockstep part did not run
    figures = {f["name"]: f for f in report["figures"]}
    for name in ("backstepping controller step", "plant step (rk4)", "autopilot tick: state frame in, answer out",
                 "Zenoh publish, 4 streams, no subscriber"):  # fmt: skip
        f = figures[name]
        assert f["unit"] == "us" and f["value"] > 0 and f["baseline"] > 0 and f["ratio"] > 0
    # the compiled equations must beat the same source run as Python, or the compiler has no reason to be here
    for name in ("backstepping controller step", "plant step (euler)"):
        assert figures[name]["baseline_name"] == "plain Python" and figures[name]["ratio"] < 0.5
    assert report["machine"]["cores"] >= 1 and report["machine"]["python"]


def test_bench_refuses_bad_options(cli):
    r = cli("bench", "--rounds", "0")
    assert r.returncode == 2 and "--rounds 0: expected 1..10" in r.stderr
