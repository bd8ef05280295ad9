"""Stage timing with compile time kept apart from run time.

``compiled(fn, *args)`` lowers and compiles a jitted function once per argument
signature (shapes, dtypes, static values, x64 mode) and records how long that took;
later calls reuse the executable (the ``MAX_COMPILED`` most recently used are kept).
``StageTimer`` accumulates wall-clock seconds per stage, blocking on JAX results so
asynchronous dispatch is not mistaken for speed.
"""

from __future__ import annotations

import contextlib
import time
from collections import OrderedDict

import jax

_COMPILED: OrderedDict = OrderedDict()
MAX_COMPILED = 64        # executables kept (least recently used dropped first)


def _signature(args) -> tuple:
    leaves, tree = jax.tree_util.tree_flatten(args)
    sig = []
    for leaf in leaves:
        if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
            sig.append((tuple(leaf.shape), str(leaf.dtype)))
        else:
            sig.append(("static", leaf))
    return (tree, tuple(sig), bool(jax.config.jax_enable_x64))


def compiled(fn, *args):
    """(executable, compile_seconds) for jitted ``fn`` at ``args``; 0 s when cached."""
    key = (fn, _signature(args))
    exe = _COMPILED.get(key)
    if exe is not None:
        _COMPILED.move_to_end(key)
        return exe, 0.0
    t0 = time.perf_counter()
    exe = fn.lower(*args).compile()
    dt = time.perf_counter() - t0
    _COMPILED[key] = exe
    while len(_COMPILED) > MAX_COMPILED:
        _COMPILED.popitem(last=False)
    return exe, dt


def clear_compiled() -> None:
    """Forget every executable :func:`compiled` holds (see ``core.executables``)."""
    _COMPILED.clear()


class StageTimer:
    """Collects ``{stage: seconds}`` and ``{stage + "_compile": seconds}``."""

    def __init__(self):
        self.times: dict[str, float] = {}

    @contextlib.contextmanager
    def stage(self, name: str):
        t0 = time.perf_counter()
        yield
        self.times[name] = self.times.get(name, 0.0) + time.perf_counter() - t0

    def run(self, name: str, fn, *args):
        """Compile (timed as ``name_compile``) and run (timed as ``name``) jitted fn."""
        exe, dt = compiled(fn, *args)
        self.times[name + "_compile"] = self.times.get(name + "_compile", 0.0) + dt
        t0 = time.perf_counter()
        out = jax.block_until_ready(exe(*args))
        self.times[name] = self.times.get(name, 0.0) + time.perf_counter() - t0
        return out

    @contextlib.contextmanager
    def remainder(self, name: str):
        """Time the block's work not recorded by any other stage (host code between the
        timed stages: gathers, compactions, copies) as stage ``name``: the block's wall
        time minus everything (run and compile) recorded into this timer meanwhile. Wrap a
        method's whole body in it so its ``total`` is its whole run time, compile apart."""
        before = sum(self.times.values())
        t0 = time.perf_counter()
        yield
        wall = time.perf_counter() - t0
        inner = sum(self.times.values()) - before
        self.times[name] = self.times.get(name, 0.0) + max(wall - inner, 0.0)

    @property
    def total(self) -> float:
        """Run time of all stages, compile excluded."""
        return sum(v for k, v in self.times.items() if not k.endswith("_compile"))
