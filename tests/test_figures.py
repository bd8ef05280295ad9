"""Every experiment runs at CI size, writes its figure and arrays, passes its check, and
gives the arrays of its committed golden file (tests/golden/, shadowlab.harness.golden)."""

from pathlib import Path

import numpy as np
import pytest

from shadowlab.harness import golden
from shadowlab.harness.figures import discover, load_module, regenerate, run_experiment

ROOT = Path(__file__).resolve().parent.parent
EXPERIMENTS = sorted(discover(ROOT))


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_experiment_at_ci_size(name, tmp_path):
    arrays = run_experiment(ROOT, name, "ci", out=tmp_path)
    assert (tmp_path / f"{name}.png").stat().st_size > 0
    saved = np.load(tmp_path / f"{name}.npz")
    assert set(saved.files) == set(arrays)
    for key in arrays:
        want = np.asarray(arrays[key])
        nan_ok = want.dtype.kind in "fc"          # NaN marks "not applicable" in some tables
        assert np.array_equal(saved[key], want, equal_nan=nan_ok), key
    # The figure's data as committed: counters and masks exactly, timings not at all.
    problems = golden.compare(ROOT, name, arrays, load_module(discover(ROOT)[name]))
    assert not problems, (f"{name}: the CI-size arrays differ from tests/golden/{name}.npz; "
                          f"if the change is intended, regenerate and commit: python -m "
                          f"shadowlab.harness.golden {name}\n  " + "\n  ".join(problems))


def test_golden_comparison_catches_changes_and_ignores_timings(tmp_path):
    arrays = {"mask": np.array([True, False]), "tests": np.arange(4), "mae": np.array([0.25]),
              "traverse_seconds": np.array([1.0]), "labels": np.array(["a", "b"])}
    golden.write(tmp_path, "toy", arrays)
    assert "traverse_seconds" not in np.load(tmp_path / "tests" / "golden" / "toy.npz").files
    slower = {**arrays, "traverse_seconds": np.array([9.0])}
    assert golden.compare(tmp_path, "toy", slower) == []
    assert golden.compare(tmp_path, "toy", {**arrays, "mae": np.array([0.25 + 1e-12])}) == []
    changed = {**arrays, "tests": np.array([0, 1, 2, 4])}
    assert golden.compare(tmp_path, "toy", changed) == [
        "tests: 1 of 4 values differ (first: np.int64(4), golden np.int64(3))"]
    assert golden.compare(tmp_path, "toy", {**arrays, "mask": np.array([True, True])})
    assert golden.compare(tmp_path, "toy", {**arrays, "mae": np.array([0.26])})
    assert golden.compare(tmp_path, "toy", {**arrays, "extra": np.zeros(1)}) == [
        "extra: new array, not in the golden file"]
    assert "no golden file" in golden.compare(tmp_path, "other", arrays)[0]


def test_golden_files_leave_out_only_the_declared_cpu_dependent_arrays(tmp_path):
    import types

    module = types.SimpleNamespace(CPU_DEPENDENT_ARRAYS=("ties", "absent"))
    arrays = {"ties": np.array([19]), "differs": np.array([0])}
    golden.write(tmp_path, "toy", arrays, module)
    assert np.load(tmp_path / "tests" / "golden" / "toy.npz").files == ["differs"]
    assert golden.compare(tmp_path, "toy", {**arrays, "ties": np.array([36])}, module) == []
    assert golden.compare(tmp_path, "toy", {**arrays, "differs": np.array([1])}, module)
    # without the module's declaration the array is compared like any other
    assert golden.compare(tmp_path, "toy", arrays) == [
        "ties: new array, not in the golden file"]


def test_every_experiment_has_a_golden_file():
    for name in EXPERIMENTS:
        assert (ROOT / "tests" / "golden" / f"{name}.npz").exists(), (
            f"python -m shadowlab.harness.golden {name}")


def test_every_experiment_has_both_sizes():
    for name in EXPERIMENTS:
        for size in ("ci", "full"):
            assert (ROOT / "configs" / "experiments" / f"{name}.{size}.toml").exists()


