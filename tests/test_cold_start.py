"""``shadowlab bench --cold``: each method's first call in a fresh process with an empty
compilation cache (shadowlab.harness.cold_start)."""

import json

import pytest

from shadowlab.cli import main
from shadowlab.core import heap
from shadowlab.core.heap import set_heap_policy
from shadowlab.harness import bench_report, cold_start

SMALL = ["camera.resolution=[16,16]", 'methods.names=["brute_force","soft_tiled"]']


def test_cold_start_measures_a_fresh_process_with_an_empty_cache(tmp_path, capsys):
    out = tmp_path / "cold.json"
    # under the heap policy that is not the tests' own, so that the children's record
    # shows they inherit the parent's (the worker returns to glibc's defaults after)
    args = ["--heap", "retain", "bench", "--cold", "--repeats", "2", "--out", str(out),
            "--quiet"]
    for o in SMALL:
        args += ["--set", o]
    try:
        assert main(args) == 0
    finally:
        set_heap_policy("system")
    data = json.loads(out.read_text())
    row = data["methods"]["brute_force"]
    # an empty cache: the first call compiles, and compiling is part of it
    assert row["cache_entries_at_start"] == 0
    assert 0 < row["compile_seconds"] <= row["first_call_seconds"]
    assert row["warm_seconds"] < row["first_call_seconds"]
    assert row["process_seconds"] > (row["import_seconds"] + row["setup_seconds"]
                                     + row["first_call_seconds"])
    assert "needs a sphere or sun light" in data["methods"]["soft_tiled"]["skipped"]
    assert data["resolution"] == [16, 16] and data["machine"]["cpus"] >= 1
    # the children run under the parent's heap policy, and the run records it
    expected = "retain" if heap._libc() is not None else "system"
    assert row["heap"] == data["machine"]["heap"] == expected
    printed = capsys.readouterr().out
    assert "brute_force" in printed and f"wrote {out}" in printed

    md = bench_report.render([("cold.json", data)])
    line = next(x for x in md.splitlines() if x.startswith("| `brute_force` |"))
    assert f"{row['first_call_seconds']:.2f}" in line and line.count("|") == 9


def test_a_failing_child_is_recorded_and_the_command_fails(tmp_path, monkeypatch):
    monkeypatch.setattr(cold_start, "_CHILD", "import sys; print('a | b', file=sys.stderr); "
                        "raise SystemExit('no compiler here')")
    out = tmp_path / "cold.json"
    args = ["bench", "--cold", "--repeats", "1", "--out", str(out), "--quiet",
            "--set", 'methods.names=["brute_force"]']
    assert main(args) == 1
    data = json.loads(out.read_text())
    failed = data["methods"]["brute_force"]["failed"]
    assert "exit status 1" in failed and "a | b" in failed and "no compiler here" in failed
    # the report keeps the table whole: one line, the failure's last line, no bare "|"
    md = bench_report.render([("cold.json", data)]).splitlines()
    (line,) = [x for x in md if x.startswith("| `brute_force` |")]
    assert "no compiler here" in line and "a | b" not in line


def test_a_child_that_prints_or_runs_long_cannot_break_the_result(tmp_path, monkeypatch):
    monkeypatch.setattr(cold_start, "TARGET_SECONDS", 0.0)     # every first call misses
    monkeypatch.setattr(cold_start, "_CHILD", "print('{not json', end=''); " + cold_start._CHILD)
    out = tmp_path / "cold.json"
    assert main(["bench", "--cold", "--repeats", "1", "--out", str(out), "--quiet",
                 "--set", "camera.resolution=[8,8]",
                 "--set", 'methods.names=["brute_force"]']) == 0
    row = json.loads(out.read_text())["methods"]["brute_force"]
    assert row["within_target"] is False and row["first_call_seconds"] > 0


def test_cold_refuses_pareto_and_only_and_a_bad_config(tmp_path, capsys):
    out = tmp_path / "cold.json"
    assert main(["bench", "--cold", "--size", "ci", "--out", str(out)]) == 2
    assert "--size (of the built-in cases) does not apply" in capsys.readouterr().err
    for extra in (["--only", "gate-1024"], ["--pareto"]):
        assert main(["bench", "--cold", *extra, "--out", str(out)]) == 2
        assert "takes no --pareto or --only" in capsys.readouterr().err
    assert main(["bench", "--cold", "--set", "camera.resolutoin=[8,8]", "--out",
                 str(out)]) == 2
    assert "resolutoin" in capsys.readouterr().err
    assert not out.exists()
