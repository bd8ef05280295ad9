"""The one table of counter names shared by every method and reference kernel.

A method reports only the counters that apply to it. Scalar counters are Python
ints or floats; per-pixel counters are arrays [H, W] and end in ``_per_pixel``.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Counter:
    name: str
    kind: str      # "int" (an exact count), "float", "map" (int array [H, W]) or
                   # "array" (1-D per-job values, e.g. iterations per job)
    meaning: str


COUNTERS: dict[str, Counter] = {c.name: c for c in [
    Counter("samples", "int", "view samples considered: valid pixels whose normal faces the light"),
    Counter("casters", "int", "shadow-casting triangles after culling (non-degenerate, not "
            "edge-on to the light, and any method-specific culling)"),
    Counter("culled_triangles", "int", "triangles removed before the shadow test "
            "(degenerate, edge-on to the light, or culled by an option)"),
    Counter("tests", "int", "sample x shadow-volume inclusion tests (test-and-set operations)"),
    Counter("tests_per_pixel", "map", "inclusion tests performed for each pixel"),
    Counter("shadowed", "int", "samples found inside at least one shadow volume"),
    Counter("lit", "int", "pixels reported lit"),
    # the shared caster culling stage (option cull_casters; geometry.caster_culling)
    Counter("culled_casters", "int", "triangles removed before the method ran by the "
            "cull_casters option (every step together; 0 when off)"),
    Counter("culled_casters_hull", "int", "of those, triangles outside the convex hull of "
            "the samples' shadow rays"),
    Counter("culled_casters_averted", "int", "of those, triangles of closed objects facing "
            "away from the light"),
    Counter("culled_casters_receivers", "int", "of those, triangles behind every sample of "
            "their light-space footprint (receiver-driven culling)"),
    # per-triangle shadow volumes over a hierarchy (clustered_ptsv, ptsv)
    Counter("front_face_culled", "int", "triangles of closed objects dropped by face culling "
            "(clustered_ptsv, ptsv: the side given by the cull_side option; izb and "
            "silhouette's manifold='closed': the side facing away from the light)"),
    Counter("node_tests", "int", "existing child nodes tested against a shadow volume"),
    Counter("trivial_accepts", "int", "nodes found entirely inside a shadow volume"),
    Counter("trivial_rejects", "int", "nodes found entirely outside a shadow volume (by a "
            "volume plane or an extra culling plane)"),
    Counter("extra_plane_rejects", "int", "nodes rejected only by the extra culling planes"),
    Counter("leaf_visits", "int", "(triangle, leaf) jobs whose tile samples were tested"),
    Counter("ta_shadowed", "int", "samples shadowed only through trivially accepted nodes"),
    Counter("jobs", "int", "traversal jobs: triangles, plus (triangle, node) jobs in two-pass"),
    Counter("pass2_jobs", "int", "(triangle, node) jobs created at the expand level"),
    Counter("job_iterations_mean", "float", "mean traversal iterations (node visits) per job"),
    Counter("job_iterations_max", "int", "largest traversal iterations of one job"),
    Counter("job_iterations_top", "array", "the 1024 largest per-job iteration counts, "
            "descending, zero-padded (int [1024])"),
    Counter("frontier_max", "int", "largest traversal frontier (jobs at one level)"),
    Counter("clusters", "int", "existing leaf nodes (clusters or non-empty leaf tiles)"),
    Counter("hierarchy_nodes", "int", "existing nodes of the hierarchy, all levels below the root"),
    Counter("hierarchy_bytes", "int", "memory of child masks plus the chosen box storage"),
    Counter("saturated_samples", "int", "samples beyond the last depth slice of the key"),
    # stencil shadow volumes (zpass, zfail)
    Counter("stencil_updates", "int", "stencil-buffer updates: shadow-quad and cap fragments "
            "that pass (zpass) or fail (zfail) the depth test"),
    Counter("stencil_updates_per_pixel", "map", "stencil updates at each pixel"),
    Counter("eye_in_volumes", "int", "shadow volumes containing the eye (zpass initialises "
            "the stencil with this count)"),
    # silhouette shadow volumes (silhouette; docs/silhouette.md)
    Counter("edges", "int", "edge records of the adjacency (an edge with more opposite vertices "
            "than a record holds fills several)"),
    Counter("open_edges", "int", "edges with one adjacent triangle"),
    Counter("nonmanifold_edges", "int", "edges with more than two adjacent triangles, or two "
            "with the same direction"),
    Counter("silhouette_edges", "int", "edge records with multiplicity m != 0"),
    Counter("side_quads", "int", "side quads extruded: the sum of |m| over edge records"),
    Counter("culled_sides", "int", "silhouette edge records whose side the visibility test "
            "culled (not drawn)"),
    Counter("clipped_sides", "int", "silhouette sides whose screen bins were taken from the "
            "part of the fin no deeper than the samples that can cross it (zpass with screen "
            "bins; performance only)"),
    Counter("cap_triangles", "int", "cap triangles drawn (front and back caps; 0 for zpass)"),
    Counter("side_tests", "int", "(sample, side) pairs the software stencil evaluates (every "
            "drawn side per sample, or the side list of the sample's screen cell)"),
    Counter("cap_tests", "int", "(sample, caster) pairs the software caps passes evaluate "
            "(every caster per sample, or the caster list of the sample's screen cell)"),
    Counter("cap_crossings_per_pixel", "map", "cap crossings the caps passes find at each "
            "sample (caps drawn by zfail, caps before the evaluation point)"),
    Counter("negative_stencil", "int", "samples whose final stencil count is below zero (a "
            "leak; 0 in an exact configuration)"),
    # TOP-tree methods (psv, d_psv, d_stackless, d_hybrid; docs/psv.md)
    Counter("visited_nodes", "int", "TOP-tree node visits summed over samples (a visit reads "
            "one node; a depth-test skip and a stackless second visit count as visits)"),
    Counter("visited_nodes_mean", "float", "visited_nodes / samples"),
    Counter("visited_nodes_per_pixel", "map", "TOP-tree node visits of each pixel's query"),
    Counter("stack_max", "int", "largest stack usage of any sample (entries)"),
    Counter("stack_max_per_pixel", "map", "largest stack usage of each pixel's query"),
    Counter("stack_overflows", "int", "pushes onto a full stack, summed over samples; each "
            "loses an intersection subtree, as in the original PSV"),
    Counter("overflow_pixels", "int", "samples with at least one stack overflow (their result "
            "may be wrong)"),
    Counter("stack_overflows_per_pixel", "map", "pushes onto a full stack of each pixel"),
    Counter("stackless_switches", "int", "D-Hybrid switches from the short stack to the "
            "stackless query, summed over samples"),
    Counter("stackless_switches_per_pixel", "map", "D-Hybrid switches to stackless per pixel"),
    Counter("tree_nodes", "int", "nodes of the TOP tree (4 per merged shadow volume)"),
    Counter("tree_depth", "int", "nodes on the longest root-to-leaf path of the TOP tree"),
    Counter("dropped_triangles", "int", "casters found inside another shadow volume during the "
            "build and not merged"),
    Counter("intersection_triangles", "int", "merged casters lying in some intersection subtree "
            "(ancestor link set)"),
    Counter("build_rounds", "int", "rounds of the parallel TOP-tree build"),
    Counter("query_chunks", "int", "query chunk kernels run (checks for finished lanes between "
            "them; lengths from the chunk_schedule option)"),
    Counter("tree_reused", "int", "1 when the TOP tree of an earlier call was reused "
            "(reuse_tree, static light and geometry), else 0"),
    # tiled soft shadows (soft_tiled, soft_overlap_sum; docs/soft_tiled.md)
    Counter("soft_clusters", "int", "triangle clusters built from the scene (Morton-sorted runs "
            "of cluster_size triangles)"),
    Counter("light_facing_survivors", "int", "non-degenerate triangles left after the "
            "light-facing culling (face_cull)"),
    Counter("gather_clusters", "int", "clusters with a triangle surviving the gather pass"),
    Counter("gather_triangles", "int", "triangles surviving the gather pass (light-facing and "
            "view-frustum cone culling)"),
    Counter("tiles", "int", "16x16 screen tiles"),
    Counter("active_tiles", "int", "tiles with at least one relevant pixel (the rest exit early)"),
    Counter("tile_cluster_pairs", "int", "active tile x gathered cluster cone tests"),
    Counter("tile_cluster_survivors", "int", "tile x cluster pairs whose cone meets the tile's "
            "bounding volume"),
    Counter("tile_triangle_pairs", "int", "tile x triangle cone tests (triangles of surviving "
            "clusters)"),
    Counter("tile_triangles", "int", "entries of all tile triangle lists before the capacity "
            "limit"),
    Counter("tile_triangles_max", "int", "longest tile triangle list before the capacity limit"),
    Counter("tile_list_lengths", "array", "triangle list length of each tile (before the "
            "capacity limit), tile-major"),
    Counter("tile_triangles_per_pixel", "map", "the triangle list length of the pixel's tile"),
    Counter("overflow_tiles", "int", "tiles whose triangle list exceeds the capacity"),
    Counter("overflow_tiles_per_pixel", "map", "1 where the pixel's tile overflowed its list"),
    Counter("dropped_entries", "int", "tile list entries beyond the capacity that were not "
            "evaluated (on_overflow='truncate'; those tiles may be wrong)"),
    Counter("rasterized_triangles", "int", "pixel x triangle pairs passing the per-pixel quick "
            "reject (in front, above the tangent plane, near the disk; with record='sphere' "
            "or 'both' also the bounding-sphere test) and rasterized"),
    Counter("rasterized_per_pixel", "map", "triangles rasterized (or summed) for each pixel"),
    Counter("near_clamp_per_pixel", "map", "rasterized triangles with a vertex behind the "
            "fragment or closer than the paper's clamp depth (s |z| < 1e-4), where its abs() "
            "and max() act"),
    # light-space methods (shadow_map, izb; docs/shadow_map.md, docs/izb.md)
    Counter("light_faces", "int", "faces of the light camera (1, or 6 for a cube)"),
    Counter("light_texels", "int", "distinct light texels read by the lookups (the only texels "
            "rasterized)"),
    Counter("sm_fragments", "int", "shadow-map fragments: triangle x texel pairs whose texel "
            "centre the triangle covers, over the texels read"),
    Counter("list_nodes", "int", "IZB: samples inserted in texel lists"),
    Counter("list_length_max", "int", "IZB: longest texel list"),
    Counter("list_length_per_pixel", "map", "IZB: length of the list of the pixel's texel (0 "
            "for samples not inserted)"),
    Counter("list_nonempty_texels", "int", "IZB: texels with a non-empty list"),
    Counter("traced_fragments", "int", "IZB: triangle x texel pairs traced (outer-conservative "
            "fragments on non-empty texels that the depth buffer did not cull)"),
    Counter("depth_culled_fragments", "int", "IZB: outer-conservative fragments on non-empty "
            "texels culled by the farthest-node depth buffer"),
    Counter("csm_texels", "int", "CSM: occupied texels (holding a sample) fully covered by a "
            "caster, so holding a conservative depth"),
    Counter("csm_small_casters", "int", "CSM: casters (per light face) not drawn because they "
            "cannot cover a texel: light-space area below 2 texels, or inradius below the "
            "inner test's disk plus its margin (thin casters; an exact skip)"),
    Counter("csm_culled", "int", "CSM: samples culled by the prepass (shadowed, not inserted)"),
    Counter("csm_culled_per_pixel", "map", "1 where the prepass culled the pixel's sample"),
    Counter("csm_false_shadows", "int", "CSM: culled samples that the exact test over every "
            "caster finds lit; must be 0 (-1 when the check is off)"),
    Counter("raster_lanes", "int", "pixel lanes the vectorized rasterizer executed: the sum "
            "over its steps of the lanes each step ran on (deferred with compact: per round "
            "the whole batch's or the flush blocks' lanes; rasterized_triangles of them did "
            "work)"),
    Counter("recorded_pairs", "int", "pixel x triangle pairs the record pass queued for the "
            "rasterizer: those passing the exact quick reject (= rasterized_triangles), or "
            "with record='sphere' those whose bounding sphere meets the pixel's light cone "
            "(the flush then runs the exact quick reject on each), with 'both' those "
            "passing both (= rasterized_triangles)"),
    Counter("cas_failures", "int", "reference kernels: compare-and-swap operations that lost a "
            "race (the slot was taken by another thread first); 0 in a serial schedule"),
]}


def check(counters: dict) -> None:
    """Raise KeyError for a counter name that is not in the table."""
    unknown = sorted(set(counters) - set(COUNTERS))
    if unknown:
        raise KeyError(f"counters not in shadowlab.core.counters.COUNTERS: {unknown}")


def markdown_table() -> str:
    """The counter table as Markdown (for the docs)."""
    rows = ["| counter | kind | meaning |", "|---|---|---|"]
    rows += [f"| `{c.name}` | {c.kind} | {c.meaning} |" for c in COUNTERS.values()]
    return "\n".join(rows)


if __name__ == "__main__":
    # python -m shadowlab.core.counters > docs/counters.md
    print("# Counters\n")
    print("Every method and reference kernel reports counters by these names "
          "(`shadowlab/core/counters.py` is the source; regenerate this file with "
          "`python -m shadowlab.core.counters > docs/counters.md`).\n")
    print(markdown_table())
