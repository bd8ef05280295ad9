"""ShadowResult's rich display: plot(), _repr_png_, _repr_html_ and the attached reference."""

import numpy as np
import pytest

from shadowlab import ShadowResult
from shadowlab.config import load_config
from shadowlab.harness import evaluate
from shadowlab.reference.raycast import render_gbuffer


def _hard():
    rng = np.random.default_rng(3)
    lit = rng.random((12, 10)) < 0.5
    truth = lit.copy()
    truth[2, 3] = not truth[2, 3]       # one false lit or false shadow
    truth[5, 5] = not truth[5, 5]
    valid = np.ones_like(lit)
    valid[0] = False
    tests = rng.integers(0, 50, size=lit.shape)
    res = ShadowResult(lit, {"tests": int(tests.sum()), "tests_per_pixel": tests},
                       {"total": 0.5}, method="toy")
    return res, truth, valid


def test_plot_panels_follow_what_is_known():
    import matplotlib.pyplot as plt

    res, truth, valid = _hard()
    fig = res.plot()
    assert [ax.get_title() for ax in fig.axes if ax.get_title()] == ["toy lit", "tests_per_pixel"]
    plt.close(fig)
    fig = res.plot(reference=truth, valid=valid)
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    false_lit = int((res.lit & ~truth & valid).sum())       # a plain count, by hand
    false_shadow = int((~res.lit & truth & valid).sum())
    assert false_lit + false_shadow == 2
    assert titles[1] == f"error: 2 px ({false_lit} false lit, {false_shadow} false shadow)"
    plt.close(fig)
    bare = ShadowResult(res.lit, {"tests": 3}, {"total": 0.1})
    fig = bare.plot()
    assert len(fig.axes) == 1
    plt.close(fig)
    with pytest.raises(ValueError, match="maps: tests_per_pixel"):
        res.plot(counter="nope")


def test_soft_error_panel_reports_the_mae():
    import matplotlib.pyplot as plt

    vis = np.linspace(0, 1, 64, dtype=np.float32).reshape(8, 8)
    truth = np.clip(vis + 0.25, 0, 1)
    fig = ShadowResult(vis, {}, {"total": 0.1}, method="soft").plot(reference=truth)
    mae = np.abs(vis - truth).mean()
    assert fig.axes[1].get_title() == f"|error|: MAE {mae:.4f}"
    plt.close(fig)


def test_png_and_html_reprs():
    res, truth, valid = _hard()
    png = res.with_reference(truth, valid)._repr_png_()
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    html = res._repr_html_()
    assert "<td>toy</td>" in html and f"<td>{res.counters['tests']}</td>" in html
    assert 'src="data:image/png;base64,' in html
    with pytest.raises(ValueError, match="differs"):
        res.with_reference(truth[:5])


def test_evaluate_attaches_its_reference():
    config = load_config(None, ["camera.resolution=[40,32]", 'methods.names=["brute_force"]'])
    scene = config.build_scene()
    view = config.views(scene)[0]
    gbuf = render_gbuffer(scene, view.camera)
    ev = evaluate(scene, gbuf, view.light, "brute_force", repeats=0)
    assert ev.result.reference is ev.reference
    assert np.array_equal(ev.result.valid, gbuf.valid)
    fig = ev.result.plot()
    want = f"error: {ev.error['mismatches']} px (0 false lit, 0 false shadow)"
    assert fig.axes[1].get_title() == want
