"""The command line: run, methods, scenes, bench, errors, atomic outputs."""

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
import trimesh

import shadowlab as sl
from shadowlab.cli import main

SMALL = ["--set", "camera.resolution=[40,32]", "--set", 'methods.names=["brute_force"]']


def test_run_default_writes_outputs(tmp_path, capsys):
    assert main(["run", *SMALL, "--out", str(tmp_path), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "brute_force" in out and "x Embree" in out
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["config"]["scene"]["source"] == "gate"
    assert metrics["summary"]["brute_force"]["mismatches"] == 0
    arrays = np.load(tmp_path / "shadows.npz")
    assert arrays["reference"].shape == (1, 32, 40)
    assert np.array_equal(arrays["brute_force/lit"], arrays["reference"])
    assert (tmp_path / "figures" / "brute_force_lit.png").stat().st_size > 0
    assert not list(tmp_path.glob(".*"))       # no temporary files left behind


def _independent_lit(mesh: trimesh.Trimesh, gbuf, light_pos):
    """Lit mask from trimesh's own Embree ray queries: the first surface a ray from the
    light meets on its way to the sample must be the sample itself."""
    idx = np.flatnonzero(gbuf.valid)
    p = gbuf.position.reshape(-1, 3)[idx]
    n = gbuf.normal.reshape(-1, 3)[idx]
    to_light = light_pos - p
    facing = np.einsum("ij,ij->i", n, to_light) > 0
    dirs = -to_light / np.linalg.norm(to_light, axis=1, keepdims=True)
    origins = np.broadcast_to(light_pos, p.shape)
    tri, ray, loc = mesh.ray.intersects_id(origins, dirs, multiple_hits=False,
                                           return_locations=True)
    first = np.full(len(p), np.inf)
    first[ray] = np.linalg.norm(loc - light_pos, axis=1)
    reach = np.linalg.norm(to_light, axis=1)
    lit = np.zeros(gbuf.valid.size, bool)
    lit[idx] = facing & (first >= reach - 1e-4 * mesh.scale)
    return lit.reshape(gbuf.valid.shape)


def test_run_on_a_mesh_file_equals_an_independent_embree_cast(tmp_path):
    knot = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    knot.apply_translation((0, 1.5, 0))
    ground = trimesh.creation.box(extents=(6, 0.1, 6))
    mesh = trimesh.util.concatenate([knot, ground])
    path = tmp_path / "model.ply"
    mesh.export(path)
    out = tmp_path / "out"
    light = [1.0, 6.0, 2.0]
    assert main(["run", "--set", f"scene.source={path}", "--set", "camera.resolution=[48,48]",
                 "--set", f"light={{type=\"point\", position={light}}}",
                 "--set", 'methods.names=["brute_force"]', "--out", str(out), "--quiet"]) == 0
    arrays = np.load(out / "shadows.npz")
    scene = sl.load_scene(path)
    metrics = json.loads((out / "metrics.json").read_text())
    cam = metrics["config"]["camera"]
    assert arrays["valid"][0].sum() > 200
    # Re-render the same view and compare the run's mask with trimesh's own ray cast.
    from shadowlab.config import load_config
    config = load_config(None, [f"scene.source={path}", "camera.resolution=[48,48]",
                                f"light={{type=\"point\", position={light}}}"])
    view = config.views(scene)[0]
    gbuf = sl.render_gbuffer(scene, view.camera)
    assert np.array_equal(gbuf.valid, arrays["valid"][0])
    want = _independent_lit(trimesh.Trimesh(scene.vertices, scene.faces, process=False),
                            gbuf, np.asarray(light))
    got = arrays["brute_force/lit"][0]
    assert np.array_equal(got, arrays["reference"][0])
    assert 0 < want.sum() < gbuf.valid.sum()
    assert np.array_equal(got, want), np.argwhere(got != want)
    assert cam is not None


def test_bad_input_exits_2_with_a_message(tmp_path, capsys):
    assert main(["run", str(tmp_path / "none.toml")]) == 2
    assert "no such config file" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("[light]\ntype = 'spot'\n")
    assert main(["run", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "light.type" in err and "directional" in err
    assert main(["run", "--set", f"scene.source={tmp_path / 'missing.obj'}"]) == 2
    assert "missing.obj" in capsys.readouterr().err
    assert main(["figures", "--root", str(tmp_path)]) == 2
    assert "no experiments folder" in capsys.readouterr().err


def test_invalid_experiment_config_exits_2_before_any_experiment_runs(tmp_path, capsys):
    (tmp_path / "experiments").mkdir()
    ran = tmp_path / "ran"
    for name in ("a_good", "b_bad"):
        (tmp_path / "experiments" / f"{name}.py").write_text(
            "import pathlib\n"
            f"def run(cfg):\n    pathlib.Path({str(ran)!r}).write_text('x')\n    return {{}}\n"
            "def plot(arrays):\n    raise AssertionError\n")
    configs = tmp_path / "configs" / "experiments"
    configs.mkdir(parents=True)
    (configs / "a_good.ci.toml").write_text("resolution = [8, 8]\n")
    (configs / "b_bad.ci.toml").write_text("resolution = [8, 8]\nrepeats = 0\n")
    assert main(["figures", "--root", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"shadowlab: error: {configs / 'b_bad.ci.toml'}: repeats must be an "
                          "integer >= 1, got 0")
    assert not ran.exists() and not (tmp_path / "figures").exists()


def test_every_user_error_exits_2_with_the_prefix(tmp_path, capsys):
    """Config, method, scene, experiment and capacity errors all print 'shadowlab: error:'
    and exit 2."""
    cases = [
        ["run", "--set", "camera.resolution=[8,8]", "--set", "reference.soft_rays=0"],
        ["run", "--set", "camera.resolution=[8,8]", "--set", 'methods.names=["soft_tiled"]'],
        ["run", "--set", "camera.resolution=[8,8]", "--set", "scene.source=fuzzy",
         "--set", "scene.params.triangles=2", "--set", "scene.params.clusters=3",
         "--set", 'methods.names=["brute_force"]'],
        ["figures", "--root", str(tmp_path)],
        ["run", "--set", "camera.resolution=[16,16]", "--set", 'methods.names=["clustered_ptsv"]',
         "--set", "methods.options.clustered_ptsv.z_bits=30"],      # a key past int32 rows
    ]
    for argv in cases:
        assert main([*argv, "--quiet"] if argv[0] == "run" else argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("shadowlab: error: ") and "Traceback" not in err, (argv, err)


def test_interrupted_write_leaves_no_half_written_file(tmp_path, monkeypatch):
    import shadowlab.core.io as sio

    def explode(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sio.np, "savez_compressed", explode)
    assert main(["run", *SMALL, "--out", str(tmp_path), "--quiet"]) == 130
    assert not (tmp_path / "shadows.npz").exists()
    assert not list(tmp_path.glob(".*"))


def test_methods_and_scenes_listings(capsys):
    assert main(["methods"]) == 0
    out = capsys.readouterr().out
    assert "brute_force" in out and "precision = 'float32'" in out
    assert "static (shadowlab bench, static light and geometry): reuse_tree=True" in out
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    for name in ("sphere_grid", "gate", "fuzzy", "terrain", "blobs", "soup"):
        assert name in out


def test_bench_writes_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "--size", "ci", "--repeats", "1", "--out", str(out), "--quiet",
                 "--set", "camera.resolution=[32,32]"]) == 0
    data = json.loads(out.read_text())
    case = data["cases"][0]
    row = case["methods"]["brute_force"]
    assert case["reference"]["median_seconds"] > 0
    assert row["error"]["mismatches"] == 0
    assert row["ratio_to_reference"] == pytest.approx(
        row["median_seconds"] / case["reference"]["median_seconds"])
    assert "compile_seconds" in row and "test" in row["stages"]
    # dynamic: every per-scene cache dropped before each call (Embree rebuilds its BVH)
    ref = case["reference"]
    assert len(ref["dynamic_runs"]) == 1 and row["dynamic_runs"][0] > 0
    assert row["dynamic_ratio"] == pytest.approx(
        row["dynamic_median_seconds"] / ref["dynamic_median_seconds"])
    # paired: an Embree pass (BVH kept) timed before each warm call of the method
    assert len(row["paired_reference_runs"]) == 1
    assert row["paired_reference_runs"][0] > 0
    assert row["paired_ratio"] == pytest.approx(
        row["median_seconds"] / row["paired_reference_median_seconds"])


def test_bench_static_ratio_uses_the_methods_static_options(tmp_path):
    """A PSV method keeps its TOP tree in the static frame (its static_options), unless
    the case sets the option itself; the dynamic frame rebuilds."""
    out = tmp_path / "bench.json"
    for case_opts, reused in (([], 1), (["--set", "methods.options.d_stackless.reuse_tree=false"],
                                         0)):
        assert main(["bench", "--size", "ci", "--repeats", "1", "--out", str(out), "--quiet",
                     "--set", "camera.resolution=[32,32]",
                     "--set", 'methods.names=["d_stackless"]', *case_opts]) == 0
        row = json.loads(out.read_text())["cases"][0]["methods"]["d_stackless"]
        assert row["counters"]["tree_reused"] == reused
        assert row["static_options"] == ({"reuse_tree": True} if reused else {})
        assert row["error"]["mismatches"] == 0 and row["dynamic_runs"][0] > 0


# The default scene (gate) made small: the scene and resolution of the pareto experiment's
# CI-size gate frame (configs/experiments/pareto.ci.toml), so both compile the same
# programs once per test session. The default config itself (gate, every method) is
# checked in test_config.py and test_resources.py.
_PARETO = tomllib.loads((Path(__file__).resolve().parent.parent / "configs" / "experiments"
                         / "pareto.ci.toml").read_text())
SMALL_GATE = ["--set", f"camera.resolution={_PARETO['resolution']}",
              *(a for k, v in _PARETO["params"]["gate"].items()
                for a in ("--set", f"scene.params.{k}={v}"))]


def test_default_run_with_every_method_skips_soft_methods_on_a_point_light(tmp_path, capsys):
    """The README's first command runs every registered method; none may break it."""
    from shadowlab import methods

    assert main(["run", *SMALL_GATE, "--out", str(tmp_path), "--quiet"]) == 0
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["config"]["scene"]["source"] == "gate"
    soft = {n for n in methods.names() if methods.get(n).soft}
    assert set(metrics["summary"]) == set(methods.names()) - soft
    assert set(metrics["skipped"]) == soft
    for name, row in metrics["summary"].items():
        if methods.get(name).kind is methods.MethodKind.EXACT:   # approximate: shadow_map
            assert row["mismatches"] == 0, name
    assert "skipped" in capsys.readouterr().out


def test_a_named_soft_method_needs_an_area_light(tmp_path, capsys):
    assert main(["run", "--set", 'methods.names=["soft_tiled"]', "--out", str(tmp_path),
                 "--quiet"]) == 2
    assert "needs a sphere or sun light" in capsys.readouterr().err
    assert not (tmp_path / "metrics.json").exists()


def test_soft_methods_run_against_the_soft_reference(tmp_path):
    assert main(["run", "--set", "scene.source=terrain", "--set", "scene.params.size=24",
                 "--set", "camera.resolution=[24,24]", "--set", "reference.soft_rays=16",
                 "--set", 'methods.names=["soft_tiled","brute_force"]', "--out", str(tmp_path),
                 "--quiet"]) == 0
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    soft = metrics["summary"]["soft_tiled"]
    assert 0 <= soft["mae"] < 0.1
    arrays = np.load(tmp_path / "shadows.npz")
    assert arrays["soft_reference"].shape == (1, 24, 24)
    assert metrics["summary"]["brute_force"]["mismatches"] == 0


def test_bench_soft_method_reports_embree_time_at_equal_error(tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "--size", "ci", "--repeats", "1", "--out", str(out), "--quiet",
                 "--set", "scene.source=terrain", "--set", "scene.params.size=24",
                 "--set", "camera.resolution=[24,24]", "--set", "reference.soft_rays=64",
                 "--set", 'methods.names=["soft_tiled"]']) == 0
    case = json.loads(out.read_text())["cases"][0]
    curve = case["soft_reference"]["curve"]
    assert [c["rays"] for c in curve] == [4, 16, 64]
    assert all(c["seconds"] > 0 and 0 <= c["mae"] <= 1 for c in curve)
    row = case["methods"]["soft_tiled"]
    assert {"mae", "rmse", "max_error", "ssim"} <= set(row["error"])
    assert "embree_seconds_at_equal_error" in row
    assert {"penumbra_mae", "penumbra_ssim"} <= set(row["error"])
    assert set(row["embree_seconds_at_equal"]) >= {"mae", "penumbra_mae", "penumbra_ssim"}
    assert set(row["embree_seconds_at_equal_lower_bound"]) <= set(row["embree_seconds_at_equal"])


def test_embree_time_at_equal_error_interpolates_log_log():
    from shadowlab.harness.bench import embree_seconds_at_error

    curve = [{"mae": 0.04, "seconds": 1.0}, {"mae": 0.01, "seconds": 16.0}]
    assert embree_seconds_at_error(curve, 0.02) == pytest.approx(4.0)
    assert embree_seconds_at_error(curve, 0.001) is None
    assert embree_seconds_at_error(curve, 0.5) is None


def test_embree_time_at_equal_error_on_each_metric():
    from shadowlab.harness.bench import embree_seconds_at_equal, embree_seconds_beyond

    curve = [{"mae": 0.04, "ssim": 0.9, "penumbra_mae": 0.4, "seconds": 1.0},
             {"mae": 0.01, "ssim": 0.99, "penumbra_mae": 0.1, "seconds": 16.0}]
    at = embree_seconds_at_equal(curve, {"mae": 0.02, "ssim": 0.9, "penumbra_mae": 0.01,
                                         "valid_pixels": 5})
    assert at["mae"] == pytest.approx(4.0)
    assert at["ssim"] == pytest.approx(1.0)          # SSIM is matched as 1 - SSIM
    assert at["penumbra_mae"] is None                 # better than the whole curve
    assert set(at) == {"mae", "ssim", "penumbra_mae"}
    # where the method beats the whole curve: at least the most accurate point's time
    beyond = embree_seconds_beyond(curve, {"mae": 0.02, "ssim": 0.995, "penumbra_mae": 0.01})
    assert beyond == {"ssim": 16.0, "penumbra_mae": 16.0}


def test_bench_bad_arguments_exit_2(tmp_path, capsys):
    assert main(["bench", "--only", "nope", "--out", str(tmp_path / "b.json")]) == 2
    err = capsys.readouterr().err
    assert "unknown case(s) nope" in err and "gate-1024" in err
    assert main(["bench", "--size", "ci", "--repeats", "0", "--out", str(tmp_path / "b.json")]) == 2
    assert "--repeats must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "b.json").exists()


@pytest.mark.parametrize("size", ["ci", "full"])
def test_every_built_in_bench_case_is_a_valid_config(size):
    """Each case of shadowlab/configs/bench.toml loads (scene parameters, methods and
    their options validated; memory not checked, this machine is not the bench's)
    without running anything; names are unique, repeats positive integers; the full
    size covers every exact method at 1024x1024 (issue 16's targets)."""
    from shadowlab.config import load_config
    from shadowlab.harness.bench import default_cases
    from shadowlab.methods import MethodKind, get, names

    cases = default_cases(size)
    assert len({c["name"] for c in cases}) == len(cases)
    covered = set()
    for c in cases:
        config = load_config(None, list(c["overrides"]), check_memory=False)
        reps = c.get("repeats", 1)
        assert isinstance(reps, int) and reps >= 1, c["name"]
        target = c.get("target")
        assert target is None or (isinstance(target, float) and target > 0), c["name"]
        if c["name"].startswith(("exact-", "psv-")):       # issue 16: 3x up to 100k, 5x at 1M
            assert target == (5.0 if "-1M-" in c["name"] else 3.0), c["name"]
        if tuple(config.camera.resolution) == (1024, 1024):
            covered |= set(config.methods.names)
    if size == "full":
        exact = {n for n in names() if get(n).kind is MethodKind.EXACT}
        assert exact <= covered, sorted(exact - covered)


def test_bench_output_states_each_method_against_its_cases_target():
    """A case's target (bench.toml) is looked up by name, recorded, and each hard method's
    static ratio is judged against it (at the target: met)."""
    from shadowlab.harness.bench import case_target, format_bench, target_verdict

    assert case_target("exact-fuzzy-100k-1024") == 3.0
    assert case_target("exact-sphere_grid-1M-1024") == 5.0
    assert case_target("gate-1024") is None and case_target("no such case") is None
    assert [target_verdict(r, 3.0) for r in (2.99, 3.0, 3.01)] == ["met", "met", "missed"]
    assert target_verdict(None, 3.0) is None and target_verdict(2.0, None) is None

    def method(ratio):
        return {"stages": {"trace": 0.01}, "compile_seconds": 0.1, "median_seconds": 0.02,
                "ratio_to_reference": ratio, "dynamic_ratio": 1.0,
                "error": {"mismatches": 0, "valid_pixels": 4}}
    case = {"name": "c", "scene": "s", "triangles": 3, "resolution": [2, 2],
            "reference": {"median_seconds": 0.01, "dynamic_median_seconds": 0.02},
            "target_ratio": 3.0, "methods": {"fast": method(2.5), "slow": method(3.5)}}
    lines = format_bench({"repeats": 1, "cases": [case]}).splitlines()
    assert "  target: at most 3x Embree (static) per method" in lines
    assert [line.split("[")[-1] for line in lines if line.lstrip().startswith(("fast", "slow"))
            ] == ["target met]", "target missed]"]
    del case["target_ratio"]
    assert "target" not in format_bench({"repeats": 1, "cases": [case]})


def test_bench_records_the_machine_load_and_says_when_it_was_busy():
    from shadowlab.harness.bench import BUSY_LOAD_PER_CORE, machine_record

    idle = {"date_utc": "2026-01-01", "cpus": 4, "load_average": [0.1, 0.2, 0.3]}
    busy = dict(idle, load_average=[4 * BUSY_LOAD_PER_CORE + 0.5, 1.0, 1.0])
    rec = machine_record(idle, idle)
    assert rec["load_average_before"] == [0.1, 0.2, 0.3] and "note" not in rec
    assert "note" not in machine_record(idle, busy)     # the run's own threads at the end
    assert "not idle at the start" in machine_record(busy, idle)["note"]
    assert machine_record(busy, idle, note="laptop").get("note").startswith("laptop; not idle")
    assert machine_record(idle, idle, note="laptop")["note"] == "laptop"


def test_the_machine_record_names_the_cpu_and_its_widest_vector_extension():
    """``cpu_description`` reads the model and the widest SIMD level from cpuinfo text
    (x86 and ARM layouts), and the bench's machine record carries it."""
    from shadowlab.core.machine import cpu_description, machine_record, machine_state

    x86 = ("processor\t: 0\nmodel name\t: AMD EPYC 9R14\nflags\t\t: fpu sse4_2 avx avx2 "
           "avx512f avx512bw\n\nprocessor\t: 1\nmodel name\t: other\nflags\t\t: fpu\n")
    assert cpu_description(x86) == {"model": "AMD EPYC 9R14", "simd": "AVX-512"}
    assert cpu_description(x86.replace(" avx512f avx512bw", ""))["simd"] == "AVX2"
    assert cpu_description("model name : Old\nflags : fpu sse2\n")["simd"] is None
    arm = "processor : 0\nFeatures : fp asimd evtstrm\nCPU part : 0xd0c\n"
    assert cpu_description(arm)["simd"] == "NEON"
    state = {"date_utc": "2026-01-01", "cpus": 2, "load_average": [0.0, 0.0, 0.0],
             "cpu": {"model": "AMD EPYC 9R14", "simd": "AVX-512"}}
    assert machine_record(state, state)["cpu"] == state["cpu"]
    assert "cpu" not in machine_record(dict(state, cpu=None), state)
    # given text never borrows this host's model; this host's record always has the keys
    assert cpu_description("flags : fpu avx2\n") == {"model": None, "simd": "AVX2"}
    assert set(machine_state()["cpu"]) == {"model", "simd"}


def test_the_machine_record_says_when_the_hypervisor_took_cpu_time():
    """``steal_seconds`` reads the steal column of /proc/stat text; the machine record
    carries the steal between its two states and notes a share above ``STEAL_SHARE`` of
    the cores' time; a state without steal time gives no record."""
    import os

    from shadowlab.core.machine import (STEAL_SHARE, cpu_clock, machine_record,
                                        steal_between, steal_seconds)

    hz = os.sysconf("SC_CLK_TCK")
    stat = "cpu  4705 0 1500 90000 400 0 30 250 0 0\ncpu0 2000 0 700 45000 200 0 15 999 0 0\n"
    assert steal_seconds(stat) == 250 / hz               # the aggregate line, not cpu0's
    assert steal_seconds("cpu  4705 0 1500 90000 400 0 30\n") is None   # no steal column
    assert steal_seconds("intr 12 3\n") is None
    start = {"date_utc": "2026-01-01", "cpus": 2, "load_average": [0.0] * 3,
             "clock": 100.0, "steal": 10.0}
    quiet = dict(start, clock=110.0, steal=10.0 + 20 * STEAL_SHARE / 2)
    shared = dict(start, clock=110.0, steal=10.0 + 20 * STEAL_SHARE * 2)
    assert steal_between(start, quiet) == {"seconds": round(10 * STEAL_SHARE, 2),
                                           "share": round(STEAL_SHARE / 2, 4)}
    rec = machine_record(start, quiet)
    assert rec["steal"]["share"] == STEAL_SHARE / 2 and "note" not in rec
    rec = machine_record(start, shared)
    assert rec["steal"]["share"] == 2 * STEAL_SHARE
    assert "another guest shared the host" in rec["note"]
    assert "steal" not in machine_record(dict(start, steal=None), shared)
    assert steal_between(start, dict(start)) is None      # no wall time passed
    # this host's clocks: a monotonic clock and, on Linux, the steal since boot
    now = cpu_clock()
    assert now["cpus"] >= 1 and now["clock"] > 0
    assert now["steal"] is None or now["steal"] >= 0


def test_run_prints_what_each_frame_skipped(tmp_path, capsys):
    assert main(["run", "--set", "camera.resolution=[16,16]", "--set",
                 'methods.names=["brute_force"]', "--set",
                 'methods.options.brute_force.cull_casters="hull_averted"',
                 "--out", str(tmp_path), "--quiet"]) == 0
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    frame = metrics["frames"][0]
    sk = frame["skipped"]
    samples = frame["methods"]["brute_force"]["counters"]["samples"]
    assert sk["sky"] + sk["back_facing"] + samples == 16 * 16
    culled = frame["methods"]["brute_force"]["counters"]["culled_casters"]
    assert culled > 0 and frame["methods"]["brute_force"]["error"]["mismatches"] == 0
    assert (f"frame 0: skipped {sk['sky']} sky and {sk['back_facing']} back-facing pixels; "
            f"casters culled: brute_force {culled}") in capsys.readouterr().out
