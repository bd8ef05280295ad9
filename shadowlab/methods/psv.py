"""Partitioned shadow volumes: ``psv``, ``d_psv``, ``d_stackless``, ``d_hybrid``.

Gerhards et al. 2015 (PSV, stack query) and Mora et al. 2016 (Deep PSV: depth test,
stackless query through ancestor links, hybrid short-stack query). The TOP tree is
built by ``top_tree.build_parallel``; the queries run vectorized over view samples as
fixed-trip masked loops (``lax.fori_loop`` of ``chunk`` steps, one node visit per
step and lane) with compaction of the unfinished lanes into a smaller power-of-two
bucket between chunks, so the long tail of expensive pixels does not keep every
lane busy. See docs/psv.md for the choices the papers leave open.

Node tests are exactly those of ``brute_force``: a sample is inside an edge plane
when ``plane(p) >= 0`` (option ``edge_tie="outside"``: ``> 0``, the other reading of
the papers' ``location > 0``) and behind a cap when ``cap(p) * scale[p] < bound[t]``
(the bias of ``common.bias_terms``).
"""

from __future__ import annotations

import functools
import weakref
import time

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import CapacityError, bucket, check_int32, pad
from ..core.numerics import materialize, pack_interval, unpack_interval, unpack_interval_np
from ..geometry.caster_culling import front_face_culled
from ..geometry.triangle_setup import shadow_volume_planes
from ..scene.caches import per_scene_cache
from ..scene.view import hard_light
from ..core.timing import StageTimer
from ..structures import top_tree as tt
from ..core.frame import (BIAS_MODES, bias_scale, bias_terms, cap_bias, precision_mode,
                          view_samples)
from .registry import Option, register
from ..core.result import ShadowResult

QUERIES = ("stack", "stackless", "hybrid")


# --------------------------------------------------------------------------- casters


