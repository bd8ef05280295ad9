"""The docs stay true to the code: counter table, methods, config keys."""

from pathlib import Path

from shadowlab import methods
from shadowlab.core.counters import COUNTERS, markdown_table

ROOT = Path(__file__).resolve().parent.parent


def test_counter_doc_is_generated_from_the_table():
    text = (ROOT / "docs" / "counters.md").read_text()
    assert markdown_table() in text, "regenerate: python -m shadowlab.core.counters > docs/counters.md"


def test_every_counter_name_is_unique_and_documented():
    assert len(COUNTERS) == len({c.name for c in COUNTERS.values()})
    for c in COUNTERS.values():
        assert c.kind in ("int", "float", "map", "array") and c.meaning


def test_readme_lists_every_method():
    readme = (ROOT / "README.md").read_text()
    for name in methods.names():
        assert f"`{name}`" in readme, f"README method table lacks {name}"


def test_readme_has_exactly_two_setup_commands_and_ci_uses_the_test_one():
    readme = (ROOT / "README.md").read_text()
    setup = readme.split("## Set up", 1)[1].split("\n## ", 1)[0]
    blocks = [b.split("```", 1)[0].strip() for b in setup.split("```bash")[1:]]
    assert len(blocks) == 2
    assert "shadowlab run" in blocks[0] and "pytest" in blocks[1]
    assert blocks[1] in (ROOT / ".ci" / "run").read_text()


def test_benchmarks_doc_is_generated_from_the_committed_json(tmp_path):
    """Regenerating docs/benchmarks.md from docs/bench_ci.json and the cold-start JSON
    gives the committed file (the hand-written part below the marker is kept)."""
    from shadowlab.harness import bench_report

    names = ("bench_ci.json", "bench_targets.json", "bench_psv.json", "bench_exact.json",
             "bench_props.json", "bench_psv_fuzzy_1m.json", "bench_izb.json",
             "bench_stencil.json",
             "bench_stencil_fuzzy.json", "bench_soft_1024.json", "cold_start.json",
             "cold_start_soft.json")
    committed = (ROOT / "docs" / "benchmarks.md").read_text()
    assert bench_report.KEEP_MARKER in committed
    out = tmp_path / "benchmarks.md"
    out.write_text(committed)
    bench_report.write_benchmarks_md([ROOT / "docs" / n for n in names], out)
    assert out.read_text() == committed, (
        "regenerate: python -m shadowlab.harness.bench_report "
        + " ".join(f"docs/{n}" for n in names) + " --out docs/benchmarks.md")


def test_bench_report_renders_hard_and_soft_cases():
    """Every number of a hand-made bench result appears, converted to ms, in its row."""
    from shadowlab.harness import bench_report

    hard = {"stages": {"setup": 0.002, "test": 0.0405, "total": 0.0425}, "compile_seconds": 1.5,
            "median_seconds": 0.0425, "ratio_to_reference": 4.25, "paired_ratio": 3.125,
            "dynamic_ratio": 1.75, "tests_per_second": 2.5e9,
            "error": {"valid_pixels": 100, "mismatches": 3}}
    soft = {"stages": {"eval": 0.25, "total": 0.25}, "compile_seconds": 0.25,
            "median_seconds": 0.25, "embree_seconds_at_equal_error": 0.75,
            "error": {"valid_pixels": 100, "mae": 0.0012, "rmse": 0.015, "max_error": 0.5,
                      "ssim": 0.975, "penumbra_pixels": 40, "penumbra_mae": 0.0125,
                      "penumbra_rmse": 0.025, "penumbra_max_error": 0.5, "penumbra_ssim": 0.875},
            "embree_seconds_at_equal": {"penumbra_mae": 0.125, "penumbra_rmse": None},
            "embree_seconds_at_equal_lower_bound": {"penumbra_ssim": 2.0}}
    case = {"name": "c1", "scene": "s", "triangles": 1234, "resolution": [16, 8],
            "valid_pixels": 100, "reference": {"median_seconds": 0.01, "runs": [0.01]},
            "soft_reference": {"rays": 256, "curve": [{"rays": 4, "seconds": 0.5, "mae": 0.003}]},
            "methods": {"m_hard": hard, "m_soft": soft, "m_skip": {"skipped": "no area light"}}}
    text = bench_report.render([("x.json", {"repeats": 2, "cases": [case]})])
    rows = {}                       # the first table row of each method
    for line in text.splitlines():
        if line.startswith("| `"):
            rows.setdefault(line.split("|")[1].strip(), line)
    assert rows["`m_hard`"].split("|")[2:9] == [" 42.5 ", " 1.50 ", " 4.25 ", " 3.12 ",
                                                 " 1.75 ", " 3 of 100 ", " 2.50 G "]
    assert "setup 2.0, test 40.5" in rows["`m_hard`"]
    assert rows["`m_soft`"].split("|")[2:9] == [" 250.0 ", " 0.25 ", " 0.0012 ", " 0.0150 ",
                                                 " 0.500 ", " 0.9750 ", " 750.0 "]
    penumbra = [line for line in text.splitlines() if line.startswith("| `m_soft` | 40 |")]
    assert penumbra == ["| `m_soft` | 40 | 0.0125 (125.0) | 0.0250 (-) | 0.500 (-) "
                        "| 0.8750 (> 2000.0) |"]     # beyond Embree's curve: a bound
    assert "skipped: no area light" in rows["`m_skip`"]
    assert "4 rays 500.0 ms MAE 0.0030" in text and "1,234 triangles, 16x8" in text
    assert "Machine load: not recorded" in text


