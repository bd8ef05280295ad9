"""Light-space cameras (shadowlab.scene.light_camera) against independent formulas."""

import math

import numpy as np
import pytest

from shadowlab.scene import DirectionalLight, PointLight, SphereLight, make
from shadowlab.scene.light_camera import (CUBE_FACES, box_corners, fit_light_camera,
                                          orthographic)


def cloud(seed, n=500, lo=-1.0, hi=1.0, offset=(0, 0, 0)):
    rng = np.random.default_rng(seed)
    return rng.uniform(lo, hi, (n, 3)) * [1.0, 0.5, 2.0] + offset


CASES = [
    (DirectionalLight((0, -1, 0)), "orthographic"),
    (DirectionalLight((0.3, -1, 0.2)), "orthographic"),
    (DirectionalLight((1, 0.05, 0)), "orthographic"),
    (SphereLight(direction=(0, -1, 1), angular_radius_deg=1.0), "orthographic"),
    (PointLight((0.5, 8, -1)), "perspective"),
    (PointLight((30, 2, 40)), "perspective"),
    (PointLight((0.1, 0.05, -0.2)), "cube"),      # inside the box
    (PointLight((0.0, 0.6, 0.0)), "cube"),        # just above it: fov would exceed 120
]


@pytest.mark.parametrize("light,kind", CASES)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_every_fitted_point_lands_on_the_grid(light, kind, dtype):
    p = cloud(1).astype(dtype)
    cam = fit_light_camera(light, p, resolution=128)
    assert cam.kind == kind and cam.resolution == (128, 128)
    assert len(cam.faces) == (6 if kind == "cube" else 1)
    face, uv, depth = cam.to_texels(p)
    assert face.dtype == np.int32 and face.shape == (len(p),)
    assert uv.dtype == depth.dtype == np.float64 and uv.shape == (len(p), 2)
    assert (uv >= 0).all() and (uv < 128).all()
    assert (depth >= cam.near).all() and (depth <= cam.far).all()
    # float32 input is the same as its exact float64 values
    f64, uv64, d64 = cam.to_texels(p.astype(np.float64))
    assert (f64 == face).all() and (uv64 == uv).all() and (d64 == depth).all()
    for f in cam.faces:
        assert f.view.shape == f.projection.shape == (4, 4)
        assert f.view.dtype == f.projection.dtype == np.float64
        np.testing.assert_allclose(f.view[:3, :3] @ f.view[:3, :3].T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(-f.view[2, :3], f.forward, atol=1e-12)  # looks down -Z


def test_casters_towards_the_light_are_inside_the_depth_range():
    p = cloud(2)
    light = DirectionalLight((0.2, -1, 0.1))
    casters = p - 5.0 * light.direction  # 5 units towards the light, above every sample
    cam = fit_light_camera(light, p, casters=casters, resolution=64)
    _, _, dc = cam.to_texels(casters)
    _, _, dp = cam.to_texels(p)
    assert (dc >= cam.near).all() and (dc <= cam.far).all()
    np.testing.assert_allclose(dp - dc, 5.0, atol=1e-9)
    assert cam.near < dc.min() and cam.far >= dp.max()
    point = PointLight((0, 10, 0))
    mid = (p + point.position) / 2
    cam = fit_light_camera(point, p, casters=mid, resolution=64)
    _, _, dm = cam.to_texels(mid)
    assert (dm >= cam.near).all() and (dm <= cam.far).all()


def test_orthographic_matrix_maps_the_box_to_the_clip_cube():
    m = orthographic(-2.0, 6.0, 1.0, 3.0, 0.5, 10.0)
    corners = np.array([[-2, 1, -0.5, 1], [6, 3, -10, 1], [2, 2, -5.25, 1]])
    np.testing.assert_allclose(corners @ m.T, [[-1, -1, -1, 1], [1, 1, 1, 1], [0, 0, 0, 1]],
                               atol=1e-15)


def test_orthographic_projection_analytic_case():
    # Straight down: frame right = +Z, up = +X (helper up (1, 0, 0) when |dir.y| > 0.9).
    # Points span x in [0, 2], y in [0, 1], z in [0, 4]: square half side 2, centre
    # (x, z) = (1, 2), padded by one texel of R = 100: half = 2 * 100 / 98.
    r = 100
    p = np.array([[0, 0, 0], [2, 1, 4], [2, 0, 0], [0, 1, 4], [1.5, 0.25, 3.0]], float)
    cam = fit_light_camera(DirectionalLight((0, -1, 0)), p, resolution=r)
    face, uv, depth = cam.to_texels(p)
    half = 2 * r / 98
    want_u = ((p[:, 2] - 2) / half + 1) / 2 * r
    want_v = (1 - (p[:, 0] - 1) / half) / 2 * r
    np.testing.assert_allclose(uv, np.stack([want_u, want_v], 1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(depth - depth[1], 1 - p[:, 1], atol=1e-12)  # along travel
    assert cam.faces[0].half_extent == pytest.approx(half)
    assert cam.faces[0].texel_size == pytest.approx(2 * half / r)
    assert (face == 0).all()


def pinhole(p, eye, target, fov_deg, r):
    """An independent pinhole: forward to the target, right = forward x up, square fov;
    the up helper is +Y unless forward is within acos(0.9) of it, then +X."""
    fwd = (target - eye) / np.linalg.norm(target - eye)
    up = np.array([1.0, 0, 0]) if abs(fwd[1]) > 0.9 else np.array([0, 1.0, 0])
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    upv = np.cross(right, fwd)
    d = p - eye
    x, y, z = d @ right, d @ upv, d @ fwd
    t = math.tan(math.radians(fov_deg) / 2)
    return np.stack([(x / z / t + 1) / 2 * r, (1 - y / z / t) / 2 * r], 1), z


@pytest.mark.parametrize("pos", [(0.5, 8, -1), (30, 2, 40), (0.2, -3, 0.1)])
def test_perspective_matches_an_independent_pinhole(pos):
    p = cloud(3)
    cam = fit_light_camera(PointLight(pos), p, resolution=256)
    assert cam.kind == "perspective"
    f = cam.faces[0]
    target = (p.min(0) + p.max(0)) / 2
    uv_want, z_want = pinhole(p, np.array(pos, float), target, f.fov_deg, 256)
    _, uv, depth = cam.to_texels(p)
    np.testing.assert_allclose(uv, uv_want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(depth, z_want, rtol=1e-12)
    # the fov is tight: the extreme point sits one texel (the padding) from the border
    edge = np.minimum(uv, 256 - uv).min()
    assert 0.99 < edge <= 1.0 + 1e-9


def test_cube_assigns_the_dominant_axis_face():
    light = PointLight((1.0, -2.0, 0.5))
    rng = np.random.default_rng(4)
    d = rng.normal(size=(2000, 3))
    ties = np.array([[1, 1, 0], [-1, 0, -1], [0, 2, -2], [3, 3, 3], [-1, -1, -1]], float)
    d = np.concatenate([d, ties])
    p = light.position + d
    cam = fit_light_camera(light, p, resolution=64, projection="cube")
    face, uv, depth = cam.to_texels(p)
    # independent: largest |component|, first axis on ties, positive face first
    want = []
    for v in d.tolist():
        a = max(range(3), key=lambda i: (abs(v[i]), -i))
        want.append(2 * a + (v[a] < 0))
    assert face.tolist() == want
    assert (uv >= 0).all() and (uv < 64).all()
    np.testing.assert_allclose(depth, np.abs(d).max(axis=1), rtol=1e-12)
    for f, (name, fwd, _) in zip(cam.faces, CUBE_FACES):
        assert f.name == name and f.fov_deg == 90.0
        np.testing.assert_array_equal(f.forward, fwd)
        # the face axis projects to the grid centre
        uvc, dc = f.project((light.position + np.array(fwd))[None])
        np.testing.assert_allclose(uvc, [[32, 32]], atol=1e-9)
        np.testing.assert_allclose(dc, [1.0])


def test_auto_picks_the_cube_when_the_points_surround_the_light():
    p = cloud(5)
    assert fit_light_camera(PointLight((0, 0, 0)), p).kind == "cube"
    with pytest.raises(ValueError, match="surround"):
        fit_light_camera(PointLight((0, 0, 0)), p, projection="perspective")
    assert fit_light_camera(PointLight((0, 0.6, 0)), p, max_fov_deg=179).kind == "perspective"


@pytest.mark.parametrize("light", [DirectionalLight((0.3, -1, 0.2)), PointLight((2, 5, 1)),
                                   PointLight((0, 0, 0))])
def test_unproject_inverts_project(light):
    p = cloud(6, n=200)
    cam = fit_light_camera(light, p, resolution=512)
    face, uv, depth = cam.to_texels(p)
    for f in np.unique(face):
        sel = face == f
        np.testing.assert_allclose(cam.faces[f].unproject(uv[sel], depth[sel]), p[sel],
                                   atol=1e-9)


def test_scene_bounds_fit():
    scene = make("gate")
    corners = box_corners(scene.bounds)
    assert corners.shape == (8, 3)
    np.testing.assert_array_equal(corners.min(0), scene.bounds[0])
    np.testing.assert_array_equal(corners.max(0), scene.bounds[1])
    cam = fit_light_camera(DirectionalLight((0.4, -1, 0.3)), corners,
                           casters=scene.vertices, resolution=256)
    _, uv, depth = cam.to_texels(scene.vertices)  # the box encloses every vertex
    assert (uv >= 0).all() and (uv < 256).all()
    assert (depth >= cam.near).all() and (depth <= cam.far).all()


def test_bad_arguments():
    p = cloud(7, n=10)
    with pytest.raises(ValueError, match="coincides"):
        fit_light_camera(PointLight(p[3]), p)
    with pytest.raises(ValueError, match="orthographic"):
        fit_light_camera(DirectionalLight((0, -1, 0)), p, projection="cube")
    with pytest.raises(ValueError, match="orthographic"):
        fit_light_camera(PointLight((0, 9, 0)), p, projection="orthographic")
    with pytest.raises(ValueError, match="resolution"):
        fit_light_camera(PointLight((0, 9, 0)), p, resolution=2)
    with pytest.raises(ValueError, match="shape"):
        fit_light_camera(PointLight((0, 9, 0)), p[:, :2])
    with pytest.raises(ValueError, match="projection"):
        fit_light_camera(PointLight((0, 9, 0)), p, projection="fisheye")


def _ordered_reference(face, p):
    """A Python-float loop: view then projection, each output the products rounded and
    added left to right (k = 0..3), then the perspective divide and the texel scale."""
    r = face.resolution[0]
    uv, depth = [], []
    for x in p.astype(np.float64).tolist():
        h = x + [1.0]
        v = [((h[0] * face.view[i, 0] + h[1] * face.view[i, 1]) + h[2] * face.view[i, 2])
             + h[3] * face.view[i, 3] for i in range(4)]
        c = [((v[0] * face.projection[i, 0] + v[1] * face.projection[i, 1])
              + v[2] * face.projection[i, 2]) + v[3] * face.projection[i, 3] for i in range(4)]
        uv.append(((c[0] / c[3] + 1.0) * 0.5 * r, (1.0 - c[1] / c[3]) * 0.5 * r))
        depth.append(-v[2])
    return np.array(uv), np.array(depth)


@pytest.mark.parametrize("light,kind", CASES)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_project_rounds_as_the_ordered_sums(light, kind, dtype):
    """project and depth equal a scalar loop bit for bit (fixed order, no BLAS), and the
    matrix product to rounding."""
    p = cloud(5, n=60).astype(dtype)
    cam = fit_light_camera(light, p, resolution=64)
    for f in cam.faces:
        uv, depth = f.project(p)
        ref_uv, ref_depth = _ordered_reference(f, p)
        assert (uv == ref_uv).all() and (depth == ref_depth).all()
        assert (f.depth(p) == depth).all()
        h = np.c_[p.astype(np.float64), np.ones(len(p))]
        v = h @ f.view.T
        clip = v @ f.projection.T
        front = -v[:, 2] > 0
        np.testing.assert_allclose(depth, -v[:, 2], rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(uv[front, 0], (clip[front, 0] / clip[front, 3] + 1) * 32,
                                   rtol=1e-11, atol=1e-9)
