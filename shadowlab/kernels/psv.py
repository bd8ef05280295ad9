"""PSV kernels: TOP-tree insertion (a thread per triangle, compare-and-swap on links)
and the PSV, D-PSV, D-Stackless and D-Hybrid queries (a thread per pixel, local stack).

The same tree layout and the same tests as ``shadowlab.structures.top_tree`` and
``shadowlab.methods.psv`` (docs/psv.md): shadow volume ``r`` owns nodes ``4r..4r+3``,
the negative child of node ``i`` is ``i + 1``, ``pos``/``inter`` hold the positive and
intersection links. See docs/kernels.md for the execution model and for which
counters depend on the schedule.

Floating point. The kernels of this file are compiled with ``fuse_fp=False`` (no
contraction of ``a * b + c`` into a fused multiply-add, ``--fmad=false`` on CUDA):

- the build classifies with non-contracted products and sums, exactly like the JAX
  build (which makes every product opaque to XLA's contraction), so both builds take
  the same branch at every node;
- the query's plane and wedge expressions are left to XLA in the JAX version, and XLA
  contracts them into FMAs on a CPU that has them. The kernel reproduces those FMAs
  explicitly (``fma`` argument; :func:`xla_contracts` probes whether XLA does), so
  both queries compute bit-identical plane values and take identical paths.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .runtime import init

wp.set_module_options({"fuse_fp": False, "enable_backward": False})

MAX_STACK = 64                       # the local stack's capacity (stack_size <= MAX_STACK)
QUERY_CODES = {"stack": 0, "stackless": 1, "hybrid": 2}
WEDGE_CODES = {"conservative": 0, "vertex": 1, "off": 2, "signed": 3}
STATUS_UNUSED, STATUS_MERGED, STATUS_DROPPED = 0, 1, 2

StackVec = wp.types.vector(length=MAX_STACK, dtype=wp.int32)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __fmaf_rn(a, b, c);
#else
return __builtin_fmaf(a, b, c);
#endif
""")
def fma32(a: wp.float32, b: wp.float32, c: wp.float32) -> wp.float32:
    """a * b + c rounded once (the fused multiply-add of the hardware)."""
    ...


# --------------------------------------------------------------------------- insertion

@wp.func
def _vertex_value(plane: wp.array2d(dtype=wp.float32), node: wp.int32,
                  verts: wp.array3d(dtype=wp.float32), r: wp.int32, v: wp.int32):
    # ((x a + y b) + z c) + d, every operation rounded (fuse_fp=False).
    return ((verts[r, v, 0] * plane[node, 0] + verts[r, v, 1] * plane[node, 1])
            + verts[r, v, 2] * plane[node, 2]) + plane[node, 3]