def test_bench_report_states_each_target_from_the_latest_file():
    """The targets table takes each case from the last file that holds it, its target
    from the JSON or else from bench.toml (by the case's name), judges every hard method's
    static ratio, names a missed method's two largest stages, and lists the targeted
    built-in cases that no file holds."""
    from shadowlab.harness import bench_report

    def hard(ratio, paired=None, **stages):
        row = {"stages": {**stages, "total": 1.0}, "compile_seconds": 0.5,
               "median_seconds": 0.25, "ratio_to_reference": ratio, "dynamic_ratio": 1.0,
               "error": {"valid_pixels": 4, "mismatches": 0}}
        return row if paired is None else dict(row, paired_ratio=paired)

    def case(name, methods, **extra):
        return {"name": name, "scene": "s", "triangles": 1000, "resolution": [2, 2],
                "valid_pixels": 4, "reference": {"median_seconds": 0.1, "runs": [0.1]},
                "methods": methods, **extra}
    older = {"cases": [case("exact-fuzzy-100k-1024", {"m": hard(4.0, a=0.1)})]}
    newer = {"cases": [case("exact-fuzzy-100k-1024", {"m": hard(3.0, a=0.1)}),
                       case("own", {"m": hard(6.0, 4.5, small=0.01, big=0.2, mid=0.03),
                                    "skip": {"skipped": "not here"}}, target_ratio=5.0),
                       case("untargeted", {"m": hard(9.0)})]}
    text = bench_report.render([("old.json", older), ("new.json", newer)])
    rows = [line for line in text.splitlines() if line.startswith("| `") and "x |" in line]
    assert rows == [
        "| `exact-fuzzy-100k-1024` | 1,000 | 3x | `m` | 3.00 | - | **met** | 250.0 |  "
        "| `new.json` |",
        # the verdict is on the static ratio, whatever the paired one says
        "| `own` | 1,000 | 5x | `m` | 6.00 | 4.50 | **missed** | 250.0 | big 200.0, mid 30.0 "
        "| `new.json` |"]
    assert "Met: 1 of 2." in text
    missing = next(line for line in text.splitlines() if line.startswith("Cases with a target"))
    assert "`exact-sphere_grid-1M-1024`" in missing and "exact-fuzzy-100k-1024" not in missing
    assert "None of these files" in bench_report.render([("new.json", {"cases": [
        case("untargeted", {"m": hard(9.0)})]})])


def test_bench_report_names_each_files_cpu_and_warns_when_they_differ():
    """The machine line names the recorded CPU; the targets table warns when its rows come
    from files measured on different CPUs (or on CPUs some file did not record), and
    says nothing when they agree."""
    from shadowlab.harness import bench_report

    def results(cpu, case_name, skipped=False):
        machine = {"date_utc": "2026-01-01", "cpus": 2, "load_average_before": [0.1] * 3,
                   "load_average_after": [0.2] * 3}
        if cpu:
            machine["cpu"] = cpu
        row = {"stages": {"total": 0.3}, "median_seconds": 0.3, "compile_seconds": 0.1,
               "ratio_to_reference": 2.0,
               "error": {"valid_pixels": 4, "mismatches": 0}}
        return {"machine": machine, "cases": [
            {"name": case_name, "scene": "s", "triangles": 10,
             "resolution": [2, 2], "valid_pixels": 4, "target_ratio": 3.0,
             "reference": {"median_seconds": 0.15, "runs": [0.15]},
             "methods": {"m": {"skipped": "not here"} if skipped else row}}]}
    wide = {"model": "AMD EPYC", "simd": "AVX-512"}
    narrow = {"model": "AMD EPYC", "simd": "AVX2"}
    text = bench_report.render([("a.json", results(wide, "c1")),
                                ("b.json", results(narrow, "c2"))])
    assert "2 CPU cores (AMD EPYC, AVX-512)" in text and "2 CPU cores (AMD EPYC, AVX2)" in text
    warning = next(line for line in text.splitlines() if "different CPUs" in line)
    assert "AMD EPYC, AVX-512: `a.json`" in warning and "AMD EPYC, AVX2: `b.json`" in warning
    same = bench_report.render([("a.json", results(wide, "c1")),
                                ("c.json", results(dict(wide), "c2"))])
    assert "`c1` |" in same and "`c2` |" in same          # both files hold rows
    assert "different CPUs" not in same
    unrecorded = bench_report.render([("a.json", results(wide, "c1")),
                                      ("old.json", results(None, "c2"))])
    assert "CPU not recorded: `old.json`" in unrecorded
    # a file whose targeted case has skipped methods only adds no row, and no warning
    no_rows = bench_report.render([("a.json", results(wide, "c1")),
                                   ("b.json", results(narrow, "c2", skipped=True))])
    assert "different CPUs" not in no_rows


