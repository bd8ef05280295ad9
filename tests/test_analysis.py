"""Metrics, boundary explanation of mismatches."""

import numpy as np

from shadowlab import Camera, PointLight, Scene
from shadowlab.analysis import compare_hard, compare_soft, error_map, penumbra_mask
from shadowlab.reference.boundary import (FACING_TOLERANCE, boundary_distance,
                                          edge_tolerance, facing_margin,
                                          unexplained_mismatches)
from shadowlab.reference.raycast import GBuffer


def test_error_map_and_counts():
    truth = np.array([[1, 0, 1], [0, 0, 1]], bool)
    lit = np.array([[1, 1, 0], [0, 1, 1]], bool)
    valid = np.array([[1, 1, 1], [1, 0, 1]], bool)
    err = error_map(lit, truth, valid)
    assert err.tolist() == [[0, 1, -1], [0, 0, 0]]
    stats = compare_hard(lit, truth, valid)
    assert stats["mismatches"] == 2 and stats["false_lit"] == 1 and stats["false_shadow"] == 1
    assert stats["valid_pixels"] == 5 and stats["invalid_pixels_lit"] == 1


def test_soft_metrics():
    truth = np.full((8, 8), 0.5)
    vis = truth.copy()
    vis[0, 0] = 1.0
    valid = np.ones((8, 8), bool)
    m = compare_soft(vis, truth, valid)
    assert np.isclose(m["max_error"], 0.5) and np.isclose(m["mae"], 0.5 / 64)
    assert np.isclose(m["rmse"], np.sqrt(0.25 / 64))
    assert compare_soft(truth, truth, valid)["ssim"] == 1.0


def test_penumbra_mask_is_the_strict_penumbra_dilated_within_valid_pixels():
    truth = np.zeros((9, 12))
    truth[:, 6:] = 1.0
    truth[4, 5] = 0.3                                      # one penumbra pixel
    truth[0, 11] = 1.0 - 1e-9                              # strictly below 1: penumbra too
    valid = np.ones(truth.shape, bool)
    valid[4, 7] = False
    m = penumbra_mask(truth, valid, dilation=2)
    want = np.zeros(truth.shape, bool)
    want[2:7, 3:8] = True
    want[0:3, 9:12] = True
    want[4, 7] = False                                     # invalid pixels never count
    assert np.array_equal(m, want)
    assert np.array_equal(penumbra_mask(truth, valid, dilation=0), (truth > 0) & (truth < 1))
    assert not penumbra_mask(np.round(truth), valid).any()  # a hard truth has none


def test_soft_metrics_over_the_penumbra_beside_the_whole_image():
    """A hard thresholding of a soft edge is diluted over the whole image but not over
    the penumbra region."""
    x = np.arange(64)
    truth = np.tile(np.clip((x - 28) / 8.0, 0.0, 1.0), (64, 1))   # a ramp over columns 29..35
    hard = (truth >= 0.5).astype(float)
    valid = np.ones(truth.shape, bool)
    m = compare_soft(hard, truth, valid, dilation=1)
    diff = np.abs(hard - truth)
    region = np.zeros(truth.shape, bool)
    region[:, 28:37] = True                                # columns 29..35 dilated by 1
    assert m["penumbra_pixels"] == region.sum() == 64 * 9
    assert np.isclose(m["mae"], diff.mean())
    assert np.isclose(m["penumbra_mae"], diff[region].mean())
    assert np.isclose(m["penumbra_rmse"], np.sqrt((diff[region] ** 2).mean()))
    assert np.isclose(m["penumbra_max_error"], 0.5) and np.isclose(m["max_error"], 0.5)
    assert m["penumbra_mae"] > 6 * m["mae"]                # 64 / 9 columns: less diluted
    assert m["penumbra_ssim"] < m["ssim"] < 1.0
    same = compare_soft(truth, truth, valid)
    assert same["penumbra_mae"] == 0.0 and np.isclose(same["penumbra_ssim"], 1.0)
    empty = compare_soft(hard, hard, valid)                # no penumbra at all
    assert empty["penumbra_pixels"] == 0 and np.isnan(empty["penumbra_ssim"])
    assert empty["penumbra_mae"] == 0.0


def _gbuffer(points, normals):
    k = len(points)
    cam = Camera(eye=(0, 1, 5), target=(0, 0, 0), resolution=(k, 1))
    return GBuffer(position=np.asarray(points, float).reshape(1, k, 3),
                   normal=np.asarray(normals, float).reshape(1, k, 3),
                   depth=np.ones((1, k)), triangle=np.zeros((1, k), np.int32),
                   valid=np.ones((1, k), bool), camera=cam)