def frustum_light_hull(camera, light_h: np.ndarray, extent: float) -> np.ndarray:
    """float64 [F, 4]: outward planes (n, d) of the convex hull of the view frustum and
    the light (for a directional light: the frustum swept ``extent`` towards it)."""
    from scipy.spatial import ConvexHull

    inv = np.linalg.inv(camera.view_projection())
    ndc = np.array([[x, y, z, 1.0] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    c = ndc @ inv.T
    corners = c[:, :3] / c[:, 3:4]
    if light_h[3] != 0:
        pts = np.vstack([corners, light_h[:3][None]])
    else:
        pts = np.vstack([corners, corners + extent * light_h[:3][None]])
    return ConvexHull(pts).equations


#: the options of the trees the PSV experiments measure: every caster in the tree, as
#: their claims were first checked (the default drops closed objects' light-averted
#: triangles; the papers' own setting is ``face_culling="front"``)
UNCULLED_TREE = {"face_culling": "none"}


def casters(scene, light, camera, dtype, face_culling: str, frustum_culling: bool):
    """Planes [T, 4, 4] (dtype, NumPy), mask of kept triangles [T] and culling counts."""
    light_h = hard_light(light).homogeneous
    # the canonical jitted setup at brute_force's padding: the same planes, bit for bit,
    # as brute_force (an ulp decides samples whose segment grazes an edge: docs/psv.md)
    t = bucket(scene.num_triangles, minimum=16)
    tri = pad(scene.triangles, t, dtype=dtype)
    planes, valid = shadow_volume_planes(jnp.asarray(tri), jnp.asarray(light_h.astype(dtype)))
    planes = np.asarray(planes).reshape(t, 4, 4)[: scene.num_triangles]
    keep = np.asarray(valid)[: scene.num_triangles].copy()
    culled = {"degenerate": int((~keep).sum()), "face": 0, "frustum": 0}
    tris = scene.triangles
    if face_culling == "averted":
        # closed objects' light-averted triangles (the shared exact rule, as clustered_ptsv)
        cull = front_face_culled(scene, light_h, "averted")
    elif face_culling != "none":      # the papers' rule by winding alone
        n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        to_l = light_h[:3] - light_h[3] * tris[:, 0]
        front = np.einsum("ij,ij->i", n, to_l) > 0
        cull = front if face_culling == "front" else ~front
    if face_culling != "none":
        culled["face"] = int((keep & cull).sum())
        keep &= ~cull
    if frustum_culling:
        eq = frustum_light_hull(camera, light_h, 4 * scene.diagonal)
        tol = 1e-6 * max(scene.diagonal, 1e-30)
        vals = tris @ eq[:, :3].T + eq[:, 3]               # [T, 3, F]
        out = np.any(np.all(vals > tol, axis=1), axis=1)
        culled["frustum"] = int((keep & out).sum())
        keep &= ~out
    return planes, keep, culled


def classification_margin(scene, light, dtype, ulps: float) -> float:
    """World-unit margin: ``ulps`` machine epsilons of the largest coordinate in play."""
    light_h = hard_light(light).homogeneous
    a = float(np.max(np.abs(scene.vertices))) if scene.num_triangles else 1.0
    if light_h[3] != 0:
        a = max(a, float(np.max(np.abs(light_h[:3]))))
    return float(ulps) * float(np.finfo(dtype).eps) * a


def build_input(scene, light, camera, samples, *, dtype, shadow_eps, bias, order, seed,
                classify_ulps, face_culling="none", frustum_culling=False, timer=None):
    """Everything before the build: cull, bias terms, margin, order and pad the casters.

    Returns (``top_tree.BuildInput``, samples' scale [S] (float64), culled counts). The
    Warp kernels (``kernels/psv.prepare``) build from this same input. Host stages are
    timed as ``casters`` (planes, culling, bias terms) and ``build_setup`` (keys, order,
    padding).
    """
    timer = timer if timer is not None else StageTimer()
    light_h = hard_light(light).homogeneous
    with timer.stage("casters"):
        planes, keep, culled = casters(scene, light, camera, dtype, face_culling,
                                       frustum_culling)
        eps = cap_bias(scene, shadow_eps)
        scale, bound = bias_terms(samples, light_h, planes, eps, bias)
        idx = np.flatnonzero(keep)
        margin = classification_margin(scene, light, dtype, classify_ulps)
    with timer.stage("build_setup"):
        inp = tt.make_input(scene.triangles[idx], planes[idx], bound[idx], idx.astype(np.int32),
                            light_h, dtype, margin, eps, order, seed,
                            bucket(max(len(idx), 1), minimum=256))
    return inp, scale, culled


def build_tree(scene, light, camera, samples, *, dtype, shadow_eps, bias, order, seed, wedge,
               classify_ulps, face_culling="none", frustum_culling=False, build="parallel",
               node_order="build", timer=None):
    """:func:`build_input`, then the build; returns (TopTree, samples' scale [S] (float64),
    culled). The JAX build is timed as ``build`` (and ``build_compact``).

    ``node_order``: "build" keeps the build's volume ids (insertion ranks);
    "breadth_first" renumbers the volumes breadth-first from the root
    (``top_tree.breadth_first_volumes``; timed as ``renumber``): the same tree, the
    same visits and results, with the nodes near the root close together in memory.
    """
    timer = timer if timer is not None else StageTimer()
    inp, scale, culled = build_input(
        scene, light, camera, samples, dtype=dtype, shadow_eps=shadow_eps, bias=bias,
        order=order, seed=seed, classify_ulps=classify_ulps, face_culling=face_culling,
        frustum_culling=frustum_culling, timer=timer)
    if build == "sequential":
        with timer.stage("build"):
            tree = tt.build_sequential(inp, wedge)
    else:
        tree = tt.build_parallel(inp, wedge, timer)
    if node_order == "breadth_first":
        with timer.stage("renumber"):
            tree = tree.renumbered(tt.breadth_first_volumes(tree))
    elif node_order != "build":
        raise ValueError(f"node_order must be 'breadth_first' or 'build'; got {node_order!r}")
    return tree, scale, culled


#: volume numberings of a built tree for the query (see :func:`build_tree`); "auto" is
#: breadth-first for a kept tree (``reuse_tree``), the build's otherwise
NODE_ORDERS = ("auto", "breadth_first", "build")


def node_order_for(option: str, reuse_tree: bool) -> str:
    """The numbering the ``node_order`` option means: "auto" renumbers a tree that is
    kept for later calls (the renumbering, 22-28 ms at 100k casters and about 0.4 s at
    1M, is paid once) and leaves a tree built for one call as built (there it costs
    about what it saves; docs/psv.md, "Node order")."""
    if option == "auto":
        return "breadth_first" if reuse_tree else "build"
    return option


# --------------------------------------------------------------------------- queries

@functools.lru_cache(maxsize=None)
def _chunk_kernel(query: str, depth_test: bool, wedge: str, stack_size: int, overflow: str,
                  stackless_cap: str, edge_tie: str, directional: bool, fast: bool = False,
                  fast_in_word: bool = False):
    """A jitted function running ``steps`` node visits of every lane of a bucket.

    ``steps`` is an int32 argument, not a compile-time constant: one compiled kernel per
    bucket size serves every chunk length of the schedule (:func:`chunk_lengths`).

    Layout for speed on XLA/CPU (measured, docs/psv.md): every node field is its own
    1D array read with one ``promise_in_bounds`` gather per field (row gathers of an
    [N, 4] array and clamped gathers cost 1.5-2x more), the per-lane stack is one flat
    array, tile-major ([tiles, K + 1, tile], row K scratch; entries of one level of a
    tile are contiguous) in the first (K + 1) * lanes entries of a buffer sized for the
    query's first bucket, which each tile addresses in place (``STACK_IN_PLACE``), and
    the state is donated so the loop updates it in place.
    Every output of the loop body is a separate fusion that XLA/CPU recomputes the whole
    step for, so the state is packed into as few arrays as possible (a node-and-flags
    word, a stack-pointer, maximum and count word, the stack, the visit count (the
    stack query keeps a finished lane's count in its word instead: ``VISITS_IN_WORD``,
    with the chunk's first step of the query, ``base``, an argument), the hybrid's
    return node).

    ``fast`` (hybrid only): the stack-mode-only step, for buckets where no lane is in
    stackless mode: a lane that would switch to stackless mode *stalls* instead (no
    visit, no state change, sign bit of its word set) and the host runs the full hybrid
    step on that bucket from the next chunk on. The full step costs twice the stack
    step (both transitions and the return node are computed for every lane).
    ``fast_in_word`` (with ``fast``, until the query's first stall): no visit counter
    array; a finished lane keeps its count in its node field (as ``VISITS_IN_WORD``)
    and a stalling lane the step it stalled at in its stats word's count field (its
    visits so far: no lane has idled before); :func:`_visits_to_array` turns both into
    the array when the hybrid leaves this mode.
    """
    k = max(stack_size, 1)

    def g(a, i):
        return a.at[i].get(mode="promise_in_bounds")

    def run_tile(state, tree, px, py, pz, scale, key, light, tol, steps, base, stack_at=0):
        if ROWS[query]:
            rows, anc = tree
        else:
            pa, pb, pc, pd, wedge_v, pos, inter, extra, anc = tree
        if directional:
            dist = jnp.ones_like(px)
        else:
            dx, dy, dz = px - light[0], py - light[1], pz - light[2]
            dist = jnp.sqrt(dx * dx + dy * dy + dz * dz)
        b = px.shape[0]
        lanes = jnp.arange(b, dtype=jnp.int32) + stack_at

        in_word = VISITS_IN_WORD[query] or (fast and fast_in_word)

        def step(step_no, s):
            w = s["word"]
            node0 = w & NODE_MASK
            twice0 = (w & TWICE) != 0
            sl0 = (w & SL) != 0
            done0 = (w & DONE) != 0
            act = ~done0
            if fast:
                act = act & (w >= 0)               # stalled lanes wait for the full step
            n = jnp.where(act, node0, 0)
            q = n & 3
            is_cap = q == 3
            if ROWS[query]:
                row = _barrier(g(rows, n))         # [lanes, 8]: one 32-byte node
                fa, fb, fc, fd, wv, ex = (row[:, i] for i in range(6))
                pchild, ichild = _as_int(row[:, 6]), _as_int(row[:, 7])
            else:
                fa, fb, fc, fd, ex = g(pa, n), g(pb, n), g(pc, n), g(pd, n), g(extra, n)
                pchild, ichild = g(pos, n), g(inter, n)
                wv = g(wedge_v, n) if wedge != "off" else None
            off = px * fa + py * fb + pz * fc + fd
            # ex: depth at a volume's first node, cap bias bound at its cap
            if edge_tie == "inside":
                inside_e = off >= 0
            else:
                inside_e = off > 0
            inside = jnp.where(is_cap, off * scale < ex, inside_e)
            has_i = ichild >= 0
            if wedge == "off":
                wedge_ok = jnp.ones_like(act)
            else:
                if wedge == "vertex":
                    wedge_ok = jnp.abs(off) < wv * dist
                elif wedge == "signed":
                    lo, hi = unpack_interval(wv)
                    wedge_ok = (off <= hi * dist + tol) & (off >= lo * dist - tol)
                else:
                    wedge_ok = jnp.abs(off) <= wv * dist + tol
            wedge_ok = wedge_ok | is_cap
            if depth_test:
                skip = (q == 0) & (key < ex)
            else:
                skip = jnp.zeros_like(act)
            if query != "stackless":
                # The stack step has several outputs (state word, stack scatter, stats);
                # materialize the node test's decisions once instead of recomputing the
                # plane test in each of their fusions (XLA/CPU).
                flags, pchild, ichild = materialize(
                    inside.astype(jnp.int32) | (wedge_ok.astype(jnp.int32) << 1)
                    | (skip.astype(jnp.int32) << 2), pchild, ichild)
                inside, wedge_ok, skip = ((flags >> i) & 1 == 1 for i in range(3))
            visited = None if in_word else s["visited"] + act

            if query != "stack" and not fast:
                # -------- stackless transitions (d_stackless, hybrid in stackless mode)
                a_link = g(anc, n >> 2)
                if stackless_cap == "paper":
                    sl_inter_ok = wedge_ok
                else:                               # public code: cap clause dropped
                    sl_inter_ok = wedge_ok & ~is_cap
                sl_desc = ~twice0 & has_i & sl_inter_ok
                sl_pos_leaf = ~inside & (pchild < 0)
                sl_node = jnp.where(skip, a_link, jnp.where(
                    sl_desc, ichild, jnp.where(~inside, jnp.where(pchild >= 0, pchild, a_link),
                                               n + 1)))
                sl_twice = skip | (~sl_desc & sl_pos_leaf)
                sl_shadow = ~skip & ~sl_desc & inside & is_cap
                sl_lit = (sl_node < 0) & ~sl_shadow

            if query == "stackless":
                shadow_now = act & sl_shadow
                done_now = act & (sl_shadow | sl_lit)
                node = jnp.where(act, sl_node, node0)
                if in_word:             # a finished lane's node field: its visit count
                    node = jnp.where(done_now, base + step_no + 1, node)
                word = _pack(node, jnp.where(act, sl_twice, twice0), sl0,
                             ((w & SHADOW) != 0) | shadow_now, done0 | done_now)
                return dict(s, word=word) if in_word else dict(s, word=word, visited=visited)

            # -------- stack transitions (psv, d_psv, hybrid in stack mode)
            st_word = s["stats"]
            sp = st_word & 63
            if query == "hybrid" and not fast:
                back = sl0 & twice0 & (n == s["ret"])   # returned to the switch node
                in_sl = sl0 & ~back
                st_mode = act & ~in_sl
                want = ~skip & has_i & wedge_ok & ~twice0
            else:
                in_sl = jnp.zeros_like(act)
                st_mode = act
                want = ~skip & has_i & wedge_ok
            can = sp < stack_size
            push = st_mode & want & can
            full = st_mode & want & ~can
            stall = jnp.zeros_like(act)
            if fast:
                # A switch would happen: leave the lane untouched for the full step.
                stall = full
                switch = lost = jnp.zeros_like(act)
                st_mode = act & ~stall
                push = push & ~stall
                visited = None if in_word else s["visited"] + st_mode
            elif query == "hybrid":
                switch = full
                lost = jnp.zeros_like(act)
            else:
                switch = jnp.zeros_like(act)
                lost = full
            go_pos = ~skip & ~inside & (pchild >= 0)
            go_neg = ~skip & inside & ~is_cap
            st_shadow = ~skip & inside & is_cap & ~switch
            need_pop = ~switch & ~go_pos & ~go_neg & ~st_shadow
            # the transition flags once for the stack scatter, the state word and stats
            vals = (push, need_pop, switch, lost, go_pos, go_neg, st_shadow, st_mode, stall)
            packed = materialize(functools.reduce(jnp.bitwise_or, [
                jnp.broadcast_to(v, act.shape).astype(jnp.int32) << i
                for i, v in enumerate(vals)]))
            (push, need_pop, switch, lost, go_pos, go_neg, st_shadow, st_mode,
             stall) = ((packed >> i) & 1 == 1 for i in range(len(vals)))
            # A push followed by a pop in the same step visits the pushed node directly.
            direct = push & need_pop
            stored = push & ~need_pop
            # Row k is a scratch row: every lane writes exactly one distinct slot, so the
            # scatter needs no bounds or collision handling (3-4x faster on XLA/CPU).
            stack = s["stack"].at[jnp.where(stored, sp, k) * b + lanes].set(
                ichild, mode="promise_in_bounds", unique_indices=True)
            sp1 = sp + push
            popped = need_pop & (sp1 > 0)
            mem_pop = popped & ~direct
            top = g(stack, jnp.where(mem_pop, sp1 - 1, k) * b + lanes)
            top = jnp.where(direct, ichild, top)
            st_lit = need_pop & (sp1 == 0)
            st_node = jnp.where(switch, ichild, jnp.where(go_pos, pchild, jnp.where(
                go_neg, n + 1, jnp.where(popped, top, -1))))
            sp2 = sp1 - popped

            if query == "hybrid" and not fast:
                sl_act = act & in_sl
                node = jnp.where(st_mode, st_node, jnp.where(sl_act, sl_node, node0))
                twice = jnp.where(st_mode, False, jnp.where(sl_act, sl_twice, twice0))
                shadow_now = (st_mode & st_shadow) | (sl_act & sl_shadow)
                lit_now = (st_mode & st_lit) | (sl_act & sl_lit)
                sl_new = jnp.where(act, in_sl | switch, sl0)
            else:
                node = jnp.where(st_mode, st_node, node0)
                twice = twice0
                shadow_now = st_mode & st_shadow
                lit_now = st_mode & st_lit
                sl_new = sl0
                if in_word:
                    node = jnp.where(shadow_now | lit_now, base + step_no + 1, node)
            word = _pack(node, twice, sl_new, ((w & SHADOW) != 0) | shadow_now,
                         done0 | shadow_now | lit_now)
            if fast:
                word = word | jnp.where(stall | (w < 0), STALL, 0)
            # stats word: sp (6 bits) | stack max << 6 (6 bits) | overflows << 12
            smax = jnp.maximum((st_word >> 6) & 63, jnp.where(st_mode, sp1, 0))
            new_sp = jnp.where(st_mode, sp2, sp)
            extra_count = lost if query == "stack" else switch
            stats = new_sp | (smax << 6) | (((st_word >> 12) + extra_count) << 12)
            if fast and in_word:        # a stalling lane's visits so far, in its count field
                stats = jnp.where(stall, (stats & 4095) | ((base + step_no) << 12), stats)
            out = dict(s, word=word, stack=stack, stats=stats)
            if not in_word:
                out["visited"] = visited
            if query == "hybrid" and not fast:
                out["ret"] = jnp.where(switch, n, s["ret"])
            return out

        return jax.lax.fori_loop(0, steps, step, state)

    def run(state, tree, pts, scale, key, light, tol, steps, base):
        # Lanes run in tiles of at most TILE (a loop over tiles, each running all
        # ``steps``), so that a tile's state and stack stay in cache during its steps.
        b = pts.shape[0]
        t = tile_size(b)
        px, py, pz = pts[:, 0], pts[:, 1], pts[:, 2]
        if t == b:
            return run_tile(state, tree, px, py, pz, scale, key, light, tol, steps, base)

        def tile(i, st):
            # A tile's inputs and state are sliced out (the state written back); its stack
            # levels are addressed in place at the tile's offset (STACK_IN_PLACE), as
            # copying them out and back cost 39 of a 32-step chunk's 277 ms at 1M lanes.
            in_place = {"stack"} & set(st) if STACK_IN_PLACE else set()
            width = {name: (k + 1) * t if name == "stack" else t for name in st}
            sub = {name: v if name in in_place else
                   jax.lax.dynamic_slice_in_dim(v, i * width[name], width[name])
                   for name, v in st.items()}
            cut = functools.partial(jax.lax.dynamic_slice_in_dim, start_index=i * t,
                                    slice_size=t)
            sub = run_tile(sub, tree, cut(px), cut(py), cut(pz), cut(scale), cut(key), light,
                           tol, steps, base, i * width["stack"] if in_place else 0)
            return {name: v if name in in_place else
                    jax.lax.dynamic_update_slice_in_dim(st[name], v, i * width[name], 0)
                    for name, v in sub.items()}

        return jax.lax.fori_loop(0, b // t, tile, state)

    return jax.jit(run, donate_argnums=0)


TILE = 32768
#: The stack query's tiles address their stack levels in the whole buffer (at the tile's
#: offset) instead of copying a tile's levels out and back per chunk: the chunk kernels
#: 0.85-0.88x for psv / d_psv on sphere_grid, 0.95-0.98x for d_hybrid; the same results
#: (docs/psv.md, "The stack stays in place across tiles";
#: docs/repro/psv_stack_in_place_ab.py).
STACK_IN_PLACE = True
#: Smallest lane bucket of a query (see :func:`run_query`). Every bucket is a compiled
#: chunk and compaction kernel; below 1024 lanes a chunk costs far less than compiling
#: another size (the 256-1024 tail had 8 more sizes per query configuration: 32 % more
#: compiles for PSV, 52 % for D-Hybrid on fuzzy at 64x64; the same chunks and results).
MIN_LANES = 1024
#: Up to this many lanes the buckets are powers of two; above it, 4 sizes per octave.
#: A small bucket's chunk costs little next to compiling its kernels, so padding it by
#: up to 2x costs less than 3 more sizes per octave (docs/psv.md, "Lane buckets").
COARSE_LANES = 8192


def lane_bucket(n: int) -> int:
    """The compiled lane count of a query or compaction holding ``n`` lanes."""
    n = max(int(n), 1)
    return bucket(n, minimum=MIN_LANES, steps=1 if n <= COARSE_LANES else 4)


BARRIER = True
#: Per query: keep no visit counter array, but a finished lane's count in its state
#: word's node field. A lane that finishes at step ``i`` of the query has visited
#: ``i + 1`` nodes (every lane runs from step 0; only the hybrid's stack-only step idles
#: lanes, so the hybrid does this only until its first stall: ``HYBRID_FAST_IN_WORD``).
#: One loop output fewer: the stack query's kernels
#: 0.88-0.91x; the stackless query's 0.94-0.95x but 1.08x on fuzzy, so it keeps its
#: array (docs/psv.md, "Visit counts in the state word"; docs/repro/psv_visits_ab.py).
VISITS_IN_WORD = {"stack": True, "stackless": False, "hybrid": False}
#: The hybrid's stack-only step (``fast``) keeps counts in the word too until the query's
#: first stall (then the array takes over; docs/psv.md, "Visit counts in the state word").
HYBRID_FAST_IN_WORD = True
# Node layout per query: packed [N, 8] rows (stack queries: the row gather costs half of
# eight 1D gathers there) or one 1D array per field (stackless: 2.6x faster so; measured).
ROWS = {"stack": True, "hybrid": True, "stackless": False}


def _barrier(x):
    return jax.lax.optimization_barrier(x) if BARRIER else x


def _as_int(v):
    """int32 node index stored bit-cast in a float row (see :func:`node_arrays`)."""
    it = jnp.int64 if v.dtype == jnp.float64 else jnp.int32
    return jax.lax.bitcast_convert_type(v, it).astype(jnp.int32)


def tile_size(b: int) -> int:
    """Lanes per tile of a bucket of ``b`` lanes: the largest power of two <= TILE that
    divides ``b`` (``b`` itself when ``b <= TILE``)."""
    if b <= TILE:
        return b
    t = TILE
    while b % t:
        t //= 2
    return t


NODE_MASK = (1 << 27) - 1
TWICE, SL, SHADOW, DONE = 1 << 27, 1 << 28, 1 << 29, 1 << 30
STALL = np.int32(np.iinfo(np.int32).min)    # sign bit: hybrid lane waiting for the full step
MAX_STACK = 63          # the stats word keeps the stack pointer and maximum in 6 bits
COUNT_MAX = (1 << 19) - 1   # and a lane's overflow / switch count in bits 12-30
VISIT_LIMIT = NODE_MASK     # visits a finished lane's node field holds (VISITS_IN_WORD)
STALL_STEP_MAX = COUNT_MAX  # a stalled lane's step in its count field (HYBRID_FAST_IN_WORD)


def _pack(node, twice, sl, shadow, done):
    """The per-lane state word: node | twice | stackless mode | shadow | done bits."""
    return ((node & NODE_MASK) | (twice.astype(jnp.int32) << 27) | (sl.astype(jnp.int32) << 28)
            | (shadow.astype(jnp.int32) << 29) | (done.astype(jnp.int32) << 30))


def unpack_state(s: dict, lane_count: str) -> dict:
    """NumPy counters of a state (or of some of its lanes): done, shadow, visited
    (finished lanes only where the state holds no ``visited`` array), stack_pointer,
    stack_max and the stats word's per-lane count as ``lane_count`` ("overflows" for the
    stack query, "switches" for the hybrid)."""
    w = np.asarray(s["word"])
    done = (w & DONE) != 0
    out = {"done": done, "shadow": (w & SHADOW) != 0,
           "visited": np.asarray(s["visited"]) if "visited" in s
           else np.where(done, w & NODE_MASK, 0)}
    if "stats" in s:
        st = np.asarray(s["stats"])
        out["stack_pointer"] = st & 63
        out["stack_max"] = (st >> 6) & 63
        out[lane_count] = st >> 12
    return out


def wedge_words(tree: tt.TopTree) -> np.ndarray:
    """[N] tree dtype: the wedge field the query reads. The bound itself, or for a signed
    wedge (``tree.wedge_lo`` set) the interval [wedge_lo, wedge] packed in one word,
    each end rounded outward to half the dtype's width (``core.numerics.pack_interval``),
    so that the node row keeps its eight fields."""
    if tree.wedge_lo is None:
        return tree.wedge
    return pack_interval(tree.wedge_lo, tree.wedge, tree.plane.dtype)


def wedge_interval_as_queried(tree: tt.TopTree) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) [N]: the wedge interval the query tests, ``lo * dist - tol <= plane(p) <=
    hi * dist + tol`` (for a symmetric wedge lo = -wedge, the same test as
    ``|plane(p)| <= wedge * dist + tol``)."""
    if tree.wedge_lo is None:
        return -tree.wedge, tree.wedge
    return unpack_interval_np(wedge_words(tree))


def node_arrays(tree: tt.TopTree, rows: bool = True) -> tuple:
    """The query's node data.

    ``rows``: rows [N, 8] (plane a, b, c, d, wedge, extra, pos, inter; extra = depth at a
    volume's first node, cap bias bound at its cap; pos and inter bit-cast to the float
    dtype's bits, int32 or int64) and anc [C]. Otherwise one 1D array per field: a, b,
    c, d, wedge, pos, inter, extra [N] and anc [C]. The wedge field is
    :func:`wedge_words`.
    """
    n = tree.plane.shape[0]
    dt = tree.plane.dtype
    extra = np.zeros(n, dt)
    extra[0::4] = tree.depth
    extra[3::4] = tree.bound
    if not rows:
        return (tree.plane[:, 0].copy(), tree.plane[:, 1].copy(), tree.plane[:, 2].copy(),
                tree.plane[:, 3].copy(), wedge_words(tree), tree.pos, tree.inter, extra,
                tree.anc)
    it = np.int32 if dt == np.float32 else np.int64
    out = np.zeros((n, 8), dt)
    out[:, :4] = tree.plane
    out[:, 4] = wedge_words(tree)
    out[:, 5] = extra
    out[:, 6] = tree.pos.astype(it).view(dt)
    out[:, 7] = tree.inter.astype(it).view(dt)
    return out, tree.anc


_DEVICE_NODES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def device_node_arrays(tree: tt.TopTree, rows: bool) -> tuple:
    """:func:`node_arrays` as device arrays, kept as long as ``tree`` lives: a tree reused
    under a static light (``reuse_tree``) does not repack and copy its nodes on every
    call (at 1M triangles 4 M rows of 32 bytes). A rebuilt tree is a new object."""
    held = _DEVICE_NODES.setdefault(tree, {})
    if rows not in held:
        held[rows] = tuple(jnp.asarray(a) for a in node_arrays(tree, rows))
    return held[rows]


@functools.lru_cache(maxsize=None)
def _init_kernel(b: int, query: str):
    """Jitted: the query state of ``b`` lanes, the first ``live`` at node ``root``.

    ``word`` packs node and flags (see :func:`_pack`; where ``VISITS_IN_WORD``, a
    finished lane's node field holds its visit count, 0 for the lanes finished here),
    ``visited`` counts node visits (the other queries); the stack queries add ``stats``
    (stack pointer, maximum stack use, overflow or switch count) and ``stack``
    [(K + 1) * b], hybrid ``ret`` (the node it switched at).
    The stack buffer is passed in and donated, not cleared: a lane reads only the levels
    below its stack pointer, which it wrote itself, and the scratch row K, whose value
    it discards.
    """
    def init(live, root, stack):
        done = jnp.arange(b, dtype=jnp.int32) >= live
        s = {"word": jnp.where(done, 0, root) | (done.astype(jnp.int32) << 30)}
        if not VISITS_IN_WORD[query]:
            s["visited"] = jnp.zeros(b, jnp.int32)
        if query != "stackless":
            s.update(stack=stack, stats=jnp.zeros(b, jnp.int32))
        if query == "hybrid":
            s["ret"] = jnp.full(b, -1, jnp.int32)
        return s
    return jax.jit(init, donate_argnums=2)


@jax.jit
def _visits_to_array(word, stats, base):
    """(visited, stats) [B] of a hybrid state after stack-only chunks that kept visit
    counts in the word (``fast_in_word``): a finished lane's count from its node field,
    a stalled lane's from its count field (the step it stalled at), else ``base`` (every
    step so far visited one node); the count field cleared for the switch count."""
    visited = jnp.where((word & DONE) != 0, word & NODE_MASK,
                        jnp.where(word < 0, stats >> 12, base))
    return visited, stats & 4095


@functools.lru_cache(maxsize=None)
def _compact_kernel(nb: int, k: int, levels: int):
    """Jitted: lanes ``keep[:live]`` of every state array and of the per-lane inputs
    (points, scale, key) moved to the front of ``nb`` lanes; the rest are done.

    The stack (passed apart from the state; tile-major in its first (K + 1) * b
    entries) is written into ``dest`` (a buffer of the same size, donated), tile-major
    for ``nb`` lanes, and only the kept lanes' first ``levels`` levels (no kept lane's
    stack pointer is above ``levels``: the caller's bound; the levels above it and the
    scratch row are never read before written). (In place, within one buffer, XLA/CPU
    fuses the gather into the update and copies the whole buffer twice to do so.)
    """
    def compact(state, stack, dest, dev, keep, live):
        valid = jnp.arange(nb, dtype=jnp.int32) < live

        def g(a, i):
            return a.at[i].get(mode="promise_in_bounds")

        out = {name: g(v, keep) for name, v in state.items()}
        out["word"] = jnp.where(valid, out["word"], DONE)
        if stack is not None:
            b, size = state["word"].shape[0], dest.shape[0]
            t, t2 = tile_size(b), tile_size(nb)
            base = (keep // t) * ((k + 1) * t) + keep % t
            idx = (base.reshape(nb // t2, 1, t2)
                   + (jnp.arange(levels, dtype=jnp.int32) * t).reshape(1, levels, 1))
            moved = g(stack, idx)                                     # [nb / t2, levels, t2]
            if t2 == nb:                            # one tile: levels * nb leading entries
                out["stack"] = jax.lax.dynamic_update_slice(dest, moved.reshape(-1), (0,))
            else:       # t2 divides TILE, which divides the buffer's lanes (stack_buffer_size)
                assert size % ((k + 1) * t2) == 0
                out["stack"] = jax.lax.dynamic_update_slice(
                    dest.reshape(size // ((k + 1) * t2), k + 1, t2), moved, (0, 0, 0)).reshape(-1)
        pts, scale, key = dev
        return out, [g(pts, keep), g(scale, keep), jnp.where(valid, g(key, keep), jnp.inf)]
    return jax.jit(compact, donate_argnums=2)


_STACK_BUFFERS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _stack_buffers(tree: tt.TopTree) -> dict:
    """Spare stacks of the queries on ``tree``, {(K + 1) * lanes: [device int32 arrays]}:
    a query takes its two stacks (the one its lanes use and the one a compaction writes
    into) from here, or clears new ones, and puts them back when done, so that the
    queries of a reused tree (``reuse_tree``) neither clear nor allocate stacks (at 1M
    lanes and K = 32, 138 MB each, cleared in 40-55 ms). At most two per stack size
    and image size; they live as long as the tree."""
    return _STACK_BUFFERS.setdefault(tree, {})


def stack_buffer_size(b: int, k: int) -> int:
    """Entries of a stack buffer for a first bucket of ``b`` lanes and ``k`` levels: room
    for (K + 1) levels of ``b`` lanes, or of ``b`` rounded up to a multiple of TILE when
    the lanes run in tiles, so that every later bucket's tile-major layout divides it."""
    return (k + 1) * (b if b <= TILE else -(-b // TILE) * TILE)


def _take_stack(spare: dict, size: int):
    held = spare.get(size)
    return held.pop() if held else jnp.zeros(size, jnp.int32)


def _give_stack(spare: dict, buf) -> None:
    if buf is not None:
        held = spare.setdefault(buf.shape[0], [])
        if len(held) < 2:
            held.append(buf)


def _copy_levels(stack_pointer_max: int, k: int) -> int:
    """Stack levels a compaction copies: the kept lanes' largest stack pointer, rounded
    up to a power of two (few compiled sizes), at most ``k``; at least 1."""
    return min(k, 1 << max(int(stack_pointer_max) - 1, 0).bit_length())


SCHEDULES = ("adaptive", "fixed")


def chunk_lengths(chunk: int, schedule: str):
    """Node visits per lane of each query chunk: a generator primed with ``next()`` and
    then sent, after each chunk, whether the check after it compacted the lanes.

    ``fixed``: ``chunk`` every time. ``adaptive``: ``chunk`` first; ``chunk // 2`` (at
    least 1) after a compaction, since the bucket is then shrinking and a late check
    leaves finished lanes stepping in it; twice the last length (at most ``2 * chunk``)
    after a check that did not compact, so that a slow tail (a few lanes with thousands
    of visits) is checked less often. (A quarter after a compaction: more compactions,
    each costing more than the steps it saved; docs/psv.md.) A finished lane neither
    visits nor changes, so the lengths change the time and ``query_chunks``, never a
    result or another counter.
    """
    steps = chunk
    while True:
        compacted = yield steps
        if schedule == "adaptive":
            steps = max(chunk // 2, 1) if compacted else min(2 * steps, 2 * chunk)


def run_query(tree: tt.TopTree, points: np.ndarray, scale: np.ndarray, key: np.ndarray,
              light_h: np.ndarray, *, query: str, depth_test: bool, wedge: str,
              stack_size: int, stackless_cap: str = "paper", edge_tie: str = "inside",
              chunk: int = 32, schedule: str = "adaptive",
              lane_order: np.ndarray | None = None, timer: StageTimer | None = None) -> dict:
    """Locate every point in the tree.

    Args:
        points: [S, 3]; scale: [S] cap-bias scale; key: [S] depth keys
            (``top_tree.light_key``), any float dtypes (rounded once to the tree's);
            light_h: float64 [4].
        query: "stack" (PSV / D-PSV; a push onto a full stack is lost and counted),
            "stackless" (D-Stackless), "hybrid" (short stack, stackless when full).
        lane_order: int [S] permutation of the points: lane i locates point
            ``lane_order[i]`` (None: point order). A lane's result does not depend on
            its neighbours, so the order changes only which lanes share a tile.

    Returns:
        dict of NumPy arrays [S]: ``shadow`` bool, ``visited``, ``stack_max``,
        ``overflows``, ``switches`` (int32; zeros where not applicable); ``chunks``.

    Lanes run a chunk of node visits per kernel call (lengths from
    :func:`chunk_lengths`: ``chunk`` each with ``schedule="fixed"``); between calls the
    unfinished lanes are compacted into the smallest lane bucket (:func:`lane_bucket`:
    powers of two from ``MIN_LANES`` to ``COARSE_LANES``, 4 sizes per octave above)
    that holds them, when that is
    smaller than the current size. The schedule changes only the time: a finished lane
    neither visits nor changes state.
    """
    if schedule not in SCHEDULES:
        raise ValueError(f"schedule must be one of {SCHEDULES}; got {schedule!r}")
    tree.check_wedge(wedge)
    timer = timer if timer is not None else StageTimer()
    dt = tree.plane.dtype.type
    s_count = points.shape[0]
    k = max(stack_size, 1)
    tol = jnp.asarray(dt(tree.margin))
    if tree.plane.shape[0] > NODE_MASK + 1:
        raise CapacityError(f"PSV query: a TOP tree of {tree.plane.shape[0]:,} nodes; a lane's "
                            f"state word holds node ids below {NODE_MASK + 1:,} (about "
                            f"{(NODE_MASK + 1) // 4:,} casters): cull casters (options "
                            "face_culling, frustum_culling) or split the scene")
    with timer.stage("query_setup"):
        treeargs = device_node_arrays(tree, ROWS[query])
        light = jnp.asarray(light_h.astype(dt))
    kernel = _chunk_kernel(query, depth_test, wedge, stack_size, "lose", stackless_cap,
                           edge_tie, bool(light_h[3] == 0))
    out = {name: np.zeros(s_count, np.int32) for name in ("stack_max", "overflows", "switches")}
    n_chunks = 0
    with timer.stage("query_setup"):
        b = lane_bucket(s_count)
        if query != "stackless":        # the stack is addressed at int32 offsets
            check_int32(stack_buffer_size(b, k), f"PSV stack entries ({k + 1} per lane)",
                        "use a smaller stack_size or render fewer samples")
        if lane_order is None:
            lane_id = np.arange(s_count)
            src = (points, scale, key)
        else:
            lane_id = np.asarray(lane_order, np.intp)
            if lane_id.shape != (s_count,) or (s_count and (
                    lane_id.min() < 0 or lane_id.max() >= s_count
                    or np.bincount(lane_id, minlength=s_count).max() != 1)):
                raise ValueError(f"lane_order must be a permutation of the {s_count} "
                                 f"points; got shape {lane_id.shape}")
            src = (points[lane_id], scale[lane_id], key[lane_id])
        cur = [pad(src[0], b, dtype=dt), pad(src[1], b, dtype=dt),
               pad(src[2], b, np.inf, dtype=dt)]
        dev = [jnp.asarray(a) for a in cur]
        del cur
        live0 = s_count if tree.root >= 0 else 0
    with timer.stage("query_setup"):
        spare, stack, has_stack = {}, None, query != "stackless"
        if has_stack:
            spare = _stack_buffers(tree)
            stack = _take_stack(spare, stack_buffer_size(b, k))
    state = timer.run("query_setup", _init_kernel(b, query), jnp.int32(live0),
                      jnp.int32(max(tree.root, 0)), stack)
    fast = fast_word = None
    if query == "hybrid":
        fast = _chunk_kernel(query, depth_test, wedge, stack_size, "lose", stackless_cap,
                             edge_tie, bool(light_h[3] == 0), True)
        if HYBRID_FAST_IN_WORD:
            fast_word = _chunk_kernel(query, depth_test, wedge, stack_size, "lose",
                                      stackless_cap, edge_tie, bool(light_h[3] == 0), True, True)
    use_fast = fast is not None
    in_word_phase = fast_word is not None     # counts in the word (no stall yet)
    dest = None
    raw_fields = [name for name in state if name not in ("stack", "ret")]
    finished = {name: [] for name in ("ids", *raw_fields)}
    lengths = chunk_lengths(chunk, schedule)
    steps, base = next(lengths), 0
    while True:
        live = len(lane_id)
        if VISITS_IN_WORD[query] and base + steps > VISIT_LIMIT:
            raise CapacityError(f"PSV query: more than {VISIT_LIMIT:,} node visits per sample "
                                "(a finished lane keeps its visit count in its node field)")
        if in_word_phase and (not use_fast or base + steps > STALL_STEP_MAX):
            # a lane stalled (or a stall step would not fit its count field): counts
            # move into the array the other hybrid steps update
            visited, stats = timer.run("query_compact", _visits_to_array, state["word"],
                                       state["stats"], jnp.int32(base))
            state = dict(state, visited=visited, stats=stats)
            in_word_phase = False
        args = (state, treeargs, *dev, light, tol, jnp.int32(steps), jnp.int32(base))
        step_fn = (fast_word if in_word_phase else fast) if use_fast else kernel
        state = timer.run("query", step_fn, *args)
        base += steps
        n_chunks += 1
        with timer.stage("query_compact"):
            word = np.asarray(state["word"])[:live]
            done = (word & DONE) != 0
            if fast is not None:
                # The full hybrid step while some lane is stalled or in stackless mode.
                use_fast = not np.any(((word < 0) | ((word & SL) != 0)) & ~done)
            keep = np.flatnonzero(~done)
            nb = lane_bucket(len(keep))
            steps = lengths.send(bool(len(keep)) and nb < b)
            if len(keep) and nb >= b:
                continue
            # Keep the finished lanes' raw words (decoded once after the loop), then
            # move the others to the front.
            fin = np.flatnonzero(done)
            finished["ids"].append(lane_id.take(fin))
            for name in raw_fields:
                if name == "visited" and in_word_phase:       # counts in the node field
                    v = word & NODE_MASK
                else:
                    v = word if name == "word" else np.asarray(state[name])[:live]
                finished[name].append(v.take(fin))
            if len(keep) == 0:
                break
            lane_id = lane_id.take(keep)
            keep_pad = np.zeros(nb, np.int32)
            keep_pad[:len(keep)] = keep
            keep_d = jnp.asarray(keep_pad)
            levels = 0
            if has_stack:
                kept_stats = np.asarray(state["stats"])[:live].take(keep)
                levels = _copy_levels((kept_stats & 63).max(), k)
                if dest is None:
                    dest = _take_stack(spare, state["stack"].shape[0])
        # On the device: no host copy of the stack, no transfer back.
        rest = {name: v for name, v in state.items() if name != "stack"}
        old = state.get("stack")
        state, dev = timer.run("query_compact", _compact_kernel(nb, k, levels), rest, old, dest,
                               dev, keep_d, jnp.int32(len(keep)))
        dest = old                   # the next compaction writes into the stack it left
        b = nb
    _give_stack(spare, state.get("stack"))
    _give_stack(spare, dest)
    with timer.stage("query_compact"):
        # The finished lanes' words in sample order (every sample finished exactly once),
        # decoded in one pass.
        ids = np.concatenate(finished.pop("ids"))
        if len(ids) != s_count:             # the loop ends only when every lane finished
            raise RuntimeError(f"PSV query: {len(ids)} of {s_count} lanes recorded")
        raw = {}
        for name, parts in finished.items():
            raw[name] = np.empty(s_count, np.int32)
            raw[name][ids] = np.concatenate(parts)
        counts = unpack_state(raw, "switches" if query == "hybrid" else "overflows")
        out.update({name: counts[name] for name in
                    ("shadow", "visited", "stack_max", "overflows", "switches")
                    if name in counts})
    if has_stack and s_count and out["visited"].max() > COUNT_MAX:
        # a lane loses or switches at most once per visit, so below this its count is exact
        raise CapacityError(f"PSV query: a sample visited {int(out['visited'].max()):,} nodes; "
                            f"its stack overflow / switch count (at most one per visit) is "
                            f"kept in {31 - 12} bits of its state (at most {COUNT_MAX:,})")
    out["chunks"] = n_chunks
    return out


# --------------------------------------------------------------------------- methods

_COMMON = {
    "order": Option("random", "insertion order of the triangles: seeded random (the "
                    "papers), mesh order, or nearest-to-the-light first", allowed=tt.ORDERS),
    "seed": Option(0, "seed of the random insertion order", kind=int, minimum=0),
    "wedge": Option("conservative", "wedge optimization: 'conservative' (a provable bound: "
                    "max vertex distance to the plane / triangle distance to the light), "
                    "'signed' (the same bound kept per side of the plane, an interval: "
                    "fewer visits, a dearer node test; docs/psv.md), 'vertex' (the public "
                    "code's max vertex angle, not a bound for wide triangles), 'off'",
                    allowed=tt.WEDGES),
    "classify_ulps": Option(64, "classification margin in machine epsilons of the largest "
                            "coordinate: a triangle within it of a plane goes to the "
                            "intersection child (0 = the paper's plain sign test)",
                            kind=int, minimum=0),
    "face_culling": Option("averted", "cull the triangles of closed objects that face away "
                           "from the light ('averted': exact, the shared rule of "
                           "clustered_ptsv and cull_casters), or every caster whose winding "
                           "normal faces the light ('front', the papers' setting; exact only "
                           "for closed meshes) or faces away ('back'); 'none' culls nothing",
                           allowed=("averted", "none", "front", "back")),
    "frustum_culling": Option(False, "cull casters outside the convex hull of the view "
                              "frustum and the light (Mora et al. 2016)", allowed=(False, True)),
    "edge_tie": Option("inside", "a sample exactly on an edge plane is inside (as "
                       "brute_force) or outside", allowed=("inside", "outside")),
    "bias": Option("receiver", "self-shadowing bias (see brute_force)", allowed=BIAS_MODES),
    "build": Option("parallel", "'parallel' (JAX rounds) or 'sequential' (NumPy reference, "
                    "slow)", allowed=("parallel", "sequential")),
    "node_order": Option("auto", "numbering of the tree's shadow volumes for the query: "
                         "'breadth_first' from the root (the nodes near the root share "
                         "cache lines; the same visits, results and counters), 'build' "
                         "(insertion rank, as built) or 'auto' (breadth-first when "
                         "reuse_tree keeps the tree, as built otherwise)",
                         allowed=NODE_ORDERS),
    "chunk": Option(32, "node visits per lane before the first check for finished lanes "
                    "(and every chunk with chunk_schedule='fixed')", kind=int, minimum=1),
    "chunk_schedule": Option("adaptive", "lengths of the query chunks between checks for "
                             "finished lanes: 'adaptive' (chunk first, chunk/2 after a "
                             "compaction, doubling up to 2 x chunk while none happens) or "
                             "'fixed' (chunk every time). Results and every counter but "
                             "query_chunks do not depend on it", allowed=SCHEDULES),
    "lane_tile": Option(1, "query lanes in square pixel tiles of this side (lanes of a "
                        "tile are neighbours in memory and visit similar nodes); 1 = "
                        "row-major samples. Results and counters do not depend on it",
                        kind=int, minimum=1, maximum=64),
    "reuse_tree": Option(False, "keep the TOP tree for the next call with the same scene, "
                         "light and build options (a static light and geometry: the tree "
                         "depends on neither camera nor samples unless frustum_culling is "
                         "on, then on the camera too), with its queries' two stack "
                         "buffers (2 x 138 MB at 1M samples and stack_size 32); off: "
                         "every call builds, as the papers time a frame",
                         allowed=(False, True)),
}

#: options the TOP tree depends on (besides the scene, the light and the precision)
_TREE_OPTIONS = ("shadow_eps", "bias", "order", "seed", "wedge", "classify_ulps",
                 "face_culling", "frustum_culling", "build", "node_order")
#: per scene: (key, (tree, culled)) of the latest tree built with ``reuse_tree``
#: (``scene.caches.drop`` forgets it, as it forgets Embree's BVH)
_TREES = per_scene_cache()


def _tree_key(light, camera, dtype, o: dict) -> tuple:
    # the numbering the option resolves to: "auto" and "breadth_first" keep one tree
    key = (hard_light(light).homogeneous.astype(np.float64).tobytes(), np.dtype(dtype).str,
           *(o[k] for k in _TREE_OPTIONS if k != "node_order"),
           node_order_for(o["node_order"], o["reuse_tree"]))
    if o["frustum_culling"]:
        key += (np.asarray(camera.view_projection(), np.float64).tobytes(),)
    return key


def _run(name, scene, gbuf, light, *, query, depth_test, stack_size=0,
         stackless_cap="paper", **o):
    timer = StageTimer()
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
    light_h = hard_light(light).homogeneous
    with precision_mode(o["precision"]) as dtype:
        key = _tree_key(light, gbuf.camera, dtype, o) if o["reuse_tree"] else None
        held = _TREES.get(scene) if key is not None else None
        reused = held is not None and held[0] == key
        if reused:
            tree, culled = held[1]
            with timer.stage("casters"):
                scale = bias_scale(samples, light_h, cap_bias(scene, o["shadow_eps"]),
                                   o["bias"])
        else:
            tree, scale, culled = build_tree(
                scene, light, gbuf.camera, samples, dtype=dtype, shadow_eps=o["shadow_eps"],
                bias=o["bias"], order=o["order"], seed=o["seed"], wedge=o["wedge"],
                classify_ulps=o["classify_ulps"], face_culling=o["face_culling"],
                frustum_culling=o["frustum_culling"], build=o["build"],
                node_order=node_order_for(o["node_order"], o["reuse_tree"]), timer=timer)
            if key is not None:
                _TREES[scene] = (key, (tree, culled))
        with timer.stage("query_setup"):
            key = tt.light_key(samples.position, light_h)
            order = samples.tile_order(o["lane_tile"]) if o["lane_tile"] > 1 else None
        res = run_query(tree, samples.position, scale, key, light_h,
                        query=query, depth_test=depth_test, wedge=o["wedge"],
                        stack_size=stack_size, stackless_cap=stackless_cap,
                        edge_tie=o["edge_tie"], chunk=o["chunk"],
                        schedule=o["chunk_schedule"], lane_order=order,
                        timer=timer)
    t_out = time.perf_counter()
    shadow = res["shadow"]
    lit = samples.scatter(~shadow, fill=False)
    st = tree.stats()
    n = max(samples.count, 1)
    counters = {
        "samples": samples.count,
        "casters": int(tree.count),
        "culled_triangles": scene.num_triangles - int(tree.count),
        "shadowed": int(shadow.sum()),
        "lit": int(lit.sum()),
        "visited_nodes": int(res["visited"].sum()),
        "visited_nodes_mean": float(res["visited"].sum()) / n,
        "visited_nodes_per_pixel": samples.scatter(res["visited"], fill=0),
        "tree_nodes": st["tree_nodes"],
        "tree_depth": st["tree_depth"],
        "dropped_triangles": st["dropped_triangles"],
        "intersection_triangles": st["intersection_triangles"],
        "build_rounds": st["build_rounds"],
        "query_chunks": int(res["chunks"]),
        "tree_reused": int(reused),
    }
    if query != "stackless":
        counters.update({
            "stack_max": int(res["stack_max"].max(initial=0)),
            "stack_max_per_pixel": samples.scatter(res["stack_max"], fill=0),
        })
    if query == "stack":
        counters.update({
            "stack_overflows": int(res["overflows"].sum()),
            "overflow_pixels": int((res["overflows"] > 0).sum()),
            "stack_overflows_per_pixel": samples.scatter(res["overflows"], fill=0),
        })
    if query == "hybrid":
        counters.update({
            "stackless_switches": int(res["switches"].sum()),
            "stackless_switches_per_pixel": samples.scatter(res["switches"], fill=0),
        })
    timer.times["output"] = time.perf_counter() - t_out
    timings = dict(timer.times, total=timer.total)
    return ShadowResult(lit, counters, timings)


_STATIC = {"reuse_tree": True}
_STACK = {"stack_size": Option(32, "stack entries per sample (a push onto a full stack is "
                               "lost, as in the original; counted as an overflow)",
                               kind=int, minimum=1, maximum=MAX_STACK)}
_HSTACK = {"stack_size": Option(12, "short-stack entries per sample before switching to the "
                                "stackless query", kind=int, minimum=1, maximum=MAX_STACK)}
# What every TOP-tree method declares; the query adds its stack or switch counters.
_COUNTERS = ("samples", "casters", "culled_triangles", "shadowed", "lit", "visited_nodes",
             "visited_nodes_mean", "visited_nodes_per_pixel", "tree_nodes", "tree_depth",
             "dropped_triangles", "intersection_triangles", "build_rounds", "query_chunks",
             "tree_reused")
_STACK_COUNTERS = ("stack_max", "stack_max_per_pixel")
_OVERFLOW_COUNTERS = ("stack_overflows", "overflow_pixels", "stack_overflows_per_pixel")
_SWITCH_COUNTERS = ("stackless_switches", "stackless_switches_per_pixel")
_STAGES = ("samples", "casters", "build_setup", "build", "build_compact", "renumber",
           "query_setup", "query", "query_compact", "output")
_SLCAP = {"stackless_cap": Option("paper", "stackless query at a cap node with an "
                                  "intersection child: 'paper' descends into it (Algorithm 3), "
                                  "'public' never does (the public code; loses occluders)",
                                  allowed=("paper", "public"))}


@register("psv", doc="Partitioned Shadow Volumes: TOP tree, stack query (Gerhards et al. 2015)",
          paper="Gerhards et al. 2015, as in Mora et al. 2016 (Algorithm 1)",
          options={**_COMMON, **_STACK}, kind="exact", stages=_STAGES, frame="light", static_options=_STATIC,
          counters=_COUNTERS + _STACK_COUNTERS + _OVERFLOW_COUNTERS)
def psv(scene, gbuf, light, *, stack_size, **o):
    return _run("psv", scene, gbuf, light, query="stack", depth_test=False,
                stack_size=stack_size, **o)


@register("d_psv", doc="PSV stack query with the depth test (Mora et al. 2016)",
          paper="Mora et al. 2016 (Section 3.3)",
          options={**_COMMON, **_STACK}, kind="exact", stages=_STAGES, frame="light", static_options=_STATIC,
          counters=_COUNTERS + _STACK_COUNTERS + _OVERFLOW_COUNTERS)
def d_psv(scene, gbuf, light, *, stack_size, **o):
    return _run("d_psv", scene, gbuf, light, query="stack", depth_test=True,
                stack_size=stack_size, **o)


@register("d_stackless", doc="stackless TOP-tree query with ancestor links and depth test "
          "(Mora et al. 2016)", paper="Mora et al. 2016 "
          "(Algorithm 3)", options={**_COMMON, **_SLCAP}, kind="exact", stages=_STAGES,
          frame="light", static_options=_STATIC,
          counters=_COUNTERS)
def d_stackless(scene, gbuf, light, *, stackless_cap, **o):
    return _run("d_stackless", scene, gbuf, light, query="stackless", depth_test=True,
                stackless_cap=stackless_cap, **o)


@register("d_hybrid", doc="short-stack TOP-tree query switching to the stackless query "
          "when the stack is full, with depth test (Mora et al. 2016)",
          paper="Mora et al. 2016 (Section 3.5)",
          options={**_COMMON, **_HSTACK, **_SLCAP}, kind="exact", stages=_STAGES, frame="light", static_options=_STATIC,
          counters=_COUNTERS + _STACK_COUNTERS + _SWITCH_COUNTERS)
def d_hybrid(scene, gbuf, light, *, stack_size, stackless_cap, **o):
    return _run("d_hybrid", scene, gbuf, light, query="hybrid", depth_test=True,
                stack_size=stack_size, stackless_cap=stackless_cap, **o)