@wp.func
def _insert(r: wp.int32,
            plane: wp.array2d(dtype=wp.float32), verts: wp.array3d(dtype=wp.float32),
            key: wp.array(dtype=wp.float32), inv_dist: wp.array(dtype=wp.float32),
            inv_vdist: wp.array2d(dtype=wp.float32),
            margin: wp.float32, cap_extra: wp.float32, wedge_mode: wp.int32,
            root: wp.array(dtype=wp.int32), pos: wp.array(dtype=wp.int32),
            inter: wp.array(dtype=wp.int32), wedge: wp.array(dtype=wp.float32),
            wedge_lo: wp.array(dtype=wp.float32),
            depth: wp.array(dtype=wp.float32), anc: wp.array(dtype=wp.int32),
            level: wp.array(dtype=wp.int32), status: wp.array(dtype=wp.int32),
            cas_failures: wp.array(dtype=wp.int32)):
    """Insert the caster of rank r (Algorithm 2 of Mora et al. with CAS on the links)."""
    first = 4 * r
    # The first triangle to arrive becomes the root.
    node = root[0]
    if node == -1:
        node = wp.atomic_cas(root, 0, -1, first)
        if node == -1:
            level[r] = 0
            status[r] = STATUS_MERGED
            return
        wp.atomic_add(cas_failures, 0, 1)           # another thread was faster
    steps = wp.int32(0)
    last = wp.int32(-1)
    kr = key[r]
    neg_cap = -(margin + cap_extra)
    while True:
        sv = node >> 2
        wp.atomic_min(depth, sv, kr)
        steps += 1
        v0 = _vertex_value(plane, node, verts, r, 0)
        v1 = _vertex_value(plane, node, verts, r, 1)
        v2 = _vertex_value(plane, node, verts, r, 2)
        lo = wp.min(wp.min(v0, v1), v2)
        hi = wp.max(wp.max(v0, v1), v2)
        is_cap = (node & 3) == 3
        code = 2                                    # 0 positive, 1 negative, 2 intersection
        if is_cap:
            if hi < neg_cap:
                code = 1
            elif lo > margin:
                code = 0
        else:
            if lo > margin:
                code = 1
            elif hi < -margin:
                code = 0
        if code == 1:
            if is_cap:                              # entirely behind a cap: already shadow
                status[r] = STATUS_DROPPED
                return
            node = node + 1                         # the negative child
            continue
        if code == 2:
            last = node
            if not is_cap and wedge_mode != 2:
                cand = wp.float32(0.0)
                if wedge_mode == 1:                 # "vertex"
                    cand = wp.max(wp.max(wp.abs(v0) * inv_vdist[r, 0],
                                         wp.abs(v1) * inv_vdist[r, 1]),
                                  wp.abs(v2) * inv_vdist[r, 2])
                elif wedge_mode == 3:               # "signed": upper and lower end
                    cand = wp.max(wp.max(wp.max(v0, v1), v2), 0.0) * inv_dist[r]
                    wp.atomic_min(wedge_lo, node,
                                  wp.min(wp.min(wp.min(v0, v1), v2), 0.0) * inv_dist[r])
                else:                               # "conservative"
                    cand = wp.max(wp.max(wp.abs(v0), wp.abs(v1)), wp.abs(v2)) * inv_dist[r]
                wp.atomic_max(wedge, node, cand)
        # Links only ever change once, from -1 to a volume, so a plain read that sees a
        # volume is final; an empty slot is claimed with compare-and-swap.
        link = wp.int32(-1)
        if code == 2:
            link = inter[node]
            if link == -1:
                link = wp.atomic_cas(inter, node, -1, first)
                if link != -1:
                    wp.atomic_add(cas_failures, 0, 1)   # lost the race for the slot
        else:
            link = pos[node]
            if link == -1:
                link = wp.atomic_cas(pos, node, -1, first)
                if link != -1:
                    wp.atomic_add(cas_failures, 0, 1)   # lost the race for the slot
        if link == -1:                              # the empty slot is ours
            status[r] = STATUS_MERGED
            level[r] = steps
            anc[r] = last
            return
        node = link                                 # occupied: descend into its volume


@wp.kernel
def top_insert(plane: wp.array2d(dtype=wp.float32), verts: wp.array3d(dtype=wp.float32),
               key: wp.array(dtype=wp.float32), inv_dist: wp.array(dtype=wp.float32),
               inv_vdist: wp.array2d(dtype=wp.float32), rank_of_thread: wp.array(dtype=wp.int32),
               count: wp.int32, margin: wp.float32, cap_extra: wp.float32,
               wedge_mode: wp.int32, serial: wp.int32,
               root: wp.array(dtype=wp.int32), pos: wp.array(dtype=wp.int32),
               inter: wp.array(dtype=wp.int32), wedge: wp.array(dtype=wp.float32),
               wedge_lo: wp.array(dtype=wp.float32),
               depth: wp.array(dtype=wp.float32), anc: wp.array(dtype=wp.int32),
               level: wp.array(dtype=wp.int32), status: wp.array(dtype=wp.int32),
               cas_failures: wp.array(dtype=wp.int32)):
    """A thread per caster (``serial=1``: one thread inserting every rank in order)."""
    t = wp.tid()
    if serial != 0:
        for r in range(count):
            _insert(r, plane, verts, key, inv_dist, inv_vdist, margin, cap_extra, wedge_mode,
                    root, pos, inter, wedge, wedge_lo, depth, anc, level, status,
                    cas_failures)
    else:
        r = rank_of_thread[t]
        if r < count:
            _insert(r, plane, verts, key, inv_dist, inv_vdist, margin, cap_extra, wedge_mode,
                    root, pos, inter, wedge, wedge_lo, depth, anc, level, status,
                    cas_failures)


