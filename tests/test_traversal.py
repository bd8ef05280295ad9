"""The traversal engine on a synthetic 32-ary tree against a plain Python traversal.

The tree has depth 3 over 32**3 integer leaf cells; a node exists where some point
falls inside it. An item is a query range [qa, qb) of cells: a child outside it is
rejected, one inside it is accepted (unless the item forbids accepts), anything else
is intersected and expanded. At a leaf, the engine counts the visit and sums the item
ids. The reference visits the same nodes with Python loops (waves, pruning and two
passes emulated as documented) and must give the same accepts, leaf state, per-job
iterations, pushed jobs and counters.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shadowlab.core import capacity
from shadowlab.engines import traversal as tv

D = 3
LEAVES = 32 ** D
ROWS = [sum(32 ** k for k in range(level)) for level in range(D)]   # first row per level
N_ROWS = sum(32 ** k for k in range(D))


@dataclasses.dataclass(frozen=True)
class RangeTests:
    levels: int = D
    counters = ("tests", "accepts", "rejects")
    frontier_per_job = 1                # the smallest first bucket: the retry path runs

    def prepare(self, data):
        return data

    def children(self, ctx, level, item, node, valid, accepted):
        row = ctx["rows"][level] + node.astype(jnp.int32)
        word = ctx["masks"][row]
        c = jnp.arange(32, dtype=jnp.uint32)
        exists = (((word[:, None] >> c[None, :]) & jnp.uint32(1)) == 1) & valid[:, None]
        if accepted is not None:
            exists &= ~accepted[row]
        child = ((node[:, None] << 5) | c[None, :]).astype(jnp.int32)
        span = jnp.left_shift(jnp.int32(1), 5 * (D - 1 - level))      # cells per child
        lo, hi = child * span, (child + 1) * span
        qa, qb = ctx["qa"][item][:, None], ctx["qb"][item][:, None]
        reject = exists & ((hi <= qa) | (lo >= qb))
        accept = exists & ~reject & ctx["may_accept"][item][:, None] & (lo >= qa) & (hi <= qb)
        intersect = exists & ~reject & ~accept
        counts = jnp.stack([jnp.sum(exists), jnp.sum(accept), jnp.sum(reject)]).astype(jnp.int32)
        accept_w, intersect_w = tv.child_words(accept, intersect)
        return accept_w, intersect_w, counts

    def leaves(self, ctx, item, node, ok, state):
        visits, item_sum = state
        cell = jnp.where(ok, node.astype(jnp.int32), LEAVES)
        return (visits.at[cell].add(1, mode="drop"),
                item_sum.at[cell].add(item, mode="drop"))


def _problem(seed=3):
    rng = np.random.default_rng(seed)
    cells = np.unique(np.concatenate([rng.integers(0, LEAVES, 2500),
                                      rng.integers(4000, 4200, 150)]))
    masks = np.zeros(N_ROWS, np.uint32)
    for level in range(D):
        child = cells >> (5 * (D - 1 - level))          # the cells' nodes at level + 1
        np.bitwise_or.at(masks, ROWS[level] + (child >> 5), np.uint32(1) << (child & 31))
    n_items = 40
    qa = rng.integers(0, LEAVES - 1, n_items)
    qb = np.minimum(qa + rng.integers(1, LEAVES // 3, n_items), LEAVES)
    may = np.ones(n_items, bool)
    may[::5] = False                    # 8 items that never accept: big frontiers
    qa[::5], qb[::5] = 0, LEAVES
    return cells, masks, qa.astype(np.int32), qb.astype(np.int32), may


def _reference(masks, qa, qb, may, *, passes, expand_level, wave, prune):
    """Python traversal with the engine's documented semantics."""
    accepted = np.zeros((N_ROWS, 32), bool)
    visits = np.zeros(LEAVES, np.int64)
    item_sum = np.zeros(LEAVES, np.int64)
    counts = np.zeros(3, np.int64)
    stats = {"leaf_visits": 0, "frontier_max": 0}

    def run(jobs, level0, stop):
        """jobs: list of (item, node); returns iterations and pushed (item, node)."""
        iters = np.zeros(len(jobs), np.int64)
        pushed = []
        size = wave if wave else max(len(jobs), 1)
        for w0 in range(0, len(jobs), size):
            seen = accepted.copy() if prune else None
            frontier = [(it, nd, w0 + j) for j, (it, nd) in enumerate(jobs[w0: w0 + size])]
            for level in range(level0, min(stop, D)):
                stats["frontier_max"] = max(stats["frontier_max"], len(frontier))
                nxt = []
                for it, nd, job in frontier:
                    iters[job] += 1
                    row = ROWS[level] + nd
                    span = 32 ** (D - 1 - level)
                    for c in range(32):
                        exists = bool((int(masks[row]) >> c) & 1)
                        if seen is not None:
                            exists &= not seen[row, c]
                        if not exists:
                            continue
                        counts[0] += 1
                        child = (nd << 5) | c
                        lo, hi = child * span, (child + 1) * span
                        if hi <= qa[it] or lo >= qb[it]:
                            counts[2] += 1
                        elif may[it] and lo >= qa[it] and hi <= qb[it]:
                            counts[1] += 1
                            accepted[row, c] = True
                        else:
                            nxt.append((it, child, job))
                frontier = nxt
            stats["frontier_max"] = max(stats["frontier_max"], len(frontier))
            if stop <= D:
                pushed += [(it, nd) for it, nd, _ in frontier]
                continue
            for it, nd, job in frontier:
                iters[job] += 1
                visits[nd] += 1
                item_sum[nd] += it
                stats["leaf_visits"] += 1
        return iters, pushed

    items = list(range(len(qa)))
    stop = expand_level if passes == 2 else D + 1
    iters1, pushed = run([(i, 0) for i in items], 0, stop)
    iters2 = np.zeros(0, np.int64)
    if passes == 2:
        iters2, _ = run(pushed, expand_level, D + 1)
    return dict(accepted=accepted, visits=visits, item_sum=item_sum, counts=counts,
                iters1=iters1, iters2=iters2, pushed=pushed, **stats)


