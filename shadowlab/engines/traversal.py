"""Level-synchronous traversal of 32-ary trees in fixed-capacity frontiers.

The engine behind ``clustered_ptsv`` and ``ptsv``, generic over what a node is and how
it is tested. Vocabulary:

- a **tree** of depth ``D`` (``tests.levels``): level 0 is the root, a node at level
  ``l`` has the uint32 key ``k``; its 32 children at level ``l + 1`` have the keys
  ``(k << 5) | c``, c = 0..31 (so keys carry 5 bits per level). Whether a child exists
  is for the test to say.
- an **item**: an int32 payload (a triangle id for the shadow-volume methods) that is
  tested against nodes;
- a **job**: an (item, node) pair that starts a traversal. Each job has an index (its
  position in the job list) and counts its *iterations* (levels expanded, plus one for
  the leaf step);
- a **frontier**: the (item, node, job) entries alive at one level, in arrays of a
  fixed capacity ``cap`` (a power of two) plus a count ``n``; entries >= n are padding.

One step at level ``l`` tests the 32 children of every frontier entry with
``tests.children`` (chunks of :data:`EXPAND_CHUNK` entries, in a loop whose trip count
follows ``n``). Each child is one of:
accepted (marked in ``accepted``, a bool [rows, 32] array with one row per inner node,
``row_offsets[l]`` the first row of level ``l``), intersected (goes on to the next
frontier) or anything else (dropped). The intersected children are compacted,
entry-major and child-minor (so the order is deterministic), into the next frontier of
the same capacity by a gather-only stream compaction: prefix sums of the entries'
popcounts, a binary search per output slot, a 5-step select of the r-th set bit. At the
last level the surviving entries are leaf jobs, handed to ``tests.leaves`` in chunks of
:data:`LEAF_CHUNK`.

Capacity: a level whose frontier would exceed ``cap`` records its true size in
``need`` (the extra entries are dropped and the state is not used); :func:`run_pass`
then retries with a bigger bucket (2x at least), so nothing is ever truncated silently.
The first try is sized from the tests' ``frontier_per_job`` (the peak frontier a job
typically grows to, a prior that only sets the first bucket), so that a scene's first
call usually needs no retry, which would cost a compile and a partial run.
The work of a level follows ``n``, not the bucket: the loops' trip counts follow the
frontier, and the frontier's arrays (:class:`Scratch`) are allocated once and reused,
never cleared (entries past ``n`` are leftovers the node test sees as padding). Until
2026-12-07 every level cleared and filled bucket-sized arrays, so a bucket 32x too
large made ``ptsv``'s traversal 3.6x slower (sphere_grid 99k after fuzzy 100k in one
process, 373 -> 1,338 ms); a larger bucket now costs memory (32 bytes per entry) only.
The caller passes a dict (``buckets``) that remembers, per (tests, options), the
buckets that sufficed; they only grow, so later frames of a scene reuse the compiled
kernel without retries. Methods keep one such dict per scene, so that one scene's
bucket never holds memory for another.

Waves and pruning: jobs run in waves of ``wave`` jobs in job order. With ``prune`` the
node test sees ``accepted`` as it was when the wave started (the accepts of earlier
waves), so it can skip nodes that an earlier job already accepted; without it every job
runs in one wave and the test sees nothing (``None``).

Two passes: pass 1 runs the jobs from level 0 down to ``expand_level`` and pushes the
surviving (item, node) entries, in the order it produced them, as the jobs of pass 2,
which runs them down to the leaves.

Counters: ``tests.children`` returns an int32 [K] increment per chunk (K =
``len(tests.counters)``), summed over every level, wave and pass; the engine adds the
leaf visits (leaf jobs), the largest frontier (entries) and per-job iterations.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
from typing import Any, NamedTuple, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import (WIDE_LOW_BITS, bucket, check_int32, retry_on_overflow,
                             wide_add, wide_min, wide_total)
from ..core.numerics import shifted_scan
from ..core.timing import compiled

LEAF_CHUNK = 4096        # leaf jobs per step of the leaf loop
EXPAND_CHUNK = 2048      # frontier entries per step of the expand loop
SELECT_CHUNK = 4096      # output slots per step of the compaction loop
MIN_FRONTIER = 4096      # smallest frontier bucket
MAX_FRONTIER = 1 << 25   # largest: 32 children per entry must be countable in int32


class NodeTests(Protocol):
    """What a method supplies to the engine: a static, hashable description (the key of
    the compiled kernels; array data travels separately as ``data``).

    Attributes:
        levels: depth D of the tree (leaves at level D).
        counters: names of the K counters that :meth:`children` increments.
        frontier_per_job: the first frontier bucket holds this many entries per job of
            a wave (a performance prior: a larger frontier is retried, a smaller one
            leaves part of the bucket unused).
    """

    levels: int
    counters: tuple[str, ...]
    frontier_per_job: int

    def prepare(self, data: Any) -> Any:
        """Turn the traced ``data`` pytree into a context, once per kernel call."""

    def children(self, ctx: Any, level, item, node, valid, accepted):
        """Classify the 32 children of N frontier entries at ``level`` (a traced int32).

        Args:
            item: int32 [N]; node: uint32 [N] parent keys; valid: bool [N] (False for
                padding entries, whose children must be neither accepted nor
                intersected); accepted: bool [rows, 32] as the wave started, or None
                without pruning.
        Returns:
            (accept, intersect, counts): uint32 [N] words (bit c: child c is accepted /
            intersected) and int32 [K]. :func:`child_words` packs [N, 32] masks.
        """

    def leaves(self, ctx: Any, item, node, ok, state):
        """Process C leaf jobs: item int32 [C], node uint32 [C] leaf keys, ok bool [C]
        (False: padding). ``state`` is the leaf state pytree; returns the new one."""


def child_words(*masks):
    """Pack bool [N, 32] child masks into uint32 [N] words (bit c = child c), all in one
    variadic reduction.

    Every mask is usually an expression of one classification of the children. Each
    separate consumer of it (a reduction, a scatter) becomes a loop fusion of its own on
    XLA/CPU that recomputes the whole classification (six copies of the plane tests in
    the clustered expansion, measured in the optimized HLO; an optimization barrier is
    removed before fusion and does not help). One reduction with every mask as an
    operand is one fusion, which computes the classification once per child (the same
    mechanism as ``core.numerics.materialize``, here with a real reduction).
    """
    c = jnp.arange(32, dtype=jnp.uint32)
    ops = tuple(m.astype(jnp.uint32) << c for m in masks)
    zero = tuple(jnp.uint32(0) for _ in masks)
    return jax.lax.reduce(ops, zero, lambda a, b: tuple(x | y for x, y in zip(a, b)), (1,))


class Scratch(NamedTuple):
    """The buffers one traversal pass works in, all of the frontier capacity [cap],
    allocated once and kept between passes (not per level or wave, whose work follows
    the frontier's true size ``n``): the frontier (item int32, node uint32, job int32), a copy of it
    that the compaction reads while it writes the next frontier over the first, and a
    level's children words (uint32) and their prefix sums (int32). Entries past ``n`` (a
    frontier) or past the tested chunks (words, sums) are left over from earlier levels
    and never read as data (the node test sees them as padding)."""

    item: Any
    node: Any
    job: Any
    read_item: Any
    read_node: Any
    read_job: Any
    words: Any
    end: Any


#: scratch buffers kept between passes, by capacity, at most SCRATCH_KEEP sets (32 bytes
#: per frontier entry each: 512 MB at 16M entries). A pass takes its set out while it
#: runs (so concurrent passes never share one) and donates it to the kernel, which hands
#: it back: no allocation, where clearing a new set cost about 90 ms at 16M entries
#: (``ptsv`` on fuzzy 100k, 1024x1024, after the levels stopped clearing their own).
#: Only memory is reused: nothing computed survives a pass.
SCRATCH_KEEP = 2
_UINT32_FIELDS = ("node", "read_node", "words")            # the others are int32
_SCRATCH: collections.OrderedDict = collections.OrderedDict()


def _take_scratch(cap: int) -> Scratch:
    kept = _SCRATCH.pop(cap, None)
    if kept is not None:
        return kept
    return Scratch(*(jnp.zeros(cap, jnp.uint32 if name in _UINT32_FIELDS else jnp.int32)
                     for name in Scratch._fields))


def _keep_scratch(cap: int, scratch: Scratch) -> None:
    _SCRATCH[cap] = scratch
    while len(_SCRATCH) > SCRATCH_KEEP:
        _SCRATCH.popitem(last=False)


def release_scratch() -> None:
    """Free the traversal's kept scratch buffers (see :data:`SCRATCH_KEEP`)."""
    _SCRATCH.clear()


