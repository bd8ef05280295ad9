"""Run time against error (experiments/pareto.py): fronts, the README block, the CLI.

The experiment itself runs at CI size in tests/test_figures.py (with its golden file);
these tests check its pieces on hand-made data, so they cost well under a second.
"""

from pathlib import Path

import numpy as np
import pytest

from shadowlab.analysis.pareto import fastest_at, pareto_front
from shadowlab.harness import pareto_readme
from shadowlab.harness.figures import load_module
from shadowlab.methods import MethodKind, get, names
from shadowlab.scene.view import DirectionalLight, PointLight, SphereLight

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def exp():
    return load_module(ROOT / "experiments" / "pareto.py")


def _front_by_loop(t, e):
    """Plain loop: i is on the front iff no j is at least as good in both and better
    in one; ordered by error, then time."""
    keep = []
    for i in range(len(t)):
        if not (np.isfinite(t[i]) and np.isfinite(e[i])):
            continue
        dominated = any(np.isfinite(t[j]) and np.isfinite(e[j]) and t[j] <= t[i]
                        and e[j] <= e[i] and (t[j] < t[i] or e[j] < e[i])
                        for j in range(len(t)))
        if not dominated:
            keep.append(i)
    # equal (t, e) duplicates: keep the first only, as pareto_front does
    out, seen = [], set()
    for i in sorted(keep, key=lambda i: (e[i], t[i], i)):
        if (t[i], e[i]) not in seen:
            out.append(i)
            seen.add((t[i], e[i]))
    return out


@pytest.mark.parametrize("seed", range(3))
def test_pareto_front_matches_a_plain_loop(seed):
    rng = np.random.default_rng(seed)
    t = rng.integers(1, 12, 40).astype(float)         # ties in both coordinates
    e = rng.integers(0, 8, 40).astype(float)
    t[3] = np.nan
    e[5] = np.nan
    got = pareto_front(t, e)
    assert list(got) == _front_by_loop(t, e)
    assert np.all(np.diff(t[got]) < 0) and np.all(np.diff(e[got]) >= 0)
    levels = np.array([-1.0, 0.0, 2.5, 7.0])
    for lev, i in zip(levels, fastest_at(levels, t, e)):
        ok = [j for j in range(40) if np.isfinite(t[j]) and np.isfinite(e[j]) and e[j] <= lev]
        assert (i == -1) if not ok else (t[i] == min(t[j] for j in ok) and e[i] <= lev)


def test_pareto_front_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="one length"):
        pareto_front([1.0, 2.0], [0.0])


def test_configs_come_from_the_registry(exp):
    hard = exp.hard_configs({"sm_resolutions": [512, 2048], "biases": ["none", "slope"]})
    methods = {m for _, m, _ in hard}
    assert methods == {n for n in names() if get(n).kind is not MethodKind.SOFT}
    sm = [(lab, o) for lab, m, o in hard if m == "shadow_map"]
    assert sorted(lab for lab, _ in sm) == ["sm2048-none", "sm2048-slope", "sm512-none",
                                            "sm512-slope"]
    soft = exp.soft_configs(True)
    assert {m for _, m, _ in soft} == {n for n in names() if get(n).kind is MethodKind.SOFT}
    presets = [o["preset"] for _, m, o in soft if "preset" in o]
    assert len(presets) == sum(len(get(m).presets) for m in {m for _, m, _ in soft})
    assert all("preset" not in o for _, _, o in exp.soft_configs(False))


def test_soft_light_variant(exp):
    class S:
        diagonal = 50.0

    sphere = exp.soft_light(S, PointLight((1.0, 2.0, 3.0)), 0.02)
    assert isinstance(sphere, SphereLight)
    assert np.allclose(sphere.position, (1, 2, 3)) and sphere.radius == pytest.approx(1.0)
    sun = SphereLight(direction=(0, -1, 0), angular_radius_deg=1.0)
    assert exp.soft_light(S, sun, 0.02) is sun
    with pytest.raises(ValueError, match="DirectionalLight"):
        exp.soft_light(S, DirectionalLight((0, -1, 0)), 0.02)


def _arrays():
    """Hand-made experiment arrays: one scene, exact a (slow), exact b (fast), a shadow
    map (fastest, 3 mismatches of 100 pixels); two soft methods."""
    a = {"scenes": np.array(["toy"]), "labels": np.array(["a", "b", "sm512-slope"]),
         "kinds": np.array(["exact", "exact", "approximate"]),
         "seconds": np.array([[0.004, 0.002, 0.001]]),
         "mismatches": np.array([[0, 0, 3]]), "fraction": np.array([[0.0, 0.0, 0.03]]),
         "unexplained": np.array([[0, 0, -1]]), "embree_seconds": np.array([0.001]),
         "valid_pixels": np.array([100]),
         "soft_labels": np.array(["s1", "s2"]), "soft_seconds": np.array([[0.05, 0.5]]),
         "soft_mae": np.array([[0.02, 0.001]]), "soft_penumbra_mae": np.array([[0.1, 0.01]]),
         "embree_rays": np.array([4, 16]), "embree_soft_seconds": np.array([[0.01, 0.04]]),
         "embree_soft_mae": np.array([[0.04, 0.01]])}
    a["embree_ratio"] = a["seconds"] / a["embree_seconds"][:, None]
    for prefix, lab, t, e in (("front", a["labels"], a["seconds"][0], a["fraction"][0]),
                              ("soft_front", a["soft_labels"], a["soft_seconds"][0],
                               a["soft_mae"][0])):
        idx = pareto_front(t, e)
        a[f"{prefix}_scene"] = np.array(["toy"] * len(idx))
        a[f"{prefix}_label"] = np.asarray(lab)[idx]
        a[f"{prefix}_error"] = e[idx]
        a[f"{prefix}_seconds"] = t[idx]
    return a