def test_brute_force_check_fails_on_a_wrong_array(tmp_path):
    """The check behind the figure can fail: a corrupted error map is caught."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bf", ROOT / "experiments" / "brute_force_error.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    arrays = dict(np.load(ROOT / "figures" / "brute_force_error.npz")) if (
        ROOT / "figures" / "brute_force_error.npz").exists() else run_experiment(
        ROOT, "brute_force_error", "ci", out=tmp_path)
    cfg = {"max_mismatch_fraction": 0.0}
    module.check(arrays, cfg)
    bad = dict(arrays)
    bad["mismatches"] = arrays["mismatches"] + 1
    with pytest.raises(AssertionError):
        module.check(bad, cfg)


def test_unknown_experiment_is_an_error(tmp_path):
    from shadowlab.harness.figures import ExperimentError

    with pytest.raises(ExperimentError, match="available"):
        regenerate(ROOT, only=["nope"], out=tmp_path)


_TOY = '''
import numpy as np

def run(cfg):
    return {"x": np.arange(3)}

def plot(arrays):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    ax.plot(arrays["x"])
    return fig

def claims(arrays, cfg):
    return [{"claim": "x is short", "measured": f"{len(arrays['x'])}", "holds": True},
            {"claim": "x sums to 4", "measured": f"{arrays['x'].sum()}",
             "holds": bool(arrays["x"].sum() == 4)}]
'''


def _toy_project(root, source: str = _TOY, required: bool = True) -> None:
    """An experiment ``toy`` with ``source`` and a CI config under ``root``."""
    (root / "experiments").mkdir(exist_ok=True)
    (root / "configs" / "experiments").mkdir(parents=True, exist_ok=True)
    (root / "experiments" / "toy.py").write_text(source)
    (root / "configs" / "experiments" / "toy.ci.toml").write_text(
        f"require_claims = {str(required).lower()}\n")


@pytest.mark.parametrize("required", [False, True])
def test_claims_are_recorded_and_enforced_only_where_required(tmp_path, required):
    import json

    from shadowlab.harness.figures import ClaimFailed

    _toy_project(tmp_path, required=required)
    out = tmp_path / "figures"
    if required:
        with pytest.raises(ClaimFailed, match="x sums to 4"):
            run_experiment(tmp_path, "toy", "ci", out=out)
    else:
        run_experiment(tmp_path, "toy", "ci", out=out)
    meta = json.loads((out / "toy.json").read_text())       # written either way
    assert [c["holds"] for c in meta["claims"]] == [True, False]
    assert meta["claims"][1]["measured"] == "3"


def test_an_untested_claim_is_recorded_and_not_enforced(tmp_path):
    """holds=None (with a note) is written as null and does not fail require_claims."""
    import json

    toy = _TOY.replace('"holds": bool(arrays["x"].sum() == 4)}]',
                       '"holds": None, "note": "x is empty here"}]')
    assert toy != _TOY
    _toy_project(tmp_path, toy)
    run_experiment(tmp_path, "toy", "ci", out=tmp_path / "figures")       # no ClaimFailed
    meta = json.loads((tmp_path / "figures" / "toy.json").read_text())
    assert meta["claims"][1]["holds"] is None
    assert meta["claims"][1]["note"] == "x is empty here"


def test_a_failing_timing_claim_is_recorded_but_never_enforced(tmp_path):
    """require_claims enforces counts, never run times (claims.TIMED)."""
    import json

    from shadowlab.harness.claims import get
    from shadowlab.harness.figures import ClaimFailed

    assert get("s14.fig8.explicit_faster").timed and not get("s14.fig6.gain2x").timed
    toy = _TOY.replace('''{"claim": "x sums to 4",''', '''{"id": "s14.fig8.explicit_faster",
             "claim": "x sums to 4",''')
    _toy_project(tmp_path, toy)
    run_experiment(tmp_path, "toy", "ci", out=tmp_path / "figures")       # no ClaimFailed
    meta = json.loads((tmp_path / "figures" / "toy.json").read_text())
    assert meta["claims"][1]["holds"] is False
    (tmp_path / "experiments" / "toy.py").write_text(toy.replace("s14.fig8.explicit_faster",
                                                                  "s14.fig6.gain2x"))
    with pytest.raises(ClaimFailed, match="x sums to 4"):
        run_experiment(tmp_path, "toy", "ci", out=tmp_path / "figures")


def test_claims_only_recomputes_claims_from_the_stored_arrays(tmp_path, capsys):
    """`shadowlab figures --claims-only`: today's claims() over the committed arrays and
    config, without running; the run's provenance stays, the recomputation is recorded."""
    import json

    from shadowlab.cli import main

    _toy_project(tmp_path, required=False)
    run_experiment(tmp_path, "toy", "ci", out=tmp_path / "figures")
    before = json.loads((tmp_path / "figures" / "toy.json").read_text())
    (tmp_path / "experiments" / "toy.py").write_text(
        _TOY.replace("arrays['x'].sum()", "arrays['x'].sum() + 1").replace(
            'arrays["x"].sum() == 4', 'arrays["x"].sum() + 1 == 4').replace(
            "def run(cfg):\n    return", "def run(cfg):\n    raise RuntimeError\n    return"))
    assert main(["figures", "--claims-only", "--root", str(tmp_path), "--quiet"]) == 0
    after = json.loads((tmp_path / "figures" / "toy.json").read_text())
    assert [c["measured"] for c in after["claims"]] == ["3", "4"]
    assert [c["holds"] for c in after["claims"]] == [True, True]
    assert after["provenance"] == before["provenance"] and "claims_provenance" in after
    (tmp_path / "figures" / "toy.npz").unlink()
    assert main(["figures", "--claims-only", "--root", str(tmp_path), "--only", "toy"]) == 2
    assert "toy.json: no committed run" in capsys.readouterr().err


