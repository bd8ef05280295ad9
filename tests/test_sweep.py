"""``shadowlab sweep``: grid validation, a real Dask LocalCluster, resume, a killed worker."""

import os
import signal
import threading
import time

import numpy as np
import pandas as pd
import pytest

from shadowlab.cli import main
from shadowlab.config import ConfigError
from shadowlab.harness import evaluate
from shadowlab.harness.sweep import load_sweep, read_task, run_sweep

BASE = """
[scene]
source = "gate"
[scene.params]
trees = 2
leaves_per_tree = 20
[camera]
resolution = [{w}, {h}]
[methods]
names = ["brute_force"]
"""

GRID = BASE + """
[sweep]
"scene.params.seed" = [0, 1]
methods.options.brute_force.bias = ["receiver", "cap"]
"""


def _write(tmp_path, text, name="grid.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize("sweep, message", [
    ('"camera.resolutin" = [[8, 8]]',
     "unknown key 'camera.resolutin' (did you mean 'resolution'?)"),
    ('"camera.resolution" = [[8, 8], [0, 8]]', "camera.resolution must be two positive integers"),
    ('"methods.options.brute_force.chunk" = [8, 5]', "methods.options.brute_force.chunk"),
    ('"camera.resolution" = [8, 8]', "camera.resolution must be two positive integers"),
    ('"scene.params.seed" = 3', "must be a non-empty list of values"),
    ('"scene.params.seed" = []', "must be a non-empty list of values"),
    ('"output.dir" = ["a", "b"]', "output keys cannot be swept"),
    ('"light" = [{type = "point"}]\n"light.position" = [[0, 9, 0]]', "overlap"),
])
def test_bad_grid_is_a_config_error_before_any_work(tmp_path, sweep, message):
    path = _write(tmp_path, BASE.format(w=8, h=8) + "[sweep]\n" + sweep + "\n")
    with pytest.raises(ConfigError) as info:
        load_sweep(path)
    assert message in str(info.value)
    assert str(path) in str(info.value)


def test_bad_point_names_the_grid_point_and_cli_exits_2(tmp_path, capsys):
    path = _write(tmp_path, BASE.format(w=8, h=8)
                  + '[sweep]\n"scene.params.seed" = [0, 1]\n"camera.fov_y_deg" = [40.0, 200.0]\n')
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "camera.fov_y_deg must be a finite number > 0 and < 180" in err
    assert "grid point 2 of 4" in err and str(path) in err
    assert not out.exists()                         # refused before anything started


def test_no_sweep_table_and_set_on_a_swept_key_are_errors(tmp_path, capsys):
    plain = _write(tmp_path, BASE.format(w=8, h=8), "plain.toml")
    assert main(["sweep", str(plain), "--quiet"]) == 2
    assert "no [sweep] table" in capsys.readouterr().err
    grid = _write(tmp_path, GRID.format(w=8, h=8))
    with pytest.raises(ConfigError, match="sets the swept key 'scene.params.seed'"):
        load_sweep(grid, ["scene.params.seed=4"])
    capsys.readouterr()
    assert main(["sweep", str(grid), "--workers", "0"]) == 2
    assert "--workers must be >= 1" in capsys.readouterr().err


def test_grid_order_keys_and_frames(tmp_path):
    path = _write(tmp_path, GRID.format(w=8, h=8) + "[animation]\nframes = 2\n"
                  "light_keys = [[1.0, 9.0, 1.0], [2.0, 9.0, 0.0]]\n")
    sweep = load_sweep(path)
    assert sweep.keys == ("scene.params.seed", "methods.options.brute_force.bias")
    assert sweep.points[1] == {"scene.params.seed": 0, "methods.options.brute_force.bias": "cap"}
    assert [(t.point, t.frame) for t in sweep.tasks] == [(p, f) for p in range(4) for f in range(2)]
    assert len({t.key for t in sweep.tasks}) == 8
    # The key depends on the resolved config, not on the file or the output folder.
    again = load_sweep(path, ["output.dir=elsewhere"])
    assert [t.key for t in again.tasks] == [t.key for t in sweep.tasks]
    assert sweep.configs[3].methods.options["brute_force"]["bias"] == "cap"


# --------------------------------------------------------------------------- on a cluster


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client, LocalCluster

    import logging

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.ERROR) as c, Client(c) as client:
        yield c, client