def test_bench_report_marks_the_times_taken_while_the_hypervisor_took_cpu_time():
    """Steal above ``STEAL_SHARE`` of the cores' time marks the method's verdict in the
    targets table and is named under its case; the machine line shows the run's steal;
    steal at or below the share, or not recorded, marks nothing."""
    from shadowlab.core.machine import STEAL_SHARE
    from shadowlab.harness import bench_report

    def results(method_share, case_share=0.0):
        row = {"stages": {"total": 0.3}, "median_seconds": 0.3, "compile_seconds": 0.1,
               "ratio_to_reference": 2.0, "error": {"valid_pixels": 4, "mismatches": 0}}
        if method_share is not None:
            row["steal"] = {"seconds": 1.25, "share": method_share}
        machine = {"date_utc": "2026-01-01", "cpus": 2,
                   "steal": {"seconds": 0.5, "share": 0.004}}
        return {"machine": machine, "cases": [
            {"name": "c", "scene": "s", "triangles": 10, "resolution": [2, 2],
             "valid_pixels": 4, "target_ratio": 3.0,
             "steal": {"seconds": 2.0, "share": case_share},
             "reference": {"median_seconds": 0.15, "runs": [0.15]},
             "methods": {"m": row, "other": dict(row, steal={"seconds": 0.0, "share": 0.0})}}]}
    text = bench_report.render([("a.json", results(2 * STEAL_SHARE))])
    row = next(line for line in text.splitlines() if line.startswith("| `c` |") and "`m`" in line)
    assert f"**met** (steal {200 * STEAL_SHARE:.1f} %)" in row
    other = next(line for line in text.splitlines() if line.startswith("| `c` |")
                 and "`other`" in line)
    assert "steal" not in other
    remark = next(line for line in text.splitlines() if line.startswith("Steal above"))
    assert f"`m` 1.25 s ({200 * STEAL_SHARE:.1f} % of the cores' time)" in remark
    assert "`other`" not in remark and "whole case" not in remark
    assert "(steal) 0.50 s (0.4 % of the cores' time)" in text
    whole = bench_report.render([("a.json", results(None, case_share=3 * STEAL_SHARE))])
    assert "the whole case 2.00 s" in whole and "(steal " not in whole
    for quiet in (STEAL_SHARE, None):
        text = bench_report.render([("a.json", results(quiet))])
        assert "Steal above" not in text and "(steal " not in text


def test_bench_report_names_the_heap_policy_of_the_run():
    from shadowlab.harness import bench_report

    data = {"machine": {"date_utc": "2026-01-01", "cpus": 2, "heap": "retain"}, "cases": []}
    line = next(x for x in bench_report.render([("a.json", data)]).splitlines()
                if x.startswith("Machine:"))
    assert line.endswith("2 CPU cores; heap policy retain.")
    data["machine"].pop("heap")
    assert "heap policy" not in bench_report.render([("a.json", data)])


def test_public_files_do_not_point_into_the_workspace():
    """No project file cites the private workspace, its design notes or paper files."""
    import re

    # the patterns are assembled so that this file does not match itself
    bad = re.compile("|".join(["shared" + "/", "DESIGN" + r"\.md", "papers" + "/",
                               r"\b[a-z]+(?:19|20)\d\d-[a-z0-9-]+\.(?:txt|md)\b"]))
    files = [ROOT / "README.md", *ROOT.joinpath("docs").glob("*.md")]
    for folder in ("shadowlab", "tests", "experiments", "configs"):
        files += [p for p in ROOT.joinpath(folder).rglob("*")
                  if p.suffix in (".py", ".toml", ".md") and p.is_file()]
    hits = [f"{p.relative_to(ROOT)}:{i}" for p in files
            for i, line in enumerate(p.read_text(errors="replace").splitlines(), 1)
            if bad.search(line)]
    assert not hits, hits
