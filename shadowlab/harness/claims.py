"""The paper-claims registry: every claim of the five papers the project measures.

One place lists each claim once, by id: the paper (cited as in docs/references.md), the
figure, table or section, the claim in our words, and the experiments meant to measure
it. An experiment's ``claims(arrays, cfg)`` refers to a claim by its id (the key
``"id"`` of a claim dict, :func:`shadowlab.harness.figures.measure_claims` refuses an
unknown id), and the ledger (:mod:`shadowlab.harness.ledger`, ``docs/claims.md``) joins
the registry with the claims recorded in ``figures/*.json``. A claim no experiment has
measured yet is still a row of the ledger ("not measured"), with ``pending`` saying why
or what would measure it.

Fields of :class:`Claim`:

- ``kind``: ``"quantitative"`` (a number or ratio the paper reports) or
  ``"qualitative"`` (an ordering or property it states);
- ``experiments``: the experiments (``experiments/<name>.py``) that measure it or are
  meant to (empty: none yet);
- ``pending``: for a claim with no measurement, why, or what would measure it;
- ``explain``: one line shown where the claim fails on our scenes (the cause where it
  is known); an experiment's own ``"note"`` on a measurement takes precedence;
- ``tested_by``: a unit test that checks the claim on a constructed case (not a
  measurement on a scene; shown beside the measurement).

Claims whose measurement is a run time or a ratio of run times are listed in
:data:`TIMED`: they are measured and recorded like the others, but a config's
``require_claims = true`` never enforces them (performance lives in benchmarks, never in
tests: on a loaded machine a timing claim would flip).
"""

from __future__ import annotations

import dataclasses

PAPERS = {
    "S14": "Sintorn et al. 2014",
    "M16": "Mora et al. 2016",
    "P13": "Pečiva et al. 2013",
    "T18": "Tokuyoshi and Mizokuchi 2018",
    "K23": "Kalbertodt 2023",
}


@dataclasses.dataclass(frozen=True)
class Claim:
    id: str
    paper: str                     # a key of PAPERS
    where: str                     # figure, table or section
    text: str
    kind: str = "quantitative"     # or "qualitative"
    experiments: tuple[str, ...] = ()
    pending: str = ""
    explain: str = ""
    tested_by: str = ""

    @property
    def timed(self) -> bool:
        """Measured by run times (recorded, never enforced by ``require_claims``)."""
        return self.id in TIMED


#: ids of the claims measured by run times (see the module docstring)
TIMED = frozenset({
    "s14.fig1.order", "s14.fig5.faster", "s14.fig5.build_stable", "s14.fig5.ffc",
    "s14.fig8.explicit_faster", "s14.fig8.culling_faster", "s14.fig8.two_pass_spikes",
    "s14.sec2_3.build_like_ptsv", "s14.fig9.build_2x", "s14.fig9.traverse_scales",
    "s14.sec3.compact_5pct", "m16.fig8.hybrid_fastest", "m16.fig8.accel",
    "m16.fig7.build_overhead", "m16.fig7.zpass_duality", "m16.fig9.stack_size",
    "p13.manifold_faster", "p13.visibility_test", "t18.fig1.speedup", "t18.fig3.stages", "k23.grid_31xn",
})

_GPU = "absolute GPU times; a CPU/XLA run cannot reproduce them, only the ratios"

