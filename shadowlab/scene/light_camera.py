"""Light-space cameras for methods that rasterize from the light (shadow maps, the
irregular z-buffer).

A :class:`LightCamera` is one or six :class:`LightFace` s, each an R x R texel grid
with OpenGL-style view and projection matrices (as :class:`~shadowlab.scene.Camera`:
view space looks down -Z, clip space is [-w, w] on every axis):

- **directional light** -> one orthographic face whose -Z is the light's travel
  direction, with a square x/y extent fitted to the given points;
- **point light** -> one perspective face from the light towards the points'
  bounding box, its field of view fitted to enclose them, or, when the points
  surround the light (their box contains it, or the fitted field of view would
  exceed ``max_fov_deg``), a **cube** of six 90 degree faces, each point in the face
  of the dominant axis of its direction from the light.

Texel coordinates ``uv`` are continuous (column, row): texel (i, j) covers
[i, i + 1) x [j, j + 1), its centre is at (i + 0.5, j + 0.5), row 0 is the top
(as image rows, like the camera's pixel (0, 0)); ``floor(uv)`` is the texel.
``depth`` is the linear distance along the face's view axis (-z in view space),
world units. The fit leaves ``padding`` texels (default 1) between the points'
extent and the grid border, and near/far margins, so every fitted point lands
inside [0, R) x [0, R) with ``near <= depth <= far``. ``casters`` (points between
the fitted points and the light, e.g. the scene's vertices or its bounding-box
corners) only move ``near`` towards the light so that they are not clipped.

All computations are float64, whatever the dtype of the input points. Points are
transformed by :func:`affine_rows`, elementwise sums in a fixed order, not by matrix
products: the rounding does not depend on BLAS (whose threads, competing for a loaded
machine, made a [N, 4] x [4, 4] product ten times slower than the arithmetic), and the
fit, :meth:`LightFace.project` and :meth:`LightFace.depth` round alike.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Union

import numpy as np

from .view import DirectionalLight, Light, PointLight, hard_light, look_at, perspective

PROJECTIONS = ("auto", "orthographic", "perspective", "cube")
# The six cube faces: (name, view axis (forward), up), OpenGL cube-map order and orientation.
CUBE_FACES = (
    ("+x", (1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
    ("-x", (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
    ("+y", (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    ("-y", (0.0, -1.0, 0.0), (0.0, 0.0, -1.0)),
    ("+z", (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
    ("-z", (0.0, 0.0, -1.0), (0.0, -1.0, 0.0)),
)


def orthographic(left: float, right: float, bottom: float, top: float,
                 near: float, far: float) -> np.ndarray:
    """float64 [4, 4]: OpenGL orthographic projection (glOrtho), view -> clip.

    Maps view-space x in [left, right], y in [bottom, top], z in [-near, -far]
    (world units) to [-1, 1] each; w stays 1.
    """
    m = np.zeros((4, 4))
    m[0, 0] = 2.0 / (right - left)
    m[1, 1] = 2.0 / (top - bottom)
    m[2, 2] = -2.0 / (far - near)
    m[0, 3] = -(right + left) / (right - left)
    m[1, 3] = -(top + bottom) / (top - bottom)
    m[2, 3] = -(far + near) / (far - near)
    m[3, 3] = 1.0
    return m


def box_corners(bounds: np.ndarray) -> np.ndarray:
    """float64 [8, 3]: the corners of an axis-aligned box ``bounds`` [2, 3] (min, max),
    e.g. ``scene.bounds`` as the points or casters of a fit."""
    b = np.asarray(bounds, dtype=np.float64)
    i = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
    return b[i, [0, 1, 2]]


def columns(points: np.ndarray) -> np.ndarray:
    """float64 [3, N]: the coordinates of world ``points`` [N, 3] as contiguous rows."""
    return np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)


def affine_rows(cols: np.ndarray, m: np.ndarray, rows) -> list[np.ndarray]:
    """Rows ``rows`` of ``m`` [>=3, 4] applied to the points (x, y, z, 1) given as
    ``cols`` [3, N] (:func:`columns`): float64 [N] each,
    ``((x m[i,0] + y m[i,1]) + z m[i,2]) + m[i,3]``.

    Each product is rounded, then added in that fixed order (k = 0..3; the fourth
    coordinate is 1, so its product is exact). Terms with a zero coefficient are left
    out: they add a signed zero, which can only change the sign of a zero result.
    """
    m = np.asarray(m, dtype=np.float64)
    out = []
    for i in rows:
        acc = None
        for k in range(3):
            c = float(m[i, k])
            if c == 0.0:
                continue
            if acc is None:
                acc = cols[k] * c
            else:
                acc += cols[k] * c
        if acc is None:
            acc = np.full(cols.shape[1], float(m[i, 3]))
        elif m[i, 3] != 0.0:
            acc += float(m[i, 3])
        out.append(acc)
    return out


def _up_helper(forward: np.ndarray) -> np.ndarray:
    """A deterministic up vector not parallel to ``forward`` (unit)."""
    return np.array([1.0, 0.0, 0.0]) if abs(forward[1]) > 0.9 else np.array([0.0, 1.0, 0.0])


def _points(x, name: str) -> np.ndarray:
    p = np.asarray(x, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
        raise ValueError(f"{name} must be finite points of shape [N, 3], got shape {p.shape}")
    return p


@dataclasses.dataclass(frozen=True, eq=False)
class LightFace:
    """One R x R texel grid seen from the light.

    Attributes:
        view: float64 [4, 4], world -> view (looks down -Z).
        projection: float64 [4, 4], view -> clip (OpenGL, [-w, w]).
        resolution: (R, R) texels.
        near, far: depth range along the view axis, world units.
        eye: float64 [3], the view origin (the light for perspective faces; a point
            on the light side of everything fitted for orthographic ones).
        forward: float64 [3], unit view axis (-Z of view space), world.
        up: float64 [3], the up vector given to the look-at.
        fov_deg: full (square) field of view in degrees; None when orthographic.
        half_extent: half the side of the orthographic window, world units; None
            when perspective.
        name: "ortho", "persp", or the cube face ("+x", "-x", ..., "-z").
    """

    view: np.ndarray
    projection: np.ndarray
    resolution: tuple[int, int]
    near: float
    far: float
    eye: np.ndarray
    forward: np.ndarray
    up: np.ndarray
    fov_deg: float | None = None
    half_extent: float | None = None
    name: str = ""

    @property
    def orthographic(self) -> bool:
        return self.fov_deg is None

    @property
    def view_projection(self) -> np.ndarray:
        """float64 [4, 4]: world -> clip."""
        return self.projection @ self.view

    @property
    def texel_size(self) -> float:
        """Side of one texel: world units (orthographic) or units of the tangent
        plane at distance 1 (perspective)."""
        r = self.resolution[0]
        if self.orthographic:
            return 2.0 * self.half_extent / r
        return 2.0 * math.tan(math.radians(self.fov_deg) / 2) / r

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Texel coordinates and depths of world ``points`` [N, 3] (any float dtype).

        Returns:
            uv float64 [N, 2] (column, row; texel centres at +0.5; not clamped, so
            points outside the grid fall outside [0, R); meaningless for points with
            depth <= 0 on a perspective face), depth float64 [N] world units.
        """
        vx, vy, vz = affine_rows(columns(points), self.view, (0, 1, 2))
        # the view is rigid (row 3 is (0, 0, 0, 1)): view-space w is exactly 1
        cx, cy, cw = affine_rows(np.stack([vx, vy, vz]), self.projection, (0, 1, 3))
        r = self.resolution[0]
        uv = np.empty((len(vx), 2))
        uv[:, 0] = (cx / cw + 1.0) * 0.5 * r
        uv[:, 1] = (1.0 - cy / cw) * 0.5 * r
        return uv, -vz

    def depth(self, points: np.ndarray) -> np.ndarray:
        """float64 [N]: the depth of world ``points`` [N, 3] along the view axis (world
        units), bit for bit the depth of :meth:`project`, without the texel coordinates."""
        return -affine_rows(columns(points), self.view, (2,))[0]

    def unproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """float64 [N, 3]: the world points with texel coordinates ``uv`` [N, 2] and
        ``depth`` [N] (the inverse of :meth:`project`)."""
        uv = np.asarray(uv, dtype=np.float64)
        depth = np.asarray(depth, dtype=np.float64)
        r = self.resolution[0]
        nx = uv[:, 0] / r * 2.0 - 1.0
        ny = 1.0 - uv[:, 1] / r * 2.0
        m = self.projection
        if self.orthographic:
            x, y = (nx - m[0, 3]) / m[0, 0], (ny - m[1, 3]) / m[1, 1]
        else:
            x, y = nx * depth / m[0, 0], ny * depth / m[1, 1]
        v = np.stack([x, y, -depth, np.ones_like(x)], axis=1)
        return (v @ np.linalg.inv(self.view).T)[:, :3]


