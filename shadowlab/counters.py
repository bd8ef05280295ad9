"""The one table of counter names shared by every method and reference kernel.

A method reports only the counters that apply to it. Scalar counters are Python
ints or floats; per-pixel counters are arrays [H, W] and end in ``_per_pixel``.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Counter:
    name: str
    kind: str      # "int" (an exact count), "float", or "map" (int array [H, W])
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
]}


def check(counters: dict) -> None:
    """Raise KeyError for a counter name that is not in the table."""
    unknown = sorted(set(counters) - set(COUNTERS))
    if unknown:
        raise KeyError(f"counters not in shadowlab.counters.COUNTERS: {unknown}")


def markdown_table() -> str:
    """The counter table as Markdown (for the docs)."""
    rows = ["| counter | kind | meaning |", "|---|---|---|"]
    rows += [f"| `{c.name}` | {c.kind} | {c.meaning} |" for c in COUNTERS.values()]
    return "\n".join(rows)