def test_mismatches_on_a_caster_edge_are_explained_others_are_not():
    # An occluder square over x < 0 at height 1; the light right above x = 0.
    occ = Scene(np.array([[-2, 1, -1], [0, 1, -1], [0, 1, 1], [-2, 1, 1]], float),
                np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(2))
    ground = Scene(np.array([[-5, 0, -5], [5, 0, -5], [5, 0, 5], [-5, 0, 5]], float),
                   np.array([[0, 2, 1], [0, 3, 2]]), np.zeros(2))
    scene = Scene.concatenate([occ, ground])
    light = PointLight((0.0, 4.0, 0.5))
    gbuf = _gbuffer([[0.0, 0, 0.5], [3.0, 0, 0], [-1.0, 0, 0]], [[0, 1, 0]] * 3)
    dist = boundary_distance(scene, gbuf, light, np.array([[0, 0], [0, 1], [0, 2]]))
    assert dist["edge"][0] < 1e-12                 # the segment grazes the occluder edge
    assert np.isinf(dist["edge"][1])               # nothing near
    truth = np.array([[True, True, False]])
    wrong = ~truth
    left = unexplained_mismatches(scene, gbuf, light, wrong, truth)
    assert sorted(map(tuple, left)) == [(0, 1), (0, 2)]


def test_edge_distance_is_in_world_units_on_a_sliver():
    # A 0.02-wide sliver at height 1 along z; the light right above its edge x = 0.
    # Segments miss the edge by 1e-6 (float32 rounding of unit coordinates: explained)
    # and by 1e-3 (a real error: not explained). In barycentric terms 1e-6 is 5e-5 of
    # the sliver's width, which a barycentric tolerance of 1e-5 would not excuse.
    sliver = Scene(np.array([[0.0, 1, -1], [0.0, 1, 1], [-0.02, 1, 0]]),
                   np.array([[0, 1, 2]]), np.zeros(1))
    light = PointLight((0.0, 4.0, 0.0))
    # A sample at x = s below the light: the segment crosses height 1 at x = 0.75 s.
    gbuf = _gbuffer([[-1e-6 / 0.75, 0, 0], [1e-6 / 0.75, 0, 0], [1e-3 / 0.75, 0, 0]],
                    [[0, 1, 0]] * 3)
    pixels = np.array([[0, 0], [0, 1], [0, 2]])
    dist = boundary_distance(sliver, gbuf, light, pixels, reach=1.0)
    np.testing.assert_allclose(dist["edge"], [1e-6, 1e-6, 1e-3], rtol=1e-6)
    assert edge_tolerance(sliver, light) < 1e-4
    truth = np.array([[False, True, True]])
    left = unexplained_mismatches(sliver, gbuf, light, ~truth, truth)
    assert sorted(map(tuple, left)) == [(0, 2)]


def test_mismatches_on_the_terminator_are_explained_far_from_the_origin_too():
    # Samples on a slanted wall whose plane holds the point light: the facing test
    # n . (L - p) is 0 up to the rounding of p, and two float64 evaluations of it (the
    # methods' n . L - n . p, truth64's n . (L - p) relative to the light) may take
    # either sign. A sample that faces the light by a cosine of 1e-6 is no boundary.
    ground = Scene(np.array([[-5, 0, -5], [5, 0, -5], [5, 0, 5], [-5, 0, 5]], float),
                   np.array([[0, 2, 1], [0, 3, 2]]), np.zeros(2))
    n = np.array([-0.6, -0.8, 0.0])
    along = np.array([0.8, -0.6, 0.0])                      # in the wall, across
    for shift in (0.0, 1e5):
        o = np.array([shift, -shift, 0.5 * shift])
        scene = Scene(ground.vertices + o, ground.faces, ground.object_id)
        light = PointLight(o + (1.0, 4.0, 0.1))
        wall = [light.position + s * along + (0, 0, z) for s, z in ((1.7, 0.3), (3.1, -0.45))]
        near = light.position + 2.3 * along
        t = 1e-6                                            # the tilt towards the light
        tilted = np.cos(t) * n + np.sin(t) * along * -1
        gbuf = _gbuffer(wall + [near], [n, n, tilted])
        pixels = np.array([[0, 0], [0, 1], [0, 2]])
        margin = facing_margin(gbuf, light, pixels)
        assert np.all(margin[:2] <= FACING_TOLERANCE)
        assert margin[2] > 1e-12
        truth = np.array([[False, True, True]])
        dist = boundary_distance(scene, gbuf, light, pixels)
        assert np.all(np.isinf(dist["edge"])) and np.all(np.isinf(dist["cut"]))
        left = unexplained_mismatches(scene, gbuf, light, ~truth, truth)
        assert sorted(map(tuple, left)) == [(0, 2)]
