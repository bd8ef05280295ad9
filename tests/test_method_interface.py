"""The method interface: options as one typed model with bounds, the registry's stamps,
the light check, and the out-of-range option refused by the CLI with exit code 2."""

import time

import numpy as np
import pytest

import shadowlab as sl
from shadowlab.cli import main
from shadowlab.methods import MethodError, MethodKind, Option, registry
from shadowlab.core.result import ShadowResult
from shadowlab.reference.raycast import DEFAULT_SHADOW_EPS


def test_stack_size_over_its_maximum_exits_2_naming_method_option_value_and_bound(
        tmp_path, capsys):
    code = main(["run", "--set", 'methods.names=["psv"]', "--set",
                 "methods.options.psv.stack_size=100", "--set", "camera.resolution=[16,16]",
                 "--out", str(tmp_path), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert "psv" in err and "stack_size" in err and "100" in err and "<= 63" in err
    assert "Traceback" not in err
    assert not (tmp_path / "metrics.json").exists()


@pytest.mark.parametrize("method,option,value,bound", [
    ("psv", "stack_size", 64, "<= 63"), ("d_hybrid", "stack_size", 0, ">= 1"),
    ("clustered_ptsv", "z_bits", 31, "<= 30"), ("brute_force", "shadow_eps", -1.0, ">= 0.0")])
def test_numeric_bounds_are_refused_by_the_registry(method, option, value, bound):
    with pytest.raises(MethodError) as info:
        registry.resolve_options(method, {option: value})
    msg = str(info.value)
    assert repr(method) in msg and f"{option}={value!r}" in msg and bound in msg


def test_bounds_are_inclusive_and_ints_become_floats():
    assert registry.resolve_options("psv", {"stack_size": 63})["stack_size"] == 63
    opts = registry.resolve_options("brute_force", {"shadow_eps": 0})
    assert opts["shadow_eps"] == 0.0 and isinstance(opts["shadow_eps"], float)
    assert registry.resolve_options("brute_force", {})["shadow_eps"] == DEFAULT_SHADOW_EPS


@pytest.mark.parametrize("value", [True, 2.5, "8", None])
def test_types_are_strict(value):
    with pytest.raises(MethodError, match="stack_size"):
        registry.resolve_options("psv", {"stack_size": value})


def test_a_bool_is_not_a_member_of_a_numeric_set_nor_a_number_of_a_bool_set():
    with pytest.raises(MethodError, match="allowed values: 1, 2"):
        registry.resolve_options("clustered_ptsv", {"passes": True})
    with pytest.raises(MethodError, match="allowed values: True, False"):
        registry.resolve_options("clustered_ptsv", {"prune": 1})
    assert registry.resolve_options("clustered_ptsv", {"passes": 2})["passes"] == 2


def test_options_model_is_one_pydantic_model_with_the_declared_bounds():
    model = registry.options_model("psv")
    schema = model.model_json_schema()["properties"]
    assert schema["stack_size"]["maximum"] == 63 and schema["stack_size"]["minimum"] == 1
    assert set(model.model_fields) == set(registry.get("psv").options)


def _toy(fail_counter=False, stage="work"):
    """A throwaway method registered under a unique name (removed afterwards)."""
    name = f"_toy_{fail_counter}_{stage}"

    @registry.register(name, doc="test", kind="approximate", counters=("samples", "lit"),
                       stages=("work",),
                       options={"level": Option(2, "a level", kind=int, minimum=0, maximum=4)})
    def toy(scene, gbuf, light, *, precision, shadow_eps, level):
        lit = np.ones(gbuf.valid.shape, bool)
        counters = {"samples": level} if fail_counter else {"samples": level, "lit": 1}
        return ShadowResult(lit, counters, {stage: 0.5, f"{stage}_compile": 2.0})
    return name


@pytest.fixture
def frame():
    scene = sl.load_scene("gate")
    from shadowlab.scene.procedural import default_view
    view = default_view("gate", scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(8, 8)))
    return scene, gbuf, view.light


def test_registry_stamps_name_options_and_total(frame):
    name = _toy()
    try:
        res = sl.compute_shadows(*frame, method=name, level=3)
        assert res.method == name
        assert res.options == {"precision": "float32", "shadow_eps": DEFAULT_SHADOW_EPS,
                               "cull_casters": "off",
                               "level": 3}
        # the toy's stages claim more than its wall time: no host time is left over
        assert res.timings == {"work": 0.5, "work_compile": 2.0, "host": 0.0, "total": 0.5}
        assert registry.get(name).kind is MethodKind.APPROXIMATE
        with pytest.raises(MethodError, match="level=5 must be int >= 0 and <= 4"):
            sl.compute_shadows(*frame, method=name, level=5)
    finally:
        registry._REGISTRY.pop(name)


def test_time_outside_the_stages_is_the_host_stage_and_counts_in_the_total(frame):
    """Work a method does between its timed stages (here a 0.2 s sleep beside a stage
    that recorded 0.01 s) is reported as the stage ``host`` and included in ``total``."""
    name = "_toy_host"

    @registry.register(name, doc="test", kind="approximate", counters=("samples",),
                       stages=("work",))
    def toy(scene, gbuf, light, *, precision, shadow_eps):
        time.sleep(0.2)
        return ShadowResult(np.ones(gbuf.valid.shape, bool), {"samples": 1}, {"work": 0.01})
    try:
        t0 = time.perf_counter()
        res = sl.compute_shadows(*frame, method=name)
        wall = time.perf_counter() - t0
        assert 0.19 <= res.timings["host"] <= wall
        assert res.timings["total"] == pytest.approx(0.01 + res.timings["host"])
        assert res.timings["total"] <= wall + 0.01
    finally:
        registry._REGISTRY.pop(name)


@pytest.mark.parametrize("fail_counter,stage,match", [(True, "work", "missing \\['lit'\\]"),
                                                      (False, "other", "undeclared timing")])
def test_registry_checks_declared_counters_and_stages(frame, fail_counter, stage, match):
    name = _toy(fail_counter, stage)
    try:
        with pytest.raises(MethodError, match=match):
            sl.compute_shadows(*frame, method=name)
    finally:
        registry._REGISTRY.pop(name)


def test_the_light_check_is_one_function(frame):
    scene, gbuf, light = frame
    assert registry.light_problem("brute_force", light) is None
    assert "needs a sphere or sun light" in registry.light_problem("soft_tiled", light)
    with pytest.raises(MethodError, match="'soft_tiled' computes soft shadows"):
        sl.compute_shadows(scene, gbuf, light, method="soft_tiled")
    with pytest.raises(MethodError, match="light must be a PointLight"):
        sl.compute_shadows(scene, gbuf, object(), method="brute_force")


def test_kernels_hang_off_the_registry():
    from shadowlab import kernels

    with_kernel = {n for n in registry.names() if registry.get(n).kernel is not None}
    assert with_kernel == {"psv", "d_psv", "d_stackless", "d_hybrid", "clustered_ptsv", "izb"}
    assert set(kernels.METHODS) == with_kernel
    assert sl.methods.available()["psv"]["kernel"] is True
    with pytest.raises(MethodError, match="no kernel version of 'zpass'"):
        registry.run_kernel(None, None, None, "zpass")


def test_evaluate_reports_warm_medians_and_compile_apart(frame):
    from shadowlab.harness import evaluate

    ev = evaluate(*frame, "brute_force", repeats=3)
    assert len(ev.runs) == 3
    assert ev.timings["total"] == pytest.approx(float(np.median([r["total"] for r in ev.runs])))
    assert ev.compile_seconds == pytest.approx(sum(
        v for r in [ev.cold] + ev.runs for k, v in r.items() if k.endswith("_compile")))
    assert ev.error["mismatches"] == 0 and ev.error["unexplained"] == 0
    assert np.array_equal(ev.reference, sl.reference_shadows(*frame))


def test_evaluate_times_a_between_call_before_each_warm_call(frame, monkeypatch):
    """The paired protocol: the calls alternate warm-up, between, method, between,
    method (each method call follows a between call), and each between call is timed."""
    import sys
    import time

    from shadowlab.harness import evaluate

    module = sys.modules["shadowlab.harness.evaluate"]
    order = []
    real = module.compute_shadows
    monkeypatch.setattr(module, "compute_shadows",
                        lambda *a, **k: order.append("method") or real(*a, **k))
    naps = iter([0.05, 0.15])

    def between():
        order.append("between")
        time.sleep(next(naps))

    ev = evaluate(*frame, "brute_force", repeats=2, between=between)
    assert order == ["method", "between", "method", "between", "method"]
    assert len(ev.between_seconds) == 2
    assert 0.05 <= ev.between_seconds[0] < ev.between_seconds[1]
    assert ev.between_seconds[1] >= 0.15
    assert evaluate(*frame, "brute_force", repeats=1).between_seconds == []
    order.clear()
    with pytest.raises(TypeError, match="'between' must be a callable"):
        evaluate(*frame, "brute_force", repeats=1, between=0.5)
    assert order == []                                  # refused before any call


def test_presets_replace_defaults_explicit_options_win_and_bad_values_are_refused(frame):
    name = "_toy_presets"

    @registry.register(name, doc="test", kind="approximate", counters=("samples",),
                       options={"level": Option(2, "a level", kind=int, minimum=0, maximum=4),
                                "mode": Option("exact", "a mode", allowed=("exact", "fast"))},
                       presets={"paper": {"level": 1, "mode": "fast"}})
    def toy(scene, gbuf, light, *, precision, shadow_eps, level, mode):
        assert mode in ("exact", "fast")                 # 'preset' is not passed on
        return ShadowResult(np.ones(gbuf.valid.shape, bool), {"samples": level}, {})
    try:
        default = registry.resolve_options(name, {})
        assert (default["preset"], default["level"], default["mode"]) == ("accurate", 2, "exact")
        paper = registry.resolve_options(name, {"preset": "paper"})
        assert (paper["level"], paper["mode"]) == (1, "fast")
        mixed = registry.resolve_options(name, {"preset": "paper", "level": 4})
        assert (mixed["level"], mixed["mode"]) == (4, "fast")
        res = sl.compute_shadows(*frame, method=name, preset="paper")
        assert res.counters["samples"] == 1 and res.options["preset"] == "paper"
        assert registry.available()[name]["presets"] == {"paper": {"level": 1, "mode": "fast"}}
        with pytest.raises(MethodError, match="preset='papr' is not allowed.*'accurate', 'paper'"):
            registry.resolve_options(name, {"preset": "papr"})
        with pytest.raises(MethodError, match="mode='slow'"):     # a bad preset value
            registry.register(name + "_bad", doc="t", kind="approximate",
                              options={"mode": Option("exact", "m", allowed=("exact",))},
                              presets={"paper": {"mode": "slow"}})(toy)
        # methods without presets have no 'preset' option
        assert "preset" not in registry.get("psv").options
    finally:
        registry._REGISTRY.pop(name)
        registry._REGISTRY.pop(name + "_bad", None)
