"""The light-space rasterizer against plain NumPy loops over (triangle, texel).

The references are independent of the homogeneous edge functions: world-space rays
from the light (or along an orthographic face's axis) through texel points tested
against the triangle (Moller-Trumbore in float64), and a separating-axis overlap test of
projected triangles and texel squares. float32 and float64 evaluation, NumPy and jit.
"""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import shadowlab as sl
from shadowlab.methods import izb
from shadowlab.scene.light_camera import fit_light_camera
from shadowlab.structures import light_raster as lr

R = 16


def _hits(origin, direction, tri):
    """bool: the line origin + t direction, t > 0, meets the closed triangle (float64)."""
    e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
    pv = np.cross(direction, e2)
    det = e1 @ pv
    if det == 0:
        return False
    tv = origin - tri[0]
    u = (tv @ pv) / det
    qv = np.cross(tv, e1)
    v = (direction @ qv) / det
    t = (e2 @ qv) / det
    return u >= 0 and v >= 0 and u + v <= 1 and t > 0


def _ray(face, uv):
    """Origin and direction of the light ray through texel point ``uv`` [2]."""
    if face.orthographic:
        p = face.unproject(np.array([uv]), np.array([0.0]))[0]
        return p, face.forward
    p = face.unproject(np.array([uv]), np.array([1.0]))[0]
    return face.eye, p - face.eye


def _frame(kind, seed):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-1, 1, (30, 3))
    tri = centres[:, None, :] + rng.normal(0, 0.7, (30, 3, 3))
    if kind == "ortho":
        light = sl.DirectionalLight(direction=(0.3, -1.0, 0.2))
        cam = fit_light_camera(light, tri.reshape(-1, 3), resolution=R)
    else:
        light = sl.PointLight(position=(0.2, 1.3, 0.1))
        grid = rng.uniform(-1, 1, (50, 3)) * (1, 0, 1) + (0, -1.0, 0)
        cam = fit_light_camera(light, grid, resolution=R, projection="perspective")
        # a few triangles reaching behind the light and one entirely behind it
        tri[:3, 0] = light.position + (0, 0.8, 0) + rng.normal(0, 0.2, (3, 3))
        tri[3] = light.position + (0, 0.5, 0) + rng.normal(0, 0.2, (3, 3))
    return cam, tri


def _cross2(a, b):
    return a[0] * b[1] - a[1] * b[0]


@functools.lru_cache(maxsize=None)
def _cached_reference(kind, seed, mode, test):
    cam, tri = _frame(kind, seed)
    return _reference(cam, tri, mode, test)


def _reference(cam, tri, mode, test):
    """set of (triangle, key) by the loop."""
    out = set()
    face = cam.faces[0]
    for t, (j, i) in itertools.product(range(len(tri)), itertools.product(range(R), range(R))):
        key = j * R + i
        if mode == "standard":
            ok = _hits(*_ray(face, (i + 0.5, j + 0.5)), tri[t])
        elif test == "corners":
            ok = all(_hits(*_ray(face, (i + du, j + dv)), tri[t]) for du, dv in lr.CORNERS)
        else:
            uv, depth = face.project(tri[t])
            if np.any(depth <= 0):
                continue
            c = np.array([i + 0.5, j + 0.5])
            area = _cross2(uv[1] - uv[0], uv[2] - uv[0])
            ok = True
            for k in range(3):
                a, b = uv[k], uv[(k + 1) % 3]
                d = _cross2(b - a, c - a) / np.linalg.norm(b - a)
                ok &= np.sign(area) * d >= np.sqrt(0.5)
        if ok:
            out.add((t, key))
    return out


@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_standard_and_inner_modes_match_loops(kind, precision):
    dtype = np.float64 if precision == "float64" else np.float32
    cam, tri = _frame(kind, 1)
    for mode, test in [("standard", "corners"), ("inner", "corners"), ("inner", "circle")]:
        t, k, setups = lr.rasterize(cam, tri, mode, test, dtype=dtype)
        got = set(zip(t.tolist(), k.tolist()))
        ref = _cached_reference(kind, 1, mode, test)
        if test == "circle":  # the loop's circle test handles front triangles only
            got = {(a, b) for a, b in got if setups[0].front[a]}
        assert len(ref) > 5, (mode, test)
        # rounding (float32 evaluation) may move an exact tie; none is expected here
        assert got == ref, (mode, test, len(got ^ ref))
    # the triangle entirely behind the point light covers nothing
    if kind == "persp":
        assert not np.any(t == 3)


