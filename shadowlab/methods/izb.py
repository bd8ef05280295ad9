"""``izb``: frustum-traced irregular z-buffer with the conservative z-prepass (exact).

Wyman et al. 2015/2016 (the IZB) and Tokuyoshi and Mizokuchi 2018 (the conservative
shadow-map prepass); see docs/izb.md. One frame:

1. **Light space.** The light camera is fitted to the view samples (orthographic for a
   directional light, a perspective face or a cube for a point light); every sample
   gets its texel (one texel function) and its depth ``delta(p)``.
2. **CSM prepass** (``prepass="csm"``). Casters in front of the light are rasterized
   inner-conservatively (``coverage``: the poster's four corners or Hertel et al.'s
   circumscribed circle) over the texels holding samples; a fully covered texel keeps
   the smallest conservative depth (``csm_depth``: the plane's farthest corner over the
   texel, or the poster's slope-scaled bias of 1). A sample whose receiver-biased point
   q (the point the exact test uses, on the ray from p to the light) lies beyond that
   depth is surely shadowed: it is written shadowed and not inserted.
3. **List build.** The remaining samples are sorted into per-texel lists (CSR; the
   capacity is the exact node count) and each list keeps the depth of its farthest node.
4. **Frustum tracing.** Every caster is rasterized outer-conservatively over the
   non-empty texels; a fragment whose nearest depth over the texel is not in front of
   the farthest node is culled; the others test every node of their list with the exact
   per-sample test of every exact method (the canonical shadow-volume planes and the
   receiver bias), in the working precision.

The light-space bookkeeping (texels, coverage, depth bounds) is float64 and widened by
margins that cover the working precision's rounding, so it only decides *which* pairs
are tested; every shadow decision is the exact test (or the prepass's conservative
cull). ``verify`` re-tests every culled sample against every caster (counter
``csm_false_shadows``, which must be 0).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import bucket, pad
from ..core.frame import caster_terms, cap_bias, precision_mode, view_samples
from ..core.numerics import max_abs, norms3
from ..core.sorting import stable_argsort
from ..core.result import ShadowResult
from ..core.timing import StageTimer
from ..geometry.caster_culling import without_culled_faces
from ..geometry.triangle_setup import shadow_volume_planes
from ..scene.view import hard_light
from ..structures import light_raster as lr
from .brute_force import _test_kernel
from .interface import MethodError
from .registry import Option, register
from .shadow_map import PROJECTIONS, fit_camera

PREPASSES = ("none", "csm")
RESOLUTIONS = (256, 512, 1024, 2048, 4096, 8192)
CSM_DEPTHS = ("corner", "slope")
#: the poster's configuration: the method's ``preset="paper"``
PAPER_PRESET = {"prepass": "csm", "coverage": "corners", "csm_depth": "slope", "csm_scale": 1,
                "csm_min_area": 0.0, "front_face_culling": False}
#: most (triangle, node) pairs, padding included, tested in one call of the pair kernel
#: (a row wider than this runs alone)
PAIR_CHUNK = 1 << 20
#: the outer raster's triangle boxes are padded by this many outer margins tau (texels):
#: the outer test accepts a texel within tau of every edge, so a box wider than that only
#: adds texels beyond the triangle's box, which the per-edge test still passes near acute
#: corners and which hold no sample the triangle can shadow (docs/izb.md, "Tight boxes").
#: tau is at least the rounding margin (coverage_margin may be 0); where tau exceeds half
#: a texel (float32 far from the frame origin) the pad is wider than the one texel it
#: replaced, and the outer margin is then honoured in full
BOX_PAD_TAUS = 2.0
#: row capacities per octave of the pair kernel's last chunk of each width
#: (:func:`core.capacity.bucket`): above the 64-row minimum at most 1/5 of it is padding
ROW_BUCKET_STEPS = 4
#: the least light-space area (texels) of a triangle that can cover a texel fully: the
#: smallest triangle containing a unit square has area 2 (one containing the texel's
#: circumscribed circle, 3 sqrt(3) / 2); the CSM skips smaller casters (exactly: they
#: write no depth)
COVERING_AREA = 2.0
#: the radius of the largest disk inside what each inner coverage test needs inside the
#: caster: the texel square's inscribed circle (corners) or its circumscribed circle
#: (circle). A caster whose light-space inradius is below this radius plus the test's
#: margin contains no such disk, so it covers no texel either (exactly: thin casters of
#: any area, such as fur strands, write no depth)
COVERING_RADIUS = {"corners": 0.5, "circle": lr.HALF_DIAGONAL}
#: relative slack of both size tests for their float64 rounding: |D| of a thin caster
#: cancels (a relative error of about eps R^2 / area, 7e-9 at R 8192 for a caster of one
#: texel), so 1e-6 keeps the skip exact up to well beyond R 8192; a caster skipped in
#: error could only make the CSM cull less, never wrongly
RELATIVE_SLACK = 1e-6


def _plane_terms(planes, bound, tri):
    """The 16 plane coefficients [..] and the bound of triangles ``tri`` (int [..])."""
    # one gather per element (planes[tri, k]), not a row gather sliced afterwards: XLA on
    # the CPU materializes the [P, 16] rows then, and the pair test ran 2x slower
    return [planes[tri, k] for k in range(16)], bound[tri]


def _shadowed_by(points, scale, node, pl, bd):
    """bool: the per-sample test of ``brute_force`` (the same expressions) of the nodes
    ``node`` against triangles given by their plane terms (:func:`_plane_terms`,
    broadcasting against ``node``)."""
    px, py, pz = (points[node, k] for k in range(3))
    e0 = px * pl[0] + py * pl[1] + pz * pl[2] + pl[3]
    e1 = px * pl[4] + py * pl[5] + pz * pl[6] + pl[7]
    e2 = px * pl[8] + py * pl[9] + pz * pl[10] + pl[11]
    cap = px * pl[12] + py * pl[13] + pz * pl[14] + pl[15]
    return (e0 >= 0) & (e1 >= 0) & (e2 >= 0) & (cap * scale[node] < bd)


def _shadowed(points, scale, planes, bound, node, tri):
    """bool [P]: :func:`_shadowed_by` on the pairs (node [P], tri [P])."""
    return _shadowed_by(points, scale, node, *_plane_terms(planes, bound, tri))


@jax.jit
def _pair_test(points, scale, planes, bound, node, tri, count):
    """int8 [S]: 1 where some pair (node, tri) [P] of the first ``count`` shadows the node."""
    hit = _shadowed(points, scale, planes, bound, node, tri)
    hit &= jnp.arange(node.shape[0]) < count
    return jnp.zeros(points.shape[0], jnp.int8).at[node].max(hit.astype(jnp.int8))


@functools.partial(jax.jit, static_argnames=("width",))
def _trace_rows(tri, first, length, order, points, scale, planes, bound, shadow, *, width):
    """Kept fragments as rows of ``width`` pairs: fragment f (triangle ``tri`` [F]) tests
    the nodes ``order[first[f] + l]``, l < ``length[f]`` <= width (its list); ``shadow``
    (int8 [S]) accumulated. Each fragment's plane terms are gathered once for its row;
    padding rows have length 0."""
    lane = jnp.arange(width, dtype=first.dtype)
    valid = lane[None, :] < length[:, None]
    node = order[jnp.where(valid, first[:, None] + lane[None, :], 0)]          # [F, W]
    pl, bd = _plane_terms(planes, bound, tri)
    hit = _shadowed_by(points, scale, node, [x[:, None] for x in pl], bd[:, None]) & valid
    return shadow.at[node].max(hit.astype(jnp.int8))


def row_width_exponents(length: np.ndarray) -> np.ndarray:
    """uint8 [K]: ``ceil(log2(length))`` of each list of ``length`` [K] (>= 1) nodes, the
    exponent of its row width (:func:`row_widths`)."""
    return np.ceil(np.log2(length)).astype(np.uint8)


def row_widths(length: np.ndarray) -> np.ndarray:
    """int64 [K]: the row width of each list of ``length`` [K] (>= 1) nodes, the length
    rounded up to a power of two, which every kept fragment of the list uses (rows of
    one width share a compiled kernel; at most half of a row is padding)."""
    return np.left_shift(1, row_width_exponents(length).astype(np.int64))


def pair_shadows(points, scale, planes, bound, node: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """bool [S]: samples shadowed by some (node, tri) pair, chunked to static capacities."""
    out = np.zeros(points.shape[0], bool)
    total = len(node)
    cap = bucket(min(total, PAIR_CHUNK), minimum=1024)
    for start in range(0, total, cap):
        n = min(cap, total - start)
        hit = _pair_test(points, scale, planes, bound,
                         jnp.asarray(pad(node[start:start + n], cap)),
                         jnp.asarray(pad(tri[start:start + n], cap)), n)
        out |= np.asarray(hit, bool)
    return out


def _delta_slope(cam, delta: np.ndarray) -> np.ndarray:
    """d delta / d depth at depths with delta [N] (1 orthographic; near / depth^2)."""
    if cam.kind == "orthographic":
        return np.ones_like(delta)
    return delta * delta / cam.near


@register("izb", doc="frustum-traced irregular z-buffer with the conservative shadow-map "
          "prepass (exact)", kind="exact",
          paper="Wyman et al. 2015/2016 (IZB); Tokuyoshi & Mizokuchi 2018 (CSM prepass)",
          counters=("samples", "casters", "culled_triangles", "tests", "tests_per_pixel",
                    "front_face_culled", "shadowed", "lit", "light_faces", "list_nodes",
                    "list_length_max", "list_length_per_pixel",
                    "list_nonempty_texels", "traced_fragments", "depth_culled_fragments",
                    "csm_texels", "csm_small_casters", "csm_culled", "csm_culled_per_pixel",
                    "csm_false_shadows"),
          stages=("samples", "setup", "light_setup", "csm", "build", "trace", "verify"),
          presets={"paper": PAPER_PRESET},
          options={
              "prepass": Option("csm", "'none' (Wyman's IZB) or 'csm' (the conservative "
                                "shadow-map prepass culls surely shadowed samples)",
                                allowed=PREPASSES),
              "resolution": Option(1024, "texels per side of each light face (IZB and CSM)",
                                   allowed=RESOLUTIONS),
              "projection": Option("auto", "point lights: one fitted perspective face, a "
                                   "cube, or auto (directional lights: orthographic)",
                                   allowed=PROJECTIONS),
              "coverage": Option("corners", "CSM full-coverage test: 'corners' (the poster) "
                                 "or 'circle' (Hertel et al. 2009)",
                                 allowed=lr.INNER_TESTS),
              "csm_depth": Option("corner", "CSM conservative depth: 'corner' (the plane's "
                                  "farthest texel corner, tight) or 'slope' (the poster's "
                                  "slope-scaled bias of 1)", allowed=CSM_DEPTHS),
              "coverage_margin": Option(1e-3, "texels every coverage decision keeps from an "
                                        "edge (raised to cover rounding)", kind=float,
                                        minimum=0.0, maximum=0.25),
              "csm_scale": Option(1, "CSM texels per IZB texel side (1: the poster's shared "
                                  "grid; k: a k x finer CSM over the same extent, read at the "
                                  "sample's finer texel)", allowed=(1, 2, 4, 8)),
              "csm_min_area": Option(0.0, "CSM: draw only casters whose light-space area is "
                                     "at least this many texels (the poster's remedy for "
                                     "small triangles; 0 draws every caster)", kind=float,
                                     minimum=0.0),
              "verify": Option(True, "re-test every CSM-culled sample against every caster "
                               "(counter csm_false_shadows)", allowed=(True, False)),
              "bias": Option("receiver", "self-shadowing bias, as brute_force; the CSM "
                             "prepass needs 'receiver'", allowed=("receiver", "cap")),
              "front_face_culling": Option(True, "drop the triangles of closed objects that "
                                           "face away from the light before anything is "
                                           "rasterized (exact: the same lit mask in about "
                                           "half the work on closed scenes; the papers "
                                           "cull nothing)", allowed=(True, False)),
          })
def izb(scene, gbuf, light, *, precision, shadow_eps, prepass, resolution, projection,
        coverage, csm_depth, coverage_margin, csm_scale, csm_min_area, verify, bias,
        front_face_culling):
    return run_frame(scene, gbuf, light, ENGINE, precision=precision, shadow_eps=shadow_eps,
                     prepass=prepass, resolution=resolution, projection=projection,
                     coverage=coverage, csm_depth=csm_depth, coverage_margin=coverage_margin,
                     csm_scale=csm_scale, csm_min_area=csm_min_area, verify=verify,
                     bias=bias, front_face_culling=front_face_culling)


def run_frame(scene, gbuf, light, engine, *, precision, shadow_eps, prepass, resolution,
              projection, coverage, csm_depth, coverage_margin, csm_scale, csm_min_area, verify,
              bias, front_face_culling):
    """One ``izb`` frame with the list build and tracing of ``engine`` (the JAX one,
    :data:`ENGINE`, or the Warp kernels' ``shadowlab.kernels.izb.ENGINE``)."""
    if prepass == "csm" and bias != "receiver":
        raise MethodError("method 'izb': option prepass='csm' needs bias='receiver' (the "
                          "prepass bounds the receiver-biased point); got bias='cap'")
    timer = StageTimer()
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
    s_count = samples.count
    light_h = hard_light(light).homogeneous
    all_triangles = scene.num_triangles
    face_culled = 0
    if front_face_culling:
        # the shared exact rule (geometry.caster_culling), before the set-up
        with timer.stage("setup"):
            scene, face_culled = without_culled_faces(scene, light_h, "averted")
    with precision_mode(precision) as dtype:
        t_cap = bucket(scene.num_triangles, minimum=16)
        tri_pad = pad(scene.triangles, t_cap, dtype=dtype)
        planes, valid = timer.run("setup", shadow_volume_planes, jnp.asarray(tri_pad),
                                  jnp.asarray(light_h.astype(dtype)))
        valid, _, scale, bound = caster_terms(scene, samples, light_h, planes, valid,
                                              shadow_eps, bias, dtype)
        casters = int(valid.sum())
        counters = {"samples": s_count, "casters": casters,
                    "culled_triangles": all_triangles - casters,
                    "front_face_culled": face_culled}
        if s_count == 0:
            for name in ("light_setup", "csm", "build", "trace", "verify"):
                timer.times[name] = 0.0
            counters.update(_empty_counters(gbuf.valid.shape))
            return ShadowResult(np.zeros(gbuf.valid.shape, bool), counters,
                                dict(timer.times, total=timer.total))
        points = jnp.asarray(samples.padded_position(dtype))
        scale_j = jnp.asarray(samples.padded(scale, dtype))
        bound_j = jnp.asarray(bound)
        ok_tri = valid[: scene.num_triangles]

        with timer.stage("light_setup"):
            cam = fit_camera(scene, samples, light, resolution, projection)
            r = cam.resolution[0]
            face, uv, key, delta_p, depth_p = lr.project_points(cam, samples.position, True)
            keys_all, inv_all = lr.unique_keys(key, len(cam.faces) * r * r)
            tw = float(lr.texel_world_size(cam, face=face, depth=depth_p).min())
            # the largest world coordinate of the casters and the samples (no [T + S, 3]
            # concatenation: each array's own maximum)
            extent = np.array([max_abs(scene.triangles), max_abs(samples.position)])
            tau = coverage_margin + lr.rounding_margin(dtype, extent, tw)
            setups = [lr.setup_face(f, scene.triangles, pad=BOX_PAD_TAUS * tau)
                      for f in cam.faces]
            # depth margin (delta units per sample): rounding of world coordinates
            m_world = 64.0 * float(np.finfo(dtype).eps) * float(extent.max())
            m_delta = _delta_slope(cam, delta_p) * m_world

        culled = np.zeros(s_count, bool)
        csm_texels = csm_small = 0
        with timer.stage("csm"):
            if prepass == "csm":
                c_cam, c_setups, c_face, c_keys, c_delta, c_tau, c_m = (
                    cam, setups, face, (keys_all, inv_all), delta_p, tau, m_delta)
                if csm_scale > 1:   # a finer grid over the same extent
                    c_cam = fit_camera(scene, samples, light, resolution * csm_scale,
                                       projection, padding=csm_scale)
                    c_face, _, c_key, c_delta = lr.project_points(c_cam, samples.position)
                    c_keys = lr.unique_keys(c_key, len(c_cam.faces) * c_cam.resolution[0] ** 2)
                    c_tau = coverage_margin + lr.rounding_margin(dtype, extent, tw / csm_scale)
                    c_setups = [lr.setup_face(f, scene.triangles, pad=BOX_PAD_TAUS * c_tau)
                                for f in c_cam.faces]
                    c_m = _delta_slope(c_cam, c_delta) * m_world
                culled, csm_texels, csm_small = _csm(
                    c_cam, c_setups, samples, light_h, c_face, c_keys, c_delta, c_m, ok_tri,
                    coverage, csm_depth, c_tau, cap_bias(scene, shadow_eps), csm_min_area)

        with timer.stage("build"):
            occupied = np.bincount(inv_all[~culled], minlength=len(keys_all)) > 0
            lkeys = keys_all[occupied]
            slot = np.where(culled, -1, (np.cumsum(occupied) - 1)[inv_all])
            lists = engine.build(slot, delta_p, m_delta, len(lkeys))

        with timer.stage("trace"):
            select = [ok_tri & s.ok for s in setups]
            with lr.x64():
                # the engine's depth culling needs each list's limit: the farthest node's
                # delta plus its margin
                frags = lr.raster(setups, lkeys, r, "outer", tau=tau, select=select,
                                  fields=engine.fragment_fields,
                                  depth_limit=(lists.maxd + lists.maxm
                                               if "depth_class" in engine.fragment_fields
                                               else None))
                shadow, tests_per, traced, depth_culled = engine.trace(
                    frags, lists, points, scale_j, planes, bound_j, s_count)
            # valid casters with a light-space determinant of exactly 0 on a face: test
            # them against every node of that face (nothing rasterizes them)
            order = lists.order
            for f, st in enumerate(setups):
                flat = np.flatnonzero(st.absdet == 0)
                odd = flat[ok_tri[flat] & np.any(st.vertex_w[flat] > 0, axis=1)]
                fn = order[face[order] == f] if len(odd) else order[:0]
                if len(fn):
                    pn, pt = np.tile(fn, len(odd)), np.repeat(odd, len(fn))
                    shadow |= pair_shadows(points, scale_j, planes, bound_j, pn, pt)[:s_count]
                    tests_per += np.bincount(pn, minlength=s_count)
            shadow |= culled

        false_shadows = -1
        with timer.stage("verify"):
            if prepass == "csm" and verify:
                false_shadows = _verify(culled, samples, points, scale_j, planes, bound,
                                        scene.num_triangles, dtype)

    lit_values = ~shadow
    lit = samples.scatter(lit_values, fill=False)
    llen = lists.length
    length_per = np.zeros(s_count, np.int64)
    length_per[order] = np.repeat(llen, llen)
    counters.update({
        "tests": int(tests_per.sum()),
        "tests_per_pixel": samples.scatter(tests_per.astype(np.int64), fill=0),
        "shadowed": int(shadow.sum()), "lit": int(lit.sum()),
        "light_faces": len(cam.faces), "list_nodes": int(len(order)),
        "list_length_max": int(llen.max(initial=0)),
        "list_length_per_pixel": samples.scatter(length_per, fill=0),
        "list_nonempty_texels": int(len(lkeys)),
        "traced_fragments": int(traced), "depth_culled_fragments": int(depth_culled),
        "csm_texels": int(csm_texels), "csm_small_casters": int(csm_small),
        "csm_culled": int(culled.sum()),
        "csm_culled_per_pixel": samples.scatter(culled.astype(np.int64), fill=0),
        "csm_false_shadows": int(false_shadows)})
    return ShadowResult(lit, counters, dict(timer.times, total=timer.total))


@dataclasses.dataclass(frozen=True)
class Lists:
    """Per-texel node lists (CSR over the non-empty texels).

    Attributes:
        order: int64 [N] sample indices, list by list, each list in sample order;
        start, length: int64 [K] of each list; maxd: float64 [K] delta of the farthest
        node; maxm: float64 [K] the largest depth margin of the list's nodes.
    """

    order: np.ndarray
    start: np.ndarray
    length: np.ndarray
    maxd: np.ndarray
    maxm: np.ndarray


class JaxEngine:
    """List build (a stable sort) and tracing (expanded (node, triangle) pairs tested by
    the jitted pair kernel)."""

    #: what :meth:`trace` reads of the outer fragments (``lr.raster``'s fields): the
    #: raster's fill does the depth culling against the lists' limits
    fragment_fields = ("depth_class",)

    @staticmethod
    def build(slot: np.ndarray, delta: np.ndarray, margin: np.ndarray, k: int) -> Lists:
        """Lists of the samples with ``slot`` [S] >= 0 (their texel's list), ``delta`` [S]
        and depth ``margin`` [S] (float64), ``k`` lists, none of them empty."""
        nodes = np.flatnonzero(slot >= 0)
        order = nodes[stable_argsort(slot[nodes])]
        length = np.bincount(slot[order], minlength=k).astype(np.int64)
        start = np.cumsum(length) - length
        if len(order) == 0:
            return Lists(order, start, length, np.full(k, -np.inf), np.zeros(k))
        return Lists(order, start, length, np.maximum.reduceat(delta[order], start),
                     np.maximum.reduceat(margin[order], start))

    @staticmethod
    def trace(frags: lr.Fragments, lists: Lists, points, scale, planes, bound, count):
        """Outer fragments ``frags``, depth-culled against the farthest node of their list
        (field ``depth_class``), then every node of the list tested: the kept fragments are
        grouped by row width (:func:`row_widths`) and each group runs in chunks of at
        most ``PAIR_CHUNK`` pairs (:func:`_trace_rows`). Runs inside ``lr.x64()``.

        Returns:
            shadow bool [count], tests per sample int64 [count], traced fragments,
            depth-culled fragments.
        """
        # the depth test ran in the raster's fill (field depth_class, against the lists'
        # limits); the kept fragments' compaction on the host: a compaction over every
        # candidate costs XLA on the CPU several times more
        depth_class = np.asarray(frags.depth_class)[: frags.candidates]
        kept = np.flatnonzero(depth_class == lr.NEARER)
        culled = np.count_nonzero(depth_class == lr.BEYOND_LIMIT)
        tri, slot = frags.host_tri_slot(kept)
        traced = len(kept)
        shadow = jnp.zeros(points.shape[0], jnp.int8)
        if traced:
            order = jnp.asarray(pad(lists.order, bucket(len(lists.order))))
            # the fragments grouped by width in one stable sort of the widths' exponents
            # (a list's width is its own: computed per list, not per fragment); the
            # groups start where the sorted width changes, and each chunk is a
            # contiguous slice of the sorted arrays
            exponent = row_width_exponents(lists.length)[slot]
            by_width = np.argsort(exponent, kind="stable")
            slot, tri = slot[by_width], tri[by_width]
            first, length = lists.start[slot], lists.length[slot]
            sorted_exponent = exponent[by_width]
            group_start = np.flatnonzero(np.r_[True, sorted_exponent[1:] !=
                                               sorted_exponent[:-1]])
            group_end = np.r_[group_start[1:], traced]
            for g0, g1 in zip(group_start, group_end):
                w = 1 << int(sorted_exponent[g0])
                step = max(1, PAIR_CHUNK // w)
                for s0 in range(g0, g1, step):
                    s1 = min(s0 + step, g1)
                    n = bucket(s1 - s0, minimum=min(64, step), steps=ROW_BUCKET_STEPS)
                    shadow = _trace_rows(jnp.asarray(pad(tri[s0:s1], n)),
                                         jnp.asarray(pad(first[s0:s1], n)),
                                         jnp.asarray(pad(length[s0:s1], n)), order, points,
                                         scale, planes, bound, shadow, width=w)
        # every node of a list is tested once by each kept fragment of its texel (no
        # scatter per pair)
        tests = np.zeros(count, np.int64)
        per_list = np.bincount(slot, minlength=len(lists.length))
        tests[lists.order] = np.repeat(per_list, lists.length)
        return (np.asarray(shadow[:count]).astype(bool), tests, traced, int(culled))


ENGINE = JaxEngine()


def _empty_counters(shape) -> dict:
    zero_map = np.zeros(shape, np.int64)
    return {"tests": 0, "tests_per_pixel": zero_map, "shadowed": 0, "lit": 0,
            "light_faces": 0, "list_nodes": 0, "list_length_max": 0,
            "list_length_per_pixel": zero_map.copy(),
            "list_nonempty_texels": 0, "traced_fragments": 0, "depth_culled_fragments": 0,
            "csm_texels": 0, "csm_small_casters": 0, "csm_culled": 0,
            "csm_culled_per_pixel": zero_map.copy(),
            "csm_false_shadows": 0}


def receiver_points(position: np.ndarray, normal: np.ndarray, light_h: np.ndarray,
                    eps: float) -> tuple[np.ndarray, np.ndarray]:
    """float64 [N, 3]: q = p + (eps / (n . l)) l, the receiver-biased point on the ray from
    each sample p (``position`` [N, 3], ``normal`` [N, 3]) to the light (l the unit
    direction to the light), where the exact methods' receiver bias puts the crossing
    (``shadowlab.core.frame.bias_terms``); and bool [N], the samples whose cut reaches a
    point light (q is the light itself: lit by the reference's criterion, whatever lies
    in front of the light)."""
    p = position
    # one [N, 3] buffer, updated in place (the same operations in the same order as
    # L.xyz - L.w p, / |.|, p + step l: the same bits; fresh 24 MB arrays at 1M samples
    # cost more in page faults than the arithmetic)
    buf = np.multiply(p, light_h[3])
    np.subtract(light_h[:3], buf, out=buf)                      # to the light
    dist = norms3(buf)
    l = np.divide(buf, dist[:, None], out=buf)
    cos = np.maximum(np.einsum("ij,ij->i", normal, l), 1e-12)
    step = eps / cos
    reaches = np.zeros(len(p), bool)
    if light_h[3] != 0:   # never past the light
        reaches = step >= dist
        np.minimum(step, dist, out=step)
    np.multiply(l, step[:, None], out=l)
    return np.add(p, l, out=l), reaches


def light_area(setup: lr.FaceSetup) -> np.ndarray:
    """float64 [T]: projected area (texels) of the triangles in front of the light on a
    face (|D| / (2 w0 w1 w2)); 0 for the others."""
    front = setup.front & setup.ok
    w = np.where(front[:, None], setup.vertex_w, 1.0)
    return np.where(front, setup.absdet / (2 * np.prod(w, axis=1)), 0.0)


def light_inradius(setup: lr.FaceSetup) -> np.ndarray:
    """float64 [T]: inradius (texels) of the projected triangles in front of the light on
    a face, 2 area / perimeter = |D| / (norm_0 w_0 + norm_1 w_1 + norm_2 w_2) (edge row i
    has norm w_j w_k times the length of the edge jk it holds); 0 for the others."""
    front = setup.front & setup.ok
    w = np.where(front[:, None], setup.vertex_w, 1.0)
    perimeter_w = np.einsum("ij,ij->i", setup.norms, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(front & (perimeter_w > 0), setup.absdet / perimeter_w, 0.0)


def csm_casters(setup: lr.FaceSetup, ok_tri: np.ndarray, test: str, tau: float,
                min_area: float = 0.0) -> tuple[np.ndarray, int]:
    """The casters the CSM draws on a face: bool [T], and how many valid casters in
    front of the light cannot cover a texel (light-space area below ``COVERING_AREA``
    or inradius below ``COVERING_RADIUS[test] + tau``; not drawn, an exact skip)."""
    drawn = ok_tri & setup.ok & setup.front
    keep = 1.0 - RELATIVE_SLACK
    area = light_area(setup)
    covers = ((area >= COVERING_AREA * keep)
              & (light_inradius(setup) >= (COVERING_RADIUS[test] + tau) * keep))
    return drawn & covers & (area >= min_area), int(np.count_nonzero(drawn & ~covers))


@functools.partial(jax.jit, static_argnames=("size",))
def _csm_depths(slot, full, hi, slope_terms, *, size):
    """float64 [size]: the CSM of the inner fragments (``full`` [C]) over ``size`` texels
    (+inf where no fragment covers a texel), and the number of texels with a depth.
    ``slope_terms``: None for the corner depth (``hi`` [C]), or the fragments' (centre,
    slope) [C] for the poster's slope-scaled depth."""
    if slope_terms is None:
        cons = hi
    else:                                       # slope >= hi exactly; the max: rounding
        centre, gslope = slope_terms
        cons = jnp.maximum(centre + gslope, hi)
    csm = jnp.full(size, jnp.inf).at[slot].min(jnp.where(full, cons, jnp.inf))
    return csm, jnp.isfinite(csm).sum()


def _csm(cam, setups, samples, light_h, face, keys_inv, delta_p, m_delta, ok_tri, test,
         depth_mode, tau, eps, min_area=0.0):
    """bool [S] samples culled by the conservative shadow map, its full texels, and the
    casters (per face) that cannot cover a texel (:func:`csm_casters`), not drawn.
    ``keys_inv``: the sorted texel keys [K] of the samples and each sample's index [S];
    ``delta_p`` [S]: the samples' delta, ``m_delta`` [S] their depth margins."""
    r = cam.resolution[0]
    keys, inv = keys_inv
    select, small = [], 0
    for s in setups:
        drawn, n_small = csm_casters(s, ok_tri, test, tau, min_area)
        select.append(drawn)
        small += n_small
    with lr.x64():
        slope = depth_mode == "slope"
        fr = lr.raster(setups, keys, r, "inner", test, tau, select,
                       fields=("slot", "covered", "hi") + (("centre", "slope") if slope else ()))
        csm, texels = _csm_depths(fr.slot, fr.covered, fr.hi,
                                  (fr.centre, fr.slope) if slope else None,
                                  size=bucket(len(keys)))
        depth = np.asarray(csm)[inv]
    # q lies between p and the light, so delta(q) <= delta(p) (both depth conventions
    # grow away from the light): only a sample with delta(p) beyond its texel's depth
    # can be culled. The prefilter keeps one more margin for the rounding of delta(q).
    cand = np.flatnonzero(delta_p + m_delta > depth)
    q, reaches = receiver_points(samples.position[cand], samples.normal[cand], light_h, eps)
    # q's depth along the face axis only (LightFace.depth rounds as project does)
    if len(cam.faces) == 1:
        delta_q = lr.face_depth(cam.faces[0], cam.faces[0].depth(q))
    else:
        delta_q = np.empty(len(cand))
        fc = face[cand]
        for f in np.unique(fc):
            sel = fc == f
            delta_q[sel] = lr.face_depth(cam.faces[f], cam.faces[f].depth(q[sel]))
    # A cut that reaches the light puts q on the light's plane (delta -> +-inf): such a
    # sample is lit (the reference's tfar = max(length - cut, 0)), so it is never culled.
    delta_q = np.where(reaches | ~np.isfinite(delta_q), -np.inf, delta_q)
    culled = np.zeros(samples.count, bool)
    culled[cand] = delta_q > depth[cand] + m_delta[cand]
    return culled, int(texels), small


def _verify(culled, samples, points, scale, planes, bound, num_triangles, dtype) -> int:
    """Culled samples that the exact test over every caster finds lit."""
    idx = np.flatnonzero(culled)
    if len(idx) == 0:
        return 0
    chunk = 16
    cap = bucket(len(idx), steps=8)
    sub_p = jnp.asarray(pad(np.asarray(points)[idx], cap))
    sub_s = jnp.asarray(pad(np.asarray(scale)[idx], cap))
    n_chunks = jnp.asarray(-(-num_triangles // chunk), dtype=jnp.int32)
    shadow = np.asarray(_test_kernel(chunk)(sub_p, sub_s, planes, jnp.asarray(bound), n_chunks))
    return int((~shadow[: len(idx)]).sum())
