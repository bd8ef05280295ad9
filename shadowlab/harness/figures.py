"""``shadowlab figures``: regenerate every experiment's figure and check its arrays.

An experiment is a module ``experiments/<name>.py`` (a jupytext percent script, so it
opens as a notebook) with

- ``run(cfg: dict) -> dict[str, np.ndarray]``: compute the arrays behind the figure;
- ``plot(arrays) -> matplotlib.figure.Figure``;
- ``check(arrays, cfg) -> None`` (optional): raise AssertionError if the arrays
  break an invariant (exactness, equal work, monotone counts): a bug, at any size;
- ``claims(arrays, cfg) -> list[dict]`` (optional): the paper's claims measured on our
  scenes, each ``{"claim": str, "measured": str, "holds": bool | None}`` (None: the
  run could not test it, with a ``"note"`` saying why) with optional ``"id"``
  (the claim's id in :mod:`shadowlab.harness.claims`, which the ledger
  ``docs/claims.md`` joins on) and ``"note"``. They are results,
  not invariants: written to the JSON and printed, and enforced only where the config
  sets ``require_claims = true`` (the CI sizes, where they are known to hold, so a
  regression shows), and never for a timing claim (``claims.TIMED``);
- ``summary(arrays, cfg) -> dict`` (optional): JSON-ready results written to the JSON
  under ``"summary"`` (e.g. a table that a document quotes);

and configs ``configs/experiments/<name>.ci.toml`` and ``<name>.full.toml``. Outputs go to
``figures/<name>.png``, ``figures/<name>.npz`` (the arrays) and ``figures/<name>.json``
(config, provenance, run seconds, claims), each written atomically.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
import traceback
from pathlib import Path

import numpy as np

from ..core import io
from . import checkpoints
from ..config.errors import ConfigError
from ..config.experiments import load_experiment_file


class ExperimentError(ValueError):
    """An experiment cannot run: no experiments folder, an unknown name, a malformed
    experiment module or claim, or an invalid config (:class:`ExperimentConfigError`)."""


class ExperimentConfigError(ExperimentError, ConfigError):
    """An invalid experiment config; the message names the file and the key
    (:mod:`shadowlab.config.experiments`)."""


class ClaimFailed(AssertionError):
    """A paper claim that the config requires (``require_claims = true``) did not hold."""


def measure_claims(module, arrays: dict, cfg: dict) -> list[dict]:
    """The experiment's claims (``module.claims``), validated: [{claim, measured, holds}],
    each with the optional keys ``id`` (a registered claim id,
    :mod:`shadowlab.harness.claims`) and ``note`` (one line on the measurement).

    ``holds`` is True, False, or None where the run could not test the claim (e.g. a
    claim about culled samples on a frame where nothing is culled: "0 of 0" must not
    read as a pass); None needs a ``note`` saying why."""
    from . import claims as registry

    if not hasattr(module, "claims"):
        return []
    found = []
    for c in module.claims(arrays, cfg):
        keys = set(c)
        if not {"claim", "measured", "holds"} <= keys or keys - {"claim", "measured", "holds",
                                                               "id", "note"}:
            raise ExperimentError("a claim needs the keys claim, measured, holds (optional: "
                                  f"id, note); got {sorted(c)}")
        if c["holds"] is None and not c.get("note"):
            raise ExperimentError(f"claim {c['claim']!r}: an untested claim (holds=None) "
                                  "needs a note saying why it could not be tested")
        out = {"claim": str(c["claim"]), "measured": str(c["measured"]),
               "holds": None if c["holds"] is None else bool(c["holds"])}
        if "id" in c:
            if c["id"] not in registry.BY_ID:
                raise ExperimentError(f"claim {c['claim']!r}: unknown claim id {c['id']!r} "
                                      "(register it in shadowlab/harness/claims.py)")
            out = {"id": str(c["id"]), **out}
        if c.get("note"):
            out["note"] = str(c["note"])
        found.append(out)
    return found


def scene_view(cfg: dict, default_scene: str = "terrain"):
    """The procedural scene of an experiment config (``scene``, ``params``), its default
    view and the G-buffer at ``cfg["resolution"]``: (scene, view, gbuf)."""
    from ..reference.raycast import render_gbuffer
    from ..scene import load_scene
    from ..scene.procedural import default_view

    name = cfg.get("scene", default_scene)
    params = dict(cfg.get("params", {}))
    scene = load_scene(name, **params)
    view = default_view(name, scene, **params)
    gbuf = render_gbuffer(scene, view.camera.replace(resolution=tuple(cfg["resolution"])))
    return scene, view, gbuf


def scene_frames(cfg: dict, names, resolution):
    """One frame per procedural scene of an experiment: yields ``(name, scene, view,
    gbuf, refs)`` for each of ``names``, with that scene's ``cfg["params"][name]``, its
    default view, the G-buffer at ``resolution`` (width, height) and the frame's shared
    :class:`~shadowlab.harness.evaluate.References`."""
    from ..reference.raycast import render_gbuffer
    from ..scene import load_scene
    from ..scene.procedural import default_view
    from .evaluate import References

    for name in names:
        params = dict(cfg.get("params", {}).get(name, {}))
        scene = load_scene(name, **params)
        view = default_view(name, scene, **params)
        gbuf = render_gbuffer(scene, view.camera.replace(resolution=tuple(resolution)))
        yield name, scene, view, gbuf, References(scene, gbuf, view.light)


def discover(root: Path) -> dict[str, Path]:
    folder = root / "experiments"
    if not folder.is_dir():
        raise ExperimentError(f"{folder}: no experiments folder; run from the repository root "
                              "or pass --root")
    return {p.stem: p for p in sorted(folder.glob("*.py")) if not p.stem.startswith("_")}


def load_module(path: Path):
    spec = importlib.util.spec_from_file_location(f"shadowlab_experiment_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    for attr in ("run", "plot"):
        if not callable(getattr(module, attr, None)):
            raise ExperimentError(f"{path}: an experiment needs a function {attr}()")
    return module


def load_experiment_config(root: Path, name: str, size: str) -> dict:
    """``configs/experiments/<name>.<size>.toml`` under ``root``, validated
    (:func:`shadowlab.config.experiments.load_experiment_file`), as a plain dict.

    Raises:
        ExperimentConfigError: no such file, invalid TOML, an unknown key, or a value
            of the wrong type or range (the message names the file and the key).
    """
    path = root / "configs" / "experiments" / f"{name}.{size}.toml"
    if not path.exists():
        raise ExperimentConfigError(f"{path}: no such experiment config (sizes: ci, full)")
    try:
        return load_experiment_file(path)
    except ConfigError as exc:
        raise ExperimentConfigError(str(exc)) from exc


def claim_label(c: dict) -> str:
    """'holds', 'FAILS' or 'untested' (``holds`` None: the run could not test it)."""
    return "untested" if c["holds"] is None else ("holds" if c["holds"] else "FAILS")


def run_as_script(file: str, size: str = "ci") -> dict:
    """``python experiments/<name>.py``: run the experiment at ``size``, check it, print
    its claims and draw the figure, writing nothing; return the arrays."""
    path = Path(file).resolve()
    module = load_module(path)
    cfg = load_experiment_config(path.parent.parent, path.stem, size)
    arrays = module.run(cfg)
    if hasattr(module, "check"):
        module.check(arrays, cfg)
    for c in measure_claims(module, arrays, cfg):
        print(f"[{claim_label(c)}] {c['claim']}: {c['measured']}")
    module.plot(arrays)
    return arrays


def run_experiment(root: Path, name: str, size: str = "ci", out: Path | None = None,
                   fresh: bool = False) -> dict:
    """Run one experiment, write its figure, arrays and metadata; return the arrays.

    Sweep points the experiment computes through :func:`checkpoints.point` are kept
    under ``out/.checkpoints`` until the figure is written, and a re-run of the same
    code and config resumes them (``fresh``: discard them first); the JSON's
    ``"checkpoint"`` lists the resumed points."""
    path = discover(root)[name]
    module = load_module(path)
    cfg = load_experiment_config(root, name, size)
    out = out or root / "figures"
    checkpoint = checkpoints.Checkpoint(out, name, size,
                                        checkpoints.run_key(name, size, cfg, path), fresh)
    from ..core.machine import machine_record, machine_state

    before = machine_state()
    t0 = time.perf_counter()
    with checkpoints.active(checkpoint):
        arrays = module.run(cfg)
    seconds = time.perf_counter() - t0
    machine = machine_record(before, machine_state())
    fig = module.plot(arrays)
    meta = {"experiment": name, "size": size, "config": cfg, "run_seconds": seconds,
            **_measured(module, arrays, cfg), "provenance": io.provenance(),
            "machine": machine}
    if checkpoint.resumed:
        meta["checkpoint"] = {"resumed": checkpoint.resumed,
                              "note": "run_seconds counts this run only; the resumed "
                                      "points were computed by an earlier run of the "
                                      "same code and config"}
    found = meta["claims"]
    io.write_npz(out / f"{name}.npz", arrays)
    io.save_figure(fig, out / f"{name}.png")
    io.write_json(out / f"{name}.json", meta)
    checkpoint.discard()
    for c in found:
        print(f"  [{claim_label(c)}] {c['claim']}: {c['measured']}",
              file=sys.stderr)
    if hasattr(module, "check"):
        module.check(arrays, cfg)
    from . import claims as registry

    # timing claims are recorded but never enforced (docs: claims.py, TIMED)
    failed = [c for c in found if c["holds"] is False
              and not ("id" in c and registry.get(c["id"]).timed)]
    if failed and cfg.get("require_claims", False):
        raise ClaimFailed(f"{name} ({size}): required claims do not hold: "
                          + "; ".join(f"{c['claim']} ({c['measured']})" for c in failed))
    return arrays


def _measured(module, arrays: dict, cfg: dict) -> dict:
    """What a figure's JSON derives from its arrays: ``claims`` and, where the
    experiment defines one, ``summary``."""
    out = {"claims": measure_claims(module, arrays, cfg)}
    if hasattr(module, "summary"):
        out["summary"] = module.summary(arrays, cfg)
    return out


def remeasure_claims(root: Path, only: list[str] | None = None) -> list[str]:
    """Recompute the claims (and summary) of committed figures from their stored arrays.

    For a change to an experiment's ``claims()`` that leaves its measurement alone: the
    arrays of ``figures/<name>.npz`` and the config recorded in ``figures/<name>.json``
    go through today's ``claims()``; the JSON keeps its run's provenance and records the
    commit the claims were recomputed at (``claims_provenance``). Returns the names done.

    Raises:
        ExperimentError: an unknown name, or a figure without its arrays.
    """
    found = discover(root)
    names = only or [n for n in found if (root / "figures" / f"{n}.json").exists()]
    done = []
    for name in names:
        if name not in found:
            raise ExperimentError(f"unknown experiment {name!r}; available: {', '.join(found)}")
        meta_path, npz_path = (root / "figures" / f"{name}{ext}" for ext in (".json", ".npz"))
        if not (meta_path.exists() and npz_path.exists()):
            raise ExperimentError(f"{meta_path}: no committed run to recompute claims from")
        module = load_module(found[name])
        meta = json.loads(meta_path.read_text())
        with np.load(npz_path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        meta.update(_measured(module, arrays, meta["config"]),
                    claims_provenance=io.provenance())
        io.write_json(meta_path, meta)
        done.append(name)
    return done


def regenerate(root: Path, size: str = "ci", only: list[str] | None = None,
               progress: bool = True, out: Path | None = None, *, workers: int | None = None,
               scheduler: str | None = None, client=None, fresh: bool = False) -> list[str]:
    """Run every experiment (or ``only`` those) writing to ``out`` (default
    ``root/figures``); return the names that failed.

    With ``workers``, ``scheduler`` or ``client`` the experiments run as tasks on Dask
    distributed, one task per experiment, as ``shadowlab sweep`` runs its tasks
    (:func:`shadowlab.harness.sweep.dask_client`): a local cluster of ``workers``
    processes, the cluster at ``scheduler``, or the given client. Every worker must see
    ``root`` at the same path (outputs are written there, atomically).

    Finished sweep points of an interrupted run are resumed unless ``fresh``
    (:func:`run_experiment`).

    Raises:
        ExperimentError: an unknown experiment name, or an invalid config (all configs
            are validated before the first experiment runs).
    """
    found = discover(root)
    names = only or list(found)
    unknown = sorted(set(names) - set(found))
    if unknown:
        raise ExperimentError(f"unknown experiment(s) {', '.join(unknown)}; "
                              f"available: {', '.join(found)}")
    for name in names:              # every config is checked before any experiment runs
        load_experiment_config(root, name, size)
    if workers is not None or scheduler is not None or client is not None:
        return _regenerate_on_dask(root, size, names, progress, out, workers, scheduler,
                                   client, fresh)
    failures = []
    for name in names:
        name, status, seconds = run_one(root, name, size, out, fresh=fresh)
        if status != "ok":
            failures.append(name)
        if progress:
            print(f"{name:<32} {status:<7} {seconds:7.1f} s", file=sys.stderr)
    return failures


def run_one(root: Path, name: str, size: str, out: Path | None = None,
            jax_cache: bool = False, fresh: bool = False) -> tuple[str, str, float]:
    """Run one experiment, printing any traceback: (name, "ok" or "FAILED", seconds).
    ``jax_cache``: turn on the persistent JAX cache first (what a Dask worker does)."""
    if jax_cache:
        from ..core.jaxcache import enable_compilation_cache

        enable_compilation_cache()
    t0 = time.perf_counter()
    try:
        run_experiment(Path(root), name, size, None if out is None else Path(out), fresh)
        status = "ok"
    except Exception:
        traceback.print_exc()
        status = "FAILED"
    return name, status, time.perf_counter() - t0


def _regenerate_on_dask(root, size, names, progress, out, workers, scheduler, client, fresh):
    from distributed import as_completed

    from .sweep import dask_client

    own = client is None
    cluster = None
    if own:
        client, cluster = dask_client(workers, scheduler)
    failures = []
    try:
        futures = {client.submit(run_one, str(Path(root).resolve()), name, size,
                                 None if out is None else str(Path(out).resolve()), True,
                                 fresh,
                                 key=f"shadowlab-figure-{size}-{name}", pure=False): name
                   for name in names}
        for future in as_completed(list(futures)):
            try:
                _, status, seconds = future.result()
            except Exception as exc:            # e.g. its worker died too often
                status, seconds = f"FAILED ({type(exc).__name__})", 0.0
            name = futures[future]
            if status != "ok":
                failures.append(name)
            if progress:
                print(f"{name:<32} {status:<7} {seconds:7.1f} s", file=sys.stderr)
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()
    return sorted(failures, key=names.index)
