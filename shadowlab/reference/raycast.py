"""Exact ray casting with Embree (through embreex): G-buffers and reference shadows.

Embree works in float32, so every cast runs in a frame-local copy of the scene:
the geometry and the rays are translated by ``-origin`` in float64 before the cast to
float32 (``origin`` from :func:`shadowlab.core.frame.frame_origin`, the camera eye
snapped to a coarse grid; one BVH per scene and origin is cached). Primary hits are
recomputed in float64 as the crossing of the float64 ray with the hit triangle's
float64 plane (Embree only picks the triangle), so every sample lies on its
triangle's plane up to float64 rounding and is accurate to float64 rounding along
the ray; the G-buffer keeps world positions and records the origin.

Shadow rays are cast *from the light towards the sample* and stop short of it where
they come within ``eps`` of the sample's tangent plane, ``eps = shadow_eps *
scene.diagonal`` (default ``shadow_eps = 1e-5``): the ray is cut by
``eps / max(n.l, 1e-6)`` along its length, ``n`` the sample's normal and ``l`` the unit
direction to the light. The sample's own triangle (and any surface through the
sample) is met exactly at the sample, so it is never hit, even for grazing rays whose
float32 hit distance is ill-conditioned; the segment tested is the exact segment
from the light to the sample less that cut. Only a blocker within ``eps`` of the
sample's tangent plane and on the ray (a contact) is missed. For a light at infinity the ray starts outside the scene's
bounding box. The exact methods use the same ``eps`` as their cap-plane bias, so the two
agree everywhere except within ``eps`` of contacts and within float32 rounding of
shadow boundaries; see docs/exactness.md for the measured tolerance.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import weakref

import numpy as np

from ..core.numerics import norms3
from ..scene.caches import per_scene_cache
from ..scene.mesh import Scene
from ..scene.view import Camera, Light, PointLight, SphereLight, hard_light

DEFAULT_SHADOW_EPS = 1e-5
_THREADS = 2          # embreex releases the GIL during a query: split rays over cores
_CHUNK = 1 << 20      # rays per Embree call, bounds the memory of one call


@dataclasses.dataclass(frozen=True, eq=False)
class GBuffer:
    """Per-pixel primary-hit data, arrays [H, W].

    Attributes:
        position: float64 [H, W, 3], position of the hit (0 where invalid), world
            coordinates for a G-buffer from :func:`render_gbuffer`.
        normal: float64 [H, W, 3], unit geometric normal turned to face the camera.
        depth: float64 [H, W], view-space depth -z_view (positive, world units; inf where
            invalid).
        triangle: int32 [H, W], hit triangle index into ``scene.faces``, -1 where invalid.
        valid: bool [H, W], the primary ray hit a triangle between near and far.
        camera: the camera that produced it (same coordinates as ``position``).
        origin: float64 [3], the frame origin the rays were cast in, in the same
            coordinates (``render_gbuffer``: the snapped camera eye; a G-buffer made
            frame-local by ``shadowlab.core.frame.localize`` has origin 0). Reference
            shadow rays are cast in this frame too. Default 0.
    """

    position: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    triangle: np.ndarray
    valid: np.ndarray
    camera: Camera
    origin: np.ndarray | None = None

    def __post_init__(self):
        origin = np.zeros(3) if self.origin is None else np.asarray(self.origin, np.float64)
        object.__setattr__(self, "origin", origin.reshape(3))

    @property
    def shape(self) -> tuple[int, int]:
        return self.valid.shape


_EMBREE_CACHE: "weakref.WeakKeyDictionary[Scene, dict]" = per_scene_cache()
_MAX_ORIGINS = 4        # BVHs kept per scene (one per frame origin; oldest dropped)


def _origin(origin) -> np.ndarray:
    return np.zeros(3) if origin is None else np.asarray(origin, np.float64).reshape(3)


def embree_scene(scene: Scene, origin=None):
    """The Embree scene (BVH) of ``scene`` translated by ``-origin`` (float64 [3],
    default 0): its float32 vertices are ``float32(v - origin)``. Built once and
    cached per Scene object and origin."""
    origin = _origin(origin)
    cache = _EMBREE_CACHE.setdefault(scene, {})
    key = tuple(origin.tolist())
    cached = cache.get(key)
    if cached is None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        cached = rtcore_scene.EmbreeScene()
        TriangleMesh(cached, np.ascontiguousarray(scene.triangles - origin, dtype=np.float32))
        if len(cache) >= _MAX_ORIGINS:
            cache.pop(next(iter(cache)))
        cache[key] = cached
    return cached


def _run_chunks(fn, n: int) -> None:
    """Call fn(lo, hi) over [0, n) in chunks, on ``_THREADS`` threads."""
    bounds = [(lo, min(lo + _CHUNK, n)) for lo in range(0, n, _CHUNK)]
    if n < 65536 or _THREADS == 1:
        for lo, hi in bounds:
            fn(lo, hi)
        return
    # Split each chunk in two so both threads get work even for a single chunk.
    parts = []
    for lo, hi in bounds:
        mid = (lo + hi) // 2
        parts += [(lo, mid), (mid, hi)]
    errors: list[BaseException] = []

    def worker(k):
        try:
            for lo, hi in parts[k::_THREADS]:
                fn(lo, hi)
        except BaseException as exc:  # re-raised in the caller
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(_THREADS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]


def intersect(scene: Scene, origins: np.ndarray, directions: np.ndarray,
              tfar: np.ndarray | None = None, frame=None) -> dict[str, np.ndarray]:
    """Closest hits of rays [N, 3]: ``primID`` int32 [N] (-1 = miss), ``u``, ``v``, ``t``.

    ``origins`` are world coordinates; the cast runs relative to ``frame`` (float64 [3],
    default 0): ray origins and geometry are translated in float64, then cast to float32.
    """
    es = embree_scene(scene, frame)
    n = len(origins)
    o = np.ascontiguousarray(np.asarray(origins, np.float64) - _origin(frame), dtype=np.float32)
    d = np.ascontiguousarray(directions, dtype=np.float32)
    far = None if tfar is None else np.ascontiguousarray(tfar, dtype=np.float32)
    prim = np.empty(n, np.int32)
    u = np.empty(n, np.float32)
    v = np.empty(n, np.float32)
    t = np.empty(n, np.float32)

    def fn(lo, hi):
        kw = {} if far is None else {"dists": far[lo:hi].copy()}
        r = es.run(o[lo:hi], d[lo:hi], output=1, **kw)
        prim[lo:hi] = r["primID"]
        u[lo:hi] = r["u"]
        v[lo:hi] = r["v"]
        t[lo:hi] = r["tfar"]

    _run_chunks(fn, n)
    return {"primID": prim, "u": u, "v": v, "t": t}


def occluded(scene: Scene, origins: np.ndarray, directions: np.ndarray,
             tfar: np.ndarray, frame=None) -> np.ndarray:
    """bool [N]: some triangle lies on the ray segment (origin, origin + tfar * dir);
    world ``origins``, cast relative to ``frame`` as in :func:`intersect`."""
    es = embree_scene(scene, frame)
    n = len(origins)
    o = np.ascontiguousarray(np.asarray(origins, np.float64) - _origin(frame), dtype=np.float32)
    d = np.ascontiguousarray(directions, dtype=np.float32)
    far = np.ascontiguousarray(np.minimum(tfar, 1e30), dtype=np.float32)
    out = np.empty(n, bool)

    def fn(lo, hi):
        r = es.run(o[lo:hi], d[lo:hi], dists=far[lo:hi].copy(), query="OCCLUDED")
        out[lo:hi] = np.asarray(r) >= 0

    _run_chunks(fn, n)
    return out


def segments_occluded(scene: Scene, points: np.ndarray, normals: np.ndarray,
                      light_points: np.ndarray | None = None,
                      light_dirs: np.ndarray | None = None, eps: float = 0.0,
                      frame=None) -> np.ndarray:
    """bool [N]: is the segment from each point [N, 3] to its light point blocked?

    Give ``light_points`` [N or 1, 3] (positions on the light) or ``light_dirs``
    [N or 1, 3] (unit directions to a light at infinity). The ray runs from the light
    to the point and stops where it comes within ``eps`` (world units) of the plane
    through the point with unit normal ``normals`` [N, 3]; for light points it starts
    ``eps`` from the light (a surface through the light is not hit). Points are world
    coordinates; Embree casts relative to ``frame`` (float64 [3], default 0).
    """
    points = np.asarray(points, dtype=np.float64)
    if light_points is not None:
        origin = np.broadcast_to(light_points, points.shape)
        seg = points - origin
        length = np.sqrt(np.einsum("ij,ij->i", seg, seg))
    else:
        w = np.broadcast_to(light_dirs, points.shape)
        lo, hi = scene.bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        # Start outside the bounding box: beyond its farthest corner along w.
        reach = np.max(w @ corners.T, axis=1) - np.einsum("ij,ij->i", points, w)
        length = np.maximum(reach, 0) + 0.01 * max(scene.diagonal, 1e-30)
        origin = points + w * length[:, None]
        seg = points - origin
    direction = seg / np.maximum(length, 1e-300)[:, None]
    facing = np.maximum(-np.einsum("ij,ij->i", direction, normals), 1e-6)
    far = length - eps / facing
    if light_points is not None:
        # The light's end: the ray starts eps from the light, so a surface through a
        # point light (edge-on to it, casting no shadow volume) is not hit at t = 0.
        origin = origin + eps * direction
        far = far - eps
    return occluded(scene, origin, direction, np.maximum(far, 0.0), frame)


def render_gbuffer(scene: Scene, camera: Camera) -> GBuffer:
    """Cast one primary ray per pixel centre; see :class:`GBuffer` for the fields.

    The rays are cast relative to the frame origin of the camera eye
    (:func:`shadowlab.core.frame.frame_origin`), recorded as ``GBuffer.origin``.
    """
    from ..core.frame import frame_origin

    frame = frame_origin(scene, camera.eye)
    origins, dirs = camera.primary_rays()
    h, w = camera.height, camera.width
    hit = intersect(scene, origins.reshape(-1, 3), dirs.reshape(-1, 3), frame=frame)
    tri = hit["primID"].astype(np.int32)
    valid = tri >= 0
    idx = np.flatnonzero(valid)
    corners = scene.triangles[tri[idx]] - frame              # [k, 3, 3] float64, local
    bu = hit["u"][idx].astype(np.float64)[:, None]
    bv = hit["v"][idx].astype(np.float64)[:, None]
    ng = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    # The float64 crossing of the float64 ray with the hit triangle's plane; Embree's
    # float32 barycentrics (error ~1e-7 of the triangle's size) only where the ray is
    # parallel to the plane at float64 precision.
    o = origins.reshape(-1, 3)[idx] - frame
    d = dirs.reshape(-1, 3)[idx].astype(np.float64)
    nd = np.einsum("ij,ij->i", ng, d)
    t = np.einsum("ij,ij->i", ng, corners[:, 0] - o) / np.where(nd != 0, nd, 1.0)
    bary = corners[:, 0] * (1 - bu - bv) + corners[:, 1] * bu + corners[:, 2] * bv
    pos = np.zeros((h * w, 3))
    pos[idx] = np.where((nd != 0)[:, None], o + t[:, None] * d, bary) + frame
    normal = np.zeros((h * w, 3))
    ng /= np.maximum(norms3(ng, keepdims=True), 1e-300)
    view_dir = pos[idx] - camera.eye
    ng *= np.where(np.einsum("ij,ij->i", ng, view_dir) > 0, -1.0, 1.0)[:, None]
    normal[idx] = ng
    _, _, back = camera.basis()
    depth = np.full(h * w, np.inf)
    depth[idx] = -(view_dir @ back)
    in_range = (depth >= camera.near) & (depth <= camera.far)
    valid &= in_range
    tri = np.where(valid, tri, -1)
    pos[~valid] = 0
    normal[~valid] = 0
    depth[~valid] = np.inf
    return GBuffer(position=pos.reshape(h, w, 3), normal=normal.reshape(h, w, 3),
                   depth=depth.reshape(h, w), triangle=tri.reshape(h, w),
                   valid=valid.reshape(h, w), camera=camera, origin=frame)


def shadow_epsilon(scene: Scene, shadow_eps: float = DEFAULT_SHADOW_EPS) -> float:
    """Absolute offset (world units) used against self-intersection and as cap bias."""
    return float(shadow_eps) * max(scene.diagonal, 1e-30)


def facing_test(n: np.ndarray, p: np.ndarray, light_h: np.ndarray) -> np.ndarray:
    """float64 [S]: the facing test ``n . (L.xyz - L.w p)`` of samples with normals n and
    positions p [S, 3] and a homogeneous light ``light_h`` [4], evaluated as
    ``n . L.xyz - L.w (n . p)`` (no normalization: its sign is the test)."""
    return n @ light_h[:3] - light_h[3] * np.einsum("ij,ij->i", n, p)


def facing_samples(gbuf: GBuffer, light: Light) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The valid samples whose camera-facing normal also faces the light.

    Returns:
        flat pixel indices int64 [S], positions float64 [S, 3], normals float64 [S, 3].
    """
    lh = hard_light(light).homogeneous
    p, n = gbuf.position.reshape(-1, 3), gbuf.normal.reshape(-1, 3)
    if gbuf.valid.all():                # no gather of every pixel before the test
        idx = None
    else:
        idx = np.flatnonzero(gbuf.valid)
        p, n = np.take(p, idx, axis=0), np.take(n, idx, axis=0)
    keep = np.flatnonzero(facing_test(n, p, lh) > 0)
    # np.take: a row gather about 2.5x faster than fancy indexing of [S, 3]
    return (keep if idx is None else idx[keep]), np.take(p, keep, axis=0), \
        np.take(n, keep, axis=0)