_SWEEP_TOY = '''
from pathlib import Path

import numpy as np

from shadowlab.harness import checkpoints


def _measure(i, options):
    log = Path(options["log"])
    log.write_text((log.read_text() if log.exists() else "") + f"{i}\\n")
    if i == 2 and Path(options["stop_flag"]).exists():
        raise RuntimeError("stopped at point 2")
    return {"i": i, "x": np.float64(i) / 2, "nan": float("nan"), "pair": (i, i + 1)}


def run(cfg):
    opts = cfg["options"]
    rows = [checkpoints.point(f"i={i}", lambda: _measure(i, opts)) for i in range(4)]
    return {"i": np.asarray([r["i"] for r in rows]), "x": np.asarray([r["x"] for r in rows]),
            "nan": np.asarray([r["nan"] for r in rows]),
            "pair": np.asarray([r["pair"] for r in rows])}


def plot(arrays):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    ax.plot(arrays["x"])
    return fig
'''


def _sweep_toy(root, scale=1):
    (root / "experiments").mkdir(exist_ok=True)
    (root / "configs" / "experiments").mkdir(parents=True, exist_ok=True)
    (root / "experiments" / "toy.py").write_text(_SWEEP_TOY)
    (root / "configs" / "experiments" / "toy.ci.toml").write_text(
        f"[options]\nlog = '{root / 'calls.log'}'\nstop_flag = '{root / 'stop'}'\n"
        f"scale = {scale}\n")
    return root / "figures"


def _calls(root):
    log = root / "calls.log"
    calls = [int(x) for x in log.read_text().split()] if log.exists() else []
    log.unlink(missing_ok=True)
    return calls


def test_a_stopped_figures_run_resumes_its_finished_points(tmp_path):
    import json

    from shadowlab.harness.checkpoints import FOLDER

    out = _sweep_toy(tmp_path)
    (tmp_path / "stop").touch()
    with pytest.raises(RuntimeError, match="stopped at point 2"):
        run_experiment(tmp_path, "toy", "ci", out=out)
    assert _calls(tmp_path) == [0, 1, 2]
    assert not (out / "toy.npz").exists()                 # nothing half-written
    assert len(list((out / FOLDER).rglob("*.json"))) == 2  # points 0 and 1 kept

    (tmp_path / "stop").unlink()
    resumed = run_experiment(tmp_path, "toy", "ci", out=out)
    assert _calls(tmp_path) == [2, 3]                      # only the unfinished points
    meta = json.loads((out / "toy.json").read_text())
    assert [p["label"] for p in meta["checkpoint"]["resumed"]] == ["i=0", "i=1"]
    for point in meta["checkpoint"]["resumed"]:           # where its time came from
        steal = point["steal"]
        assert steal is None or (steal["seconds"] >= 0 and 0 <= steal["share"] <= 1)
    machine = meta["machine"]                               # the load the run was timed under
    assert machine["cpus"] >= 1 and len(machine["load_average_after"]) == 3
    assert not (out / FOLDER).exists()                     # removed once written

    fresh = run_experiment(tmp_path, "toy", "ci", out=tmp_path / "again")
    assert _calls(tmp_path) == [0, 1, 2, 3]
    assert "checkpoint" not in json.loads((tmp_path / "again" / "toy.json").read_text())
    for k in fresh:                                        # NaN, tuples, NumPy scalars alike
        np.testing.assert_array_equal(resumed[k], fresh[k])
        assert resumed[k].dtype == fresh[k].dtype
    assert fresh["pair"].tolist() == [[0, 1], [1, 2], [2, 3], [3, 4]]
    assert fresh["i"].dtype.kind == "i" and np.isnan(fresh["nan"]).all()


