"""``compact_children`` of the working tree against that of a base commit, on a
synthetic frontier of 3 M entries (12 % of children set, 11.5 M outputs) in a 16 M-entry
bucket, alternating in one process (7 calls each after a compiling one); both must give
identical outputs, padding slots included.

usage: python docs/repro/compaction_search_ab.py [BASE]   (default: 371cb3b~1, the
commit before the windowed search)
"""
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


def main(base: str) -> None:
    old = module_at(base, "shadowlab/engines/traversal.py", "shadowlab.engines.traversal_base")
    rng = np.random.default_rng(0)
    cap, n, p = 1 << 24, 3_000_000, 0.12
    bits = rng.random((n, 32)) < p
    words = np.zeros(cap, np.uint32)
    words[:n] = (bits * (1 << np.arange(32, dtype=np.uint64))).sum(1).astype(np.uint32)
    pop = bits.sum(1)
    end = np.full(cap, np.iinfo(np.int32).max, np.int32)
    end[:n] = np.cumsum(pop)
    args = [jnp.asarray(words), jnp.asarray(end), jnp.int32(int(pop.sum())),
            jnp.asarray(rng.integers(0, 1000, cap).astype(np.int32)),
            jnp.asarray(rng.integers(0, 1000, cap).astype(np.uint32)), jnp.zeros(cap, jnp.int32)]
    fo, fn = jax.jit(old.compact_children), jax.jit(new.compact_children)
    a, b = jax.block_until_ready(fo(*args)), jax.block_until_ready(fn(*args))
    print("outputs", int(pop.sum()), "identical:",
          all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, b)))
    times = {"base": [], "new": []}
    for _ in range(7):
        for arm, f in (("base", fo), ("new", fn)):
            t = time.perf_counter()
            jax.block_until_ready(f(*args))
            times[arm].append(round(1e3 * (time.perf_counter() - t)))
    print("ms", times)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "371cb3b~1")