def _expand_level(tests, ctx, level, row_offsets, st, acc_seen, buf: Scratch, n):
    """Expand the frontier in ``buf`` (n valid entries, n <= cap) at ``level`` (traced):
    test the children of each entry in chunks, add the counters, record accepts (a row
    scatter-max into ``st["accepted"]``) and iterations, then compact the intersected
    children into the frontier's arrays (the chunks read are copied aside first, so the
    compaction can overwrite them). Returns the state, the buffers and the next
    frontier's true size (> cap: overflow, retried by the host)."""
    cap = buf.item.shape[0]
    e = min(cap, EXPAND_CHUNK)
    iters_cap = st["iters"].shape[0]
    row0 = row_offsets[level]

    def body(i, carry):
        words, end, total, counts, acc, iters, ri, rn, rj = carry
        s = i * e
        t = jax.lax.dynamic_slice_in_dim(buf.item, s, e)
        nd = jax.lax.dynamic_slice_in_dim(buf.node, s, e)
        jb = jax.lax.dynamic_slice_in_dim(buf.job, s, e)
        valid = s + jnp.arange(e) < n
        accept_w, w, increment = tests.children(ctx, level, t, nd, valid, acc_seen)
        counts = wide_add(counts, increment)
        rows = jnp.where(accept_w != 0, row0 + nd.astype(jnp.int32), acc.shape[0])
        accept = ((accept_w[:, None] >> jnp.arange(32, dtype=jnp.uint32)) & 1) == 1
        acc = acc.at[rows].max(accept, mode="drop")
        iters = iters.at[jnp.where(valid, jb, iters_cap)].add(1, mode="drop")
        chunk_end = total + jnp.cumsum(jax.lax.population_count(w).astype(jnp.int32))
        words = jax.lax.dynamic_update_slice_in_dim(words, w, s, 0)
        end = jax.lax.dynamic_update_slice_in_dim(end, chunk_end, s, 0)
        ri, rn, rj = (jax.lax.dynamic_update_slice_in_dim(r, x, s, 0)
                      for r, x in ((ri, t), (rn, nd), (rj, jb)))
        return words, end, chunk_end[-1], counts, acc, iters, ri, rn, rj

    chunks = (n + e - 1) // e
    words, end, total, counts, acc, iters, ri, rn, rj = jax.lax.fori_loop(
        0, chunks, body, (buf.words, buf.end, jnp.int32(0), st["counts"], st["accepted"],
                          st["iters"], buf.read_item, buf.read_node, buf.read_job))
    st = dict(st, counts=counts, iters=iters, accepted=acc)
    item, node, job = compact_children(words, end, chunks * e, total, ri, rn, rj,
                                       out=(buf.item, buf.node, buf.job))
    return st, Scratch(item, node, job, ri, rn, rj, words, end), total