@pytest.mark.parametrize("change", ["config", "fresh"])
def test_checkpoints_of_another_config_or_a_fresh_run_are_not_resumed(tmp_path, change):
    out = _sweep_toy(tmp_path)
    (tmp_path / "stop").touch()
    with pytest.raises(RuntimeError):
        run_experiment(tmp_path, "toy", "ci", out=out)
    _calls(tmp_path)
    (tmp_path / "stop").unlink()
    if change == "config":
        _sweep_toy(tmp_path, scale=2)
        run_experiment(tmp_path, "toy", "ci", out=out)
    else:                                                  # through the command line
        from shadowlab.cli import main

        assert main(["figures", "--root", str(tmp_path), "--only", "toy", "--fresh",
                     "--quiet"]) == 0
    assert _calls(tmp_path) == [0, 1, 2, 3]
    assert (out / "toy.npz").exists()


def test_a_point_outside_a_figures_run_is_computed_and_given_as_json_gives_it():
    from shadowlab.harness import checkpoints

    got = checkpoints.point("p", lambda: {"a": np.int64(3), "b": (1.5, np.nan),
                                          "c": np.arange(2)})
    assert got["a"] == 3 and type(got["a"]) is int
    assert got["b"][0] == 1.5 and np.isnan(got["b"][1]) and got["c"] == [0, 1]
    with pytest.raises(TypeError, match="JSON-able"):
        checkpoints.point("p", lambda: {"a": object()})


def test_a_repeated_label_is_refused_and_an_unreadable_point_is_recomputed(tmp_path):
    from shadowlab.harness import checkpoints

    cp = checkpoints.Checkpoint(tmp_path, "toy", "ci", "k")
    with checkpoints.active(cp):
        assert checkpoints.point("a", lambda: 1) == 1
        with pytest.raises(ValueError, match="used twice"):
            checkpoints.point("a", lambda: 2)
    (stored,) = cp.directory.glob("*.json")
    stored.write_text('{"label": "a", "val')          # e.g. a disk that filled up
    again = checkpoints.Checkpoint(tmp_path, "toy", "ci", "k")
    assert again.stored == 1
    with checkpoints.active(again):
        assert checkpoints.point("a", lambda: 3) == 3
    assert again.resumed == [] and again.written == 1


def test_the_checkpoint_key_follows_the_config_size_and_experiment_source(tmp_path):
    from shadowlab.harness import checkpoints

    module = ROOT / "experiments" / "silhouette_work.py"
    key = checkpoints.run_key("silhouette_work", "ci", {"repeats": 1}, module)
    assert checkpoints.run_key("silhouette_work", "ci", {"repeats": 1}, module) == key
    assert checkpoints.run_key("silhouette_work", "ci", {"repeats": 2}, module) != key
    assert checkpoints.run_key("silhouette_work", "full", {"repeats": 1}, module) != key
    toy = tmp_path / "toy.py"
    toy.write_text(module.read_text() + "\n# edited\n")
    assert checkpoints.run_key("silhouette_work", "ci", {"repeats": 1}, toy) != key


def test_fresh_with_claims_only_is_refused(tmp_path, capsys):
    from shadowlab.cli import main

    assert main(["figures", "--claims-only", "--fresh", "--root", str(tmp_path)]) == 2
    assert "--claims-only runs nothing, so --fresh" in capsys.readouterr().err