def test_summary_and_readme_block_state_the_fronts(exp):
    a = _arrays()
    exp.check(a, {})
    s = exp.summary(a, {})
    assert [r["fastest"] for r in s["front"]["toy"]] == ["b", "sm512-slope"]
    assert [r["fastest"] for r in s["soft_front"]["toy"]] == ["s2", "s1"]
    # s1's MAE 0.02 lies on Embree's curve (0.04 at 10 ms, 0.01 at 40 ms): log-log
    # interpolation gives 20 ms; s2's 0.001 lies below it: None
    assert s["soft_front"]["toy"][1]["embree_seconds"] == pytest.approx(0.02)
    assert s["soft_front"]["toy"][0]["embree_seconds"] is None
    block = pareto_readme.render_block({"summary": s, "size": "ci",
                                        "config": {"resolution": [10, 10], "repeats": 1}})
    assert block.startswith(pareto_readme.BEGIN) and block.endswith(pareto_readme.END)
    assert "| 0 | `b` | 2.00 | 2.00x |" in block
    assert "| 3 | `sm512-slope` | 1.00 | 1.00x |" in block
    assert "| 0.0200 | `s1` | 50.00 | 20.00 |" in block
    assert "| 0.0010 | `s2` | 500.00 | > 40.00 (beyond" in block   # below the curve
    assert "`a`" not in block                       # dominated by b
    points = [{"rays": 4, "seconds": 0.01, "mae": 0.04}, {"rays": 16, "seconds": 0.04, "mae": 0.01}]
    worse = {"error": 0.08, "embree_seconds": None}
    assert pareto_readme._embree_at(worse, points) == "< 10.00 (4 rays are more accurate)"
    assert pareto_readme._embree_at({"error": 0.02, "embree_seconds": 0.02}, points) == "20.00"
    assert "load was not recorded" in block
    machine = {"cpus": 2, "load_average_before": [0.3, 0.5, 0.6],
               "load_average_after": [1.9, 1.8, 1.2]}
    block = pareto_readme.render_block({"summary": s, "size": "full", "machine": machine,
                                        "config": {"resolution": [10, 10], "repeats": 1}})
    assert "load average 0.30 at the start and 1.90 at the end (2 cores" in block
    busy = dict(machine, note="not idle at the start: 1-minute load average 3.00")
    assert "Note: not idle at the start" in pareto_readme.machine_sentence({"machine": busy})


def test_check_fails_on_unexplained_exact_error(exp):
    a = _arrays()
    a["unexplained"] = np.array([[1, 0, -1]])
    with pytest.raises(AssertionError):
        exp.check(a, {})


def test_replace_block_keeps_the_rest_and_refuses_missing_markers():
    b, e = pareto_readme.BEGIN, pareto_readme.END
    text = f"head\n{b}\nold\n{e}\ntail\n"
    assert pareto_readme.replace_block(text, f"{b}\nnew\n{e}") == f"head\n{b}\nnew\n{e}\ntail\n"
    for bad in ("no markers\n", f"{e}\n{b}\n", f"{b}\n{e}\n{b}\n{e}\n"):
        with pytest.raises(pareto_readme.ReadmeBlockError, match="once each"):
            pareto_readme.replace_block(bad, f"{b}\n{e}")


def test_readme_block_is_generated_from_the_committed_json(tmp_path):
    readme = (ROOT / "README.md").read_text()
    out = tmp_path / "README.md"
    out.write_text(readme)
    pareto_readme.update_readme(ROOT / "figures" / "pareto.json", out)
    assert out.read_text() == readme, (
        "regenerate: python -m shadowlab.harness.pareto_readme")


def test_cli_bench_pareto_bad_input(capsys):
    from shadowlab.cli import main

    assert main(["bench", "--render-only"]) == 2
    assert "needs --pareto" in capsys.readouterr().err
    assert main(["bench", "--pareto", "--set", "camera.resolution=[8,8]"]) == 2
    assert "takes no config" in capsys.readouterr().err
    assert main(["bench", "--pareto", "--render-only", "--root", "/nonexistent"]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_cli_bench_pareto_renders_the_committed_json(capsys):
    from shadowlab.cli import main

    assert main(["bench", "--pareto", "--render-only", "--root", str(ROOT)]) == 0
    out = capsys.readouterr().out
    assert pareto_readme.BEGIN in out and "hard shadows" in out


def test_unknown_soft_scene_is_a_config_error(exp):
    from shadowlab.harness.figures import ExperimentConfigError

    cfg = {"scenes": ["gate"], "resolution": [8, 8], "embree_rays": [2], "truth_rays": 2,
           "options": {"sm_resolutions": [512], "biases": ["slope"],
                       "soft_scenes": ["gat"]}}
    with pytest.raises(ExperimentConfigError, match="soft_scenes.*gat"):
        exp.run(cfg)