def test_grid_on_a_local_cluster_then_a_rerun_does_no_work(tmp_path, cluster, capsys):
    c, client = cluster
    sweep = load_sweep(_write(tmp_path, GRID.format(w=24, h=24)), repeats=1)
    out = tmp_path / "out"
    logs = []
    res = run_sweep(sweep, out, client=client, jax_cache=tmp_path / "jax", progress=False,
                    log=logs.append)
    assert logs == ["4 tasks, 0 already done"] and res.ran == 4 and not res.failures
    table = pd.read_parquet(out / "results.parquet")
    assert len(table) == 4 * 1                      # 4 points x 1 method
    assert list(table["scene.params.seed"]) == [0, 0, 1, 1]
    assert list(table["methods.options.brute_force.bias"]) == ["receiver", "cap"] * 2
    assert (table["mismatches"] == 0).all() and (table["unexplained"] == 0).all()
    assert (table["warm_seconds"] > 0).all() and table["ratio_to_reference"].notna().all()
    assert any((tmp_path / "jax").iterdir())        # the workers' persistent cache was used
    # The table carries what the harness measures in this process (counters exactly).
    point = sweep.configs[2]
    scene = point.build_scene()
    view = point.views(scene)[0]
    from shadowlab.reference.raycast import render_gbuffer
    gbuf = render_gbuffer(scene, view.camera)
    ev = evaluate(scene, gbuf, view.light, "brute_force", point.methods.options["brute_force"],
                  repeats=0)
    row = table.iloc[2]
    for name, value in ev.result.scalar_counters().items():
        assert row[name] == value, name
    assert row["valid_pixels"] == gbuf.valid.sum()

    # A re-run does no work: every task file is kept as it was.
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "tasks").iterdir()}
    logs.clear()
    again = run_sweep(sweep, out, client=client, progress=False, log=logs.append)
    assert logs == ["4 tasks, 4 already done"] and again.ran == 0
    assert {p.name: p.stat().st_mtime_ns for p in (out / "tasks").iterdir()} == stamps
    pd.testing.assert_frame_equal(again.table, table)

    # The CLI on the same cluster through --scheduler; a half-written file is never read.
    (out / "tasks" / f"{sweep.tasks[0].key}.json").write_text('{"key": "trunc')
    assert read_task(out / "tasks" / f"{sweep.tasks[0].key}.json") is None
    path = _write(tmp_path, GRID.format(w=24, h=24))
    assert main(["sweep", str(path), "--out", str(out), "--scheduler", c.scheduler_address,
                 "--repeats", "1", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "4 tasks, 3 already done" in printed and "4 rows (1 tasks run" in printed
    assert len(pd.read_parquet(out / "results.parquet")) == 4


def test_a_worker_killed_mid_sweep_loses_nothing(tmp_path, cluster):
    c, client = cluster
    # A shape no worker has compiled yet (a task's first call compiles for seconds), and
    # three frames per point: 12 tasks.
    sweep = load_sweep(_write(tmp_path, GRID.format(w=20, h=28) + "[animation]\nframes = 3\n"
                              "light_keys = [[1.0, 9.0, 1.0], [2.0, 9.0, 0.0]]\n"), repeats=1)
    out = tmp_path / "out"
    pids = client.run(os.getpid)
    box = {}
    thread = threading.Thread(target=lambda: box.update(res=run_sweep(
        sweep, out, client=client, jax_cache=False, progress=False, log=lambda s: None)))
    thread.start()
    victim, running, deadline = None, [], time.time() + 60
    while victim is None and time.time() < deadline:
        for addr, keys in client.processing().items():
            if keys and addr in pids:
                victim, running = addr, list(keys)
                break
        time.sleep(0.02)
    assert victim is not None, "no task started"
    os.kill(pids[victim], signal.SIGKILL)           # a task of this worker is in flight
    done_at_kill = len(list((out / "tasks").glob("[!.]*.json")))
    thread.join(120)
    assert not thread.is_alive()
    res = box["res"]
    assert all(k.startswith("shadowlab-task-") for k in running)
    assert done_at_kill < 12 and not res.failures and res.tasks == 12
    table = pd.read_parquet(out / "results.parquet")
    assert len(table) == 12 and (table["mismatches"] == 0).all()
    assert sorted(table["frame"].unique()) == [0, 1, 2]
    assert sorted(p.name for p in (out / "tasks").glob("[!.]*.json")) == \
        sorted(f"{t.key}.json" for t in sweep.tasks)
    assert np.isfinite(table["warm_seconds"]).all()
    assert pids[victim] not in client.run(os.getpid).values()   # the worker was replaced


def test_the_shipped_example_is_a_valid_sweep():
    from pathlib import Path

    sweep = load_sweep(Path(__file__).resolve().parent.parent / "configs" / "sweeps" / "example.toml")
    assert len(sweep.points) == 4 and len(sweep.tasks) == 4
    assert sweep.configs[3].scene.source == "soup"
    assert sweep.configs[3].camera.resolution == (96, 96)


_TOY_EXPERIMENT = '''
import os
import numpy as np

def run(cfg):
    return {"x": np.arange(cfg["frames"]), "pid": np.array(os.getpid())}

def plot(arrays):
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    ax.plot(arrays["x"])
    return fig
'''


def test_figures_run_on_the_cluster(tmp_path, cluster):
    from shadowlab.harness.figures import regenerate

    c, client = cluster
    (tmp_path / "experiments").mkdir()
    (tmp_path / "configs" / "experiments").mkdir(parents=True)
    for name, n in (("one", 3), ("two", 5)):
        (tmp_path / "experiments" / f"{name}.py").write_text(_TOY_EXPERIMENT)
        config = tmp_path / "configs" / "experiments" / f"{name}.full.toml"
        config.write_text(f"frames = {n}\n")
    assert regenerate(tmp_path, size="full", client=client, progress=False) == []
    workers = set(client.run(os.getpid).values())
    for name, n in (("one", 3), ("two", 5)):
        arrays = np.load(tmp_path / "figures" / f"{name}.npz")
        assert list(arrays["x"]) == list(range(n))
        assert int(arrays["pid"]) in workers            # computed on a worker
        assert (tmp_path / "figures" / f"{name}.png").stat().st_size > 0


def test_ctrl_c_leaves_a_consistent_folder_and_a_rerun_resumes(tmp_path, cluster, monkeypatch):
    import distributed

    c, client = cluster
    sweep = load_sweep(_write(tmp_path, GRID.format(w=24, h=24) + "[animation]\nframes = 2\n"
                              "light_keys = [[1.0, 9.0, 1.0], [2.0, 9.0, 0.0]]\n"), repeats=1)
    out = tmp_path / "out"
    real = distributed.as_completed

    def interrupted(futures):             # Ctrl-C as the first task finishes
        for future in real(futures):
            yield future
            raise KeyboardInterrupt

    monkeypatch.setattr(distributed, "as_completed", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(sweep, out, client=client, jax_cache=False, progress=False,
                  log=lambda s: None)
    monkeypatch.setattr(distributed, "as_completed", real)
    assert not (out / "results.parquet").exists()
    files = list((out / "tasks").glob("[!.]*.json"))
    assert 1 <= len(files) <= 8 and all(read_task(f) is not None for f in files)
    logs = []
    res = run_sweep(sweep, out, client=client, jax_cache=False, progress=False, log=logs.append)
    done = int(logs[0].split(", ")[1].split()[0])
    assert logs[0].startswith("8 tasks, ") and done >= 1 and res.ran == 8 - done
    assert len(res.table) == 8 and not res.failures


def test_a_soft_method_on_a_point_light_is_refused_before_any_work(tmp_path):
    base = BASE.format(w=8, h=8).replace('["brute_force"]', '["soft_tiled"]')
    path = _write(tmp_path, base + '[sweep]\n"light" = [{type = "sphere", position = [0.0, 9.0, '
                  '0.0], radius = 0.5}, {type = "point", position = [0.0, 9.0, 0.0]}]\n')
    with pytest.raises(ConfigError, match=r"soft_tiled.*needs a sphere or sun light.*grid "
                                          r"point 2 of 2: light = \{type = 'point'"):
        load_sweep(path)
    # A light the scene's default view cannot complete is found before any work too.
    path = _write(tmp_path, base + '[sweep]\n"light.type" = ["sphere"]\n', "nr.toml")
    with pytest.raises(ConfigError, match=r"needs light.radius.*grid point 1 of 1"):
        load_sweep(path)