def light_facing(gbuf: GBuffer, light: Light) -> np.ndarray:
    """bool [H, W]: valid samples whose camera-facing normal also faces the light."""
    idx, _, _ = facing_samples(gbuf, light)
    out = np.zeros(gbuf.valid.size, bool)
    out[idx] = True
    return out.reshape(gbuf.valid.shape)


def reference_shadows(scene: Scene, gbuf: GBuffer, light: Light,
                      shadow_eps: float = DEFAULT_SHADOW_EPS) -> np.ndarray:
    """Exact hard shadows by one Embree shadow ray per candidate pixel.

    An area light is treated as its centre. See the module docstring for the
    self-intersection offset.

    Returns:
        bool [H, W], True = lit (valid, facing the light, segment to the light free).
    """
    hl = hard_light(light)
    idx, p, n = facing_samples(gbuf, hl)
    eps = shadow_epsilon(scene, shadow_eps)
    if isinstance(hl, PointLight):
        blocked = segments_occluded(scene, p, n, light_points=hl.position[None], eps=eps,
                                    frame=gbuf.origin)
    else:
        blocked = segments_occluded(scene, p, n, light_dirs=-hl.direction[None], eps=eps,
                                    frame=gbuf.origin)
    lit = np.zeros(gbuf.valid.size, bool)
    lit[idx] = ~blocked
    return lit.reshape(gbuf.valid.shape)