def _traverse(qa, qb, masks, may, passes, expand_level, wave, prune, buckets=None,
              tests=None):
    """The engine on the range problem (``tests``: RangeTests() by default), from an
    empty accepted set and leaf state (and the smallest buckets unless ``buckets``
    remembers others)."""
    data = {"rows": jnp.asarray(ROWS, jnp.int32), "masks": jnp.asarray(masks),
            "qa": jnp.asarray(qa), "qb": jnp.asarray(qb), "may_accept": jnp.asarray(may)}
    return tv.traverse(RangeTests() if tests is None else tests, data, data["rows"],
                       np.arange(len(qa), dtype=np.int32),
                       jnp.zeros((N_ROWS, 32), bool),
                       (jnp.zeros(LEAVES, jnp.int32), jnp.zeros(LEAVES, jnp.int32)),
                       passes=passes, expand_level=expand_level, wave=wave, prune=prune,
                       buckets=buckets)


@pytest.mark.parametrize("passes,expand_level,wave,prune,overflows", [
    (1, 1, None, False, True), (2, 2, None, False, True), (1, 1, 7, True, True),
    (2, 1, 16, True, False)])
def test_engine_visits_the_same_nodes_as_a_python_loop(passes, expand_level, wave, prune,
                                                       overflows):
    cells, masks, qa, qb, may = _problem()
    buckets = {}                            # start from the smallest bucket: overflow retry
    got = _traverse(qa, qb, masks, may, passes, expand_level, wave, prune, buckets)
    want = _reference(masks, qa, qb, may, passes=passes, expand_level=expand_level,
                      wave=wave, prune=prune)
    assert (want["frontier_max"] > tv.MIN_FRONTIER) == overflows   # the retry path ran
    # the bucket that sufficed is remembered in the caller's dict, and only there
    grown = max(v for k, v in buckets.items() if k[0] != "out")
    assert grown >= want["frontier_max"] and (grown > tv.MIN_FRONTIER) == overflows
    again = _traverse(qa, qb, masks, may, passes, expand_level, wave, prune, buckets)
    np.testing.assert_array_equal(again.counts, got.counts)
    assert want["counts"][1] > 0 and want["leaf_visits"] > 0
    np.testing.assert_array_equal(np.asarray(got.accepted), want["accepted"])
    visits, item_sum = jax.device_get(got.leaf_state)
    np.testing.assert_array_equal(visits, want["visits"])
    np.testing.assert_array_equal(item_sum, want["item_sum"])
    assert not visits[np.setdiff1d(np.arange(LEAVES), cells)].any()   # only existing leaves
    np.testing.assert_array_equal(got.counts, want["counts"])
    assert got.leaf_visits == want["leaf_visits"]
    assert got.frontier_max == want["frontier_max"]
    np.testing.assert_array_equal(got.iterations_pass1, want["iters1"])
    np.testing.assert_array_equal(got.iterations_pass2, want["iters2"])
    pushed = np.array(want["pushed"], np.int64).reshape(-1, 2)
    np.testing.assert_array_equal(got.pass2_items, pushed[:, 0])
    np.testing.assert_array_equal(got.pass2_nodes, pushed[:, 1])