def test_circle_implies_corners_and_program1_equals_corners():
    for kind, seed in [("ortho", 2), ("persp", 3)]:
        cam, tri = _frame(kind, seed)
        tri = tri * 3.0  # larger triangles: more fully covered texels
        c_t, c_k, st = lr.rasterize(cam, tri, "inner", "corners", tau=1e-6)
        h_t, h_k, _ = lr.rasterize(cam, tri, "inner", "circle", tau=1e-6)
        corners = set(zip(c_t.tolist(), c_k.tolist()))
        circle = set(zip(h_t.tolist(), h_k.tolist()))
        assert circle <= corners and len(corners) > len(circle) > 0
        # Program 1 on every centre-covered texel of a front triangle
        s_t, s_k, _ = lr.rasterize(cam, tri, "standard")
        s = st[0]
        keep = s.front[s_t]
        s_t, s_k = s_t[keep], s_k[keep]
        p1 = lr.program1_covered(s.edges[s_t], s.vertex_w[s_t], s.absdet[s_t], s_k % R, s_k // R)
        mine = lr.coverage(s.edges[s_t], s.norms[s_t], s_k % R, s_k // R, "inner", "corners")
        assert np.array_equal(p1, mine) and p1.sum() > 0


def _sat_overlap(uv, i, j, grow):
    """Closed projected triangle uv [3, 2] meets the texel square grown by ``grow``."""
    sq = np.array([[i - grow, j - grow], [i + 1 + grow, j - grow], [i + 1 + grow, j + 1 + grow],
                   [i - grow, j + 1 + grow]])
    axes = [np.array([1.0, 0.0]), np.array([0.0, 1.0])]
    axes += [np.array([-(uv[(k + 1) % 3] - uv[k])[1], (uv[(k + 1) % 3] - uv[k])[0]]) for k in range(3)]
    for ax in axes:
        a, b = uv @ ax, sq @ ax
        if a.max() < b.min() or b.max() < a.min():
            return False
    return True


@pytest.mark.parametrize("pad", [1.0, izb.BOX_PAD_TAUS * 1e-3])
@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_outer_mode_is_conservative_and_tight(kind, precision, pad):
    """Every texel square the projected triangle meets (separating axes) is found; a
    found one meets the triangle's square grown by the box pad: one texel, or with the
    IZB's pad of 2 tau (tau = 1e-3) the outer test is the separating-axis test up to
    that margin (the box gives the x and y axes, the edge test the edge normals)."""
    dtype = np.float64 if precision == "float64" else np.float32
    cam, tri = _frame(kind, 4)
    t, k, setups = lr.rasterize(cam, tri, "outer", tau=1e-3, dtype=dtype, pad=pad)
    got = set(zip(t.tolist(), k.tolist()))
    face = cam.faces[0]
    n_front = 0
    for ti in range(len(tri)):
        uv, depth = face.project(tri[ti])
        if np.any(depth <= 0):
            # a triangle through the light plane: every standard fragment is an outer one
            st_t, st_k, _ = lr.rasterize(cam, tri[ti:ti + 1], "standard")
            assert {(ti, x) for x in st_k.tolist()} <= got
            continue
        n_front += 1
        for j, i in itertools.product(range(R), range(R)):
            inside = _sat_overlap(uv, i, j, 0.0)
            if inside:
                assert (ti, j * R + i) in got
            if (ti, j * R + i) in got:
                assert _sat_overlap(uv, i, j, 1.05 * pad)    # within the box padding
    assert n_front > 20


@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_standard_mode_needs_no_box_pad(kind, precision):
    """The shadow map's boxes without padding give the same centre-covered fragments as
    with the one-texel pad: random triangles, slivers at every slope, fans sharing edges
    and (in perspective) triangles reaching behind the light."""
    dtype = np.float64 if precision == "float64" else np.float32
    found = 0
    for seed in (4, 5, 6):
        for make in (_frame, _sliver_frame):
            cam, tri = make(kind, seed)
            t1, k1, _ = lr.rasterize(cam, tri, "standard", dtype=dtype, pad=1.0)
            t0, k0, _ = lr.rasterize(cam, tri, "standard", dtype=dtype, pad=0.0)
            assert np.array_equal(t0, t1) and np.array_equal(k0, k1)
            found += len(t0)
    assert found > 500


@pytest.mark.parametrize("offset", [0.0, 1e5])
@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_points_of_a_triangle_fall_in_its_tightest_box(kind, offset):
    """The IZB's box claim with its smallest pad (coverage_margin 0: 2 x the float64
    rounding margin): every point of a front triangle (vertices, edge points, interior
    points), projected as the samples are (``project_points``), lies in a texel of the
    triangle's box; also with the frame 1e5 units from the origin."""
    cam0, tri = _frame(kind, 11)
    light = (sl.DirectionalLight(direction=(0.3, -1.0, 0.2)) if kind == "ortho"
             else sl.PointLight(position=(0.2 + offset, 1.3, 0.1)))
    tri = tri + (offset, 0.0, 0.0)
    points = tri.reshape(-1, 3)
    cam = (fit_light_camera(light, points, resolution=R) if kind == "ortho" else
           fit_light_camera(light, np.array([[-1.0, -1.0, -1.0], [1.0, -1.0, 1.0]]) +
                            (offset, 0.0, 0.0), resolution=R, projection="perspective"))
    face, uv, _, _ = lr.project_points(cam, points)
    tws = lr.texel_world_size(cam, points)
    tw = float(tws[tws > 0].min())                  # points in front of the light
    pad = 2.0 * lr.rounding_margin(np.float64, np.abs(points).max(), tw)
    setups = [lr.setup_face(f, tri, pad) for f in cam.faces]
    rng = np.random.default_rng(5)
    w = np.concatenate([np.eye(3), [[0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5]],
                        rng.dirichlet((1.0, 1.0, 1.0), 20)])     # [K, 3] barycentrics
    checked = 0
    for f, st in enumerate(setups):
        for t in np.flatnonzero(st.front & st.ok):
            p = w @ tri[t]                                          # [K, 3] world points
            pf, puv, _, _ = lr.project_points(cam, p)
            on = pf == f
            if not on.any():
                continue
            col0, col1, row0, row1 = st.bbox[t]
            ij = np.floor(puv[on]).astype(np.int64)
            inside = (ij[:, 0] >= 0) & (ij[:, 0] < R) & (ij[:, 1] >= 0) & (ij[:, 1] < R)
            ij = ij[inside]
            assert ((ij[:, 0] >= col0) & (ij[:, 0] <= col1) & (ij[:, 1] >= row0)
                    & (ij[:, 1] <= row1)).all(), (t, st.bbox[t], puv[on][inside])
            checked += len(ij)
    assert checked > 100


def test_jit_equals_numpy():
    cam, tri = _frame("persp", 5)
    setups = [lr.setup_face(f, tri) for f in cam.faces]
    keys = np.arange(R * R)
    t, slot = lr.candidates(setups, keys, R)
    col, row = keys[slot] % R, keys[slot] // R
    e, n = setups[0].edges[t].astype(np.float32), setups[0].norms[t].astype(np.float32)
    for mode in ("standard", "inner", "outer"):
        ref = lr.coverage(e, n, col, row, mode, tau=1e-3)
        fn = jax.jit(lambda e, n, c, r, mode=mode: lr.coverage(e, n, c, r, mode, tau=1e-3, xp=jnp))
        assert np.array_equal(np.asarray(fn(e, n, col, row)), ref)


def test_depth_plane_matches_the_ray_hit_and_bounds_the_square():
    for kind in ("ortho", "persp"):
        cam, tri = _frame(kind, 6)
        face = cam.faces[0]
        t, k, setups = lr.rasterize(cam, tri, "standard")
        s = setups[0]
        col, row = k % R, k // R
        lo, hi, centre = lr.depth_range(s.depth[t], col, row)
        for x in range(0, len(t), max(1, len(t) // 40)):
            o, d = _ray(face, (col[x] + 0.5, row[x] + 0.5))
            tt = tri[t[x]]
            n = np.cross(tt[1] - tt[0], tt[2] - tt[0])
            hit = o + d * ((tt[0] - o) @ n) / (d @ n)
            _, depth = face.project(hit[None])
            assert np.isclose(lr.face_depth(face, depth)[0], centre[x], rtol=1e-9, atol=1e-9)
            assert lo[x] <= centre[x] <= hi[x]


def _texel_space_edges(uv):
    """Edge rows [1, 3, 3] and norms [1, 3] of a triangle given in texel space [3, 2]
    (orthographic: P_i = (u_i, v_i, 1)), oriented inside-positive."""
    p = np.concatenate([np.asarray(uv, float), np.ones((3, 1))], axis=1)
    rows = np.stack([np.cross(p[(i + 1) % 3], p[(i + 2) % 3]) for i in range(3)])
    rows *= np.sign(np.linalg.det(p))
    return rows[None], np.hypot(rows[:, 0], rows[:, 1])[None]


def test_exact_analytic_right_triangle_on_texel_corners():
    """Triangle (1,1), (5.5,1), (1,5.5): legs exactly on texel borders (exact ties),
    hypotenuse u + v = 6.5 through texel centres' diagonals."""
    e, n = _texel_space_edges([(1, 1), (5.5, 1), (1, 5.5)])
    ij = np.array([(i, j) for j in range(8) for i in range(8)])
    col, row = ij[:, 0], ij[:, 1]
    ee, nn = np.repeat(e, len(ij), 0), np.repeat(n, len(ij), 0)
    cov = {m: {tuple(x) for x in ij[lr.coverage(ee, nn, col, row, m)]}
           for m in ("inner", "outer", "standard")}
    circle = {tuple(x) for x in ij[lr.coverage(ee, nn, col, row, "inner", "circle")]}
    # the closed square inside: i, j >= 1 (corners on the legs count) and the far corner
    # (i + 1) + (j + 1) <= 6.5
    assert cov["inner"] == {(i, j) for i, j in ij if i >= 1 and j >= 1 and i + j <= 4}
    # circle: the centre at least sqrt(2)/2 from every edge: i + 0.5 - 1 >= 0.707 and
    # (6.5 - i - j - 1) / sqrt(2) >= 0.707
    assert circle == {(2, 2)}
    # every texel whose closed square meets the closed triangle is an outer fragment
    touching = {(i, j) for i, j in ij if i <= 5 and j <= 5 and i + j <= 6}
    assert touching <= cov["outer"]
    assert cov["outer"] - touching <= {(6, 0), (0, 6)}   # beyond the acute vertices only
    # centres inside: i, j >= 1 and i + j + 1 < 6.5
    assert cov["standard"] == {(i, j) for i, j in ij if i >= 1 and j >= 1 and i + j <= 5}


def test_top_left_rule_covers_a_shared_edge_centre_once():
    """Two triangles sharing the diagonal u = v through texel centres: each centre on it
    belongs to exactly one of them."""
    ij = np.array([(i, j) for j in range(6) for i in range(6)])
    col, row = ij[:, 0], ij[:, 1]
    hits = []
    for tri in ([(0, 0), (6, 0), (6, 6)], [(0, 0), (6, 6), (0, 6)]):
        e, n = _texel_space_edges(tri)
        hits.append(lr.coverage(np.repeat(e, len(ij), 0), np.repeat(n, len(ij), 0), col, row,
                                "standard"))
    diag = col == row
    assert np.all(hits[0][diag] ^ hits[1][diag])
    assert np.all(hits[0] | hits[1])


@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_jax_raster_equals_the_numpy_enumeration(kind, monkeypatch):
    """The count-then-fill raster (JAX, padded capacities) yields exactly the candidates of
    the NumPy enumeration, with its coverage and depth range, over a sparse key set and a
    triangle selection, with every box narrowed to its rows' spans; its covered fragments
    are those of the whole boxes. Outside ``x64()`` it refuses to run."""
    cam, tri = _frame(kind, 8)
    setups = [lr.setup_face(f, tri) for f in cam.faces]
    keys = np.arange(0, R * R, 3)
    select = [np.arange(len(tri)) % 4 != 1]
    monkeypatch.setattr(lr, "NARROW_MIN_COLUMNS", 1)          # every box narrowed
    t_box, slot_box = lr.candidates(setups, keys, R, select)
    for mode in ("standard", "inner", "outer"):
        t, slot = lr.candidates(setups, keys, R, select, mode, "corners", 1e-3)
        box_cov = lr.coverage(setups[0].unit[t_box], None, keys[slot_box] % R,
                              keys[slot_box] // R, mode, tau=1e-3)
        col, row = keys[slot] % R, keys[slot] // R
        lo, hi, centre = lr.depth_range(setups[0].depth[t], col, row)
        with lr.x64():
            fr = lr.raster(setups, keys, R, mode, "corners", 1e-3, select=select)
            assert fr.candidates == len(t)
            n = fr.candidates
            assert not np.asarray(fr.covered)[n:].any()        # padding never covered
            assert np.array_equal(np.asarray(fr.tri)[:n], t)
            assert np.array_equal(np.asarray(fr.slot)[:n], slot)
            cov = lr.coverage(setups[0].unit[t], None, col, row, mode, tau=1e-3)
            assert np.array_equal(np.asarray(fr.covered)[:n], cov)
            # the covered fragments are the whole boxes' ones, in the same order
            assert np.array_equal(np.asarray(fr.tri)[:n][cov], t_box[box_cov])
            assert np.array_equal(np.asarray(fr.slot)[:n][cov], slot_box[box_cov])
            assert n < len(t_box)
            for got, want in ((fr.lo, lo), (fr.hi, hi), (fr.centre, centre)):
                np.testing.assert_allclose(np.asarray(got)[:n], want, rtol=1e-12, atol=1e-12)
    with pytest.raises(RuntimeError, match="x64"):
        lr.raster(setups, keys, R, "outer", "corners", 1e-3)


def test_raster_computes_only_the_fields_asked_for():
    """A raster asked for some fields gives them bit for bit as the full raster does, None
    for the others; an unknown field, and compacting one not computed, are refused."""
    cam, tri = _frame("persp", 8)
    setups = [lr.setup_face(f, tri) for f in cam.faces]
    keys = np.arange(0, R * R, 2)
    with lr.x64():
        full = lr.raster(setups, keys, R, "outer", "corners", 1e-3)
        for fields in (("tri", "slot", "covered", "lo"), ("slot", "covered", "hi", "centre",
                                                           "slope"), ("covered",)):
            part = lr.raster(setups, keys, R, "outer", "corners", 1e-3, fields=fields)
            assert part.candidates == full.candidates
            for name in lr.FRAGMENT_FIELDS:
                got = getattr(part, name)
                if name in fields:
                    assert np.array_equal(np.asarray(got), np.asarray(getattr(full, name)))
                else:
                    assert got is None
        with pytest.raises(ValueError, match="unknown fragment fields.*'depth'.*allowed"):
            lr.raster(setups, keys, R, "outer", fields=("slot", "depth"))
        with pytest.raises(ValueError, match="not computed"):
            lr.raster(setups, keys, R, "outer", fields=("covered", "slot")).compact("lo")
    assert len(full.compact("lo")[0]) == int(np.asarray(full.covered).sum()) > 0


@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_depth_class_is_the_coverage_and_depth_test(kind):
    """The fill's depth class equals, fragment by fragment, a NumPy evaluation of the
    full raster's coverage and ``lo < limit[slot]`` (limits drawn between the fragments'
    depths, so both outcomes occur); the host triangle and key index equal the device
    arrays; the field and its limit come together."""
    cam, tri = _frame(kind, 9)
    setups = [lr.setup_face(f, tri) for f in cam.faces]
    keys = np.arange(0, len(cam.faces) * R * R, 3)
    with lr.x64():
        full = lr.raster(setups, keys, R, "outer", "corners", 1e-3)
        n = full.candidates
        lo = np.asarray(full.lo)[:n]
        slot = np.asarray(full.slot)[:n]
        covered = np.asarray(full.covered)[:n]
        limit = np.random.default_rng(3).uniform(lo.min(), lo.max(), len(keys))
        limit[:5] = lo.max() + 1.0                        # every fragment of a key kept
        # exact ties (lo == limit: culled), on covered fragments of other keys
        cand = np.flatnonzero(covered & (slot >= 5))
        tie = cand[np.unique(slot[cand], return_index=True)[1]][::7][:20]   # one per key
        limit[slot[tie]] = lo[tie]
        part = lr.raster(setups, keys, R, "outer", "corners", 1e-3,
                         fields=("depth_class",), depth_limit=limit)
        with pytest.raises(ValueError, match="depth_class.*depth_limit"):
            lr.raster(setups, keys, R, "outer", fields=("depth_class",))
        with pytest.raises(ValueError, match="depth_class.*depth_limit"):
            lr.raster(setups, keys, R, "outer", fields=("lo",), depth_limit=limit)
    assert part.candidates == n and part.lo is None and part.covered is None
    got = np.asarray(part.depth_class)
    want = np.where(covered, np.where(lo < limit[slot], lr.NEARER, lr.BEYOND_LIMIT),
                    lr.NOT_COVERED)
    assert np.array_equal(got[:n], want)
    assert (got[n:] == lr.NOT_COVERED).all()
    assert {lr.NEARER, lr.BEYOND_LIMIT, lr.NOT_COVERED} <= set(want.tolist())
    assert (got[tie] == lr.BEYOND_LIMIT).all() and len(tie) > 5
    index = np.flatnonzero(got[:n] == lr.NEARER)
    t, k = part.host_tri_slot(index)
    assert t.dtype == k.dtype == np.int64
    assert np.array_equal(t, np.asarray(full.tri)[index])
    assert np.array_equal(k, slot[index])


@pytest.mark.parametrize("n,size", [(0, 16), (7, 6 * 16 * 16), (500, 64), (500, 2000)])
def test_unique_keys_equals_numpy_unique(n, size):
    """Both branches (occupancy table, sort) against np.unique."""
    key = np.random.default_rng(n + size).integers(0, size, n)
    keys, inv = lr.unique_keys(key, size)
    ref, ref_inv = np.unique(key, return_inverse=True)
    assert np.array_equal(keys, ref) and np.array_equal(inv, ref_inv.ravel())
    assert inv.dtype == np.int64 and np.array_equal(keys[inv], key)


@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_setup_face_equals_a_per_triangle_loop(kind):
    """The column-wise set-up against a per-triangle loop over [3, 3] matrices (the
    homogeneous corners by a matrix product, edge rows by np.cross, the determinant by
    np.linalg.det, the depth plane by solving for the plane through the corners'
    deltas): booleans and boxes equal, values to rounding."""
    for seed in (7, 8, 9):
        cam, tri = _frame(kind, seed)
        tri[5, 2] = tri[5, 0] + 0.5 * (tri[5, 1] - tri[5, 0])     # a degenerate triangle
        face = cam.faces[0]
        s = lr.setup_face(face, tri)
        m = lr.homogeneous_matrix(face)
        r = face.resolution[0]
        for t in range(len(tri)):
            p = tri[t] @ m[:, :3].T + m[:, 3]                     # [3, 3] rows (u w, v w, w)
            w = p[:, 2].copy()
            if face.orthographic:
                p[:, 2] = 1.0
                w[:] = 1.0
            det = np.linalg.det(p)
            rows = np.stack([np.cross(p[(i + 1) % 3], p[(i + 2) % 3]) for i in range(3)])
            rows *= -1.0 if det < 0 else 1.0
            if abs(det) <= 1e-9 * np.abs(p).max() ** 3:
                # degenerate (t = 5): the sign of det is rounding noise, which differs
                # between LAPACK builds, so the rows are compared up to their sign
                rows *= -1.0 if np.sum(rows * s.edges[t]) < 0 else 1.0
            scale = np.abs(rows).max() + 1e-300
            np.testing.assert_allclose(s.edges[t], rows, rtol=0, atol=1e-9 * scale)
            np.testing.assert_allclose(s.absdet[t], abs(det), rtol=1e-9,
                                       atol=1e-9 * np.abs(p).max() ** 3)
            assert s.front[t] == (w > 0).all()
            assert s.ok[t] == ((s.absdet[t] > 0) and (w > 0).any())
            if s.front[t] and s.ok[t] and abs(det) > 1e-6 * np.abs(p).max() ** 3:
                uv = p[:, :2] / w[:, None]
                lo, hi = np.floor(uv.min(0) - 1.0), np.floor(uv.max(0) + 1.0)
                box = [np.clip(lo[0], 0, r - 1), np.clip(hi[0], -1, r - 1),
                       np.clip(lo[1], 0, r - 1), np.clip(hi[1], -1, r - 1)]
                if hi[0] < 0 or lo[0] > r - 1 or hi[1] < 0 or lo[1] > r - 1:
                    box = [1, 0, 1, 0]
                assert list(s.bbox[t]) == box
                # the depth plane interpolates the corners' deltas at their texel points
                for i in range(3):
                    got = s.depth[t] @ np.array([uv[i, 0], uv[i, 1], 1.0])
                    np.testing.assert_allclose(got, s.vertex_delta[t, i], rtol=1e-7,
                                               atol=1e-9)
            nz = s.norms[t] > 0
            np.testing.assert_allclose(s.unit[t][nz], s.edges[t][nz] / s.norms[t][nz, None],
                                       rtol=1e-15)


def _sliver_frame(kind, seed):
    """Thin triangles spanning many rows at every slope (steep, diagonal, almost
    horizontal: edge coefficients a of about 1e-9 and 1e-15 texels), fans of triangles
    sharing edges, and, in perspective, triangles reaching behind the light."""
    cam, tri = _frame(kind, seed)
    rng = np.random.default_rng(seed + 100)
    base = rng.uniform(-1, 1, (40, 3))
    ang = rng.uniform(0, np.pi, 40)
    ang[:4] = [0.0, 1e-9, 1e-15, np.pi / 2]
    d = np.stack([np.cos(ang), 0.0 * ang, np.sin(ang)], 1) * 3.0
    side = np.stack([-np.sin(ang), 0.0 * ang, np.cos(ang)], 1) * rng.uniform(1e-4, 0.05, (40, 1))
    sliver = np.stack([base, base + side, base + d], 1)
    return cam, np.concatenate([tri, sliver, tri[:6] * 1.5])


@pytest.mark.parametrize("kind", ["ortho", "persp"])
@pytest.mark.parametrize("min_columns", [1, 4])
def test_row_spans_keep_every_covered_fragment(kind, precision, min_columns, monkeypatch):
    """Candidates narrowed to each row's passing columns (row_spans; every box narrowed,
    or the boxes at least 4 texels wide) hold every fragment the coverage test accepts
    among the whole box's candidates, in every mode, for the evaluation dtype's rounding;
    and they cut the slivers' boxes. Boxes narrower than the threshold are whole."""
    monkeypatch.setattr(lr, "NARROW_MIN_COLUMNS", min_columns)
    dtype = np.float64 if precision == "float64" else np.float32
    eps = float(np.finfo(dtype).eps)
    for seed in (11, 12):
        cam, tri = _sliver_frame(kind, seed)
        slivers = set(range(30, 70))
        setups = [lr.setup_face(f, tri) for f in cam.faces]
        keys = np.arange(R * R)
        t_box, slot_box = lr.candidates(setups, keys, R)
        box_pairs = set(zip(t_box.tolist(), slot_box.tolist()))
        for mode, test, tau in [("standard", "corners", 0.0), ("standard", "corners", 0.3),
                                ("inner", "corners", 1e-3),
                                ("inner", "circle", 0.0), ("outer", "corners", 1e-3),
                                ("outer", "corners", 0.0), ("outer", "corners", 0.7)]:
            col, row = keys[slot_box] % R, keys[slot_box] // R
            cov = lr.coverage(setups[0].unit[t_box].astype(dtype), None, col, row, mode,
                              test, tau)
            t, slot = lr.candidates(setups, keys, R, None, mode, test, tau, eps)
            narrowed = set(zip(t.tolist(), slot.tolist()))
            covered = set(zip(t_box[cov].tolist(), slot_box[cov].tolist()))
            assert covered <= narrowed <= box_pairs, (mode, test, tau)
            assert len(covered) > 10
            n_box = sum(p[0] in slivers for p in box_pairs)
            n_cut = sum(p[0] in slivers for p in narrowed)
            assert n_cut < (0.9 if tau > 0.5 else 0.7) * n_box, (mode, test, tau, n_cut, n_box)
            width = setups[0].bbox[:, 1] - setups[0].bbox[:, 0] + 1
            small = set(np.flatnonzero(width < min_columns).tolist())
            assert ({p for p in narrowed if p[0] in small}
                    == {p for p in box_pairs if p[0] in small})
        monkeypatch.setattr(lr, "NARROW_MIN_COLUMNS", R + 1)
        monkeypatch.setattr(lr, "NARROW_DENSE_COLUMNS", R + 1)
        t, slot = lr.candidates(setups, keys, R, None, "inner", "corners", 1e-3, eps)
        assert np.array_equal(t, t_box) and np.array_equal(slot, slot_box)
        monkeypatch.setattr(lr, "NARROW_MIN_COLUMNS", min_columns)


def test_narrow_width_follows_each_faces_key_density(monkeypatch):
    """Boxes from 16 columns are always narrowed; narrower ones down to 8 where a row is
    expected to hold 2 keys (width x the face's key density); and row_segments uses each
    face's own width (two copies of a face: dense keys on the first, sparse on the other)."""
    assert lr.narrow_min_columns(0, 100) == 16
    assert lr.narrow_min_columns(1, 100) == 16         # sparse: 200 columns for 2 keys
    assert lr.narrow_min_columns(2, 12) == 12
    assert lr.narrow_min_columns(3, 12) == 8
    assert lr.narrow_min_columns(100, 100) == 8
    assert lr.narrow_min_columns(25, 100) == 8 and lr.narrow_min_columns(24, 100) == 9
    cam, tri = _sliver_frame("ortho", 11)
    setup = lr.setup_face(cam.faces[0], tri)
    width = setup.bbox[:, 1] - setup.bbox[:, 0] + 1
    assert np.any((width >= 8) & (width < 16))
    seen = []
    real = lr.row_spans
    monkeypatch.setattr(lr, "row_spans", lambda unit, box, *a, **k: (
        seen.append(box[:, 1] - box[:, 0] + 1), real(unit, box, *a, **k))[1])
    keys = np.concatenate([np.arange(R * R), R * R + np.arange(0, R * R, 64)])
    lr.candidates([setup, setup], keys, R, None, "outer", "corners", 1e-3)
    dense, sparse = seen[0], (seen[1] if len(seen) > 1 else np.zeros(0, np.int64))
    assert dense.min() >= 8 and np.any(dense < 16)
    assert np.all(sparse >= 16)


def test_row_spans_on_hand_made_rows():
    """One binding edge per case, in unit rows (a, b, c): the passing columns of a row
    are an interval widened by one column (the coverage test decides inside it); an
    edge with a = 0 (an edge at infinity too) bounds no column; a tiny slope widens the
    bound by its rounding instead of cutting the row."""
    box = np.array([[0, 15, 0, 15]])
    owner, row = np.array([0]), np.array([4])

    def span(edge, mode="standard", tau=0.0):
        unit = np.zeros((1, 3, 3))
        unit[0, :, 2] = np.inf                      # two edges that never bind
        unit[0, 0] = edge
        lo, hi = lr.row_spans(unit, box, owner, row, mode, "corners", tau)
        return int(lo[0]), int(hi[0])

    # u - 5.2 >= 0 at the centre u = col + 0.5: col >= 4.7, so 5.. (4 after widening)
    assert span((1.0, 0.0, -5.2)) == (4, 15)
    # -u + 9.0 >= 0: col <= 8.5, so ..8 (9 after widening)
    assert span((-1.0, 0.0, 9.0)) == (0, 9)
    # a sloped edge: u + v - 10 >= 0 at v = 4.5: col >= 5, so 4..
    assert span((0.5 ** 0.5, 0.5 ** 0.5, -10 * 0.5 ** 0.5)) == (4, 15)
    # outer: a corner within tau = 0.5 of the inside: col >= 4.7 - 0.5 - 0.5, so 3..
    assert span((1.0, 0.0, -5.2), "outer", 0.5) == (3, 15)
    # inner corners: every corner tau = 0.5 inside: col >= 4.7 + 0.5 + 0.5, so 5..
    assert span((1.0, 0.0, -5.2), "inner", 0.5) == (5, 15)
    # standard has no margin: tau changes nothing
    assert span((1.0, 0.0, -5.2), "standard", 5.0) == (4, 15)
    for edge in ((0.0, 1.0, -6.0), (0.0, 1.0, -3.0), (0.0, 0.0, -np.inf), (0.0, 0.0, np.inf)):
        assert span(edge) == (0, 15)
    assert span((1e-15, 1.0, -4.5)) == (0, 15)
    # the box clamps, and a row with no passing column has lo > hi
    lo, hi = span((1.0, 0.0, -40.0))
    assert lo > hi and lo <= 16


@pytest.mark.parametrize("size", [1, 64, 1000, 4096, 70001])
def test_key_rank_equals_searchsorted(size):
    """KeyRank (bitmap and per-word counts) gives np.searchsorted's indices for every
    texel key from 0 to size, for empty, sparse, dense and word-aligned key sets."""
    rng = np.random.default_rng(size)
    for n in (0, 1, size // 7, size):
        keys = np.sort(rng.choice(size, n, replace=False)).astype(np.int64)
        x = np.arange(size + 1)
        got = lr.KeyRank(keys, size)(x)
        assert np.array_equal(got, np.searchsorted(keys, x)), n


def test_row_segments_with_and_without_the_rank_table(monkeypatch):
    """The count pass gives the same segments from the rank table as from binary
    searches (the former lookup), over sparse keys, a triangle
    selection and narrowed rows."""
    cam, tri = _sliver_frame("persp", 13)
    setups = [lr.setup_face(f, tri) for f in cam.faces]
    keys = np.flatnonzero(np.random.default_rng(3).random(R * R) < 0.4)
    select = [np.arange(len(tri)) % 5 != 2]
    for mode in (None, "outer", "inner"):
        with_table = lr.row_segments(setups, keys, R, select, mode, "corners", 1e-3)
        monkeypatch.setattr(lr, "key_rank", lambda keys, size: None)
        searched = lr.row_segments(setups, keys, R, select, mode, "corners", 1e-3)
        monkeypatch.undo()
        assert len(with_table[0]) > 50
        for a, b in zip(with_table, searched):
            assert np.array_equal(a, b), mode


def test_an_unknown_mode_is_refused(monkeypatch):
    """The coverage test and the narrowed count pass name the allowed modes."""
    monkeypatch.setattr(lr, "NARROW_MIN_COLUMNS", 1)
    cam, tri = _frame("ortho", 2)
    setups = [lr.setup_face(f, tri) for f in cam.faces]
    keys = np.arange(R * R)
    t, slot = lr.candidates(setups, keys, R)
    with pytest.raises(ValueError, match="standard.*inner.*outer"):
        lr.coverage(setups[0].unit[t], None, keys[slot] % R, keys[slot] // R, "centre")
    with pytest.raises(ValueError, match="standard.*inner.*outer"):
        lr.candidates(setups, keys, R, None, "centre")