def _concentric_disk(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shirley-Chiu concentric map of the unit square onto the unit disk (area-preserving)."""
    a = 2 * u - 1
    b = 2 * v - 1
    use_a = np.abs(a) > np.abs(b)
    r = np.where(use_a, a, b)
    safe_a = np.where(a == 0, 1.0, a)
    safe_b = np.where(b == 0, 1.0, b)
    phi = np.where(use_a, (np.pi / 4) * (b / safe_a), np.pi / 2 - (np.pi / 4) * (a / safe_b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def _orthonormal(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors [..., 3] perpendicular to unit w [..., 3] and to each other."""
    helper = np.where(np.abs(w[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(helper, w)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(w, e1)


def soft_reference(scene: Scene, gbuf: GBuffer, light: SphereLight, rays_per_pixel: int = 64,
                   seed: int = 0, shadow_eps: float = DEFAULT_SHADOW_EPS,
                   progress: bool = False) -> np.ndarray:
    """Fraction of an area light's disk visible from each pixel, by stratified sampling.

    The light's silhouette disk as seen from the sample (perpendicular to the direction
    to its centre; for a sun, the disk of angular radius ``angular_radius_deg`` in the
    tangent plane at unit distance) is sampled area-uniformly, without cosine
    weighting: ``rays_per_pixel`` is rounded up to a square k*k, one jittered sample per
    stratum of the concentric disk map. A light sample below the surface's tangent
    plane counts as blocked and is not traced. Each light sample above it is tested with the same segment test
    as :func:`reference_shadows`.

    Returns:
        float64 [H, W] in [0, 1]; 0 on invalid pixels.
    """
    if not isinstance(light, SphereLight):
        raise TypeError("soft_reference needs a SphereLight (a sphere or a sun)")
    k = max(1, math.ceil(math.sqrt(rays_per_pixel)))
    n_rays = k * k
    valid_idx = np.flatnonzero(gbuf.valid)
    pos = gbuf.position.reshape(-1, 3)[valid_idx]
    nrm = gbuf.normal.reshape(-1, 3)[valid_idx]
    eps = shadow_epsilon(scene, shadow_eps)
    rng = np.random.default_rng(seed)
    vis = np.zeros(len(valid_idx))
    si, sj = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    si = si.reshape(-1)
    sj = sj.reshape(-1)
    block = max(1, (1 << 21) // n_rays)
    starts = range(0, len(valid_idx), block)
    if progress:
        from tqdm import tqdm
        starts = tqdm(starts, desc="soft reference", unit="block", leave=False)
    for lo in starts:
        hi = min(lo + block, len(valid_idx))
        p = pos[lo:hi]
        m = hi - lo
        x, y = _concentric_disk((si[None] + rng.random((m, n_rays))) / k,
                                (sj[None] + rng.random((m, n_rays))) / k)
        if light.is_sun:
            w = np.broadcast_to(-light.direction, p.shape)
            centre = p + w                                   # the disk at unit distance
            disk_r = np.full(m, math.tan(math.radians(light.angular_radius_deg)))
        else:
            to_c = light.position - p
            dist = norms3(to_c)
            w = to_c / dist[:, None]
            r = light.radius
            inside = dist <= r
            # The silhouette circle of the sphere seen from p: centre pulled towards p by
            # r^2 / dist, radius r * sqrt(1 - r^2 / dist^2).
            pull = np.where(inside, 0.0, r * r / np.maximum(dist, 1e-300))
            disk_r = np.where(inside, r, r * np.sqrt(np.maximum(1 - (r / dist) ** 2, 0)))
            centre = light.position - pull[:, None] * w
        e1, e2 = _orthonormal(w)
        target = centre[:, None] + disk_r[:, None, None] * (
            x[..., None] * e1[:, None] + y[..., None] * e2[:, None])      # [m, n, 3]
        dirs = target - p[:, None]
        dirs /= norms3(dirs, keepdims=True)
        above = np.einsum("mri,mi->mr", dirs, nrm[lo:hi]) > 0
        # only the samples above the tangent plane are traced (the others are blocked
        # anyway): a pixel facing away from the whole light costs no ray
        sel = np.flatnonzero(above.reshape(-1))
        rows = sel // n_rays
        flat_p = p[rows]
        flat_n = nrm[lo:hi][rows]
        lit = np.zeros(m * n_rays, bool)
        if len(sel):
            if light.is_sun:
                blocked = segments_occluded(scene, flat_p, flat_n,
                                            light_dirs=dirs.reshape(-1, 3)[sel], eps=eps,
                                            frame=gbuf.origin)
            else:
                blocked = segments_occluded(scene, flat_p, flat_n,
                                            light_points=target.reshape(-1, 3)[sel], eps=eps,
                                            frame=gbuf.origin)
            lit[sel] = ~blocked
        vis[lo:hi] = lit.reshape(m, n_rays).mean(axis=1)
    out = np.zeros(gbuf.valid.size)
    out[valid_idx] = vis
    return out.reshape(gbuf.valid.shape)