def test_the_first_bucket_follows_the_tests_frontier_prior(monkeypatch):
    """With ``frontier_per_job`` large enough for the peak frontier the first try is the
    only one (one kernel, that bucket remembered); with 1 the same problem retries, and
    both give the Python loop's results."""
    cells, masks, qa, qb, may = _problem()
    want = _reference(masks, qa, qb, may, passes=1, expand_level=1, wave=None, prune=False)
    jobs = len(qa)
    assert want["frontier_max"] > tv.MIN_FRONTIER

    @dataclasses.dataclass(frozen=True)
    class PriorTests(RangeTests):
        frontier_per_job = -(-want["frontier_max"] // jobs)

    caps = []
    kernel = tv.pass_kernel
    monkeypatch.setattr(tv, "pass_kernel", lambda *a: caps.append(a[4]) or kernel(*a))
    for spec, retried in ((PriorTests(), False), (RangeTests(), True)):
        caps.clear()
        buckets = {}
        got = _traverse(qa, qb, masks, may, 1, 1, None, False, buckets, tests=spec)
        first = tv.bucket(spec.frontier_per_job * jobs, minimum=tv.MIN_FRONTIER)
        assert caps[0] == first and (len(caps) > 1) == retried
        assert buckets[(spec, False, 0, D + 1)] == caps[-1] >= want["frontier_max"]
        np.testing.assert_array_equal(got.counts, want["counts"])
        assert got.frontier_max == want["frontier_max"]
        visits, _ = jax.device_get(got.leaf_state)
        np.testing.assert_array_equal(visits, want["visits"])


@pytest.fixture
def two_bit_counters(monkeypatch):
    """The engine's two-word counters with 2 low bits: every few increments carry."""
    tv.pass_kernel.cache_clear()
    monkeypatch.setattr(capacity, "WIDE_LOW_BITS", 2)
    yield
    tv.pass_kernel.cache_clear()         # no kernel traced with 2 bits outlives the test


@pytest.mark.parametrize("passes,expand_level,wave,prune", [(1, 1, None, False),
                                                            (2, 1, 16, True)])
def test_counters_that_carry_keep_every_total(two_bit_counters, passes, expand_level, wave,
                                              prune):
    """The counters, leaf visits and pushed jobs are two-word totals (so a frame's node
    tests may pass 2**31): with a carry every 4 counts they still equal the Python loop."""
    cells, masks, qa, qb, may = _problem()
    got = _traverse(qa, qb, masks, may, passes, expand_level, wave, prune)
    want = _reference(masks, qa, qb, may, passes=passes, expand_level=expand_level,
                      wave=wave, prune=prune)
    assert min(want["counts"]) > 4 and want["leaf_visits"] > 4
    np.testing.assert_array_equal(got.counts, want["counts"])
    assert got.leaf_visits == want["leaf_visits"]
    pushed = np.array(want["pushed"], np.int64).reshape(-1, 2)
    assert passes == 1 or len(pushed) > 4
    np.testing.assert_array_equal(got.pass2_items, pushed[:, 0])
    np.testing.assert_array_equal(got.pass2_nodes, pushed[:, 1])


def test_a_frontier_whose_children_int32_cannot_count_is_refused():
    """A frontier bucket of 2**26 entries (2**31 children) is refused with a clear error
    before anything is allocated, not run with wrapping prefix sums."""
    cells, masks, qa, qb, may = _problem()
    buckets = {(RangeTests(), False, 0, D + 1): 2 ** 26}
    with pytest.raises(capacity.CapacityError, match="frontier.*prune"):
        _traverse(qa, qb, masks, may, 1, 1, None, False, buckets)


@pytest.mark.parametrize("size", [8, 64])
def test_slot_owners_equal_searchsorted(size):
    """The compaction's owner of each output slot below the total equals
    ``searchsorted(end[:n], slot, side="right")``: empty entries (equal prefix sums),
    long runs of them (a window of entries longer than the chunk), entries with up to 32
    children (a chunk inside one entry), chunks that end past the total, a full bucket,
    and leftover values past the tested entries, which it must not read. Slots past the
    total get an entry below n."""
    rng = np.random.default_rng(3)
    owners = jax.jit(tv._slot_owners, static_argnums=2)
    for _ in range(150):
        cap = int(rng.choice([8, 64, 512]))
        n = int(rng.integers(1, cap + 1))
        pop = rng.integers(0, 33, n) * (rng.random(n) < rng.choice([0.05, 0.6, 1.0]))
        end = rng.integers(-5, 50, cap).astype(np.int32)           # leftovers past n
        end[:n] = np.cumsum(pop)
        total = int(end[n - 1])
        for base in range(0, total, size):
            got = np.asarray(owners(jnp.asarray(end), jnp.int32(base), size, jnp.int32(n)))
            q = base + np.arange(size)
            live = q < total
            np.testing.assert_array_equal(got[live],
                                          np.searchsorted(end[:n], q[live], side="right"))
            assert np.all((got >= 0) & (got < n))


def test_compaction_keeps_entry_major_child_minor_order():
    rng = np.random.default_rng(0)
    cap = 64
    words = rng.integers(0, 2 ** 32, cap, dtype=np.uint64).astype(np.uint32)
    words[rng.random(cap) < 0.5] = 0
    n = 50                                                  # entries past n are padding
    pop = np.array([bin(int(w)).count("1") for w in words[:n]])
    end = rng.integers(0, 40, cap).astype(np.int32)        # leftovers past n, never read
    end[:n] = np.cumsum(pop)
    item = np.arange(cap, dtype=np.int32) + 100
    node = rng.integers(0, 1000, cap).astype(np.uint32)
    job = np.arange(cap, dtype=np.int32) * 3
    total = int(pop.sum())
    assert total > cap                                      # truncated at cap
    ni, nn, nj = tv.compact_children(jnp.asarray(words), jnp.asarray(end), jnp.int32(n),
                                     jnp.int32(total), jnp.asarray(item), jnp.asarray(node),
                                     jnp.asarray(job))
    want = [(item[j], (int(node[j]) << 5) | c, job[j]) for j in range(n) for c in range(32)
            if (int(words[j]) >> c) & 1][:cap]
    np.testing.assert_array_equal(np.asarray(ni), [w[0] for w in want])
    np.testing.assert_array_equal(np.asarray(nn), [w[1] for w in want])
    np.testing.assert_array_equal(np.asarray(nj), [w[2] for w in want])
