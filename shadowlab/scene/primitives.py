"""Triangle-mesh primitives for the procedural scenes.

Every function returns ``(vertices, faces)``: vertices float64 [v, 3] in world units,
faces int32 [f, 3] indexing them. Closed primitives (box, sphere, cylinder, prism)
share vertices along every edge, so they are watertight, and are wound
counter-clockwise seen from outside (outward normals by the right-hand rule).
Open primitives (grids) are wound so that their normal points along +Y.

Batched helpers (:func:`boxes`, :func:`instances`) build many copies in one vectorised
step; construction cost is O(output) NumPy work with no Python loop per triangle.
"""

from __future__ import annotations

import math

import numpy as np

Mesh = tuple[np.ndarray, np.ndarray]


def _mesh(vertices, faces) -> Mesh:
    return (np.ascontiguousarray(vertices, dtype=np.float64),
            np.ascontiguousarray(faces, dtype=np.int32))


def merge(meshes: list[Mesh]) -> Mesh:
    """Concatenate meshes into one (face indices are offset, nothing is welded)."""
    verts, faces, off = [], [], 0
    for v, f in meshes:
        verts.append(v)
        faces.append(np.asarray(f, dtype=np.int64) + off)
        off += len(v)
    return _mesh(np.concatenate(verts), np.concatenate(faces))


def grid_faces(nx: int, nz: int) -> np.ndarray:
    """int32 [2 (nx-1) (nz-1), 3]: two triangles per cell of an nx x nz vertex grid.

    Vertex (i, j) (row j along z, column i along x) has index ``j * nx + i``. The
    winding gives +Y normals when x grows with i and z grows with j.
    """
    j, i = np.meshgrid(np.arange(nz - 1), np.arange(nx - 1), indexing="ij")
    a = (j * nx + i).reshape(-1)       # (i, j)
    b = a + 1                          # (i+1, j)
    c = a + nx                         # (i, j+1)
    d = c + 1                          # (i+1, j+1)
    # (a, c, b): (0,0,0)->(0,0,1)->(1,0,0): cross(dz, dx) = +Y.
    return np.stack([np.stack([a, c, b], 1), np.stack([b, c, d], 1)], 1).reshape(-1, 3) \
        .astype(np.int32)


def height_grid(heights: np.ndarray, x_range: tuple[float, float],
                z_range: tuple[float, float]) -> Mesh:
    """A height field over a regular grid (an open surface, normals towards +Y).

    Args:
        heights: float [nz, nx] (nx, nz >= 2), y of each grid vertex, world units.
        x_range, z_range: (min, max) extent of the grid, world units.

    Returns:
        vertices [nz * nx, 3], faces [2 (nx-1) (nz-1), 3].
    """
    heights = np.asarray(heights, dtype=np.float64)
    nz, nx = heights.shape
    xs = np.linspace(x_range[0], x_range[1], nx)
    zs = np.linspace(z_range[0], z_range[1], nz)
    zz, xx = np.meshgrid(zs, xs, indexing="ij")
    verts = np.stack([xx, heights, zz], axis=-1).reshape(-1, 3)
    return _mesh(verts, grid_faces(nx, nz))


def quad_grid(x_range: tuple[float, float], z_range: tuple[float, float], y: float = 0.0,
              cells: int = 1) -> Mesh:
    """A flat horizontal rectangle at height ``y`` split into cells x cells squares.

    Returns:
        vertices [(cells+1)^2, 3], faces [2 cells^2, 3]; normals +Y.
    """
    return height_grid(np.full((cells + 1, cells + 1), float(y)), x_range, z_range)


_BOX_CORNERS = np.array([[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)],
                        dtype=np.float64)   # corner c has x = bit 0, y = bit 1, z = bit 2
_BOX_FACES = np.array([
    [0, 4, 6], [0, 6, 2],   # -x
    [1, 3, 7], [1, 7, 5],   # +x
    [0, 1, 5], [0, 5, 4],   # -y
    [2, 6, 7], [2, 7, 3],   # +y
    [0, 2, 3], [0, 3, 1],   # -z
    [4, 5, 7], [4, 7, 6],   # +z
], dtype=np.int64)


def boxes(lo: np.ndarray, hi: np.ndarray) -> Mesh:
    """k axis-aligned closed boxes.

    Args:
        lo, hi: float [k, 3] (or [3]) opposite corners, world units.

    Returns:
        vertices [8 k, 3], faces [12 k, 3]; box i owns faces 12 i .. 12 i + 11.
    """
    lo = np.atleast_2d(np.asarray(lo, dtype=np.float64))
    hi = np.atleast_2d(np.asarray(hi, dtype=np.float64))
    lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
    verts = lo[:, None] + _BOX_CORNERS[None] * (hi - lo)[:, None]
    faces = _BOX_FACES[None] + 8 * np.arange(len(lo))[:, None, None]
    return _mesh(verts.reshape(-1, 3), faces.reshape(-1, 3))