@wp.kernel
def own_depth(key: wp.array(dtype=wp.float32), status: wp.array(dtype=wp.int32),
              depth: wp.array(dtype=wp.float32)):
    """A merged volume's own triangle passes its first node."""
    r = wp.tid()
    if status[r] == STATUS_MERGED:
        depth[r] = wp.min(depth[r], key[r])


# --------------------------------------------------------------------------- queries

@wp.func
def _plane_value(plane: wp.array2d(dtype=wp.float32), n: wp.int32, px: wp.float32,
                 py: wp.float32, pz: wp.float32, fma: wp.int32):
    if fma != 0:                    # XLA's contraction: fma(z, c, fma(x, a, y * b)) + d
        return fma32(pz, plane[n, 2], fma32(px, plane[n, 0], py * plane[n, 1])) + plane[n, 3]
    return ((px * plane[n, 0] + py * plane[n, 1]) + pz * plane[n, 2]) + plane[n, 3]


@wp.kernel
def top_query(plane: wp.array2d(dtype=wp.float32), pos: wp.array(dtype=wp.int32),
              inter: wp.array(dtype=wp.int32), wedge: wp.array(dtype=wp.float32),
              wedge_lo: wp.array(dtype=wp.float32),
              depth: wp.array(dtype=wp.float32), anc: wp.array(dtype=wp.int32),
              bound: wp.array(dtype=wp.float32), root: wp.int32,
              pts: wp.array2d(dtype=wp.float32), scale: wp.array(dtype=wp.float32),
              key: wp.array(dtype=wp.float32), light: wp.vec4f, tol: wp.float32,
              query: wp.int32, depth_test: wp.int32, wedge_mode: wp.int32,
              stack_size: wp.int32, paper_cap: wp.int32, tie_inside: wp.int32,
              fma: wp.int32,
              shadow_out: wp.array(dtype=wp.int32), visited_out: wp.array(dtype=wp.int32),
              stack_max_out: wp.array(dtype=wp.int32), overflows_out: wp.array(dtype=wp.int32),
              switches_out: wp.array(dtype=wp.int32)):
    """One thread locates one sample; the stack lives in the thread's local memory.

    ``query``: 0 stack (PSV / D-PSV), 1 stackless (D-Stackless), 2 hybrid (D-Hybrid).
    Every loop iteration visits one node, exactly one step of the JAX query.
    """
    i = wp.tid()
    px = pts[i, 0]
    py = pts[i, 1]
    pz = pts[i, 2]
    dist = wp.float32(1.0)
    if light[3] != 0.0:
        dx = px - light[0]
        dy = py - light[1]
        dz = pz - light[2]
        if fma != 0:
            dist = wp.sqrt(fma32(dz, dz, fma32(dx, dx, dy * dy)))
        else:
            dist = wp.sqrt((dx * dx + dy * dy) + dz * dz)
    s = scale[i]
    k = key[i]
    stack = StackVec()
    node = root
    done = bool(root < 0)
    shadow = bool(False)
    twice = bool(False)
    visited = wp.int32(0)
    sp = wp.int32(0)
    stack_max = wp.int32(0)
    overflows = wp.int32(0)
    in_sl = bool(False)             # hybrid: running in stackless mode
    ret = wp.int32(-1)              # hybrid: the node where it switched
    switches = wp.int32(0)
    while not done:
        n = node
        sv = n >> 2
        is_cap = (n & 3) == 3
        off = _plane_value(plane, n, px, py, pz, fma)
        inside = False
        if is_cap:
            inside = off * s < bound[sv]
        elif tie_inside != 0:
            inside = off >= 0.0
        else:
            inside = off > 0.0
        pchild = pos[n]
        ichild = inter[n]
        has_i = ichild >= 0
        wedge_ok = True
        if not is_cap:
            if wedge_mode == 1:
                wedge_ok = wp.abs(off) < wedge[n] * dist
            elif wedge_mode == 0:
                lim = wp.float32(0.0)
                if fma != 0:
                    lim = fma32(wedge[n], dist, tol)
                else:
                    lim = wedge[n] * dist + tol
                wedge_ok = wp.abs(off) <= lim
            elif wedge_mode == 3:           # signed: lo * dist - tol <= off <= hi * dist + tol
                lim_hi = wp.float32(0.0)
                lim_lo = wp.float32(0.0)
                if fma != 0:
                    lim_hi = fma32(wedge[n], dist, tol)
                    lim_lo = fma32(wedge_lo[n], dist, -tol)
                else:
                    lim_hi = wedge[n] * dist + tol
                    lim_lo = wedge_lo[n] * dist - tol
                wedge_ok = off <= lim_hi and off >= lim_lo
        skip = depth_test != 0 and (n & 3) == 0 and k < depth[sv]
        a_link = anc[sv]
        visited += 1

        # ---- stackless transitions (D-Stackless; D-Hybrid in stackless mode)
        sl_inter_ok = wedge_ok
        if paper_cap == 0:
            sl_inter_ok = wedge_ok and not is_cap
        sl_desc = (not twice) and has_i and sl_inter_ok
        sl_node = n + 1
        if skip:
            sl_node = a_link
        elif sl_desc:
            sl_node = ichild
        elif not inside:
            if pchild >= 0:
                sl_node = pchild
            else:
                sl_node = a_link
        sl_twice = skip or ((not sl_desc) and (not inside) and pchild < 0)
        sl_shadow = (not skip) and (not sl_desc) and inside and is_cap
        sl_lit = sl_node < 0 and not sl_shadow

        # D-Hybrid back at the switch node with both visits done: resume the stack
        if query == 2 and in_sl and twice and n == ret:
            in_sl = False
        # D-Stackless, and D-Hybrid in stackless mode, take the stackless transition
        if query == 1 or (query == 2 and in_sl):
            node = sl_node
            twice = sl_twice
            if sl_shadow:
                shadow = True
                done = True
            if sl_lit:
                done = True
            continue
        want = (not skip) and has_i and wedge_ok and (not twice)
        switch = False
        sp1 = sp
        if want:
            if sp < stack_size:
                stack[sp] = ichild
                sp1 = sp + 1
            elif query == 2:
                switch = True
            else:
                overflows += 1          # lost: this intersection subtree is never visited
        stack_max = wp.max(stack_max, sp1)
        twice = False
        if switch:
            switches += 1
            in_sl = True
            ret = n
            node = ichild
            sp = sp1
        elif (not skip) and (not inside) and pchild >= 0:
            node = pchild
            sp = sp1
        elif (not skip) and inside and not is_cap:
            node = n + 1
            sp = sp1
        elif (not skip) and inside and is_cap:
            shadow = True
            done = True
            sp = sp1
        elif sp1 > 0:
            node = stack[sp1 - 1]
            sp = sp1 - 1
        else:
            done = True
            sp = sp1
    shadow_out[i] = wp.where(shadow, 1, 0)
    visited_out[i] = visited
    stack_max_out[i] = stack_max
    overflows_out[i] = overflows
    switches_out[i] = switches


