"""``ptsv``: per-triangle shadow volumes over a 2D tile hierarchy (Sintorn et al. 2011).

The baseline of Sintorn et al. 2014, modelled as that paper describes it: a full
32-ary tree over the image whose leaves are 8 x 4 pixel tiles (32 view samples) and
whose inner nodes alternate 4 x 8 and 8 x 4 children (32 x 32, 256 x 128, 1024 x 1024
pixels at 1024 x 1024), each node bounded by its 2D tile rectangle and the min / max
depth of its samples (a hierarchical depth buffer). Triangles are traversed with the
same engine (:mod:`shadowlab.engines.traversal`), node tests, planes and exact leaf test
as ``clustered_ptsv`` (its ``run_traversal_method`` with ``kind="ptsv"``); the extra culling
planes are PTSV's two 2D silhouette edges of the shadow volume (option
``culling_planes``). Empty tiles (no view sample) are absent from the tree.
"""

from __future__ import annotations

from .clustered_ptsv import (COMMON_TRAVERSAL_OPTIONS, PAPER_OPTIONS, TRAVERSAL_DECLARATION,
                             run_traversal_method)
from .registry import register


@register("ptsv", doc="per-triangle shadow volumes over a 2D min/max depth tile hierarchy "
          "(8x4 leaf tiles)", paper="Sintorn et al. 2011 (as described in 2014)",
          **TRAVERSAL_DECLARATION, presets={"paper": PAPER_OPTIONS["ptsv"]},
          options={k: v for k, v in COMMON_TRAVERSAL_OPTIONS.items() if k != "leaf_samples"})
def ptsv(scene, gbuf, light, **opts):
    result, _ = run_traversal_method(scene, gbuf, light, kind="ptsv", method="ptsv",
                                     options=opts, **opts)
    return result
