"""G-buffer and reference shadows against analytic scenes."""

import math

import numpy as np
import pytest
import trimesh

from shadowlab import (Camera, DirectionalLight, PointLight, Scene, SphereLight,
                       reference_shadows, render_gbuffer, soft_reference)
from scenes import sphere_over_plane


def _quad(y=0.0, half=50.0, x_max=None):
    x1 = half if x_max is None else x_max
    v = np.array([[-half, y, -half], [x1, y, -half], [x1, y, half], [-half, y, half]], float)
    return Scene(v, np.array([[0, 2, 1], [0, 3, 2]]), np.zeros(2), ("quad",), "quad")


def test_plane_depth_position_and_normal_are_analytic():
    cam = Camera(eye=(0.3, 4.0, 5.0), target=(0, 0, 0), fov_y_deg=50, near=0.1, far=100,
                 resolution=(64, 48))
    g = render_gbuffer(_quad(), cam)
    assert g.valid.shape == (48, 64) and g.depth.shape == (48, 64)
    o, d = cam.primary_rays()
    t = -o[..., 1] / d[..., 1]
    hit = (t > 0)
    assert np.array_equal(g.valid, hit)
    np.testing.assert_allclose(g.position[hit], (o + t[..., None] * d)[hit], atol=2e-5)
    _, _, back = cam.basis()
    want_depth = (t[..., None] * d @ -back)
    np.testing.assert_allclose(g.depth[hit], want_depth[hit], rtol=1e-5)
    np.testing.assert_allclose(g.normal[hit], np.broadcast_to([0, 1, 0], g.normal[hit].shape),
                               atol=1e-12)
    assert np.all(g.triangle[hit] >= 0) and np.all(g.triangle[~hit] == -1)


def test_sphere_depth_matches_ray_sphere_intersection():
    s = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    scene = Scene(s.vertices, s.faces, np.zeros(len(s.faces)))
    cam = Camera(eye=(0, 0, 4), target=(0, 0, 0), fov_y_deg=40, near=0.5, far=10,
                 resolution=(48, 48))
    g = render_gbuffer(scene, cam)
    o, d = cam.primary_rays()
    b = np.einsum("hwi,hwi->hw", o, d)
    disc = b * b - (np.einsum("hwi,hwi->hw", o, o) - 1)
    inside = disc > 0.05                     # away from the silhouette
    t = -b - np.sqrt(np.maximum(disc, 0))
    assert g.valid[inside].all()
    np.testing.assert_allclose(g.depth[inside], (t * d[..., 2] * -1)[inside], atol=2e-3)
    # normals point back at the camera
    to_eye = cam.eye - g.position
    assert np.all(np.einsum("hwi,hwi->hw", g.normal, to_eye)[g.valid] > 0)


def test_pixel_zero_is_top_left_and_far_plane_clips():
    # A quad only in the x < 0, y > 0 quadrant, facing a camera that looks down -Z.
    v = np.array([[-5, 0.01, 0], [-0.01, 0.01, 0], [-0.01, 5, 0], [-5, 5, 0]], float)
    scene = Scene(v, np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(2))
    cam = Camera(eye=(0, 0, 3), target=(0, 0, 0), resolution=(32, 32), near=0.1, far=10)
    g = render_gbuffer(scene, cam)
    assert g.valid[:16, :16].all() and not g.valid[16:].any() and not g.valid[:, 16:].any()
    g_far = render_gbuffer(scene, cam.replace(far=2.5))
    assert not g_far.valid.any()


def _segment_distance(points, centre, light_pos=None, direction=None):
    """Distance from centre to the segment point -> light (or the ray against direction)."""
    if direction is not None:
        seg = -np.asarray(direction) * 1e6
    else:
        seg = light_pos - points
    s = np.clip(np.einsum("...i,...i->...", centre - points, seg)
                / np.einsum("...i,...i->...", seg, seg), 0, 1)
    closest = points + s[..., None] * seg
    return np.linalg.norm(closest - centre, axis=-1)


@pytest.mark.parametrize("light", [PointLight((1.0, 6.0, 0.5)),
                                   DirectionalLight((-0.3, -1.0, 0.2))])
