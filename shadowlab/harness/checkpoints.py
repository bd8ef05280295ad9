"""Per-point checkpoints: a stopped ``shadowlab figures`` run keeps the points it finished.

An experiment whose full size takes hours (``silhouette_work``, ``pareto``,
``clustered_city``) computes its sweep point by point through :func:`point`::

    row = checkpoints.point(f"objects={n}", lambda: measure(n))

Outside a figures run (a notebook, ``python experiments/<name>.py``, a test calling
``run`` directly) :func:`point` just calls ``compute``. Inside one,
:func:`~shadowlab.harness.figures.run_experiment` activates a :class:`Checkpoint`, and
each finished point is written atomically to
``<out>/.checkpoints/<experiment>-<size>-<key>/<point-hash>.json``. A re-run with the
same key reads the finished points instead of computing them, prints how many it
resumed, and lists them (label, when written, load average then) under
``"checkpoint"`` in the figure's JSON, so resumed timings stay attributable. The
folder is removed once the figure is written.

The key is a hash of everything that could change a point: the experiment, the size,
its config, the shadowlab version, the git commit with a hash of the uncommitted
changes, and the experiment module's source. Folders of the same experiment and size
under another key are stale and are removed when a run starts. ``figures --fresh``
discards even a matching folder.

A point's values must be JSON-able: numbers (NaN and infinities are kept), strings,
booleans, lists and dicts; NumPy scalars and arrays become numbers and (nested) lists,
and tuples become lists. Points are compute-bound rows of scalars, so JSON is small.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..core import io

#: the folder, under a figures output folder, that holds unfinished runs' points
FOLDER = ".checkpoints"

_active: contextvars.ContextVar["Checkpoint | None"] = contextvars.ContextVar(
    "shadowlab_checkpoint", default=None)


def _plain(value):
    """NumPy scalars and arrays, tuples and dicts as plain JSON values (non-finite
    floats kept, unlike :func:`shadowlab.core.io.jsonable`)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    raise TypeError(f"a checkpointed point's value must be JSON-able, got "
                    f"{type(value).__name__}")


def _as_json(values):
    """``values`` as a JSON round trip returns them (what a resumed point gives)."""
    return json.loads(json.dumps(_plain(values)))


def _code_state() -> dict:
    """The git commit of the installed package and a hash of its uncommitted changes
    (both None outside a git checkout)."""
    here = Path(__file__).resolve().parent
    state = {"commit": None, "changes": None}
    with contextlib.suppress(Exception):
        run = lambda *a: subprocess.run(["git", *a], capture_output=True, cwd=here,
                                        timeout=10, check=True).stdout
        state["commit"] = run("rev-parse", "HEAD").decode().strip() or None
        state["changes"] = hashlib.sha256(run("diff", "HEAD")).hexdigest()[:16]
    return state


def run_key(name: str, size: str, cfg: dict, module_file: str | os.PathLike | None) -> str:
    """The hash that decides whether stored points may be resumed (module docstring)."""
    from .. import __version__

    source = Path(module_file).read_bytes() if module_file else b""
    ident = {"experiment": name, "size": size, "config": _plain(cfg),
             "version": __version__, **_code_state(),
             "module": hashlib.sha256(source).hexdigest()}
    return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:16]


class Checkpoint:
    """The finished points of one (experiment, size, key) under ``out/.checkpoints``."""

    def __init__(self, out: str | os.PathLike, name: str, size: str, key: str,
                 fresh: bool = False):
        self.root = Path(out) / FOLDER
        self.directory = self.root / f"{name}-{size}-{key}"
        self.resumed: list[dict] = []
        self.written = 0
        prefix = f"{name}-{size}-"
        if self.root.is_dir():
            for stale in self.root.iterdir():
                if stale.name.startswith(prefix) and (fresh or stale != self.directory):
                    shutil.rmtree(stale, ignore_errors=True)
        self.stored = len(list(self.directory.glob("*.json"))) if self.directory.is_dir() else 0

    def _path(self, label: str) -> Path:
        return self.directory / f"{hashlib.sha256(label.encode()).hexdigest()[:20]}.json"

    def point(self, label: str, compute: Callable[[], Any]) -> Any:
        """The stored values of point ``label``, or ``compute()`` stored under it."""
        path = self._path(label)
        if path.exists():
            record = json.loads(path.read_text())
            if record.get("label") == label:
                self.resumed.append({k: record[k] for k in ("label", "written", "load_average")})
                return record["values"]
        values = compute()
        record = {"label": label, "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                  "load_average": [round(x, 2) for x in os.getloadavg()],
                  "values": _plain(values)}
        with io.atomic_path(path) as tmp:
            tmp.write_text(json.dumps(record))
        self.written += 1
        return _as_json(record["values"])

    def discard(self) -> None:
        """Remove this run's folder (and ``.checkpoints`` if that leaves it empty)."""
        shutil.rmtree(self.directory, ignore_errors=True)
        with contextlib.suppress(OSError):
            self.root.rmdir()


@contextlib.contextmanager
def active(checkpoint: Checkpoint):
    """Make ``checkpoint`` the one :func:`point` uses inside the block."""
    if checkpoint.stored:
        print(f"resuming from {checkpoint.directory}: {checkpoint.stored} finished "
              f"point(s) stored", file=sys.stderr)
    token = _active.set(checkpoint)
    try:
        yield checkpoint
    finally:
        _active.reset(token)


def point(label: str, compute: Callable[[], Any]) -> Any:
    """One sweep point: ``compute()``, or its stored values when a figures run resumes.
    ``label`` names the point uniquely within the experiment (e.g. ``"objects=5100"``).
    The values come back as JSON gives them (lists for tuples and arrays) whether
    computed or resumed, so an experiment behaves the same either way."""
    checkpoint = _active.get()
    if checkpoint is None:
        return _as_json(compute())
    return checkpoint.point(label, compute)


__all__ = ["Checkpoint", "FOLDER", "active", "point", "run_key"]