@dataclasses.dataclass(frozen=True, eq=False)
class LightCamera:
    """The light-space camera of a light: one face, or six for a cube.

    Attributes:
        kind: "orthographic", "perspective" or "cube".
        faces: the faces (1, or 6 in :data:`CUBE_FACES` order).
        light: the hard light it was fitted for (PointLight or DirectionalLight).
        resolution: (R, R) texels per face.
    """

    kind: str
    faces: tuple[LightFace, ...]
    light: Union[PointLight, DirectionalLight]
    resolution: tuple[int, int]

    @property
    def near(self) -> float:
        return self.faces[0].near

    @property
    def far(self) -> float:
        return self.faces[0].far

    def face_of(self, points: np.ndarray) -> np.ndarray:
        """int32 [N]: the face of each world point. For a cube: the dominant axis of
        its direction d from the light, 2 * axis + (d[axis] < 0), ties to the lower
        axis; otherwise 0."""
        p = np.asarray(points, dtype=np.float64)
        if self.kind != "cube":
            return np.zeros(len(p), dtype=np.int32)
        d = p - self.light.position
        axis = np.argmax(np.abs(d), axis=1)
        neg = np.take_along_axis(d, axis[:, None], axis=1)[:, 0] < 0
        return (2 * axis + neg).astype(np.int32)

    def to_texels(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Map world ``points`` [N, 3] (float32 or float64) to light texels.

        Returns:
            face int32 [N]; uv float64 [N, 2] texel coordinates on that face (column,
            row, texel centres at +0.5); depth float64 [N], world units along the
            face's view axis. On a cube, points on a seam (|d_i| = |d_j|) may round a
            few ulps outside their face and are clamped onto its border.
        """
        if len(self.faces) == 1:
            uv, depth = self.faces[0].project(points)
            return np.zeros(len(uv), dtype=np.int32), uv, depth
        p = np.asarray(points, dtype=np.float64)
        face = self.face_of(p)
        uv = np.empty((len(p), 2))
        depth = np.empty(len(p))
        for f in np.unique(face):
            sel = face == f
            uv[sel], depth[sel] = self.faces[f].project(p[sel])
        if self.kind == "cube":
            r = float(self.resolution[0])
            np.clip(uv, 0.0, np.nextafter(r, 0.0), out=uv)
        return face, uv, depth


def fit_light_camera(light: Light, points: np.ndarray, casters: np.ndarray | None = None,
                     resolution: int = 1024, projection: str = "auto",
                     max_fov_deg: float = 120.0, padding: int = 1) -> LightCamera:
    """Fit the light-space camera of ``light`` to ``points``.

    Args:
        light: PointLight, DirectionalLight, or SphereLight (its centre light is used).
        points: [N, 3] world points that must land on the grid (the view samples'
            positions, or ``box_corners(scene.bounds)``), N >= 1.
        casters: optional [M, 3] world points that may occlude ``points`` (only
            ``near`` moves to include those towards the light).
        resolution: R, texels per side of every face (R > 2 * padding).
        projection: "auto"; for point lights "perspective" or "cube" force one;
            "orthographic" only for directional lights.
        max_fov_deg: widest single perspective face before "auto" picks the cube,
            degrees in (0, 180).
        padding: texels left free between the points' extent and the grid border.

    Raises:
        ValueError: bad arguments; a point coincides with a point light; a forced
            single perspective face that cannot enclose the points.
    """
    light = hard_light(light)
    p = _points(points, "light camera points")
    if len(p) == 0:
        raise ValueError("light camera needs at least one point to fit")
    c = p[:0] if casters is None else _points(casters, "light camera casters")
    r = int(resolution)
    if r != resolution or r <= 2 * int(padding) or padding < 0:
        raise ValueError(f"light camera resolution must be an integer > 2 * padding "
                         f"({2 * int(padding)}), got {resolution}")
    if projection not in PROJECTIONS:
        raise ValueError(f"light camera projection must be one of {PROJECTIONS}, "
                         f"got {projection!r}")
    if not 0 < max_fov_deg < 180:
        raise ValueError(f"light camera max_fov_deg must be in (0, 180), got {max_fov_deg}")
    grow = r / (r - 2 * int(padding))  # tight extent -> padded extent
    if isinstance(light, DirectionalLight):
        if projection not in ("auto", "orthographic"):
            raise ValueError(f"a directional light has an orthographic light camera, "
                             f"not {projection!r}")
        face = _fit_orthographic(light.direction, columns(p), c, r, grow)
        return LightCamera("orthographic", (face,), light, (r, r))
    if projection == "orthographic":
        raise ValueError("a point light has a perspective or cube light camera, "
                         "not 'orthographic'")
    cols = columns(p)
    if not np.all(np.any(cols != np.asarray(light.position)[:, None], axis=0)):
        raise ValueError("a light camera point coincides with the point light")
    if projection != "cube":
        face = _fit_perspective(light.position, cols, c, r, grow, max_fov_deg)
        if face is not None:
            return LightCamera("perspective", (face,), light, (r, r))
        if projection == "perspective":
            raise ValueError(f"the points surround the light: no single perspective face "
                             f"of at most {max_fov_deg} degrees encloses them")
    return LightCamera("cube", _fit_cube(light.position, p, c, r), light, (r, r))


def _margin(scale: float, cols: np.ndarray) -> float:
    """A small positive depth margin, world units, relative to the fitted size."""
    if scale > 0:
        return 1e-3 * scale
    return 1e-3 * max(1.0, float(np.abs(cols).max()))


def _fit_orthographic(direction, cols, c, r, grow) -> LightFace:
    """``cols`` [3, N]: the points' coordinates (:func:`columns`); ``c`` [M, 3]."""
    fwd = np.asarray(direction, dtype=np.float64)
    up = _up_helper(fwd)
    basis = np.zeros((3, 4))
    basis[:2, :3] = look_at(np.zeros(3), fwd, up)[:2, :3]  # rows: right, up
    basis[2, :3] = fwd
    x, y, along = affine_rows(cols, basis, (0, 1, 2))
    lo = np.array([x.min(), y.min()])
    hi = np.array([x.max(), y.max()])
    centre = (lo + hi) / 2
    half = float((hi - lo).max()) / 2
    c_along = affine_rows(columns(c), basis, (2,))[0] if len(c) else along[:0]
    near_along = float(min(along.min(), c_along.min() if len(c) else np.inf))
    far_along = float(along.max())
    margin = _margin(max(far_along - near_along, 2 * half), cols)
    if half == 0:
        half = margin
    half *= grow
    eye = basis[0, :3] * centre[0] + basis[1, :3] * centre[1] + fwd * (near_along - margin)
    near, far = 0.5 * margin, far_along - near_along + 1.5 * margin
    view = look_at(eye, eye + fwd, up)
    proj = orthographic(-half, half, -half, half, near, far)
    return LightFace(view, proj, (r, r), near, far, eye, fwd, up, None, half, "ortho")


def _fit_perspective(position, cols, c, r, grow, max_fov_deg) -> LightFace | None:
    """``cols`` [3, N]: the points' coordinates (:func:`columns`); ``c`` [M, 3]."""
    lo, hi = cols.min(axis=1), cols.max(axis=1)
    if np.all((lo <= position) & (position <= hi)):
        return None  # the box contains the light
    target = (lo + hi) / 2
    fwd = (target - position) / np.linalg.norm(target - position)
    up = _up_helper(fwd)
    view = look_at(position, target, up)
    vx, vy, vz = affine_rows(cols, view, (0, 1, 2))   # as LightFace.project rounds them
    depth = -vz
    if depth.min() <= 0:
        return None
    tan_max = float((np.maximum(np.abs(vx), np.abs(vy)) / depth).max())
    tan_half = tan_max * grow if tan_max > 0 else 1e-6
    fov = 2 * math.degrees(math.atan(tan_half))
    if fov > max_fov_deg:
        return None
    cdepth = -affine_rows(columns(c), view, (2,))[0] if len(c) else depth[:0]
    cdepth = cdepth[cdepth > 0]
    near = 0.5 * float(min(depth.min(), cdepth.min() if len(cdepth) else np.inf))
    far = float(depth.max()) * (1 + 1e-3)
    return LightFace(view, perspective(fov, 1.0, near, far), (r, r), near, far,
                     np.asarray(position, dtype=np.float64).copy(), fwd, up, fov, None,
                     "persp")


def _fit_cube(position, p, c, r) -> tuple[LightFace, ...]:
    dom = np.abs(p - position).max(axis=1)
    cdom = np.abs(c - position).max(axis=1) if len(c) else dom[:0]
    cdom = cdom[cdom > 0]
    near = 0.5 * float(min(dom.min(), cdom.min() if len(cdom) else np.inf))
    far = float(dom.max()) * (1 + 1e-3)
    proj = perspective(90.0, 1.0, near, far)
    eye = np.asarray(position, dtype=np.float64)
    faces = []
    for name, fwd, up in CUBE_FACES:
        fwd, up = np.array(fwd), np.array(up)
        faces.append(LightFace(look_at(eye, eye + fwd, up), proj, (r, r), near, far,
                               eye.copy(), fwd, up, 90.0, None, name))
    return tuple(faces)