def test_sphere_shadow_on_plane_has_the_analytic_extent(light):
    scene = sphere_over_plane(subdivisions=5, radius=1.0, height=2.0)
    cam = Camera(eye=(0, 7, 7), target=(0, 0.5, 0), fov_y_deg=55, near=0.5, far=50,
                 resolution=(96, 96))
    g = render_gbuffer(scene, cam)
    lit = reference_shadows(scene, g, light)
    centre = np.array([0, 2.0, 0])
    ground = g.valid & (np.abs(g.position[..., 1]) < 1e-9)
    if isinstance(light, PointLight):
        dist = _segment_distance(g.position, centre, light_pos=light.position)
    else:
        dist = _segment_distance(g.position, centre, direction=light.direction)
    clear = np.abs(dist - 1.0) > 0.01       # the inscribed polyhedron differs by < 0.2 %
    shadowed_analytic = dist < 1.0
    assert (ground & clear & shadowed_analytic).sum() > 100
    assert np.array_equal(lit[ground & clear], ~shadowed_analytic[ground & clear])
    # A convex sphere never shadows itself: every light-facing sphere pixel is lit.
    on_sphere = g.valid & ~ground
    to_l = light.to_light(g.position)[0]
    facing = np.einsum("hwi,hwi->hw", g.normal, to_l) > 0
    assert (on_sphere & facing).sum() > 50
    assert lit[on_sphere & facing].all()
    assert not lit[on_sphere & ~facing].any()
    assert not lit[~g.valid].any()


def test_soft_reference_matches_the_half_plane_penumbra():
    """A sun straight above, a half-plane occluder at height h covering x < 0: the visible
    fraction of the sun disk at ground point x is the disk area right of -x / h (tan space)."""
    h, ang = 1.0, 5.0
    occluder = _quad(y=h, half=100.0, x_max=0.0)
    ground = _quad(y=0.0, half=100.0)
    scene = Scene.concatenate([occluder, ground])
    cam = Camera(eye=(0.0, 0.6, 0.8), target=(0, 0, 0), fov_y_deg=30, near=0.05, far=10,
                 resolution=(40, 40))
    g = render_gbuffer(scene, cam)
    sun = SphereLight(direction=(0, -1, 0), angular_radius_deg=ang)
    vis = soft_reference(scene, g, sun, rays_per_pixel=400, seed=1)
    on_ground = g.valid & (np.abs(g.position[..., 1]) < 1e-9)
    r = math.tan(math.radians(ang))
    # Unit-disk area with t > -u is acos(-u) + u * sqrt(1 - u^2), u = x / (h * tan(ang)).
    u = np.clip(g.position[..., 0] / h / r, -1, 1)
    want = (np.arccos(-u) + u * np.sqrt(1 - u * u)) / np.pi
    assert on_ground.sum() > 500
    penumbra = on_ground & (np.abs(u) < 1)
    assert penumbra.sum() > 50
    np.testing.assert_allclose(vis[on_ground], want[on_ground], atol=0.03)
    assert np.all((vis >= 0) & (vis <= 1)) and np.all(vis[~g.valid] == 0)


def test_tiny_sphere_light_agrees_with_hard_shadows():
    scene = sphere_over_plane(subdivisions=3)
    cam = Camera(eye=(0, 7, 7), target=(0, 0.5, 0), resolution=(48, 48), near=0.5, far=50)
    g = render_gbuffer(scene, cam)
    hard = reference_shadows(scene, g, PointLight((1, 6, 0.5)))
    soft = soft_reference(scene, g, SphereLight(position=(1, 6, 0.5), radius=1e-4),
                          rays_per_pixel=4)
    assert np.mean((soft > 0.5) == hard) > 0.995


def test_soft_reference_traces_only_samples_above_the_tangent_plane(monkeypatch):
    """Samples below a pixel's tangent plane are blocked without a ray: a sun grazing the
    ground from below its horizon costs no ray on the ground."""
    from shadowlab.reference import raycast

    traced = []
    real = raycast.segments_occluded

    def counting(scene, p, n, **kw):
        traced.append(len(p))
        return real(scene, p, n, **kw)

    monkeypatch.setattr(raycast, "segments_occluded", counting)
    scene = sphere_over_plane(subdivisions=2)
    g = render_gbuffer(scene, Camera(eye=(0, 7, 7), target=(0, 0.5, 0), resolution=(24, 24),
                                     near=0.5, far=50))
    ground = g.valid & (np.abs(g.position[..., 1]) < 1e-9)
    sun = SphereLight(direction=(0.0, 0.2, -1.0), angular_radius_deg=3.0)   # from below
    vis = soft_reference(scene, g, sun, rays_per_pixel=16, seed=0)
    assert ground.sum() > 100 and not vis[ground].any()
    assert 0 < sum(traced) <= 16 * int((g.valid & ~ground).sum())
