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
resumed, and lists them (label, when written, host and load average then) under
``"checkpoint"`` in the figure's JSON, so resumed timings stay attributable. The
folder is removed once the figure is written.

The key is a hash of what decides a point's values: the experiment, the size, its
config, the experiment module's source, the shadowlab version and a hash of the installed
package's source files (:func:`code_hash`: every ``.py`` and ``.toml`` under
``shadowlab/``, read directly, so uncommitted edits count and rewritten figures do not),
and the toolchain (Python, NumPy, JAX, jaxlib, the backend, x64). Not in the key: the
machine. Each point records the host, the load average it was measured at and the CPU
time the hypervisor took while it was computed (``steal``, see
:func:`shadowlab.core.machine.steal_between`), and the JSON lists them for resumed
points. Folders of the same experiment and size under
another key are removed (with a message) when a run starts; ``figures --fresh``
discards a matching one too. Two runs of the same experiment and size at once share
one folder, and a resumed point is whichever finished first.

A point's values must be JSON-able: numbers (NaN and infinities are kept), strings,
booleans, lists and dicts; NumPy scalars and arrays become numbers and (nested) lists,
and tuples become lists. Points are compute-bound rows of scalars, so JSON is small.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import hashlib
import json
import os
import shutil
import socket
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..core import io
from ..core.machine import cpu_clock, load_average, steal_between

#: the folder, under a figures output folder, that holds unfinished runs' points
FOLDER = ".checkpoints"

_active: contextvars.ContextVar["Checkpoint | None"] = contextvars.ContextVar(
    "shadowlab_checkpoint", default=None)


def _numpy(value):
    """``json``'s fallback: NumPy scalars and arrays as numbers and (nested) lists;
    anything else is refused."""
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    raise TypeError(f"a checkpointed point's value must be JSON-able, got "
                    f"{type(value).__name__}")


def _dumps(value, **kwargs) -> str:
    """JSON text of ``value``, NumPy values included (non-finite floats kept, unlike
    :func:`shadowlab.core.io.jsonable`)."""
    return json.dumps(value, default=_numpy, **kwargs)


def _as_json(values):
    """``values`` as a JSON round trip returns them (what a resumed point gives)."""
    return json.loads(_dumps(values))


@functools.lru_cache(maxsize=1)
def code_hash() -> str:
    """A hash of the installed package's source: every ``*.py`` and ``*.toml`` file under
    ``shadowlab/`` (paths and contents). It reads the files, not git, so it covers
    uncommitted and untracked changes and installs outside a checkout, and it does not
    change when a run rewrites its outputs (``figures/``). Computed once per process."""
    package = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for path in sorted(p for ext in ("*.py", "*.toml") for p in package.rglob(ext)):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def _toolchain() -> dict:
    """What else decides a point's values: Python, NumPy, JAX and jaxlib, the backend."""
    import jax
    import jaxlib

    return {"python": sys.version.split()[0], "numpy": np.__version__,
            "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "backend": jax.default_backend(), "x64": bool(jax.config.jax_enable_x64)}


def run_key(name: str, size: str, cfg: dict, module_file: str | os.PathLike | None) -> str:
    """The hash that decides whether stored points may be resumed (module docstring)."""
    from .. import __version__

    source = Path(module_file).read_bytes() if module_file else b""
    ident = {"experiment": name, "size": size, "config": cfg,
             "version": __version__, "code": code_hash(), **_toolchain(),
             "module": hashlib.sha256(source).hexdigest()}
    return hashlib.sha256(_dumps(ident, sort_keys=True).encode()).hexdigest()[:16]


class Checkpoint:
    """The finished points of one (experiment, size, key) under ``out/.checkpoints``."""

    def __init__(self, out: str | os.PathLike, name: str, size: str, key: str,
                 fresh: bool = False):
        self.root = Path(out) / FOLDER
        self.directory = self.root / f"{name}-{size}-{key}"
        self.resumed: list[dict] = []
        self.written = 0
        self._seen: set[str] = set()
        if self.root.is_dir():
            for stale in sorted(self.root.iterdir()):
                if stale.name.rsplit("-", 1)[0] == f"{name}-{size}" and \
                        (fresh or stale != self.directory):
                    kept = len(list(stale.glob("*.json")))
                    why = "--fresh" if stale == self.directory else \
                        "another code, config or toolchain"
                    print(f"discarding {kept} checkpointed point(s) of {name} ({size}) in "
                          f"{stale} ({why})", file=sys.stderr)
                    shutil.rmtree(stale, ignore_errors=True)
        self.stored = len(list(self.directory.glob("*.json"))) if self.directory.is_dir() else 0

    def _path(self, label: str) -> Path:
        return self.directory / f"{hashlib.sha256(label.encode()).hexdigest()[:20]}.json"

    def _stored(self, path: Path, label: str):
        """The record stored for ``label``, or None (absent, unreadable or another label)."""
        try:
            record = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        ok = isinstance(record, dict) and record.get("label") == label and "values" in record
        return record if ok else None

    def point(self, label: str, compute: Callable[[], Any]) -> Any:
        """The stored values of point ``label``, or ``compute()`` stored under it.

        Raises:
            ValueError: ``label`` was already used in this run (labels name points
                uniquely; a repeat would silently reuse the first point's values).
        """
        if label in self._seen:
            raise ValueError(f"checkpoint label {label!r} used twice in one run; each sweep "
                             f"point needs its own label (a repeated sweep value?)")
        self._seen.add(label)
        path = self._path(label)
        record = self._stored(path, label)
        if record is not None:
            self.resumed.append({k: record.get(k) for k in
                                 ("label", "written", "host", "load_average", "steal")})
            return record["values"]
        clock = cpu_clock()
        values = compute()
        record = {"label": label, "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                  "host": socket.gethostname(), "load_average": load_average(),
                  "steal": steal_between(clock, cpu_clock()), "values": values}
        text = _dumps(record)
        with io.atomic_path(path) as tmp:
            tmp.write_text(text)
        self.written += 1
        return json.loads(text)["values"]

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