CLAIMS: tuple[Claim, ...] = (
    # ---------------------------------------------------------------- Sintorn et al. 2014
    Claim("s14.fig1.order", "S14", "Fig. 1",
          "On the gate view the cluster hierarchy is faster than PTSV, and PTSV faster than "
          "ZPASS (4.2 / 7.46 / 12.16 ms)",
          experiments=("clustered_stages",),
          explain="CPU/XLA engine: a level-synchronous traversal pays per level, not per "
                  "warp; see docs/clustered_ptsv.md"),
    Claim("s14.fig1c.volume", "S14", "Fig. 1c, Sec. 2.1",
          "Explicit bounds give the hierarchy a much smaller total volume than implicit "
          "bounds (and than PTSV's tiles; we require < half of either, leaf level)",
          experiments=("clustered_heatmaps",)),
    Claim("s14.fig3.ptsv_discontinuities", "S14", "Fig. 3",
          "PTSV tests pixels at steep depth discontinuities far more often than elsewhere",
          kind="qualitative", experiments=("clustered_heatmaps",)),
    Claim("s14.fig3.cluster_discontinuities", "S14", "Fig. 3",
          "The cluster hierarchy (explicit bounds) tests the pixels at steep depth "
          "discontinuities much less often than PTSV (we require >= 2x)",
          experiments=("clustered_heatmaps",)),
    Claim("s14.fig6.implicit_more", "S14", "Sec. 2 (remaining problems), Fig. 6",
          "With implicit bounds the hierarchy needs significantly more test-and-sets than "
          "PTSV over the animations",
          experiments=("clustered_animation",)),
    Claim("s14.fig6.culling_planes", "S14", "Fig. 6",
          "The per-vertex culling planes reduce the test-and-sets (modest in CITADEL, "
          "significant in VILLA)",
          experiments=("clustered_animation",)),
    Claim("s14.fig6.le_ptsv", "S14", "Fig. 6, Sec. 2.1",
          "With explicit bounds the hierarchy needs as many test-and-sets as PTSV or fewer, "
          "in (almost) every frame of the fly-throughs",
          experiments=("clustered_animation",),
          explain="where PTSV's 8x4 tiles have no depth discontinuity their depth ranges are "
                  "tight, and the deeper tree of 8x8 leaves tests more samples per leaf"),
    Claim("s14.city.le_ptsv", "S14", "Fig. 6, Sec. 2.1 (a city scene)",
          "With explicit bounds the hierarchy needs as many test-and-sets as PTSV or fewer, "
          "also on a city (closed boxes on a ground slab, thin posts in front, a point light "
          "high above), at every resolution",
          experiments=("clustered_city",)),
    Claim("s14.fig6.gain2x", "S14", "Fig. 6, Sec. 2.1",
          "In frames with steep depth discontinuities the hierarchy often needs more than 2x "
          "fewer test-and-sets than PTSV",
          experiments=("clustered_animation",)),
    Claim("s14.fig6.vs_silhouette_planes", "S14", "Sec. 2 (triangle setup), Fig. 6",
          "The new per-vertex culling planes remove more false positives than PTSV's 2D "
          "silhouette planes",
          experiments=("clustered_animation",)),
    Claim("s14.fig7.one_pass_peak", "S14", "Fig. 7",
          "In one pass a few jobs (triangles) need about 10x the average number of "
          "traversal iterations",
          experiments=("clustered_load_balance",)),
    Claim("s14.fig7.two_pass_peak", "S14", "Fig. 7",
          "With two passes no job needs many more iterations than the average "
          "(we require the largest <= 8x the average)",
          experiments=("clustered_load_balance",),
          explain="a pass-2 job is a (triangle, node) pair at level L; one large lit triangle "
                  "above a dense leaf still holds all of its leaves' work"),
    Claim("s14.fig7.makespan", "S14", "Fig. 7, Sec. 2.2",
          "Two passes remove the load-balancing spikes: over P persistent workers the "
          "makespan comes close to the ideal total / P",
          experiments=("clustered_load_balance",)),
    Claim("s14.fig8.explicit_faster", "S14", "Fig. 8",
          "Explicit bounds make the traversal significantly faster than implicit bounds",
          experiments=("clustered_animation",)),
    Claim("s14.fig8.culling_faster", "S14", "Fig. 8",
          "The culling planes make the traversal faster",
          experiments=("clustered_animation",)),
    Claim("s14.fig8.two_pass_spikes", "S14", "Fig. 8",
          "The two-pass traversal removes the spikes of the traversal time",
          kind="qualitative",
          pending="not observable on a level-synchronous CPU engine (every level is one "
                  "vectorised step; there are no idle warps to wait for); "
                  "s14.fig7.makespan measures the cause instead"),
    Claim("s14.fig5.faster", "S14", "Fig. 5",
          "The cluster hierarchy outperforms PTSV and ZPASS over the fly-throughs, except "
          "in views with very few shadow volumes, where ZPASS is faster",
          experiments=("clustered_stages",),
          explain="CPU/XLA engine: a level-synchronous traversal pays per level, not per "
                  "warp; see docs/clustered_ptsv.md"),
    Claim("s14.fig5.build_stable", "S14", "Fig. 5",
          "Build, triangle setup and merge cost a low, nearly constant time per frame; the "
          "traversal is view dependent",
          experiments=("clustered_stages",),
          explain="a loaded machine stretches these 0.1-0.3 s stages unevenly: the 2026-11 "
                  "run under load 4-7 measured a 166 % spread, the idle 2026-12-04 re-run "
                  "34 % against the traversal's 45 %"),
    Claim("s14.fig5.ffc", "S14", "Fig. 5",
          "Light front-face culling (closed objects) improves the total time significantly",
          experiments=("clustered_stages",)),
    Claim("s14.sec2_3.build_like_ptsv", "S14", "Sec. 2.3, Fig. 5",
          "Building the hierarchy takes about as long as PTSV's hierarchical depth buffer",
          experiments=("clustered_stages",)),
    Claim("s14.fig9.build_2x", "S14", "Fig. 9, Sec. 3",
          "At 1080p building the hierarchy takes about twice as long as at 720p / 1024^2",
          experiments=("clustered_stages",),
          explain="timings on a shared CPU; the build no longer materialises full-tree "
                  "arrays (its cost follows the samples, docs/clustered_ptsv.md)"),
    Claim("s14.fig9.traverse_scales", "S14", "Fig. 9, Sec. 3",
          "Traversal scales much better with resolution than the build (more nodes are "
          "trivially accepted)",
          experiments=("clustered_stages",),
          explain="the automatic z bits give 1080p (and 720p) a 10-bit z against 9 bits "
                  "at 1024^2 (s14.sec2.z_bits), so the 1024^2 hierarchy is the smallest of "
                  "the three (37 MB against 144 MB at 720p and 288 MB at 1080p, medians): "
                  "the ratio to 1024^2 mixes resolution with key size; between 720p and "
                  "1080p, same key, the traversal grows 1.81x for 2.25x the samples"),
    Claim("s14.sec3.compact_5pct", "S14", "Sec. 3",
          "The compact box storage runs at most 5 % slower than full storage",
          experiments=("clustered_stages",)),
    Claim("s14.sec3.memory", "S14", "Sec. 3",
          "At 1024^2 the full tree has 8.65 M nodes: 1 MB of bits, 198 MB of full boxes or "
          "33 MB of pointers plus a compact list that never exceeded 52,000 boxes; 1080p "
          "needs (66 + 2) MB expected",
          experiments=("clustered_stages",),
          explain="our compact storage counts masks, start counts and 24-byte boxes of "
                  "the existing nodes, not the paper's layouts; those reproduce its 1024^2 "
                  "figures (33 MiB = 8.65 M x 4-byte pointers; docs/clustered_ptsv.md), but "
                  "its 1080p (66 + 2) MB does not follow from its key: 1920 x 1080 needs one "
                  "more bit per image axis (2048 > 1920), which at least quadruples the full "
                  "tree, not doubles it"),
    Claim("s14.sec2.z_bits", "S14", "Sec. 2",
          "Nine bits for z' are more than sufficient at 1024^2 for all scenes",
          experiments=("clustered_stages",),
          explain="the automatic z bits (two more than the x / y bits) are the paper's 9 at "
                  "1024^2 only; at other sizes see the measured bits"),
    # ---------------------------------------------------------------- Mora et al. 2016
    Claim("m16.fig3.front_point", "M16", "Fig. 3, Sec. 3.3",
          "A point in front of every occluder (closer to the light) is lit; PSV must visit "
          "the tree to prove it, the depth test stops at the root volume",
          kind="qualitative", tested_by="tests/test_psv_paper_examples.py::test_fig3_point_in_front"),
    Claim("m16.fig4.stackless_path", "M16", "Fig. 4, Sec. 3.4",
          "The stackless query answers like the stack query without a stack, jumping back "
          "along ancestor links; the hybrid switches to it when its short stack is full and "
          "otherwise visits exactly D-PSV's nodes",
          kind="qualitative", tested_by="tests/test_psv_paper_examples.py::test_fig4_stackless_path"),
    Claim("m16.fig5.stack_low", "M16", "Fig. 5, Sec. 3.5",
          "PSV's stack usage stays below half of its size (16 of 32) for most image points "
          "and comes close to the maximum only in a few places",
          experiments=("psv_queries",)),
    Claim("m16.fig6.lit_only", "M16", "Fig. 6, Sec. 4.2",
          "The depth test leaves shadowed points' visits nearly unchanged and reduces lit "
          "points' visits significantly",
          experiments=("psv_queries",)),
    Claim("m16.fig6.order", "M16", "Fig. 6, Sec. 4.2",
          "D-Stackless visits more nodes than D-PSV but fewer than PSV; D-Hybrid is "
          "comparable to D-PSV",
          kind="qualitative", experiments=("psv_queries",),
          explain="D-Stackless exceeds PSV where the depth test saves little: every jump back "
                  "along an ancestor link re-tests nodes that a stack would have popped; the "
                  "paper sees the same on SHIP and EXCAVATOR (114 %, 106 %)"),
    Claim("m16.fig7.always_fewer", "M16", "Fig. 7, Sec. 4.2",
          "D-PSV and D-Hybrid visit fewer nodes than PSV in every frame",
          experiments=("psv_animation",)),
    Claim("m16.fig7.light_behind_peak", "M16", "Fig. 7, Sec. 4.2",
          "PSV peaks when the light is behind and close to the camera; the depth test "
          "removes most of that peak",
          experiments=("psv_animation",),
          explain="our sphere-grid fly-through (6x6 spheres, 36 k triangles, 512x512) has no "
                  "pronounced peak: PSV visits 41-61 nodes per pixel over the 24 frames, and "
                  "its largest frame is not the one with the light nearest the camera; the "
                  "depth test removes 7-13 % in every frame; why it removes no more is not "
                  "analysed (the paper's scenes are not available)"),
    Claim("m16.fig8.dpsv_pct", "M16", "Fig. 8",
          "D-PSV and D-Hybrid visit 62-72 % of PSV's nodes",
          experiments=("psv_animation",),
          explain="the depth test saves 6-13 % of the visits on every scene and light "
                  "position here (psv_queries: 87-94 % on gate, sphere_grid, fuzzy and blobs), "
                  "not the paper's 28-38 %; not analysed further (a hypothesis, untested: the "
                  "random insertion order mixes near and far triangles in every subtree, so "
                  "the subtrees' minimum depths rarely exceed a sample's)"),
    Claim("m16.fig8.dstackless_pct", "M16", "Fig. 8",
          "D-Stackless visits 84-114 % of PSV's nodes",
          experiments=("psv_animation",),
          explain="as for m16.fig6.order: the jumps back along ancestor links cost more than "
                  "the depth test saves, which is 6-13 % here (m16.fig8.dpsv_pct)"),
    Claim("m16.fig8.hybrid_fastest", "M16", "Fig. 8, Sec. 4.3",
          "D-Hybrid has the best average time with the smallest standard deviation "
          "(except on SHIP)",
          experiments=("psv_animation",),
          explain="on a CPU there is no register pressure: the stack query costs the same "
                  "at any stack size, and the hybrid's bookkeeping is pure overhead"),
    Claim("m16.fig8.accel", "M16", "Fig. 8, Sec. 4.3",
          "Every depth-tested query is faster than PSV on average (acceleration 1.13-1.59); "
          "D-Hybrid's best factor is 1.43-3.05",
          experiments=("psv_animation",)),
    Claim("m16.fig7.build_overhead", "M16", "Fig. 7, Sec. 4.3",
          "The modified build (depth per volume, atomic minimum) has a small overhead over "
          "the original build",
          pending="not measurable as such: the one build here always computes the depths and "
                  "ancestor links (all four queries share it), so there is no original build "
                  "to time against"),
    Claim("m16.fig7.zpass_duality", "M16", "Fig. 7, Sec. 4.3",
          "Z-PASS is fast where PSV is pathological (light behind the camera) and slow with "
          "large elongated shadow quads: a duality",
          kind="qualitative", experiments=("psv_animation",),
          explain="the duality is a fill-rate effect of rasterized quads (their screen area), "
                  "which this engine does not have: `zpass` evaluates every (sample, "
                  "triangle) pair, so its time hardly depends on the light position and "
                  "Z-PASS / PSV follows PSV's cost alone"),
    Claim("m16.fig9.stack_size", "M16", "Fig. 9, Sec. 4.4",
          "D-Hybrid's time has a best stack size (12 for small scenes, 16-20 for complex "
          "ones); a too small stack switches to stackless too often",
          experiments=("psv_queries",),
          explain="on a CPU a larger stack costs no registers or occupancy, so wherever a "
                  "smaller stack switches the largest one is fastest; the paper's optimum "
                  "is a GPU register-pressure trade-off"),
    Claim("m16.sec3_5.no_overflow", "M16", "Sec. 3.5, 4",
          "D-Hybrid never overflows; PSV and D-PSV with a 32-entry stack do not overflow on "
          "the paper's scenes except EXCAVATOR (48)",
          experiments=("psv_queries", "psv_animation")),
    Claim("m16.sec4_1.memory", "M16", "Sec. 3.6, 4.1",
          "Depth and ancestor links add no memory: 4 nodes of 32 bytes per triangle",
          tested_by="tests/test_psv_paper_examples.py::test_sec4_1_node_memory",
          pending="4 nodes of 32 bytes per merged triangle (float32 rows; the arrays are "
                  "sized to a capacity bucket of volumes), the depth in an otherwise unused "
                  "slot of the volume's first node, so no memory; the ancestor link is a "
                  "separate int32 per volume, 4 bytes per triangle (3 %), which the paper "
                  "packs into unused bits"),
    Claim("m16.sec4_4.random_order", "M16", "Sec. 4.4",
          "The randomised insertion order keeps TOP trees from becoming unbalanced "
          "(after Gerhards et al. 2015)",
          kind="qualitative", experiments=("psv_insertion_order",)),
    # ---------------------------------------------------------------- Pečiva et al. 2013
    Claim("p13.exact_nonmanifold", "P13", "Abstract, Sec. 1",
          "Silhouette shadow volumes give per-sample exact shadows for arbitrary "
          "(non-manifold) triangle meshes",
          kind="qualitative", experiments=("silhouette_*",)),
    Claim("p13.vs_shadow_map", "P13", "Tables 5, 6",
          "On Sponza, silhouette shadow volumes outperform 8k shadow mapping on AMD GPUs and "
          "are comparable elsewhere",
          experiments=("silhouette_*",),
          explain="CPU/XLA: the software stencil tests sides and caps per sample, while a "
                  "shadow-map lookup is one texel per sample; the GPU's rasterizer and "
                  "stencil hardware that make volumes cheap have no CPU counterpart"),
    Claim("p13.visibility_test", "P13", "Fig. 9, 10",
          "The side-visibility test (and the front cap shifted to infinity) improves the "
          "frame rate",
          experiments=("silhouette_variants",),
          explain="the test culls 5 % of the sides on the atrium; the screen bins already "
                  "keep a culled side out of most samples' lists, so the saving is below "
                  "the run-to-run spread of a CPU run"),
    Claim("p13.visibility_exact", "P13", "Sec. 3.4, Algorithms 3-6",
          "The clip-space visibility test culls only sides that cannot change the stencil",
          kind="qualitative", experiments=("silhouette_robustness", "silhouette_variants"),
          explain="its near and far planes cull sides that a depth-clamped ZFAIL count "
                  "still needs, and it picks the wrong diagonal for some sides "
                  "(docs/silhouette.md); the exact test (`cull_sides=\"exact\"`) changes "
                  "no pixel"),
    Claim("p13.caps_infinity", "P13", "Sec. 3.3, eq. 6; Table 5",
          "Moving the front cap to infinity (drawn wherever the eye ray meets the "
          "triangle) leaves the ZFAIL image unchanged",
          kind="qualitative", experiments=("silhouette_variants",)),
    Claim("p13.table1.sides", "P13", "Table 1",
          "Silhouette sides are far fewer than per-triangle volume sides (GS against "
          "GSTR), ever fewer as the tessellation grows",
          experiments=("silhouette_work",)),
    Claim("p13.tables3_4.objects", "P13", "Tables 3, 4",
          "At a constant triangle count, more objects cost more",
          kind="qualitative", experiments=("silhouette_work",)),
    Claim("p13.manifold_sides", "P13", "Sec. 4",
          "The 2-manifold fast path (GS2M) draws fewer sides than the general path, about "
          "half on closed objects",
          experiments=("silhouette_work", "silhouette_variants")),
    Claim("p13.manifold_faster", "P13", "Sec. 4",
          "The 2-manifold implementation is faster than the general one (the paper leaves "
          "the percentage as 'XY %')",
          kind="qualitative", experiments=("silhouette_variants",)),
    # ---------------------------------------------------------------- Tokuyoshi and Mizokuchi 2018
    Claim("t18.fig1.speedup", "T18", "Fig. 1, Sec. 4",
          "The conservative shadow-map prepass more than doubles the IZB hard-shadow speed "
          "(8.52 -> 3.59 ms at 4K)",
          experiments=("izb_*",)),
    Claim("t18.fig3.stages", "T18", "Fig. 3",
          "With node culling IZB creation drops 3.28 -> 1.07 ms and frustum tracing "
          "9.12 -> 0.58 ms (list lengths shrink)",
          experiments=("izb_*",)),
    Claim("t18.tab1.cull_rate", "T18", "Table 1",
          "The barycentric full-coverage test culls 56.0 % / 37.4 % of the shading points "
          "(Hertel et al. 2009: 55.5 % / 35.8 %) at the same cost",
          experiments=("izb_*",)),
    Claim("t18.conservative", "T18", "Sec. 2",
          "The conservative shadow map never shadows a lit point (the result stays exact)",
          kind="qualitative", experiments=("izb_*",)),
    # ---------------------------------------------------------------- Kalbertodt 2023
    Claim("k23.overlap_sum", "K23", "Rasterization",
          "Summing the overlap areas of the occluders over-shadows (two half-covers give 1, "
          "not 0.5); the bitset union does not",
          kind="qualitative", experiments=("soft_tiled_error",)),
    Claim("k23.clamp", "K23", "Projection",
          "The max(0.0001, ...) clamp of the projection works without artifacts",
          kind="qualitative", experiments=("soft_tiled_stability",),
          explain="abs() mirrors a caster vertex behind the fragment and the clamp pulls in "
                  "one within 1e-4 / s in front of it (the fragment's neighbours on its own "
                  "surface, and objects touching the receiver), so the projected triangle "
                  "covers the wrong cells; the homogeneous projection with two-sided lists "
                  "(the defaults) removes the error"),
    Claim("k23.rotation", "K23", "Fixing banding",
          "Randomly rotating the grid removes the banding without visible noise",
          kind="qualitative", experiments=("soft_tiled_error",)),
    Claim("k23.grid_31xn", "K23", "Grid size optimization",
          "31x3 / 31x5 / 31x7 grids cost 2.1 / 2.5 / 3.1 ms against 5 ms for 16x16, "
          "trading banding for time",
          experiments=("soft_tiled_error",)),
    Claim("k23.ffc", "K23", "Gather pass",
          "Culling light-facing triangles removes more triangles than back-face culling "
          "(terrain faces the light)",
          experiments=("soft_tiled_culling",)),
    Claim("k23.gather", "K23", "Performance",
          "The gather pass reduces 13 M triangles to about 2.5 M (about 19 %)",
          experiments=("soft_tiled_culling",)),
    Claim("k23.halfz", "K23", "Depth discontinuities & half-z",
          "Half-z splitting of the tile depth range helps less than expected; tiles with "
          "large depth ranges overflow the list",
          kind="qualitative", experiments=("soft_tiled_culling",)),
)

