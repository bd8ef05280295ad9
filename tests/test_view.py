"""Camera matrices, primary rays, lights and animations."""

import numpy as np
import pytest

from shadowlab import Animation, Camera, DirectionalLight, PointLight, SphereLight


def test_projection_maps_primary_rays_to_their_pixel_centres():
    cam = Camera(eye=(1, 2, 5), target=(0, 0.5, 0), fov_y_deg=50, near=0.2, far=80,
                 resolution=(40, 30))
    o, d = cam.primary_rays()
    points = o + 7.0 * d                                      # a point on every ray
    clip = np.c_[points.reshape(-1, 3), np.ones(40 * 30)] @ cam.view_projection().T
    ndc = clip[:, :3] / clip[:, 3:]
    col = (ndc[:, 0] + 1) / 2 * 40 - 0.5
    row = (1 - ndc[:, 1]) / 2 * 30 - 0.5
    rows, cols = np.mgrid[0:30, 0:40]
    np.testing.assert_allclose(col, cols.reshape(-1), atol=1e-9)
    np.testing.assert_allclose(row, rows.reshape(-1), atol=1e-9)
    assert np.all(np.abs(ndc) <= 1)


def test_view_space_looks_down_minus_z_and_depth_maps_to_clip():
    cam = Camera(eye=(0, 0, 3), target=(0, 0, 0), near=0.5, far=10, resolution=(8, 8))
    v = cam.view_matrix() @ [0, 0, 0, 1]
    assert np.allclose(v[:3], [0, 0, -3])
    for z, want in ((-0.5, -1.0), (-10.0, 1.0)):
        c = cam.projection_matrix() @ [0, 0, z, 1]
        assert np.isclose(c[2] / c[3], want)


@pytest.mark.parametrize("kwargs, message", [
    ({"eye": (0, 0, 0), "target": (0, 0, 0)}, "coincide"),
    ({"up": (0, 0, 1)}, "parallel"),
    ({"fov_y_deg": 180}, "fov_y_deg"),
    ({"near": 0}, "near"),
    ({"near": 5, "far": 1}, "near < far"),
    ({"resolution": (0, 4)}, "resolution"),
    ({"eye": (0, float("nan"), 1)}, "finite"),
])
def test_bad_cameras_are_rejected(kwargs, message):
    base = {"eye": (0, 0, 3), "target": (0, 0, 0)}
    base.update(kwargs)
    with pytest.raises(ValueError, match=message):
        Camera(**base)


def test_lights():
    p = PointLight((0, 4, 0))
    d, dist = p.to_light(np.array([[0.0, 1, 0]]))
    assert np.allclose(d, [[0, 1, 0]]) and np.allclose(dist, 3)
    sun = DirectionalLight((0, -2, 0))
    assert np.allclose(sun.homogeneous, [0, 1, 0, 0])
    assert np.allclose(SphereLight(position=(1, 2, 3), radius=0.5).homogeneous, [1, 2, 3, 1])
    disk = SphereLight(direction=(0, -1, 0), angular_radius_deg=0.27)
    assert disk.is_sun and isinstance(disk.center_light, DirectionalLight)
    with pytest.raises(ValueError, match="not both"):
        SphereLight(position=(0, 1, 0), radius=1, direction=(0, -1, 0), angular_radius_deg=1)
    with pytest.raises(ValueError, match="radius"):
        SphereLight(position=(0, 1, 0), radius=0)


@pytest.mark.parametrize("shape,dtype", [((1000, 3), np.float64), ((7, 5, 3), np.float32),
                                         ((3,), np.float64), ((0, 3), np.float64)])
def test_point_light_directions_equal_the_row_wise_formula(shape, dtype):
    """``to_light`` works on coordinate columns; its bits are those of the row-wise
    d / max(|d|, 1e-300) with |d| = sqrt((d0^2 + d1^2) + d2^2) in float64, far from the
    origin too."""
    light = PointLight((3.5, -2.0, 1e5 + 0.3))
    points = (np.random.default_rng(1).normal(size=shape) * 1e3).astype(dtype)
    d = light.position - points.astype(np.float64)
    dist = np.sqrt(np.sum(d * d, axis=-1))          # a length-3 sum: sequential order
    got, got_dist = light.to_light(points)
    assert got.dtype == np.float64 and got.shape == shape
    np.testing.assert_array_equal(got_dist, dist)
    np.testing.assert_array_equal(got, d / np.maximum(dist, 1e-300)[..., None])


def test_animation_samples_key_frames_evenly():
    cam = Camera(eye=(0, 0, 3), target=(0, 0, 0), resolution=(4, 4))
    anim = Animation(cam, PointLight((0, 5, 0)), frames=5,
                     eye_keys=[(0, 0, 3), (4, 0, 3), (4, 4, 3)],
                     light_keys=[(0, 5, 0), (2, 5, 0)])
    views = anim.views()
    assert len(views) == 5
    assert np.allclose(views[0].camera.eye, (0, 0, 3))
    assert np.allclose(views[2].camera.eye, (4, 0, 3))       # the middle key
    assert np.allclose(views[1].camera.eye, (2, 0, 3))
    assert np.allclose(views[4].camera.eye, (4, 4, 3))
    assert np.allclose(views[2].light.position, (1, 5, 0))
    assert all(v.camera.resolution == (4, 4) for v in views)
    with pytest.raises(ValueError, match="frames"):
        Animation(cam, PointLight((0, 5, 0)), frames=0)