# --------------------------------------------------------------------------- host side

_XLA_FMA: dict = {}


def xla_contracts(dtype=np.float32) -> bool:
    """Whether XLA on this machine contracts ``x*a + y*b`` into ``fma(x, a, y*b)``.

    The JAX query leaves contraction to XLA; the kernel must round the same way to take
    the same path at every node. Probed once per dtype with values where the fused and
    unfused results differ.
    """
    key = np.dtype(dtype).name
    if key not in _XLA_FMA:
        import jax
        import jax.numpy as jnp

        rng = np.random.default_rng(1)
        x = rng.standard_normal((4, 4096)).astype(dtype)
        f = jax.jit(lambda x: x[0] * x[1] + x[2] * x[3])
        got = np.asarray(f(jnp.asarray(x)))
        plain = x[0] * x[1] + x[2] * x[3]
        _XLA_FMA[key] = bool(np.any(got != plain))
    return _XLA_FMA[key]


def _arr(a, dtype, device):
    a = np.ascontiguousarray(a, dtype=dtype)
    return wp.array(a, dtype=wp.dtype_from_numpy(a.dtype), device=device)


def build_tree(inp, wedge: str = "conservative", schedule: str = "threads",
               thread_order: np.ndarray | None = None, device: str | None = None):
    """Build the TOP tree of ``inp`` (a ``top_tree.BuildInput``, float32) with the kernels.

    Args:
        schedule: ``"threads"`` launches a thread per caster (thread t inserts rank
            ``thread_order[t]``, default t); ``"serial"`` launches one thread inserting
            ranks 0, 1, ... in order (deterministic on any device).
        thread_order: a permutation of ranks over threads (emulates another arrival order).

    Returns:
        (``top_tree.TopTree``, stats dict with ``cas_failures``). On Warp's CPU backend a
        ``"threads"`` launch runs thread 0, 1, ... one after the other, so with the
        default order it is the serial schedule; the tree then equals
        ``top_tree.build_sequential`` and ``build_parallel`` node for node.
    """
    from ..structures import top_tree as tt

    dev = init(device)
    if inp.planes.dtype != np.float32:
        raise ValueError("the PSV kernels run in float32 (precision='float32')")
    c = inp.key.shape[0]
    n = 4 * c
    f32, i32 = np.float32, np.int32
    plane = _arr(inp.planes.reshape(n, 4), f32, dev)
    if thread_order is None:
        thread_order = np.arange(c)
    order = np.full(c, c, i32)
    order[: len(thread_order)] = thread_order
    outs = dict(
        root=wp.full(1, -1, dtype=wp.int32, device=dev),
        pos=wp.full(n, -1, dtype=wp.int32, device=dev),
        inter=wp.full(n, -1, dtype=wp.int32, device=dev),
        wedge=wp.full(n, -np.inf, dtype=wp.float32, device=dev),
        wedge_lo=wp.full(n, np.inf, dtype=wp.float32, device=dev),
        depth=wp.full(c, np.inf, dtype=wp.float32, device=dev),
        anc=wp.full(c, -1, dtype=wp.int32, device=dev),
        level=wp.full(c, -1, dtype=wp.int32, device=dev),
        status=wp.zeros(c, dtype=wp.int32, device=dev),
        cas_failures=wp.zeros(1, dtype=wp.int32, device=dev))
    key = _arr(inp.key, f32, dev)
    serial = schedule == "serial"
    if schedule not in ("threads", "serial"):
        raise ValueError(f"unknown schedule {schedule!r}; allowed: threads, serial")
    wp.launch(top_insert, dim=1 if serial else c, device=dev, inputs=[
        plane, _arr(inp.verts, f32, dev), key, _arr(inp.inv_dist, f32, dev),
        _arr(inp.inv_vdist, f32, dev), _arr(order, i32, dev), int(inp.count),
        f32(inp.margin), f32(inp.cap_extra), WEDGE_CODES[wedge], int(serial),
        *outs.values()])
    wp.launch(own_depth, dim=c, device=dev, inputs=[key, outs["status"], outs["depth"]])
    h = {k: v.numpy() for k, v in outs.items()}
    tree = tt.TopTree(inp.planes.reshape(n, 4).copy(), h["pos"], h["inter"], h["wedge"],
                      h["depth"], h["anc"], h["level"], h["status"], inp.tri.copy(),
                      inp.bound.copy(), int(h["root"][0]), inp.count, 1, inp.margin,
                      h["wedge_lo"] if wedge == "signed" else None)
    return tree, {"cas_failures": int(h["cas_failures"][0])}