def box(lo, hi) -> Mesh:
    """One closed axis-aligned box with corners ``lo``, ``hi`` [3]: 8 vertices, 12 faces."""
    return boxes(lo, hi)


def uv_sphere(stacks: int, slices: int) -> Mesh:
    """A closed unit sphere at the origin (latitude/longitude tessellation).

    Args:
        stacks: latitude bands (>= 2); slices: longitude sectors (>= 3).

    Returns:
        vertices [slices (stacks-1) + 2, 3], faces [2 slices (stacks-1), 3]. The two
        poles are single vertices; faces are ordered band by band from the north pole.
    """
    if stacks < 2 or slices < 3:
        raise ValueError(f"uv_sphere needs stacks >= 2 and slices >= 3, got {stacks}, {slices}")
    theta = np.pi * np.arange(1, stacks) / stacks             # polar angle of inner rings
    phi = 2 * np.pi * np.arange(slices) / slices
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack([st * np.cos(phi), np.broadcast_to(ct, (stacks - 1, slices)),
                     -st * np.sin(phi)], axis=-1).reshape(-1, 3)
    north, south = len(ring), len(ring) + 1
    verts = np.concatenate([ring, [[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]])
    s = np.arange(slices)
    s1 = (s + 1) % slices
    faces = [np.stack([np.full(slices, north), s, s1], 1)]     # north cap
    if stacks > 2:
        r = np.arange(stacks - 2)[:, None]
        a = r * slices + s                                      # ring r
        b = r * slices + s1
        c = a + slices                                          # ring r + 1 (further south)
        d = b + slices
        faces.append(np.stack([np.stack([a, c, d], -1), np.stack([a, d, b], -1)], 2)
                     .reshape(-1, 3))
    last = (stacks - 2) * slices
    faces.append(np.stack([last + s, np.full(slices, south), last + s1], 1))  # south cap
    return _mesh(verts, np.concatenate(faces))


def sphere_resolution(triangles: int) -> tuple[int, int]:
    """(stacks, slices) of a UV sphere with about ``triangles`` = 2 slices (stacks-1)
    faces and slices ~ 2 stacks (square-ish quads at the equator)."""
    stacks = max(2, round((1 + math.sqrt(1 + triangles)) / 2))
    slices = max(3, round(triangles / (2 * (stacks - 1))))
    return stacks, slices


def cylinder(segments: int, rings: int = 1) -> Mesh:
    """A closed unit cylinder: radius 1 around the +Y axis, y in [0, 1], with caps.

    Args:
        segments: sectors around the axis (>= 3); rings: bands along the axis (>= 1).

    Returns:
        vertices [(rings + 1) segments + 2, 3], faces [2 segments (rings + 1), 3]: the
        side band by band from y = 0, then the bottom and the top cap (fans).
    """
    if segments < 3 or rings < 1:
        raise ValueError(f"cylinder needs segments >= 3 and rings >= 1, got {segments}, "
                         f"{rings}")
    phi = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([np.cos(phi), np.zeros(segments), -np.sin(phi)], 1)
    levels = [ring + [0.0, k / rings, 0.0] for k in range(rings + 1)]
    verts = np.concatenate(levels + [[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    s = np.arange(segments)
    s1 = (s + 1) % segments
    n = segments
    side = [np.concatenate([np.stack([s + k * n, s1 + k * n, s1 + (k + 1) * n], 1),
                            np.stack([s + k * n, s1 + (k + 1) * n, s + (k + 1) * n], 1)])
            for k in range(rings)]
    centre = (rings + 1) * n
    top = rings * n
    faces = np.concatenate(side + [
        np.stack([np.full(n, centre), s1, s], 1),                           # bottom cap
        np.stack([np.full(n, centre + 1), top + s, top + s1], 1),           # top cap
    ])
    return _mesh(verts, faces)


def torus(major_segments: int, minor_segments: int, minor_radius: float) -> Mesh:
    """A closed torus around the +Y axis: the tube's centre circle has radius 1 in the
    y = 0 plane, the tube radius ``minor_radius`` (0 < r < 1).

    Returns:
        vertices [M m, 3], faces [2 M m, 3] (M = major_segments >= 3 sectors around the
        axis, m = minor_segments >= 3 around the tube), wound outward.
    """
    if major_segments < 3 or minor_segments < 3 or not 0 < minor_radius < 1:
        raise ValueError("torus needs major_segments, minor_segments >= 3 and 0 < "
                         f"minor_radius < 1, got {major_segments}, {minor_segments}, "
                         f"{minor_radius}")
    big, small = major_segments, minor_segments
    u = 2 * np.pi * np.arange(big)[:, None] / big
    v = 2 * np.pi * np.arange(small)[None, :] / small
    radial = 1 + minor_radius * np.cos(v)
    verts = np.stack([np.cos(u) * radial, np.broadcast_to(minor_radius * np.sin(v),
                                                           (big, small)),
                      -np.sin(u) * radial], axis=-1).reshape(-1, 3)
    i = np.arange(big)[:, None]
    j = np.arange(small)[None, :]
    a = i * small + j
    b = i * small + (j + 1) % small
    c = ((i + 1) % big) * small + j
    d = ((i + 1) % big) * small + (j + 1) % small
    faces = np.stack([np.stack([a, c, d], -1), np.stack([a, d, b], -1)], 2).reshape(-1, 3)
    return _mesh(verts, faces)


def capsule(stacks: int, slices: int, half_length: float) -> Mesh:
    """A closed capsule along Y: a unit sphere (:func:`uv_sphere`, an odd number of
    ``stacks`` so that no vertex lies on the equator) whose northern half is moved up and
    southern half down by ``half_length`` (>= 0); the band across the equator becomes
    the cylinder between the two hemispheres. Faces as :func:`uv_sphere`."""
    if stacks % 2 == 0:
        raise ValueError(f"capsule needs an odd number of stacks, got {stacks}")
    if not half_length >= 0:
        raise ValueError(f"capsule needs half_length >= 0, got {half_length}")
    verts, faces = uv_sphere(stacks, slices)
    verts = verts.copy()
    verts[:, 1] += np.sign(verts[:, 1]) * half_length
    return _mesh(verts, faces)


def gable_prism(lo, hi) -> Mesh:
    """A closed gabled roof: a triangular prism filling the box ``lo``..``hi`` [3]
    with its ridge along x at the top centre (z midway): 6 vertices, 8 faces."""
    (x0, y0, z0), (x1, y1, z1) = np.asarray(lo, float), np.asarray(hi, float)
    zm = 0.5 * (z0 + z1)
    verts = [[x0, y0, z0], [x0, y0, z1], [x0, y1, zm],
             [x1, y0, z0], [x1, y0, z1], [x1, y1, zm]]
    faces = [[0, 1, 2], [3, 5, 4],                 # gable ends (-x, +x)
             [0, 3, 4], [0, 4, 1],                 # bottom
             [1, 4, 5], [1, 5, 2],                 # +z slope
             [0, 2, 5], [0, 5, 3]]                 # -z slope
    return _mesh(verts, faces)


def instances(vertices: np.ndarray, faces: np.ndarray, offsets: np.ndarray,
              scales: np.ndarray | float = 1.0,
              rotations: np.ndarray | None = None) -> Mesh:
    """k transformed copies of one mesh, ``p' = offset + rotation @ (scale * p)``.

    Args:
        vertices [v, 3], faces [f, 3]: the template.
        offsets: float [k, 3] translations.
        scales: float, [k] uniform or [k, 3] per-axis scale factors.
        rotations: optional float [k, 3, 3] rotation matrices.

    Returns:
        vertices [k v, 3], faces [k f, 3]; copy i owns faces f i .. f (i+1) - 1.
    """
    offsets = np.atleast_2d(np.asarray(offsets, dtype=np.float64))
    k = len(offsets)
    s = np.asarray(scales, dtype=np.float64)
    s = np.broadcast_to(s.reshape(-1, 1) if s.ndim == 1 else s, (k, 3)) if s.ndim else \
        np.full((k, 3), float(s))
    v = vertices[None] * s[:, None]                                   # [k, v, 3]
    if rotations is not None:
        v = np.einsum("kij,kvj->kvi", rotations, v)
    v = v + offsets[:, None]
    f = faces[None].astype(np.int64) + len(vertices) * np.arange(k)[:, None, None]
    return _mesh(v.reshape(-1, 3), f.reshape(-1, 3))


def triangle_soup(corners: np.ndarray) -> Mesh:
    """Independent triangles (no shared vertices) from corners float [m, 3, 3]."""
    corners = np.asarray(corners, dtype=np.float64)
    return _mesh(corners.reshape(-1, 3), np.arange(3 * len(corners)).reshape(-1, 3))


def random_rotations(rng: np.random.Generator, k: int) -> np.ndarray:
    """float64 [k, 3, 3]: uniformly distributed random rotation matrices."""
    q = rng.normal(size=(k, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Volume enclosed by a closed mesh, positive when its faces are wound outward."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
