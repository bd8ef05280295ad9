"""``shadowlab sweep``: a grid of run configs x frames, evaluated on Dask distributed.

A sweep config is a run config (:mod:`shadowlab.config`) plus a ``[sweep]`` table that
maps dotted keys to lists of values; the grid is the product of the lists, in the
order the keys are written (the last key varies fastest)::

    [sweep]
    "scene.source" = ["gate", "soup"]
    "camera.resolution" = [[64, 64], [128, 128]]
    "methods.options.psv.stack_size" = [8, 32]

Every grid point is validated like ``shadowlab run`` validates a config, before any
work starts. A *task* is one grid point and one frame of its view or animation,
evaluated with all of the point's methods by :func:`shadowlab.harness.evaluate` (the
harness's timing protocol: ``warmup`` calls with compile time kept apart, then the
median of ``repeats`` warm calls). Tasks run on a Dask cluster: by default a
``LocalCluster`` of single-threaded worker processes, or an existing cluster given by
its scheduler address.

Outputs, under the output folder ``DIR``:

- ``DIR/tasks/<key>.json``: one file per finished task, written atomically (a temporary
  file renamed into place), so a task file is either complete or absent. ``<key>`` is a
  hash of the task's resolved config (everything but ``output`` and the config's file
  name), its frame, the timing protocol and the shadowlab version; a re-run skips the
  tasks whose file exists, and a worker killed mid-task leaves no file, so Dask's
  retry of the task on another worker starts from scratch.
- ``DIR/results.parquet``: the gathered table (:data:`FIXED_COLUMNS`), one row per
  (grid point, frame, method), written atomically once every task has finished.
- ``DIR/sweep.json``: the grid (keys, values, task keys), written before the work starts.

Read the table with ``pandas.read_parquet("DIR/results.parquet")``.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import json
import os
import statistics
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Sequence

from ..config.errors import ConfigError, show
from ..config.loading import _KEY_SEGMENT, config_from_data, read_source
from ..core import io

#: Columns every results table has, before the swept keys' columns and the counters.
FIXED_COLUMNS = (
    "point", "frame", "method", "kind", "task", "scene", "valid_pixels",
    "mismatches", "unexplained", "mismatch_fraction", "false_lit", "false_shadow",
    "mae", "rmse", "max_error", "ssim",
    "warm_seconds", "compile_seconds", "reference_seconds", "ratio_to_reference",
)
_ERROR_KEYS = ("mismatches", "unexplained", "mismatch_fraction", "false_lit", "false_shadow",
               "mae", "rmse", "max_error", "ssim")


class SweepError(RuntimeError):
    """Tasks of a sweep failed; ``failures`` maps task keys to their error text. The
    table of the tasks that finished is written all the same."""

    def __init__(self, message: str, failures: dict[str, str]):
        super().__init__(message)
        self.failures = failures


# --------------------------------------------------------------------------- the grid


@dataclasses.dataclass(frozen=True)
class Task:
    """One grid point and one frame: what a worker needs to evaluate it."""

    key: str
    point: int
    frame: int
    values: dict            # swept key -> value at this point
    config: Any             # the point's RunConfig
    repeats: int
    warmup: int


@dataclasses.dataclass
class Sweep:
    """A validated sweep: the swept keys, their values, the configs of the grid points
    (RunConfig, in grid order) and the tasks (point-major, then frame)."""

    source: str
    keys: tuple[str, ...]
    values: tuple[tuple, ...]
    configs: list
    tasks: list[Task]

    @property
    def points(self) -> list[dict]:
        """The grid points as {swept key: value}, in grid order."""
        return [dict(zip(self.keys, combo)) for combo in itertools.product(*self.values)]


def _flatten(table: dict, prefix: str = "") -> dict[str, Any]:
    """``[sweep]`` as {dotted key: value}: quoted dotted keys as written, sub-tables
    (``scene.source = [...]`` written unquoted) joined with dots."""
    out = {}
    for k, v in table.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, dict):
            out.update(_flatten(v, key))
        else:
            out[key] = v
    return out


def _set(data: dict, key: str, value: Any, label: str) -> None:
    table = data
    parts = key.split(".")
    for i, part in enumerate(parts[:-1]):
        nxt = table.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"{label}: [sweep] {key!r}: {'.'.join(parts[:i + 1])} is a "
                              "value, not a table")
        table = nxt
    table[parts[-1]] = copy.deepcopy(value)


def task_key(config, frame: int, repeats: int, warmup: int) -> str:
    """The hash naming a task's result: its resolved config (without ``output`` and the
    config's file name and overrides, which do not change results), frame, timing
    protocol and the shadowlab version. 20 hex digits of SHA-256."""
    from .. import __version__

    resolved = config.to_dict()
    for k in ("source", "overrides", "output"):
        resolved.pop(k, None)
    text = json.dumps({"config": resolved, "frame": frame, "repeats": repeats,
                       "warmup": warmup, "version": __version__}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def load_sweep(path: str | os.PathLike, overrides: Sequence[str] = (), *,
               repeats: int = 3, warmup: int = 1, check_memory: bool = True,
               check_views: bool = True) -> Sweep:
    """Read a sweep config and validate every grid point before anything runs.

    Args:
        path: a TOML run config with a ``[sweep]`` table.
        overrides: ``--set key=value`` strings applied to every point (they may not set a
            swept key).
        repeats, warmup: the timing protocol of every task (``harness.evaluate``).
        check_views: build each distinct scene once and resolve every point's views and
            methods against it (what ``run`` checks only once it has the scene).

    Raises:
        ConfigError: no or a malformed ``[sweep]`` table, or a grid point that is not a
            valid run config (the message names the file, the key, what is allowed and
            the grid point).
    """
    if repeats < 0 or warmup < 0:
        raise ConfigError(f"sweep: repeats and warmup must be >= 0, got {repeats}, {warmup}")
    data, label, base_dir, default_out = read_source(path)
    example = ('e.g. [sweep] "camera.resolution" = [[64, 64], [128, 128]]')
    if "sweep" not in data:
        raise ConfigError(f"{label}: no [sweep] table; a sweep config is a run config plus a "
                          f"[sweep] table mapping dotted keys to lists of values, {example}")
    table = data.pop("sweep")
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{label}: [sweep] must be a non-empty table of dotted keys -> "
                          f"lists of values, {example}; got {show(table)}")
    grid = _flatten(table)
    for key, values in grid.items():
        parts = key.split(".")
        if not all(_KEY_SEGMENT.match(p) for p in parts):
            raise ConfigError(f"{label}: [sweep] {key!r} is not a dotted key such as "
                              f"camera.resolution; {example}")
        if parts[0] == "output":
            raise ConfigError(f"{label}: [sweep] {key!r}: output keys cannot be swept (a "
                              "sweep writes under its --out folder)")
        if parts[0] == "sweep":
            raise ConfigError(f"{label}: [sweep] {key!r}: a sweep cannot be nested")
        if not isinstance(values, list) or not values:
            raise ConfigError(f"{label}: [sweep] {key!r} must be a non-empty list of values, "
                              f"got {show(values)}; {example}")
    keys = list(grid)
    for a in keys:
        for b in keys:
            if a != b and b.startswith(a + "."):
                raise ConfigError(f"{label}: [sweep] {a!r} and {b!r} overlap (one is inside "
                                  "the other); sweep one of them")
    if isinstance(overrides, str):
        overrides = (overrides,)
    for text in overrides:
        okey = text.partition("=")[0].strip()
        for key in keys:
            if okey == key or key.startswith(okey + ".") or okey.startswith(key + "."):
                raise ConfigError(f"--set: override {text!r} sets the swept key {key!r}; "
                                  "change its list in [sweep] instead")
    values = tuple(tuple(grid[k]) for k in keys)
    combos = list(itertools.product(*values))
    configs, tasks = [], []
    for i, combo in enumerate(combos):
        point = copy.deepcopy(data)
        for key, value in zip(keys, combo):
            _set(point, key, value, label)
        where = ", ".join(f"{k} = {show(v)}" for k, v in zip(keys, combo))
        try:
            config = config_from_data(point, label, base_dir, default_out, list(overrides),
                                      check_memory=check_memory)
        except ConfigError as exc:
            raise ConfigError(f"{exc} (in [sweep] grid point {i + 1} of {len(combos)}: "
                              f"{where})") from None
        configs.append(config)
        for frame in range(config.animation.frames):
            tasks.append(Task(task_key(config, frame, repeats, warmup), i, frame,
                              dict(zip(keys, combo)), config, repeats, warmup))
    if check_views:
        _check_views(configs, combos, keys, label)
    return Sweep(label, tuple(keys), values, configs, tasks)


def _check_views(configs, combos, keys, label) -> None:
    """What ``shadowlab run`` finds only once it has the scene, found before anything
    runs: a scene that cannot be built, a camera or light that cannot be resolved
    against the scene's default view, a soft-shadow method named explicitly with a point
    or directional light. Each distinct scene is built once, then dropped."""
    from ..methods import MethodError
    from ..scene import SceneError
    from .run import runnable_methods

    def where(i):
        return (f"(in [sweep] grid point {i + 1} of {len(configs)}: "
                + ", ".join(f"{k} = {show(v)}" for k, v in zip(keys, combos[i])) + ")")

    groups: dict[str, list[int]] = {}
    for i, config in enumerate(configs):
        groups.setdefault(json.dumps(config.scene.model_dump(), sort_keys=True, default=str),
                          []).append(i)
    for points in groups.values():
        try:
            scene = configs[points[0]].build_scene()
        except SceneError as exc:
            raise ConfigError(f"{label}: scene: {exc} {where(points[0])}") from None
        seen = set()
        for i in points:
            config = configs[i]
            view_key = json.dumps([config.camera.model_dump(), config.light.model_dump(),
                                   config.animation.model_dump(), list(config.methods.names)],
                                  sort_keys=True, default=str)
            if view_key in seen:
                continue
            seen.add(view_key)
            try:
                runnable_methods(config, config.views(scene))
            except ConfigError as exc:
                raise ConfigError(f"{exc} {where(i)}") from None
            except MethodError as exc:
                raise ConfigError(f"{label}: methods.names: {exc} {where(i)}") from None


# --------------------------------------------------------------------------- a task


_SCENES: dict[str, Any] = {}        # per worker process: scenes already built


def _scene(config):
    key = json.dumps(config.scene.model_dump(), sort_keys=True, default=str)
    if key not in _SCENES:
        if len(_SCENES) >= 4:
            _SCENES.clear()
        _SCENES[key] = config.build_scene()
    return _SCENES[key]


def read_task(path: Path) -> dict | None:
    """A finished task's record, or None when there is none (or it cannot be read:
    then the task is run again)."""
    try:
        record = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and record.get("complete") is True else None


def run_task(task: Task, out_dir: str, jax_cache: str | bool | None = None) -> dict:
    """Evaluate one task and write ``out_dir/tasks/<key>.json`` atomically (runs on a
    worker). Returns ``{"key", "seconds", "skipped"}``; a task whose file already exists
    (a retry after the write) is not run again.

    ``jax_cache``: the persistent JAX cache folder (None: the default,
    ``$SHADOWLAB_JAX_CACHE`` or ``~/.cache/shadowlab/jax``; False: no persistent cache).
    The worker process keeps its compiled programs in memory between tasks.
    """
    from ..core import jaxcache
    from ..reference.raycast import render_gbuffer
    from .evaluate import References, evaluate
    from .run import runnable_methods

    target = Path(out_dir) / "tasks" / f"{task.key}.json"
    if read_task(target) is not None:
        return {"key": task.key, "seconds": 0.0, "skipped": True}
    if jax_cache is False:
        jaxcache.disable_compilation_cache()
    else:
        jaxcache.enable_compilation_cache(jax_cache or None)
    t0 = time.perf_counter()
    config = task.config
    scene = _scene(config)
    views = config.views(scene)
    methods, skipped = runnable_methods(config, views)
    view = views[task.frame]
    gbuf = render_gbuffer(scene, view.camera)
    ref = config.reference
    refs = References(scene, gbuf, view.light, shadow_eps=ref.shadow_eps,
                      soft_rays=ref.soft_rays, seed=ref.seed)
    refs.hard(repeats=max(task.repeats, 1))
    reference_seconds = statistics.median(refs.hard_seconds)
    results = {}
    for name in methods:
        ev = evaluate(scene, gbuf, view.light, name, config.methods.options.get(name, {}),
                      reference=refs, repeats=task.repeats, warmup=task.warmup)
        results[name] = {"kind": ev.kind.value, "error": ev.error, "timings": ev.timings,
                         "compile_seconds": ev.compile_seconds,
                         "counters": ev.result.scalar_counters()}
    record = {"key": task.key, "point": task.point, "frame": task.frame,
              "values": task.values, "scene": scene.name,
              "valid_pixels": int(gbuf.valid.sum()), "reference_seconds": reference_seconds,
              "methods": results, "skipped": skipped, "config": config.to_dict(),
              "timing": {"repeats": task.repeats, "warmup": task.warmup},
              "provenance": io.provenance(), "seconds": time.perf_counter() - t0,
              "complete": True}
    io.write_json(target, record)
    return {"key": task.key, "seconds": record["seconds"], "skipped": False}


# --------------------------------------------------------------------------- the table


def _cell(value, as_text: bool):
    """A swept value as a table cell: scalars as they are, arrays and tables (and every
    value of a key whose values mix types) as their TOML text (``[64, 64]``)."""
    return show(value) if as_text else value


def _text_keys(sweep: Sweep) -> set[str]:
    """Swept keys whose cells are text: a non-scalar value, or values of mixed types."""
    out = set()
    for key, values in zip(sweep.keys, sweep.values):
        kinds = {type(v) for v in values}
        if len(kinds) > 1 or not kinds <= {bool, int, float, str}:
            out.add(key)
    return out


def rows_of(record: dict, keys: Sequence[str], text_keys=frozenset()) -> list[dict]:
    """The table rows of one task record, one per method (``text_keys``: swept keys
    whose cells are TOML text)."""
    rows = []
    ref_s = record["reference_seconds"]
    for name, m in record["methods"].items():
        row = {"point": record["point"], "frame": record["frame"], "method": name,
               "kind": m["kind"], "task": record["key"], "scene": record["scene"],
               "valid_pixels": record["valid_pixels"]}
        for k in _ERROR_KEYS:
            row[k] = m["error"].get(k)
        warm = m["timings"]["total"]
        row.update(warm_seconds=warm, compile_seconds=m["compile_seconds"],
                   reference_seconds=ref_s,
                   ratio_to_reference=warm / ref_s if ref_s > 0 else None)
        for k in keys:
            row[k] = _cell(record["values"][k], k in text_keys)
        for k, v in m["counters"].items():
            row[k if k not in row else f"counter_{k}"] = v
        rows.append(row)
    return rows


def gather(out_dir: str | os.PathLike, sweep: Sweep, write: bool = True):
    """The results table (a pandas DataFrame) of the finished tasks of ``sweep``;
    written to ``out_dir/results.parquet`` (atomically) when ``write``."""
    import pandas as pd

    rows = []
    tasks = Path(out_dir) / "tasks"
    for task in sweep.tasks:
        record = read_task(tasks / f"{task.key}.json")
        if record is not None:
            rows.extend(rows_of(record, sweep.keys, _text_keys(sweep)))
    columns = list(FIXED_COLUMNS[:4]) + list(sweep.keys) + list(FIXED_COLUMNS[4:])
    extra = sorted({k for r in rows for k in r} - set(columns))
    table = pd.DataFrame(rows, columns=columns + extra)
    for k in ("unexplained", "mismatches", "false_lit", "false_shadow"):
        table[k] = table[k].astype("Int64")          # None (not applicable) -> <NA>
    for k in ("mismatch_fraction", "mae", "rmse", "max_error", "ssim", "ratio_to_reference"):
        table[k] = table[k].astype("float64")        # None -> NaN
    if write:
        with io.atomic_path(Path(out_dir) / "results.parquet") as tmp:
            table.to_parquet(tmp, index=False)
    return table


# --------------------------------------------------------------------------- running


@dataclasses.dataclass
class SweepOutput:
    """What :func:`run_sweep` did: the table, its path, and task counts."""

    table: Any
    path: Path
    tasks: int
    already_done: int
    ran: int
    failures: dict


def dask_client(workers: int | None, scheduler: str | None):
    """(Client, LocalCluster or None): a client of the cluster at ``scheduler``, or of a
    new LocalCluster of ``workers`` single-threaded worker processes (default: the CPU
    count), without a dashboard."""
    import logging

    from distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler), None
    n = workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=logging.ERROR)
    return Client(cluster), cluster


def run_sweep(sweep: Sweep, out_dir: str | os.PathLike, *, workers: int | None = None,
              scheduler: str | None = None, client=None, jax_cache: str | bool | None = None,
              progress: bool = True, log: Callable[[str], None] = print) -> SweepOutput:
    """Run the tasks of ``sweep`` not yet done, on Dask, then gather the table.

    Args:
        out_dir: the sweep's folder (``tasks/``, ``results.parquet``, ``sweep.json``).
        workers: worker processes of the default ``LocalCluster`` (one thread each;
            default: the machine's CPU count).
        scheduler: the address of an existing Dask scheduler (``tcp://host:8786``)
            instead of a local cluster; every worker must import the same shadowlab.
        client: an existing ``distributed.Client`` to use (then neither is started).
        jax_cache: the workers' persistent JAX cache (see :func:`run_task`).

    A worker that dies mid-task is replaced (LocalCluster's nanny) and Dask runs the
    task again elsewhere (up to ``distributed.scheduler.allowed-failures`` times). On
    Ctrl-C the pending tasks are cancelled and the cluster closed; finished task files
    are complete and are reused by the next run.

    Raises:
        SweepError: some tasks failed (the table of the others is written first).
    """
    from tqdm import tqdm

    out = Path(out_dir)
    tasks_dir = out / "tasks"
    tasks_dir.mkdir(parents=True, exist_ok=True)
    todo = [t for t in sweep.tasks if read_task(tasks_dir / f"{t.key}.json") is None]
    done = len(sweep.tasks) - len(todo)
    log(f"{len(sweep.tasks)} tasks, {done} already done")
    io.write_json(out / "sweep.json", {
        "source": sweep.source, "keys": list(sweep.keys), "values": list(sweep.values),
        "tasks": [{"key": t.key, "point": t.point, "frame": t.frame} for t in sweep.tasks]})
    failures: dict[str, str] = {}
    if todo:
        own = client is None
        cluster = None
        if own:
            client, cluster = dask_client(workers, scheduler)
        futures = {}
        try:
            from distributed import as_completed

            # Dask keys are unique per submission: a key cancelled by an interrupted
            # sweep may still be known to the scheduler when the sweep is run again.
            token = uuid.uuid4().hex[:8]
            futures = {client.submit(run_task, t, str(out.resolve()), jax_cache,
                                     key=f"shadowlab-task-{t.key}-{token}", pure=False): t.key
                       for t in todo}
            with tqdm(total=len(todo), unit="task", desc="sweep", disable=not progress) as bar:
                for future in as_completed(list(futures)):
                    try:
                        future.result()
                    except Exception as exc:            # a task's error: record, go on
                        failures[futures[future]] = f"{type(exc).__name__}: {exc}"
                    bar.update(1)
        except BaseException:
            if futures:
                client.cancel(list(futures))
            raise
        finally:
            if own:
                client.close()
                if cluster is not None:
                    cluster.close()
    table = gather(out, sweep)
    result = SweepOutput(table, out / "results.parquet", len(sweep.tasks), done,
                         len(todo) - len(failures), failures)
    if failures:
        first = next(iter(failures.items()))
        raise SweepError(f"{len(failures)} of {len(sweep.tasks)} tasks failed (a re-run "
                         f"retries them); first, task {first[0]}: {first[1]}", failures)
    return result


__all__ = ["FIXED_COLUMNS", "Sweep", "SweepError", "SweepOutput", "Task", "dask_client",
           "gather", "load_sweep", "read_task", "rows_of", "run_sweep", "run_task", "task_key"]
