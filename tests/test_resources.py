"""Work too large for the machine is refused up front: the memory estimate against
real allocations, the limit, and the exit-2 error of ``shadowlab run``."""

from __future__ import annotations

import os

import pytest

import shadowlab as sl
from shadowlab.cli import main
from shadowlab.config import ConfigError, load_config
from shadowlab.config import resources
from shadowlab.config.resources import (ENV_VAR, estimate_run_bytes, format_bytes,
                                        memory_limit, parse_bytes)

HUGE = ["--set", "camera.resolution=[100000,100000]"]


def test_huge_resolution_exits_2_naming_estimate_and_limit(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert main(["run", *HUGE, "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("shadowlab: error: --set: camera.resolution = [100000, 100000] is "
                          "too large for this machine")
    names = sl.methods.names()
    soft = any(sl.methods.get(n).soft for n in names)
    est = estimate_run_bytes((100000, 100000), 1, len(names), soft)
    limit, how = memory_limit()
    assert f"need an estimated {format_bytes(est.total)}" in err
    assert f"more than the limit of {format_bytes(limit)} ({how})" in err
    assert ENV_VAR in err
    assert not list(tmp_path.iterdir())             # nothing written


def test_env_var_sets_the_limit(monkeypatch, capsys):
    monkeypatch.setenv(ENV_VAR, "1MiB")
    assert memory_limit() == (2**20, f"set by {ENV_VAR}=1MiB")
    # The default 256 x 256 run with every method needs more than 1 MiB ...
    with pytest.raises(ConfigError) as info:
        load_config()
    msg = str(info.value)
    assert msg.startswith("<built-in default>: camera.resolution = [256, 256] is too large")
    assert "limit of 1 MiB (set by SHADOWLAB_MEMORY_LIMIT=1MiB)" in msg
    # ... and fits 1 GiB; the check can be skipped.
    load_config(check_memory=False)
    monkeypatch.setenv(ENV_VAR, "1GiB")
    est = resources.check_run_memory(load_config())
    assert 0 < est.total < 2**30
    monkeypatch.setenv(ENV_VAR, "lots")
    assert main(["run", "--set", "camera.resolution=[8,8]", "--quiet"]) == 2
    assert "shadowlab: error: SHADOWLAB_MEMORY_LIMIT: 'lots' is not an amount" in \
        capsys.readouterr().err


def test_normal_resolution_passes_the_check(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    cfg = load_config(None, ["camera.resolution=[1024,1024]"])
    est = resources.check_run_memory(cfg)
    limit, _ = memory_limit()
    assert est.pixels == 1024 * 1024 and est.total <= limit


def test_default_limit_is_a_fraction_of_available_memory(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    limit, how = memory_limit()
    physical = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    assert 0 < limit <= resources.MEMORY_FRACTION * physical
    assert how.startswith(f"{resources.MEMORY_FRACTION:.0%} of the ")


@pytest.mark.parametrize("text, expect", [("1024", 1024), ("8GiB", 8 * 2**30),
                                          ("512M", 512 * 2**20), ("2GB", 2 * 10**9),
                                          ("1e9", 10**9), (" 1.5 kib ", 1536)])
def test_parse_bytes(text, expect):
    assert parse_bytes(text) == expect


@pytest.mark.parametrize("bad", ["", "lots", "-1G", "0", "8 parsecs"])
def test_parse_bytes_refuses(bad):
    with pytest.raises(ValueError):
        parse_bytes(bad)


def test_estimate_counts_the_real_per_pixel_arrays():
    """The estimate's per-pixel byte counts are those of the arrays the run allocates."""
    scene = sl.load_scene("gate")
    cfg = load_config(None, ["camera.resolution=[12,10]", 'methods.names=["brute_force"]',
                             "output.figures=false"])
    (view,) = cfg.views(scene)
    pixels = 12 * 10
    origins, dirs = view.camera.primary_rays()
    assert (origins.nbytes + dirs.nbytes) / pixels == resources.PRIMARY_RAYS
    gbuf = sl.render_gbuffer(scene, view.camera)
    gbuf_bytes = sum(getattr(gbuf, f).nbytes for f in ("position", "normal", "depth",
                                                        "triangle", "valid"))
    assert gbuf_bytes / pixels == resources.GBUFFER
    # What a run keeps per frame: valid, reference, the method's lit mask and maps.
    from shadowlab.harness.run import run
    out = run(cfg, progress=False, write=False)
    kept = sum(a.nbytes for a in out.arrays.values())
    est = estimate_run_bytes((12, 10), 1, methods=1)
    assert kept <= est.kept / resources.STACK_COPIES
    method = sum(a.nbytes for k, a in out.arrays.items() if k.startswith("brute_force/"))
    assert 0 < method / pixels <= resources.KEPT_METHOD
    assert est.per_frame == pixels * (resources.PRIMARY_RAYS + resources.EMBREE_HITS
                                      + resources.GBUFFER + resources.REFERENCE_RAYS
                                      + resources.METHOD_WORK)


def test_estimate_scales_with_pixels_frames_and_methods():
    one = estimate_run_bytes((100, 50), 1, 1)
    assert estimate_run_bytes((200, 50), 1, 1).total == 2 * one.total
    more_frames = estimate_run_bytes((100, 50), 3, 1)
    assert more_frames.per_frame == one.per_frame and more_frames.kept == 3 * one.kept
    assert estimate_run_bytes((100, 50), 1, 4).kept > one.kept
    assert estimate_run_bytes((100, 50), 1, 1, soft=True).kept > one.kept
    assert format_bytes(224 * 2**30) == "224 GiB" and format_bytes(512) == "512 B"
    assert 1 < estimate_run_bytes((100000, 100000)).total / 2**40 < 10   # TiB