def query(tree, points, scale, key, light_h, *, query: str, depth_test: bool, wedge: str,
          stack_size: int, stackless_cap: str = "paper", edge_tie: str = "inside",
          fma: bool | None = None, device: str | None = None) -> dict:
    """Locate every point with the query kernel (a thread per sample).

    Same arguments and results as ``methods.psv.run_query`` (without ``chunks``):
    dict of NumPy arrays [S]: ``shadow`` bool, ``visited``, ``stack_max``, ``overflows``,
    ``switches`` (int32). ``fma`` (default: :func:`xla_contracts`) rounds the plane
    and wedge expressions as XLA does.
    """
    dev = init(device)
    tree.check_wedge(wedge)
    if stack_size > MAX_STACK:
        raise ValueError(f"stack_size {stack_size} > the kernel's MAX_STACK {MAX_STACK}")
    if fma is None:
        fma = xla_contracts(np.float32)
    f32, i32 = np.float32, np.int32
    s = points.shape[0]
    outs = [wp.zeros(max(s, 1), dtype=wp.int32, device=dev) for _ in range(5)]
    if s:
        lh = light_h.astype(f32)
        # the interval as the JAX query reads it (a signed wedge's ends rounded outward)
        from ..methods.psv import wedge_interval_as_queried
        lo, hi = wedge_interval_as_queried(tree)
        wp.launch(top_query, dim=s, device=dev, inputs=[
            _arr(tree.plane, f32, dev), _arr(tree.pos, i32, dev), _arr(tree.inter, i32, dev),
            _arr(hi, f32, dev), _arr(lo, f32, dev), _arr(tree.depth, f32, dev), _arr(tree.anc, i32, dev),
            _arr(tree.bound, f32, dev), int(tree.root), _arr(points, f32, dev),
            _arr(scale, f32, dev), _arr(key, f32, dev), wp.vec4f(*lh), f32(tree.margin),
            QUERY_CODES[query], int(depth_test), WEDGE_CODES[wedge], int(stack_size),
            int(stackless_cap == "paper"), int(edge_tie == "inside"), int(bool(fma)), *outs])
    h = [o.numpy()[:s] for o in outs]
    return {"shadow": h[0].astype(bool), "visited": h[1], "stack_max": h[2],
            "overflows": h[3], "switches": h[4]}


