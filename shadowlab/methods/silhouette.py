"""``silhouette``: silhouette shadow volumes for arbitrary meshes (Pečiva 2013).

Per frame, every edge record of the scene's adjacency (welded by exact position, per
object or per scene, split into records of at most ``max_opposite`` opposite vertices;
``shadowlab.scene.adjacency``) gets a *multiplicity* m: the signed number of its
adjacent triangles on each side of the plane through the edge and the light. With the
paper's deterministic rule (Algorithms 1 and 2) each triangle's contribution is one
sign s_T computed once from its vertices in sorted (lexicographic) order, and an edge
adds it with the parity of its place in that order: (mid, hi) +1, (lo, hi) -1, (lo, mid)
+1. The side quad of an edge is extruded to infinity |m| times with the sign of m;
caps are the triangles themselves (front) and their projections to infinity (back).

The stencil is evaluated in software, exactly: for every view sample an integer count
of the signed crossings of its view ray with sides (and caps for ZFAIL), from the
predicates of ``shadowlab.engines.silhouette_stencil``. The lit mask is ``count == 0``.

Receiver bias (option ``bias``): the reference tests the segment from the cut point
q = p + eps / max(n.l, 1e-6) l to the light (lit if q lies beyond a point light), so
the count is evaluated at q, eye-relative: ZFAIL with true front caps counts the caps
behind q; ZPASS counts the sides between the eye and q and adds the front caps crossed
on that segment (nonzero only where q is hidden: a blocker within the cut, or a crease
next to the sample), which makes it exact at any q; ZFAIL with the caps at infinity
subtracts the same caps. ``bias="none"`` evaluates at the sample p itself with no caps
before it (a GPU's depth test against the sample: not exact, see the docs).

See docs/silhouette.md for the options, the paper's choices (``preset="paper"``) and
what each costs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import bucket, pad
from ..core.frame import cap_bias, precision_mode, view_samples
from ..core.numerics import cross3, opaque_multiplier, opaque_zero, ordered_dot
from ..core.result import ShadowResult
from ..core.timing import StageTimer
from ..engines.silhouette_bins import (batch_arrays, cap_shapes, clip_fins, farthest_depth,
                                      nearest_depth, sample_grid, screen_bins, side_planes,
                                      side_shapes)
from ..engines.silhouette_stencil import (binned_cap_kernel, binned_side_kernel, cap_kernel,
                                          cap_table, edge_table, side_kernel, vertex_terms)
from ..geometry.caster_culling import front_face_culled
from ..geometry.clip_visibility import CULL_MODES, side_visible
from ..geometry.triangle_setup import shadow_volume_planes
from ..scene.view import PointLight, hard_light
from .registry import Option, register

MULTIPLICITY = ("sorted", "unsorted", "planes")

#: the paper's own choices (``preset="paper"``): visibility test of Algorithms 3-6, front
#: cap at infinity (eq. 6) with ZFAIL, only exactly coplanar lights cull a triangle, and
#: the GPU's depth test against the sample itself (no receiver bias); and the general path
#: for arbitrary meshes, every triangle casting (its 2-manifold variant, GS2M, is the
#: default here: the same lit mask, half the casters of a closed object).
PAPER_PRESET = {"cull_sides": "paper", "front_cap": "infinity", "degenerate": "paper",
                "bias": "none", "manifold": "off"}


@jax.jit
def triangle_signs(lo, mid, hi, light):
    """Algorithm 2 per triangle: s_T int32 [T] and the cap terms [T, 4].

    lo, mid, hi [T, 3]: eye-relative vertices in sorted order; light [4] eye-relative.
    s_T = sgn(((hi - lo) x (L - L_w lo)) . (mid - lo)); cap terms: n_T = (mid - lo) x
    (hi - lo) and n_T . lo.
    """
    mul = opaque_multiplier(opaque_zero(light))
    lw = light[3]
    a = [lo[:, k] for k in range(3)]
    b = [mid[:, k] for k in range(3)]
    c = [hi[:, k] for k in range(3)]
    to_light = [light[k] - mul(lw, a[k]) for k in range(3)]
    n = cross3([c[k] - a[k] for k in range(3)], to_light, mul)
    v = ordered_dot(n, [b[k] - a[k] for k in range(3)], mul)
    nt = cross3([b[k] - a[k] for k in range(3)], [c[k] - a[k] for k in range(3)], mul)
    nlo = ordered_dot(nt, a, mul)
    return jnp.sign(v).astype(jnp.int32), jnp.stack([*nt, nlo], axis=1)


@jax.jit
def slot_signs_unsorted(a, b, o, light):
    """Per slot [R, K] the record's own evaluation -CompMult(A, O, B) (no sorting).

    a, b [R, 1, 3] record endpoints (A < B), o [R, K, 3] opposite vertices, eye-relative.
    """
    mul = opaque_multiplier(opaque_zero(light))
    lw = light[3]
    av = [a[..., k] for k in range(3)]
    to_light = [light[k] - mul(lw, av[k]) for k in range(3)]
    n = cross3([b[..., k] - av[k] for k in range(3)], to_light, mul)
    v = ordered_dot(n, [o[..., k] - av[k] for k in range(3)], mul)
    return -jnp.sign(v).astype(jnp.int32)


@jax.jit
def slot_signs_planes(a, b, o, light):
    """Per slot [R, K] the sign of the light against the normalised plane (A, B, O)."""
    mul = opaque_multiplier(opaque_zero(light))
    av = [a[..., k] for k in range(3)]
    n = cross3([b[..., k] - av[k] for k in range(3)], [o[..., k] - av[k] for k in range(3)],
               mul)
    d = -ordered_dot(n, av, mul)
    length = jnp.sqrt(ordered_dot(n, n, mul))
    safe = jnp.where(length > 0, length, 1)
    v = ordered_dot([x / safe for x in n], [light[k] for k in range(3)], mul) + \
        mul(light[3], d / safe)
    return jnp.sign(v).astype(jnp.int32)


def record_multiplicity(adj, s_t: np.ndarray, verts: np.ndarray, light, multiplicity: str
                        ) -> np.ndarray:
    """Algorithm 1: int32 [R], the multiplicity of every edge record.

    Args:
        adj: the scene's :class:`~shadowlab.scene.adjacency.Adjacency`.
        s_t: int32 [m] per scene triangle s_T (0 = casts nothing).
        verts: [V, 3] eye-relative welded vertices (working dtype).
        light: [4] eye-relative homogeneous light (working dtype).
        multiplicity: "sorted" (each slot adds parity * s_T: +1 for the opposite vertex
            below A or above B, -1 between them), "unsorted" or "planes" (each slot
            evaluates its own expression; slots of triangles with s_T = 0 add nothing).
    """
    tri_k, opp_k = adj.triangle, adj.opposite
    slot = tri_k >= 0
    rv = adj.record_vertices
    if multiplicity == "sorted":
        a_, b_ = rv[:, :1], rv[:, 1:]
        parity = np.where((a_ < opp_k) & (opp_k < b_), -1, 1)
        contrib = parity * s_t[np.maximum(tri_k, 0)]
    else:
        fn = slot_signs_unsorted if multiplicity == "unsorted" else slot_signs_planes
        contrib = np.asarray(fn(jnp.asarray(verts[rv[:, 0]][:, None]),
                                jnp.asarray(verts[rv[:, 1]][:, None]),
                                jnp.asarray(verts[np.maximum(opp_k, 0)]), jnp.asarray(light)))
        contrib = contrib * (s_t[np.maximum(tri_k, 0)] != 0)
    return np.where(slot, contrib, 0).sum(axis=1).astype(np.int32)


def eye_in_volumes(scene, eye: np.ndarray, light_h: np.ndarray, active: np.ndarray) -> int:
    """Number of active triangles whose shadow volume contains the eye (float64).

    The segment from the eye to a point light (the ray towards a directional light)
    crosses the triangle strictly inside (Möller-Trumbore in float64).
    """
    tri = scene.triangles[active]
    if len(tri) == 0:
        return 0
    if light_h[3]:
        d = light_h[:3] / light_h[3] - eye
        tmax = 1.0
    else:
        d = light_h[:3]
        tmax = np.inf
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = det != 0
    inv = 1.0 / np.where(ok, det, 1.0)
    s = eye - tri[:, 0]
    u = np.einsum("ij,ij->i", s, h) * inv
    qv = np.cross(s, e1)
    v = (qv @ d) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    hit = ok & (u > 0) & (v > 0) & (u + v < 1) & (t > 0) & (t < tmax)
    return int(hit.sum())


def silhouette(scene, gbuf, light, *, precision, shadow_eps, stencil, multiplicity, front_cap,
               manifold, adjacency, max_opposite, degenerate, bias, cull_sides, bins, chunk):
    zfail = stencil == "zfail"
    binned = bins == "screen"
    timer = StageTimer()
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
    cam = gbuf.camera
    eye = np.asarray(cam.eye, np.float64)
    lh = hard_light(light).homogeneous
    point = isinstance(hard_light(light), PointLight)
    m_tri = scene.num_triangles
    with precision_mode(precision) as dtype:
        with timer.stage("adjacency"):
            adj = scene.adjacency(adjacency, max_opposite, dtype)
        with timer.stage("setup"):
            light_rel = np.append(lh[:3] - lh[3] * eye, lh[3]).astype(dtype)
            verts = (adj.positions.astype(np.float64) - eye).astype(dtype)
            faces = adj.faces
            srt = np.sort(faces, axis=1)
            t_cap = bucket(m_tri, minimum=chunk)
            lo, mid, hi = (pad(verts[srt[:, k]], t_cap, dtype=dtype) for k in range(3))
            light_j = jnp.asarray(light_rel)
        s_t, cap_terms = timer.run("multiplicity", triangle_signs, jnp.asarray(lo),
                                   jnp.asarray(mid), jnp.asarray(hi), light_j)
        planes, valid = timer.run("setup", shadow_volume_planes,
                                  jnp.asarray(pad(scene.triangles, t_cap, dtype=dtype)),
                                  jnp.asarray(lh.astype(dtype)))
        with timer.stage("multiplicity"):
            s_t = np.asarray(s_t)[:m_tri].copy()
            active = adj.kept & (s_t != 0)
            if degenerate == "cull":
                active &= np.asarray(valid)[:m_tri]
            face_culled = 0
            if manifold == "closed":
                # the shared exact rule (closed objects' light-averted triangles, none of
                # an object around the light); any subset of casters keeps the silhouette
                # a closed cycle, since a triangle's three edges share its s_T
                averted = front_face_culled(scene, lh, "averted")
                face_culled = int((active & averted).sum())
                active &= ~averted
            s_t = np.where(active, s_t, 0).astype(np.int32)
            m_rec = record_multiplicity(adj, s_t, verts, light_j, multiplicity)
            sil = np.flatnonzero(m_rec)
        vt = timer.run("setup", vertex_terms, jnp.asarray(verts), light_j)
        ev = adj.edge_vertices
        etable = timer.run("setup", edge_table, jnp.asarray(verts[ev[:, 0]]),
                           jnp.asarray(verts[ev[:, 1]]), vt[ev[:, 0]], vt[ev[:, 1]], light_j)
        etable = np.asarray(etable)
        # the visibility test of the sides (Algorithms 3-6 or the exact pyramid test)
        with timer.stage("visibility"):
            rec_edge = adj.record_edge[sil]
            if cull_sides != "off" and len(sil):
                vis = side_visible(adj.positions.astype(np.float64)[ev[rec_edge, 0]],
                                   adj.positions.astype(np.float64)[ev[rec_edge, 1]],
                                   lh, cam, cull_sides)
            else:
                vis = np.ones(len(sil), bool)
            culled = int((~vis).sum())
            drawn = sil[vis]
            # one padding row at least: the binned pass reads it past a list's end
            r_cap = bucket(len(drawn) + 1, minimum=chunk)
            table = pad(etable[adj.record_edge[drawn]], r_cap, dtype=dtype)
            m_pad = pad(m_rec[drawn], r_cap, dtype=np.int32)
            w_pad = np.abs(m_pad).astype(np.int32)
        # evaluation points
        with timer.stage("bias"):
            eps = cap_bias(scene, shadow_eps)
            p, n = samples.position, samples.normal
            l_hat, dist = hard_light(light).to_light(p)
            # per coordinate column, in the order of einsum("ij,ij->i", n, l_hat) and of
            # the row-wise p + cut l_hat - eye (the same bits, no [S, 3] temporaries)
            cut = eps / np.maximum(n[:, 0] * l_hat[:, 0] + n[:, 1] * l_hat[:, 1]
                                   + n[:, 2] * l_hat[:, 2], 1e-6)
            beyond_light = cut >= dist if point else np.zeros(samples.count, bool)
            at_q = bias in ("receiver", "receiver_visible")
            q_pad = np.zeros((samples.capacity, 3), dtype)
            for k in range(3):
                q_pad[: samples.count, k] = ((p[:, k] + cut * l_hat[:, k]) if at_q
                                             else p[:, k]) - eye[k]
            q_rel = jnp.asarray(q_pad)
        zero = opaque_zero(light_j, jnp.int32)
        q_host = q_pad[: samples.count]

        def per_sample(x):
            """int64 [S] host counts of a kernel's padded per-sample output [S']."""
            return np.asarray(x)[: samples.count].astype(np.int64)
        basis = cam.basis()
        eps_w = float(np.finfo(dtype).eps)
        clipped_sides = 0
        if binned:
            with timer.stage("stencil_bins"):
                grid = sample_grid(q_host, basis, samples.shape)
                q_blocks = jnp.asarray(grid.q)
                slot = jnp.asarray(samples.padded(grid.slot, np.int32))
        if binned and len(drawn):
            with timer.stage("stencil_bins"):
                ends = [verts[ev[adj.record_edge[drawn], k]] for k in range(2)]
                shapes = side_shapes(*ends, light_rel, eps_w, *grid.q_len_range)
                near = planes = None
                if not zfail:       # crossings before q only: cut by depth, fins clipped
                    near = nearest_depth(shapes[0][0], basis, directions=2)
                    planes = side_planes(*ends, light_rel, eps_w, grid.q_len_range[1])
                    shape, clipped = clip_fins(shapes[0], grid, basis, eps_w)
                    shapes, clipped_sides = [shape], int(clipped.sum())
                sb = screen_bins(grid, shapes, eps_w, basis, near, planes=planes)
                args = batch_arrays(grid, sb)
            sten, upd = timer.run("stencil", binned_side_kernel(zfail), q_blocks,
                                  *map(jnp.asarray, args), jnp.asarray(table),
                                  jnp.asarray(m_pad), jnp.asarray(w_pad), zero, slot)
            side_tests = sb.tests
        else:
            sten, upd = timer.run("stencil", side_kernel(chunk, zfail), q_rel,
                                  jnp.asarray(table), jnp.asarray(m_pad), jnp.asarray(w_pad),
                                  zero)
            side_tests = samples.count * len(drawn)
        sten, upd = (per_sample(x) for x in (sten, upd))
        cap_triangles = 0
        # caps: ZFAIL draws them; at the cut point q, the caps between the eye and q
        # (nonzero only where q is hidden) complete ZPASS and the caps at infinity
        passes = []
        if zfail:
            back = bool(point and lh[3] > 0)
            if front_cap == "infinity":
                passes.append(("eye_ray", back, 1, True))
            else:                   # true caps (depth cut beyond q) and back caps apart
                passes.append(("behind", False, 1, True))
                if back:
                    passes.append(("none", True, 1, True))
            cap_triangles = int((s_t != 0).sum()) * (2 if point else 1)
        if bias == "receiver" and (not zfail or front_cap == "infinity"):
            passes.append(("front", False, -1, False))
        cap_tests = 0
        cap_crossings = np.zeros(samples.count, np.int64)
        if passes:
            with timer.stage("caps"):
                keep = np.flatnonzero(s_t != 0)
                tri_edges = _triangle_edges(adj, srt)[keep]
                terms = np.asarray(cap_terms)[keep]
                # one zero-sign row at least: the binned pass reads it past a list's end
                k_cap = bucket(len(keep) + 1, minimum=chunk)
                signs = jnp.asarray(pad(s_t[keep], k_cap, dtype=np.int32))
        for span, back, factor, drawn_caps in passes:
            with timer.stage("caps"):
                rows = jnp.asarray(pad(cap_table(etable, tri_edges, terms, span, back),
                                       k_cap, dtype=dtype))
            if binned and len(keep):
                with timer.stage("caps_bins"):
                    shapes = cap_shapes(verts[srt[keep]], light_rel[:3] if back else None)
                    if span == "none":
                        shapes = shapes[1:]                 # the back caps' shape only
                    near = nearest_depth(shapes[0][0], basis) if span == "front" else None
                    far = farthest_depth(shapes[0][0], basis) if span == "behind" else None
                    sb = screen_bins(grid, shapes, eps_w, basis, near, far)
                    args = batch_arrays(grid, sb)
                cs, cu = timer.run("caps", binned_cap_kernel(span, back), q_blocks,
                                   *map(jnp.asarray, args), rows, signs, zero, slot)
                cap_tests += sb.tests
            else:
                cs, cu = timer.run("caps", cap_kernel(chunk, span, back), q_rel, rows,
                                   signs, zero)
                cap_tests += samples.count * len(keep)
            cs, cu = (per_sample(x) for x in (cs, cu))
            # the kernel counts exits; caps crossed before q are entries of the ZPASS
            # count, and the part of the caps at infinity that a true cap would not draw
            sten = sten + factor * cs
            cap_crossings = cap_crossings + cu
            if drawn_caps:
                upd = upd + cu
        n_eye = 0
        if not zfail:
            with timer.stage("eye"):
                n_eye = eye_in_volumes(scene, eye, lh, active)
            sten = sten + n_eye
        count = sten
    shadow = (count != 0) & ~beyond_light
    lit = samples.scatter(~shadow, fill=False)
    casters = int(active.sum())
    rep = adj.report
    counters = {
        "samples": samples.count, "casters": casters, "culled_triangles": m_tri - casters,
        "front_face_culled": face_culled, "edges": rep.records,
        "open_edges": rep.open_edges,
        "nonmanifold_edges": rep.nonmanifold_edges,
        "silhouette_edges": int(len(sil)), "side_quads": int(np.abs(m_rec).sum()),
        "culled_sides": culled, "clipped_sides": clipped_sides,
        "cap_triangles": int(cap_triangles),
        "stencil_updates": int(upd.sum()),
        "stencil_updates_per_pixel": samples.scatter(upd, fill=0),
        "side_tests": int(side_tests), "cap_tests": int(cap_tests),
        "cap_crossings_per_pixel": samples.scatter(cap_crossings, fill=0),
        "negative_stencil": int((count < 0).sum()),
        "eye_in_volumes": int(n_eye),
        "shadowed": int(shadow.sum()), "lit": int(lit.sum()),
    }
    return ShadowResult(lit, counters, dict(timer.times, total=timer.total))


def _triangle_edges(adj, srt: np.ndarray) -> np.ndarray:
    """int [m, 3]: the edge index of each triangle's sorted edges (lo, mid), (mid, hi),
    (lo, hi) (-1 for skipped triangles)."""
    counts = adj.edge_count.astype(np.int64)
    entry_edge = np.repeat(np.arange(len(counts)), counts)
    t = adj.entry_triangle.astype(np.int64)
    o = adj.entry_opposite
    slot = np.where(o == srt[t, 2], 0, np.where(o == srt[t, 0], 1, 2))
    out = np.full((len(srt), 3), -1, dtype=np.int64)
    out[t, slot] = entry_edge
    return out


register(
    "silhouette",
    doc="silhouette shadow volumes for arbitrary meshes: per-edge multiplicity, sides "
        "extruded |m| times, caps, exact software stencil (ZPASS/ZFAIL)",
    paper="Pečiva 2013", kind="exact", presets={"paper": PAPER_PRESET},
    counters=("samples", "casters", "culled_triangles", "front_face_culled", "edges",
              "open_edges", "nonmanifold_edges", "silhouette_edges", "side_quads",
              "culled_sides", "clipped_sides",
              "cap_triangles", "stencil_updates", "stencil_updates_per_pixel",
              "side_tests", "cap_tests", "cap_crossings_per_pixel", "negative_stencil",
              "eye_in_volumes", "shadowed", "lit"),
    stages=("samples", "adjacency", "setup", "multiplicity", "visibility", "bias",
            "stencil_bins", "stencil", "caps_bins", "caps", "eye"),
    options={
        "stencil": Option("zpass", "stencil counting: 'zpass' (crossings between the eye and "
                          "the sample, started at the eye's count) or 'zfail' (crossings "
                          "behind the sample, with caps)", allowed=("zpass", "zfail")),
        "multiplicity": Option("sorted", "edge multiplicity: 'sorted' (the paper's "
                               "deterministic rule), 'unsorted' or 'planes' (the per-slot "
                               "evaluations that leak)", allowed=MULTIPLICITY),
        "front_cap": Option("true", "ZFAIL front cap: 'true' (the triangle) or 'infinity' "
                            "(moved to the far plane, eq. 6)", allowed=("true", "infinity")),
        "manifold": Option("closed", "'closed': closed objects cast from their "
                           "light-facing triangles only (the 2-manifold fast path, the "
                           "shared exact averted culling; objects around a point light keep "
                           "every triangle); 'off': every triangle casts (the paper's "
                           "general path)", allowed=("off", "closed")),
        "adjacency": Option("object", "edge adjacency per 'object' (as the paper's buffers) "
                            "or across the 'scene'", allowed=("object", "scene")),
        "max_opposite": Option(2, "opposite vertices per edge record (longer edges are "
                               "split)", kind=int, minimum=1, maximum=64),
        "degenerate": Option("cull", "'cull': triangles the setup finds degenerate or "
                             "edge-on cast nothing (as brute_force); 'paper': only an "
                             "exactly coplanar light (sign 0) culls",
                             allowed=("cull", "paper")),
        "bias": Option("receiver", "'receiver': the count at the reference's cut point "
                       "(exact); 'receiver_visible': the same without the caps between the "
                       "eye and that point (exact only where it is visible; a GPU's cost); "
                       "'none': the count at the sample itself (a GPU's depth test)",
                       allowed=("receiver", "receiver_visible", "none")),
        "cull_sides": Option("off", "visibility test of the sides: 'off', 'paper' "
                             "(Algorithms 3-6) or 'exact' (view pyramid, corrected)",
                             allowed=CULL_MODES),
        "bins": Option("screen", "which sides and caps each sample tests: 'screen' (those "
                       "whose padded screen box holds its point, from per-cell lists; the "
                       "same counts) or 'off' (all of them)", allowed=("screen", "off")),
        "chunk": Option(16, "records per unrolled loop step", allowed=(4, 8, 16, 32)),
    })(silhouette)
