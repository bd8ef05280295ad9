"""``compact_children`` of the working tree against that of a base commit, on a
synthetic frontier of 3 M entries (12 % of children set, 11.5 M outputs; with
``sparse``, 1.5 M of 6 M entries with one child each, as clustered_ptsv's frontiers at
1M triangles) in a 16 M-entry bucket, alternating in one process (7 calls each after a
compiling one); both must give identical outputs in the slots below the total.
Either signature is called (``length``, the tested entries, since 2026-12-07).

usage: python docs/repro/compaction_search_ab.py [BASE] [sparse]   (default: 371cb3b~1,
the commit before the windowed search)
"""
import inspect
import subprocess
import sys
import time
import types

import jax
import jax.numpy as jnp
import numpy as np

from shadowlab.engines import traversal as new


def module_at(commit: str, path: str, name: str):
    """The module ``name`` as it was at ``commit`` (its source from git, run in its
    package so that relative imports resolve to the working tree's)."""
    source = subprocess.check_output(["git", "show", f"{commit}:{path}"], text=True)
    mod = types.ModuleType(name)
    mod.__package__ = name.rpartition(".")[0]
    sys.modules[name] = mod                 # dataclasses look their module up there
    exec(compile(source, f"{commit}:{path}", "exec"), mod.__dict__)
    return mod


def main(base: str, sparse: bool) -> None:
    old = module_at(base, "shadowlab/engines/traversal.py", "shadowlab.engines.traversal_base")
    rng = np.random.default_rng(0)
    cap = 1 << 24
    if sparse:
        n = 6_000_000
        bits = np.zeros((n, 32), bool)
        has = rng.random(n) < 0.25
        bits[np.flatnonzero(has), rng.integers(0, 32, int(has.sum()))] = True
    else:
        n = 3_000_000
        bits = rng.random((n, 32)) < 0.12
    words = np.zeros(cap, np.uint32)
    words[:n] = (bits * (1 << np.arange(32, dtype=np.uint64))).sum(1).astype(np.uint32)
    pop = bits.sum(1)
    end = np.full(cap, np.iinfo(np.int32).max, np.int32)
    end[:n] = np.cumsum(pop)
    total = int(pop.sum())
    data = [jnp.asarray(rng.integers(0, 1000, cap).astype(np.int32)),
            jnp.asarray(rng.integers(0, 1000, cap).astype(np.uint32)), jnp.zeros(cap, jnp.int32)]

    def call(mod):
        fn = jax.jit(mod.compact_children)
        if "length" in inspect.signature(mod.compact_children).parameters:
            args = [jnp.asarray(words), jnp.asarray(end), jnp.int32(n), jnp.int32(total), *data]
        else:
            args = [jnp.asarray(words), jnp.asarray(end), jnp.int32(total), *data]
        return lambda: fn(*args)

    fo, fn = call(old), call(new)
    a, b = jax.block_until_ready(fo()), jax.block_until_ready(fn())
    print("outputs", total, "identical:",
          all(np.array_equal(np.asarray(x)[:total], np.asarray(y)[:total])
              for x, y in zip(a, b)))
    times = {"base": [], "new": []}
    for _ in range(7):
        for arm, f in (("base", fo), ("new", fn)):
            t = time.perf_counter()
            jax.block_until_ready(f())
            times[arm].append(round(1e3 * (time.perf_counter() - t)))
    print("ms", times)


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "sparse"]
    main(args[0] if args else "371cb3b~1", "sparse" in sys.argv[1:])