def compact_children(words, end, length, total, item, node, job, out=None):
    """Stream compaction of the set children of a frontier, entry-major, child-minor.

    Args:
        words: uint32 [cap], bit c set if child c of entry j goes on; end: int32 [cap],
            inclusive prefix sums of the popcounts over the entries [0, length) (later
            entries are not read); total: int32, the number of set bits; item, node,
            job: [cap]. out: the three [cap] arrays to write into (None: new zeros).
    Returns:
        item int32 [cap], node uint32 [cap] (the child keys ``(node << 5) | c``) and job
        int32 [cap]: ``out`` with its first min(total, cap) entries replaced by the set
        bits', and entries up to the end of their last chunk of SELECT_CHUNK by
        leftovers.
    """
    cap = item.shape[0]
    sc = min(cap, SELECT_CHUNK)

    def select(i, carry):
        ntri, nnode, njob = carry
        q = i * sc + jnp.arange(sc, dtype=jnp.int32)
        j = _slot_owners(end, i * sc, sc, length)
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

    if out is None:
        out = (jnp.zeros(cap, jnp.int32), jnp.zeros(cap, jnp.uint32), jnp.zeros(cap, jnp.int32))
    m = jnp.minimum(total, cap)
    return jax.lax.fori_loop(0, (m + sc - 1) // sc, select, tuple(out))


def _bisect(end, q, lo, hi, steps):
    """The first index j in [lo, hi] with end[j] > q (hi: none in [lo, hi)), for end
    ascending on [lo, hi), in ``steps`` >= bit_length(hi - lo) halvings (q, lo, hi of one
    shape)."""
    last = end.shape[0] - 1

    def halve(_, bounds):               # invariant: the answer lies in [a, b]
        a, b = bounds
        mid = (a + b) // 2              # < b unless a == b (then end[b] is not read)
        go = (a < b) & (end[jnp.minimum(mid, last)] <= q)
        return jnp.where(go, mid + 1, a), jnp.where(go, b, mid)

    a, _ = jax.lax.fori_loop(0, steps, halve, (lo, hi))
    return a


def _slot_owners(end, base, size: int, length):
    """int32 [size]: for the output slots base .. base + size - 1 below the total, the
    entry each belongs to, ``searchsorted(end[:length], slot, side="right")`` (end int32
    [cap]: inclusive prefix sums of the entries' child counts, ascending on [0, length),
    not read past it; slots past the total get some entry below ``length``).

    Without a search per slot: two scalar bisections find the window of entries that own
    the chunk's slots; each entry of it with children marks its first slot in the chunk
    (a scatter-max of its index; the window's first entry marks slot 0), and a prefix max
    over the chunk carries each mark to the entry's later slots. A binary search per slot
    took about 13 dependent gathers (a window of a few thousand entries), which made the
    compaction cost 42-55 ns per output slot on sparse frontiers (clustered_ptsv at 1M
    triangles, one child per entry); the marks cost two gathers and a scatter per entry
    of the window plus log2(size) vector passes.
    """
    length = jnp.asarray(length, jnp.int32)
    zero = jnp.zeros((), jnp.int32)
    steps = 32 - jax.lax.clz(length)
    lo = _bisect(end, base, zero, length, steps)
    hi = _bisect(end, base + size - 1, zero, length, steps)
    last = end.shape[0] - 1

    def mark(k, owner):
        j = lo + k * size + jnp.arange(size, dtype=jnp.int32)
        jj = jnp.minimum(j, last)
        start = jnp.where(jj > 0, end[jnp.maximum(jj - 1, 0)], 0)
        pos = jnp.maximum(start - base, 0)
        keep = (j <= hi) & (j < length) & (end[jj] > start) & (pos < size)
        return owner.at[jnp.where(keep, pos, size)].max(j, mode="drop")

    owner = jax.lax.fori_loop(0, (hi - lo) // size + 1, mark, jnp.zeros(size, jnp.int32))
    return shifted_scan(owner, jnp.maximum, 0)          # owners are >= 0


def _copy_chunks(dst, src, offset, n, chunk):
    """The arrays ``dst`` with [offset, offset + n) set from ``src``'s [0, n), in chunks of
    ``chunk`` entries (the work follows n; up to chunk - 1 entries past n are copied
    too, so dst needs that much room past offset + n, and src as much past n)."""
    def body(i, d):
        return tuple(jax.lax.dynamic_update_slice_in_dim(
            x, jax.lax.dynamic_slice_in_dim(y, i * chunk, chunk), offset + i * chunk, 0)
            for x, y in zip(d, src))

    return jax.lax.fori_loop(0, (n + chunk - 1) // chunk, body, tuple(dst))


@functools.lru_cache(maxsize=64)
def pass_kernel(tests: NodeTests, prune: bool, level0: int, stop: int, cap: int,
                out_cap: int):
    """A jitted traversal pass: waves of jobs from ``level0`` down to ``stop`` (stop <= D:
    push the surviving (item, node) entries at level ``stop``; stop > D: run the leaf
    jobs). One call runs every wave and level: no host round trip per level or per wave.
    One loop body serves every inner level (the level is data), which keeps compile
    times short.

    The returned function takes (data, row_offsets int32 [D], jobs_item int32 [J],
    jobs_node uint32 [J], n_jobs, wave_size, accepted bool [rows, 32], leaf_state,
    scratch), J >= n_jobs + EXPAND_CHUNK, wave_size <= cap, ``scratch`` a
    :class:`Scratch` of capacity cap (donated; its contents do not matter), and returns
    (state, scratch). The state is a dict: accepted, leaf,
    iters int32 [J] (per job), counts int32 [2, K], need int32 [levels of the pass + 1]
    (largest frontier per level: > cap means overflow), fmax, leaf_visits [2], out_n [2]
    and the pushed entries out_item / out_node [out_cap + EXPAND_CHUNK]. ``counts``,
    ``leaf_visits`` and ``out_n`` are two-word totals (``core.capacity.wide_add``: they
    never wrap).

    Every loop's trip count follows the frontier's true size, not the capacity, and
    nothing capacity-sized is cleared: a capacity twice as large cost ``ptsv`` on fuzzy
    100k (1024x1024) about 400 ms more (of 1.2 s) when each level cleared and wrote
    capacity-sized arrays.
    """
    d = tests.levels
    last = min(stop, d)

    def run(data, row_offsets, jobs_item, jobs_node, n_jobs, wave_size, accepted,
            leaf_state, scratch):
        ctx = tests.prepare(data)
        iters_cap = jobs_item.shape[0]
        e = min(cap, EXPAND_CHUNK)
        st = dict(accepted=accepted, leaf=leaf_state,
                  iters=jnp.zeros(iters_cap, jnp.int32),
                  counts=jnp.zeros((2, len(tests.counters)), jnp.int32),
                  need=jnp.zeros(last - level0 + 1, jnp.int32), fmax=jnp.int32(0),
                  leaf_visits=jnp.zeros(2, jnp.int32), out_n=jnp.zeros(2, jnp.int32),
                  out_item=jnp.zeros(out_cap + e if stop <= d else 0, jnp.int32),
                  out_node=jnp.zeros(out_cap + e if stop <= d else 0, jnp.uint32))

        def wave(w, carry):
            st, buf = carry
            start = w * wave_size
            n = jnp.minimum(n_jobs - start, wave_size).astype(jnp.int32)

            def load(i, b):                      # the wave's jobs into the frontier
                s = i * e
                return b._replace(
                    item=jax.lax.dynamic_update_slice_in_dim(
                        b.item, jax.lax.dynamic_slice_in_dim(jobs_item, start + s, e), s, 0),
                    node=jax.lax.dynamic_update_slice_in_dim(
                        b.node, jax.lax.dynamic_slice_in_dim(jobs_node, start + s, e), s, 0),
                    job=jax.lax.dynamic_update_slice_in_dim(
                        b.job, start + s + jnp.arange(e, dtype=jnp.int32), s, 0))

            buf = jax.lax.fori_loop(0, (n + e - 1) // e, load, buf)
            # pruning sees the accepts of earlier waves only (a level's accepts come from
            # its own expansion, so the wave's start state is the level's start state)
            acc_seen = st["accepted"] if prune else None

            def level_body(level, carry):
                st, buf, n = carry
                li = level - level0
                st = dict(st, fmax=jnp.maximum(st["fmax"], n), need=st["need"].at[li].max(n))
                return _expand_level(tests, ctx, level, row_offsets, st, acc_seen, buf,
                                     jnp.minimum(n, cap))

            st, buf, n = jax.lax.fori_loop(level0, last, level_body, (st, buf, n))
            st = dict(st, fmax=jnp.maximum(st["fmax"], n),
                      need=st["need"].at[last - level0].max(n))
            n = jnp.minimum(n, cap)
            if stop <= d:                                    # pass 1 of two: push jobs
                o = wide_min(st["out_n"], out_cap)
                out_item, out_node = _copy_chunks((st["out_item"], st["out_node"]),
                                                  (buf.item, buf.node), o, n, e)
                return dict(st, out_n=wide_add(st["out_n"], n), out_item=out_item,
                            out_node=out_node), buf
            chunk = min(cap, LEAF_CHUNK)                     # leaf jobs

            def leaf_body(i, carry):
                leaf, iters = carry
                t = jax.lax.dynamic_slice_in_dim(buf.item, i * chunk, chunk)
                k = jax.lax.dynamic_slice_in_dim(buf.node, i * chunk, chunk)
                jb = jax.lax.dynamic_slice_in_dim(buf.job, i * chunk, chunk)
                ok = i * chunk + jnp.arange(chunk) < n
                iters = iters.at[jnp.where(ok, jb, iters_cap)].add(1, mode="drop")
                return tests.leaves(ctx, t, k, ok, leaf), iters

            leaf, iters = jax.lax.fori_loop(0, (n + chunk - 1) // chunk, leaf_body,
                                            (st["leaf"], st["iters"]))
            return dict(st, iters=iters, leaf_visits=wide_add(st["leaf_visits"], n),
                        leaf=leaf), buf

        n_waves = (n_jobs + wave_size - 1) // wave_size
        return jax.lax.fori_loop(0, n_waves, wave, (st, scratch))

    return jax.jit(run, donate_argnums=(8,))


def run_pass(tests: NodeTests, data, row_offsets, accepted, leaf_state, jobs_item: np.ndarray,
             jobs_node: np.ndarray, n_jobs: int, *, level0: int, stop: int,
             wave: int | None, prune: bool, out_cap: int, buckets: dict, timer=None,
             compile_stage: str = "traverse_compile"):
    """One traversal pass (see :func:`pass_kernel`), retried with a bigger frontier
    bucket (or push capacity) until nothing overflows (``core.capacity.retry_on_overflow``).

    Args:
        jobs_item, jobs_node: host arrays [n_jobs] (int32 items, uint32 keys at
            ``level0``). wave: jobs per wave (None: one wave). out_cap: capacity for
            pushed entries (grown on overflow). buckets: the remembered frontier
            buckets (see the module docstring), read and updated. timer: a ``StageTimer`` whose
            ``compile_stage`` accumulates compile seconds (or None).
    Returns:
        the kernel's final state (device arrays, see :func:`pass_kernel`) and out_cap.
    """
    total = max(n_jobs, 1)
    wave_size = min(wave, total) if wave else total
    key = (tests, prune, level0, stop)
    first = max(bucket(wave_size, minimum=MIN_FRONTIER),
                min(bucket(tests.frontier_per_job * wave_size), MAX_FRONTIER))
    remedy = "turn on the `prune` option with a smaller `wave`, or render fewer samples"

    def step(caps):
        cap, out_cap = caps
        # a level's children are counted by int32 prefix sums (up to 32 per entry), and the
        # pushed entries are written at int32 offsets
        check_int32(32 * cap, f"traversal children of a {cap:,}-entry frontier", remedy)
        check_int32(out_cap + cap + (2 << WIDE_LOW_BITS), "traversal pass-2 jobs",
                    "use passes=1 or a smaller expand_level, or render fewer samples")
        length = bucket(n_jobs + EXPAND_CHUNK, minimum=MIN_FRONTIER)
        check_int32(length, "traversal job list", remedy)
        jt = np.zeros(length, np.int32)
        jn = np.zeros(length, np.uint32)
        jt[:n_jobs], jn[:n_jobs] = jobs_item, jobs_node
        kern = pass_kernel(tests, prune, level0, stop, cap, out_cap)
        args = (data, row_offsets, jnp.asarray(jt), jnp.asarray(jn), jnp.int32(n_jobs),
                jnp.int32(wave_size), accepted, leaf_state, _take_scratch(cap))
        exe, dt = compiled(kern, *args)
        if timer is not None:
            timer.times[compile_stage] = timer.times.get(compile_stage, 0.0) + dt
        st, scratch = exe(*args)
        _keep_scratch(cap, scratch)
        return st, (int(np.asarray(st["need"]).max()), int(wide_total(st["out_n"])))

    def grow_frontier(need, cap):
        # counts below a truncated level are underestimates: grow by 2x at least, but not
        # past the largest frontier whose children int32 counts (then only as needed)
        want = bucket(need, minimum=MIN_FRONTIER)
        return want if want > MAX_FRONTIER else min(max(want, 2 * cap), MAX_FRONTIER)

    st, (cap, out_cap) = retry_on_overflow(
        step, (max(buckets.get(key, 0), first), out_cap),
        grow=(grow_frontier, lambda need, cap: bucket(need, minimum=MIN_FRONTIER)))
    buckets[key] = cap
    return st, out_cap


@dataclasses.dataclass(frozen=True, eq=False)
class Traversal:
    """What :func:`traverse` returns.

    Attributes:
        accepted: bool [rows, 32] device array, the accepted children per inner node.
        leaf_state: the final leaf state pytree (device arrays).
        iterations_pass1: int [jobs] per pass-1 job, in job order.
        iterations_pass2: int [pass-2 jobs] (empty with one pass).
        pass2_items: int32 [pass-2 jobs]; pass2_nodes: uint32 [pass-2 jobs] keys at
            ``expand_level``.
        counts: int64 [K], the node test counters (names: ``tests.counters``).
        leaf_visits: leaf jobs run; frontier_max: the largest frontier (entries).
    """

    accepted: Any
    leaf_state: Any
    iterations_pass1: np.ndarray
    iterations_pass2: np.ndarray
    pass2_items: np.ndarray
    pass2_nodes: np.ndarray
    counts: np.ndarray
    leaf_visits: int
    frontier_max: int


def traverse(tests: NodeTests, data, row_offsets, items: np.ndarray, accepted, leaf_state, *,
             passes: int, expand_level: int, wave: int | None, prune: bool,
             buckets: dict | None = None, timer=None) -> Traversal:
    """Traverse one job per item from the root (pass 1) and, with ``passes=2``, the
    (item, node) jobs pass 1 pushed at ``expand_level`` (pass 2) down to the leaves.

    Args:
        tests: the node tests (static, hashable). data: the arrays they read (a pytree).
        row_offsets: int32 [D] first row of each level in ``accepted``.
        items: int32 [J] host array, one root job per item, in job order.
        accepted: bool [rows, 32] initial accepts; leaf_state: initial leaf pytree.
        passes: 1 or 2; expand_level: the level where pass 1 stops (1..D).
        wave: jobs per wave (None: one wave); prune: the node test sees earlier waves'
            accepts.
        buckets: the frontier and push buckets that sufficed in earlier calls, read and
            grown in place (a dict the caller keeps per scene); None: start from the
            smallest buckets.
    """
    buckets = {} if buckets is None else buckets
    d = tests.levels
    stop = expand_level if passes == 2 else d + 1
    key2 = ("out", tests, prune, expand_level)
    out_cap = buckets.get(key2, MIN_FRONTIER) if passes == 2 else 0
    st1, out_cap = run_pass(tests, data, row_offsets, accepted, leaf_state, items,
                            np.zeros(len(items), np.uint32), len(items), level0=0, stop=stop,
                            wave=wave, prune=prune, out_cap=out_cap, buckets=buckets,
                            timer=timer)
    host = jax.device_get({k: st1[k] for k in ("iters", "counts", "fmax", "leaf_visits",
                                                "out_n")})
    iters1 = host["iters"][: len(items)]
    counts = wide_total(host["counts"])
    leaf_visits, fmax = int(wide_total(host["leaf_visits"])), int(host["fmax"])
    items2 = np.zeros(0, np.int32)
    nodes2 = np.zeros(0, np.uint32)
    iters2 = np.zeros(0, np.int64)
    st = st1
    if passes == 2:
        buckets[key2] = out_cap
        m = int(wide_total(host["out_n"]))
        items2 = np.asarray(st1["out_item"])[:m]
        nodes2 = np.asarray(st1["out_node"])[:m]
        st, _ = run_pass(tests, data, row_offsets, st1["accepted"], st1["leaf"], items2,
                         nodes2, m, level0=expand_level, stop=d + 1, wave=wave, prune=prune,
                         out_cap=0, buckets=buckets, timer=timer)
        h2 = jax.device_get({k: st[k] for k in ("iters", "counts", "fmax", "leaf_visits")})
        iters2 = h2["iters"][:m]
        counts += wide_total(h2["counts"])
        leaf_visits += int(wide_total(h2["leaf_visits"]))
        fmax = max(fmax, int(h2["fmax"]))
    return Traversal(st["accepted"], st["leaf"], iters1, iters2, items2, nodes2, counts,
                     leaf_visits, fmax)
