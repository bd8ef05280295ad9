"""compact_children with the windowed search (the working tree's) against the previous
full-array searchsorted, on a synthetic frontier of 3 M entries (12 % of children set,
11.5 M outputs) in a 16 M-entry bucket, alternating in one process; also the chunk size.

usage: python docs/repro/compaction_search_ab.py
"""
import time, sys, numpy as np, jax, jax.numpy as jnp
from shadowlab.engines import traversal as tv
rng = np.random.default_rng(0)
cap, n, p = 1 << 24, 3_000_000, 0.12
bits = (rng.random((n, 32)) < p)
words = np.zeros(cap, np.uint32)
words[:n] = (bits * (1 << np.arange(32, dtype=np.uint64))).sum(1).astype(np.uint32)
pop = bits.sum(1)
end = np.full(cap, np.iinfo(np.int32).max, np.int32); end[:n] = np.cumsum(pop)
total = int(pop.sum())
args = [jnp.asarray(words), jnp.asarray(end), jnp.int32(total), jnp.asarray(rng.integers(0, 1000, cap).astype(np.int32)), jnp.asarray(rng.integers(0, 1000, cap).astype(np.uint32)), jnp.zeros(cap, jnp.int32)]
ref = None
for sc in (4096, 16384, 65536):
    tv.SELECT_CHUNK = sc
    f = jax.jit(tv.compact_children)
    out = jax.block_until_ready(f(*args))
    if ref is None: ref = out
    same = all(np.array_equal(np.asarray(a)[:total], np.asarray(b)[:total]) for a, b in zip(out, ref))
    ts = []
    for _ in range(5):
        t = time.perf_counter(); jax.block_until_ready(f(*args)); ts.append(time.perf_counter() - t)
    print(sc, f"{np.median(ts)*1e3:.1f} ms", same)

def old_compact(words, end, total, item, node, job):
    cap = item.shape[0]
    sc = min(cap, 4096)
    def select(i, carry):
        ntri, nnode, njob = carry
        q = i * sc + jnp.arange(sc, dtype=jnp.int32)
        j = jnp.minimum(jnp.searchsorted(end, q, side="right"), cap - 1).astype(jnp.int32)
        r = q - jnp.where(j > 0, end[jnp.maximum(j - 1, 0)], 0)
        w = words[j]
        pos = jnp.zeros(sc, jnp.uint32)
        for width in (16, 8, 4, 2, 1):
            c = jax.lax.population_count((w >> pos) & jnp.uint32((1 << width) - 1))
            go = r >= c.astype(jnp.int32)
            r = jnp.where(go, r - c.astype(jnp.int32), r)
            pos = jnp.where(go, pos + jnp.uint32(width), pos)
        ntri = jax.lax.dynamic_update_slice_in_dim(ntri, item[j], i * sc, 0)
        nnode = jax.lax.dynamic_update_slice_in_dim(nnode, (node[j] << 5) | pos, i * sc, 0)
        njob = jax.lax.dynamic_update_slice_in_dim(njob, job[j], i * sc, 0)
        return ntri, nnode, njob
    m = jnp.minimum(total, cap)
    return jax.lax.fori_loop(0, (m + sc - 1) // sc, select,
        (jnp.zeros(cap, jnp.int32), jnp.zeros(cap, jnp.uint32), jnp.zeros(cap, jnp.int32)))
tv.SELECT_CHUNK = 4096
fo, fn = jax.jit(old_compact), jax.jit(tv.compact_children)
a, b = jax.block_until_ready(fo(*args)), jax.block_until_ready(fn(*args))
print("identical full outputs", all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, b)))
to, tn = [], []
for _ in range(7):
    t = time.perf_counter(); jax.block_until_ready(fo(*args)); to.append(time.perf_counter() - t)
    t = time.perf_counter(); jax.block_until_ready(fn(*args)); tn.append(time.perf_counter() - t)
print("old", np.round(np.array(to) * 1e3), "new", np.round(np.array(tn) * 1e3))