# --------------------------------------------------------------------------- methods

METHODS = {"psv": ("stack", False), "d_psv": ("stack", True),
           "d_stackless": ("stackless", True), "d_hybrid": ("hybrid", True)}


def prepare(scene, gbuf, light, options: dict):
    """The inputs both versions share: samples, build input, per-sample scale and key.

    The build input is ``methods.psv.build_input`` itself (culling, bias, margin,
    insertion order), so the kernel build sees the JAX build's ``BuildInput``.
    """
    from ..methods import psv as psvm
    from ..structures import top_tree as tt
    from ..core.frame import view_samples
    from ..scene.view import hard_light

    samples = view_samples(gbuf, light)
    light_h = hard_light(light).homogeneous
    inp, scale, _ = psvm.build_input(
        scene, light, gbuf.camera, samples, dtype=np.float32,
        shadow_eps=options["shadow_eps"], bias=options["bias"], order=options["order"],
        seed=options["seed"], classify_ulps=options["classify_ulps"],
        face_culling=options["face_culling"], frustum_culling=options["frustum_culling"])
    key = tt.light_key(samples.position, light_h)
    return samples, inp, scale, key, light_h


def run(method: str, scene, gbuf, light, *, schedule: str = "threads", device=None,
        **options):
    """A PSV method run with the kernels: ``ShadowResult`` with the JAX method's counters.

    ``options`` are the registry options of ``method`` (defaults filled in the same way);
    ``precision`` must be float32; ``build`` and ``node_order`` are ignored (the kernel
    builds, and queries its tree as built: the numbering changes no counter). Counters
    are those of ``methods.psv`` except ``build_rounds`` and ``query_chunks`` (no rounds
    or chunks here; ``tree_reused`` is always 0: the kernel builds on every call), plus
    the kernel's ``cas_failures``; timings: ``build``, ``query``
    (seconds, compile excluded: the kernels are loaded before the clock starts).
    """
    import time

    from ..methods.registry import call_options
    from ..core.result import ShadowResult

    if method not in METHODS:
        raise ValueError(f"unknown PSV method {method!r}; allowed: {', '.join(METHODS)}")
    o = call_options(method, options)
    if o["precision"] != "float32":
        raise ValueError("the PSV kernels run in float32 only (precision='float32')")
    kind, depth_test = METHODS[method]
    stack_size = o.get("stack_size", 0)
    stackless_cap = o.get("stackless_cap", "paper")
    dev = init(device)
    load(dev)
    from ..core.frame import localize
    local = localize(scene, gbuf, light, "light")       # as methods.psv (frame="light")
    scene, gbuf, light = local.scene, local.gbuf, local.light
    samples, inp, scale, key, light_h = prepare(scene, gbuf, light, o)
    t0 = time.perf_counter()
    tree, bstats = build_tree(inp, o["wedge"], schedule=schedule, device=dev)
    t1 = time.perf_counter()
    res = query(tree, samples.position.astype(np.float32), scale.astype(np.float32),
                key.astype(np.float32), light_h, query=kind, depth_test=depth_test,
                wedge=o["wedge"], stack_size=stack_size, stackless_cap=stackless_cap,
                edge_tie=o["edge_tie"], device=dev)
    t2 = time.perf_counter()
    shadow = res["shadow"]
    lit = samples.scatter(~shadow, fill=False)
    st = tree.stats()
    n = max(samples.count, 1)
    counters = {
        "samples": samples.count, "casters": int(tree.count),
        "culled_triangles": scene.num_triangles - int(tree.count),
        "shadowed": int(shadow.sum()), "lit": int(lit.sum()),
        "visited_nodes": int(res["visited"].sum()),
        "visited_nodes_mean": float(res["visited"].sum()) / n,
        "visited_nodes_per_pixel": samples.scatter(res["visited"], fill=0),
        "tree_nodes": st["tree_nodes"], "tree_depth": st["tree_depth"],
        "dropped_triangles": st["dropped_triangles"],
        "intersection_triangles": st["intersection_triangles"],
        "cas_failures": bstats["cas_failures"],
        "tree_reused": 0,                    # the kernel builds on every call
    }
    if kind != "stackless":
        counters["stack_max"] = int(res["stack_max"].max(initial=0))
        counters["stack_max_per_pixel"] = samples.scatter(res["stack_max"], fill=0)
    if kind == "stack":
        counters["stack_overflows"] = int(res["overflows"].sum())
        counters["overflow_pixels"] = int((res["overflows"] > 0).sum())
        counters["stack_overflows_per_pixel"] = samples.scatter(res["overflows"], fill=0)
    if kind == "hybrid":
        counters["stackless_switches"] = int(res["switches"].sum())
        counters["stackless_switches_per_pixel"] = samples.scatter(res["switches"], fill=0)
    opts = dict(o, schedule=schedule)
    return ShadowResult(lit, counters, {"build": t1 - t0, "query": t2 - t1, "total": t2 - t0},
                        f"kernels.{method}", opts)


def load(device: str | None = None) -> None:
    """Compile (or load from the kernel cache) this file's kernels on ``device``."""
    wp.load_module(top_query.module, device=init(device))