BY_ID = {c.id: c for c in CLAIMS}


def get(claim_id: str) -> Claim:
    """The registered claim ``claim_id``; KeyError naming the known ids' papers if none."""
    try:
        return BY_ID[claim_id]
    except KeyError:
        raise KeyError(f"unknown claim id {claim_id!r}; registered ids start with "
                       f"{', '.join(sorted({k.split('.')[0] for k in BY_ID}))} "
                       "(shadowlab.harness.claims.CLAIMS)") from None


def measured(claim_id: str, measured_text: str, holds: bool, *, label: str = "",
             note: str = "") -> dict:
    """A claim dict for an experiment's ``claims()``: the registered text (prefixed by
    ``label``, e.g. the scene), what was measured and whether it holds."""
    c = get(claim_id)
    out = {"id": c.id, "claim": f"{label}: {c.text}" if label else c.text,
           "measured": str(measured_text), "holds": bool(holds)}
    if note:
        out["note"] = str(note)
    return out


def outcome(holds: bool, *, tested: bool, why_untested: str) -> dict:
    """The ``holds`` part of a claim dict: ``{"holds": bool}``, or, where the run could
    not test the claim (``tested`` False: e.g. nothing was culled, so "0 of 0" cannot
    fail), ``{"holds": None, "note": "untested: <why_untested>"}``."""
    if tested:
        return {"holds": bool(holds)}
    return {"holds": None, "note": f"untested: {why_untested}"}
