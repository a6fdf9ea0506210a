"""rtk.RaycastingScene: Open3D's interface over rtk, checked against brute
force in numpy, on closed meshes where inside/outside is known exactly, at
shared edges and vertices, with the shapes, dtypes and bad input a user
brings; against Open3D itself where python3-open3d is installed."""
import math

import numpy as np
import pytest

import rtk


def cube(n=4, c=(0.5, 0.25, -0.75), h=0.5):
    """The closed box c +- h, each face an n x n grid (n a power of two and
    c, h exact: every vertex exact in float), outward-facing triangles."""
    verts, tris, index = [], [], {}

    def vid(p):
        key = tuple(p)
        if key not in index:
            index[key] = len(verts)
            verts.append(p)
        return index[key]

    for axis in range(3):
        for side in (-1, 1):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            for i in range(n):
                for j in range(n):
                    q = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = [0.0, 0.0, 0.0]
                        p[axis] = c[axis] + side * h
                        p[u] = c[u] - h + 2 * h * (i + di) / n
                        p[v] = c[v] - h + 2 * h * (j + dj) / n
                        q.append(vid(p))
                    a, b, cc, d = q if side > 0 else q[::-1]
                    tris += [[a, b, cc], [a, cc, d]]
    return np.array(verts, np.float32), np.array(tris, np.int64)


def sphere(seg=24, rings=12):
    """A closed UV sphere of radius 1 (shared poles)."""
    v = [[0, 0, 1]]
    for r in range(1, rings):
        th = math.pi * r / rings
        for s in range(seg):
            ph = 2 * math.pi * s / seg
            v.append([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    v.append([0, 0, -1])
    t = []
    for s in range(seg):
        t.append([0, 1 + s, 1 + (s + 1) % seg])
    for r in range(rings - 2):
        for s in range(seg):
            a, b = 1 + r * seg + s, 1 + r * seg + (s + 1) % seg
            t += [[a, a + seg, b], [b, a + seg, b + seg]]
    last = len(v) - 1
    for s in range(seg):
        a, b = 1 + (rings - 2) * seg + s, 1 + (rings - 2) * seg + (s + 1) % seg
        t.append([a, last, b])
    return np.array(v, np.float32), np.array(t, np.int32)


def brute_closest(v, t, q):
    """Distances from points q to triangles (v, t) by dense projection: the
    nearest of the face projections inside and the three edges."""
    a, b, c = (v[t[:, k]].astype(np.float64) for k in range(3))
    out = []
    for p in q.astype(np.float64):
        def seg(x, y):
            d = y - x
            tt = np.clip(np.einsum("ij,ij->i", p - x, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0, 1)
            return np.linalg.norm(x + tt[:, None] * d - p, axis=1)
        e = np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a))
        n = np.cross(b - a, c - a)
        nn = np.linalg.norm(n, axis=1)
        n = n / np.where(nn > 0, nn, 1)[:, None]
        dist = np.einsum("ij,ij->i", p - a, n)
        proj = p - dist[:, None] * n
        # inside: the same side of every edge
        s1 = np.einsum("ij,ij->i", np.cross(b - a, proj - a), n)
        s2 = np.einsum("ij,ij->i", np.cross(c - b, proj - b), n)
        s3 = np.einsum("ij,ij->i", np.cross(a - c, proj - c), n)
        inside = (s1 >= 0) & (s2 >= 0) & (s3 >= 0) & (nn > 0)
        f = np.where(inside, np.abs(dist), np.inf)
        out.append(min(e[nn > 0].min(), f.min()))
    return np.array(out)


@pytest.fixture
def cube_scene():
    v, t = cube()
    s = rtk.RaycastingScene()
    assert s.add_triangles(v, t) == 0
    return s, v, t


def test_cast_rays_shapes_and_keys(cube_scene):
    s, v, t = cube_scene
    rays = rtk.RaycastingScene.create_rays_pinhole(60, [0.5, 0.25, -0.75], [3, 2, 1], [0, 0, 1], 16, 12)
    assert rays.shape == (12, 16, 6) and rays.dtype == np.float32
    ans = s.cast_rays(rays)
    assert set(ans) == {"t_hit", "geometry_ids", "primitive_ids", "primitive_uvs", "primitive_normals"}
    assert ans["t_hit"].shape == (12, 16) and ans["t_hit"].dtype == np.float32
    assert ans["primitive_uvs"].shape == (12, 16, 2) and ans["primitive_normals"].shape == (12, 16, 3)
    hit = ans["geometry_ids"].numpy() != rtk.INVALID_ID
    assert hit.any() and not hit.all()
    assert np.all(np.isinf(ans["t_hit"].numpy()[~hit]))
    assert np.all(ans["primitive_ids"].numpy()[~hit] == rtk.INVALID_ID)
    # hit points lie on the cube's surface
    r = rays.numpy().reshape(-1, 6)[hit.ravel()]
    p = r[:, :3] + ans["t_hit"].numpy()[hit][:, None] * r[:, 3:]
    d = np.abs(p - np.array([0.5, 0.25, -0.75])).max(axis=1)
    assert np.allclose(d, 0.5, atol=1e-5)
    n = ans["primitive_normals"].numpy()[hit]
    assert np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-6)
    # facing the rays: outward normals against incoming directions
    assert np.all(np.einsum("ij,ij->i", n, r[:, 3:]) < 0)
    occ = s.test_occlusions(rays)
    assert occ.dtype == bool and np.array_equal(occ.numpy(), hit)
    assert not s.test_occlusions(rays, tfar=1e-3).numpy().any()


def test_rays_in_every_dtype_and_layout(cube_scene):
    """float64 rays are read as they are (rounded to float as rtk traces),
    strided views without a copy, other dtypes converted: the same answers."""
    s, v, t = cube_scene
    rays = rtk.RaycastingScene.create_rays_pinhole(60, [0.5, 0.25, -0.75], [3, 2, 1], [0, 0, 1], 16, 12).numpy()
    ref = s.cast_rays(rays)
    wide = np.zeros((12, 16, 9), np.float32)
    wide[..., 1:7] = rays
    for r in (rays.astype(np.float64), wide[..., 1:7], np.asfortranarray(rays.reshape(-1, 6)).reshape(12, 16, 6)):
        ans = s.cast_rays(r)
        for k in ref:
            assert np.array_equal(ans[k].numpy(), ref[k].numpy()), k
        assert np.array_equal(s.test_occlusions(r).numpy(), s.test_occlusions(rays).numpy())
    # an image's rows (..., W, 6) go as 4x2 blocks of pixels, a flat
    # array as it comes: the same answers, widths not a multiple of 4 too
    for w, h in ((16, 12), (13, 7)):
        img = rtk.RaycastingScene.create_rays_pinhole(60, [0.5, 0.25, -0.75], [3, 2, 1], [0, 0, 1], w, h).numpy()
        a, b = s.cast_rays(img), s.cast_rays(img.reshape(-1, 6))
        for k in a:
            assert np.array_equal(a[k].numpy().reshape(b[k].numpy().shape), b[k].numpy()), k
        assert np.array_equal(s.test_occlusions(img).numpy().reshape(-1), s.test_occlusions(img.reshape(-1, 6)).numpy())
    ints = np.array([[3, 0, -1, -1, 0, 0], [3, 9, 0, -1, 0, 0]], np.int32)  # a hit and a miss
    assert np.array_equal(s.cast_rays(ints)["t_hit"].numpy(), [2.0, np.inf])
    with pytest.raises(ValueError):
        s.test_occlusions(rays, tnear=2.0, tfar=1.0)
    with pytest.raises(ValueError):
        s.test_occlusions(rays, tnear=-1.0)


def test_counts_and_lists_at_vertices_and_edges(cube_scene):
    """Rays through every vertex and edge middle of the closed cube, from
    outside: each crossing once, so even counts all the way through and odd
    up to the centre; the list sorted and equal to the counts."""
    s, v, t = cube_scene
    centre = np.array([0.5, 0.25, -0.75], np.float32)
    targets = np.concatenate([v, 0.5 * (v[t[:, 0]] + v[t[:, 1]])])
    rng = np.random.default_rng(1)
    d = targets - centre
    d = d / np.linalg.norm(d, axis=1, keepdims=True) + rng.uniform(-0.3, 0.3, d.shape)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    origins = (targets + 2 * d).astype(np.float32)
    rays = np.concatenate([origins, (-d).astype(np.float32)], axis=1)
    counts = s.count_intersections(rays).numpy()
    assert counts.dtype == np.int32
    # (a ray that grazes the cube at a corner or along an edge crosses 0 or 2 times)
    assert np.all(counts % 2 == 0), np.unique(counts)
    assert (counts == 2).mean() > 0.5
    lst = s.list_intersections(rays)
    splits = lst["ray_splits"].numpy()
    assert np.array_equal(np.diff(splits), counts)
    th = lst["t_hit"].numpy()
    for i in range(len(rays)):
        seg = th[splits[i]:splits[i + 1]]
        assert np.all(np.diff(seg) >= 0)
    assert np.array_equal(lst["ray_ids"].numpy(), np.repeat(np.arange(len(rays)), counts))
    # from the centre: exactly one crossing, through vertices and edges too
    out = np.concatenate([np.broadcast_to(centre, targets.shape), targets - centre], axis=1).astype(np.float32)
    assert np.all(s.count_intersections(out).numpy() == 1)


def test_occupancy_and_signed_distance_exact(cube_scene):
    s, v, t = cube_scene
    c = np.array([0.5, 0.25, -0.75])
    on = np.concatenate([v, 0.5 * (v[t[:, 0]] + v[t[:, 1]]), (v[t[:, 0]] + v[t[:, 1]] + 2.0 * v[t[:, 2]]) / 4])
    occ = s.compute_occupancy(on.astype(np.float32)).numpy()
    assert occ.dtype == np.float32 and np.all(occ == 1)  # on the surface: inside
    assert np.all(s.compute_signed_distance(on.astype(np.float32)).numpy() == 0)
    rng = np.random.default_rng(2)
    p = c + rng.uniform(-0.8, 0.8, (2000, 3))
    inside = np.all(np.abs(p - c) < 0.5, axis=1)
    edge = np.abs(np.abs(p - c) - 0.5).min(axis=1) < 1e-6
    occ = s.compute_occupancy(p).numpy()
    assert occ.dtype == np.float64
    assert np.array_equal(occ[~edge] == 1, inside[~edge])
    sd = s.compute_signed_distance(p).numpy()
    want = brute_closest(v, t, p)
    assert np.allclose(np.abs(sd), want, rtol=1e-9, atol=1e-12)
    assert np.all((sd < 0) == (inside & (want > 0)))


def test_closest_points_vs_brute_force():
    v, t = sphere()
    s = rtk.RaycastingScene()
    s.add_triangles(v, t)
    rng = np.random.default_rng(3)
    q = rng.uniform(-1.5, 1.5, (500, 3)).astype(np.float32)
    ans = s.compute_closest_points(q)
    assert set(ans) == {"points", "geometry_ids", "primitive_ids", "primitive_uvs", "primitive_normals"}
    assert ans["points"].dtype == np.float32
    d = s.compute_distance(q).numpy()
    assert d.dtype == np.float32
    want = brute_closest(v, t, q)
    assert np.allclose(d, want, rtol=1e-6, atol=1e-7)
    assert np.allclose(np.linalg.norm(ans["points"].numpy() - q, axis=1), d, atol=1e-6)
    # the reported triangle and barycentrics give the reported point
    pid = ans["primitive_ids"].numpy()
    uv = ans["primitive_uvs"].numpy().astype(np.float64)
    a, b, c = (v[t[pid, k]].astype(np.float64) for k in range(3))
    p = (1 - uv[:, :1] - uv[:, 1:]) * a + uv[:, :1] * b + uv[:, 1:] * c
    assert np.allclose(p, ans["points"].numpy(), atol=1e-5)
    # signed: inside the sphere negative, by the mesh's exact parity
    sd = s.compute_signed_distance(q).numpy()
    r = np.linalg.norm(q, axis=1)
    clear = np.abs(r - 1) > 0.05  # (the mesh lies within 0.05 of the unit sphere)
    assert np.all((sd[clear] < 0) == (r[clear] < 1))


def test_closest_points_ties_report_the_least_triangle(cube_scene):
    """Points on the cube's vertices, and beyond its corners (nearest to a
    corner), tie every triangle around the vertex: the least index is
    reported (rtk.h), whatever backend or order of the walk."""
    s, v, t = cube_scene
    lo, hi = v.min(axis=0), v.max(axis=0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])],
                       np.float32)
    outward = np.sign(corners - 0.5 * (lo + hi)) * 0.125
    q = np.concatenate([v, corners + outward.astype(np.float32)])
    near = np.concatenate([np.arange(len(v)), [np.flatnonzero((v == c).all(axis=1))[0] for c in corners]])
    want = np.array([np.flatnonzero((t == i).any(axis=1)).min() for i in near])
    got = s.compute_closest_points(q)["primitive_ids"].numpy()
    assert np.array_equal(got, want)
    # one point at a time, and a batch in another order: the same
    one = np.array([s.compute_closest_points(p[None])["primitive_ids"].numpy()[0] for p in q[::-1]])
    assert np.array_equal(one[::-1], want)


def test_points_in_every_dtype_and_layout(cube_scene):
    """Points go to rtk's arrays call as they are (float32, float64) or
    converted (views, other dtypes): the same answers for the same points,
    float64 answers for float64 points rounding to the float32 ones."""
    s, v, t = cube_scene
    rng = np.random.default_rng(5)
    lo, hi = v.min(axis=0), v.max(axis=0)
    q = np.concatenate([rng.uniform(lo - 1, hi + 1, (300, 3)), v]).astype(np.float32)
    ref = s.compute_closest_points(q)
    ref_d, ref_sd = s.compute_distance(q).numpy(), s.compute_signed_distance(q).numpy()
    ref_occ = s.compute_occupancy(q).numpy()
    assert (ref_occ == 1).any() and (ref_occ == 0).any()
    wide = np.zeros((len(q), 5), np.float32)
    wide[:, 1:4] = q
    for p in (wide[:, 1:4], np.asfortranarray(q), q.reshape(-1, 1, 3), q.astype(np.float64)):
        shape = p.shape[:-1]
        f32 = p.dtype == np.float32
        ans = s.compute_closest_points(p)
        assert ans["points"].dtype == p.dtype
        for k in ref:
            got = ans[k].numpy().reshape(ref[k].numpy().shape)
            assert np.array_equal(got.astype(ref[k].numpy().dtype), ref[k].numpy()), k
        for fn, want in ((s.compute_distance, ref_d), (s.compute_signed_distance, ref_sd),
                         (s.compute_occupancy, ref_occ)):
            got = fn(p).numpy()
            assert got.shape == shape and got.dtype == (np.float32 if f32 else np.float64)
            assert np.array_equal(got.reshape(-1).astype(np.float32), want), fn.__name__
    # other dtypes: converted exactly, answered in float32
    ints = np.array([[3, 0, 0], [0, 0, 0], [-2, 1, 1]], np.int32)
    d = s.compute_distance(ints).numpy()
    assert d.dtype == np.float32 and np.array_equal(d, s.compute_distance(ints.astype(np.float32)).numpy())


def test_float64_kept():
    s = rtk.RaycastingScene()
    s.add_triangles(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64), np.array([[0, 1, 2]]))
    q = np.array([[0.3, 0.3, 1e-12], [0.3, 0.3, -1e-12]])
    d = s.compute_distance(q).numpy()
    assert d.dtype == np.float64 and d[0] == 1e-12 and d[1] == 1e-12
    p = s.compute_closest_points(q)["points"].numpy()
    assert p.dtype == np.float64 and np.array_equal(p[0], [0.3, 0.3, 0.0])


def test_double_points_far_from_the_origin():
    """A box 10^5 from the origin (float's grid there: 2^-7) and float64
    points 1e-4 inside and outside its faces, edges and corners: every sign
    right, as the double points they are."""
    c = (131072.0, -65536.5, 32768.25)
    v, t = cube(4, c, 0.5)
    s = rtk.RaycastingScene()
    s.add_triangles(v, t)
    rng = np.random.default_rng(3)
    base = np.array(c) + rng.choice([-0.5, 0.5], (300, 3)) * (rng.random((300, 3)) < 0.7)  # faces, edges, corners
    base[~(np.abs(base - np.array(c)) == 0.5).any(axis=1), 0] = c[0] + 0.5
    on = np.abs(base - np.array(c)) == 0.5
    outward = np.where(on, np.sign(base - np.array(c)), 0.0)
    outward /= np.linalg.norm(outward, axis=1)[:, None]
    for delta in (1e-3, 1e-4):
        q = np.concatenate([base + delta * outward, base - delta * outward])
        sd = s.compute_signed_distance(q).numpy()
        assert sd.dtype == np.float64
        assert np.all(sd[:300] > 0) and np.all(sd[300:] < 0)
        assert np.array_equal(s.compute_occupancy(q).numpy(), np.repeat([0, 1], 300))
    assert np.all(s.compute_occupancy(base).numpy() == 1)  # on the surface


def test_zero_area_triangles_and_empty():
    """Open3D 0.16 aborts the process on these; rtk leaves them out."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2], [3, 3, 3]], np.float32)
    t = np.array([[0, 1, 2], [3, 4, 3], [3, 3, 3]])
    s = rtk.RaycastingScene()
    s.add_triangles(v, t)
    d = s.compute_distance(np.array([[2.5, 2.5, 2.5]], np.float32)).numpy()
    assert abs(d[0] - np.linalg.norm([2.5 - 0.5, 2.5 - 0.5, 2.5])) < 1e-5 or d[0] > 3
    e = rtk.RaycastingScene()
    assert e.cast_rays(np.zeros((0, 6), np.float32))["t_hit"].shape == (0,)
    ans = e.cast_rays(np.array([[0, 0, 0, 1, 0, 0]], np.float32))
    assert np.isinf(ans["t_hit"].numpy()[0])
    assert np.isinf(e.compute_distance(np.zeros((1, 3), np.float32)).numpy()[0])
    assert e.compute_occupancy(np.zeros((1, 3), np.float32)).numpy()[0] == 0


def test_bad_input_is_an_error_not_a_crash(cube_scene):
    s, v, t = cube_scene
    with pytest.raises(ValueError):
        s.cast_rays(np.zeros((4, 5), np.float32))
    with pytest.raises(ValueError):
        s.compute_distance(np.zeros((4,), np.float32))
    with pytest.raises(TypeError):
        s.compute_distance(np.array([["a", "b", "c"]]))
    with pytest.raises(ValueError):
        s.add_triangles(v, np.array([[0, 1, len(v)]]))
    with pytest.raises(ValueError):
        s.add_triangles(v[:, :2], t)
    with pytest.raises(TypeError):
        s.add_triangles(v, t.astype(np.float32))
    with pytest.raises(ValueError):
        rtk.RaycastingScene(nthreads=-1)
    # NaN points and rays: answered as nothing, not crashed
    d = s.compute_distance(np.array([[np.nan, 0, 0], [0.5, 0.25, 0]], np.float32)).numpy()
    assert np.isnan(d[0]) and d[1] > 0
    r = s.cast_rays(np.array([[np.nan, 0, 0, 1, 0, 0]], np.float32))
    assert np.isinf(r["t_hit"].numpy()[0])


def test_pinhole_matches_open3d():
    o3d = pytest.importorskip("open3d")
    R = o3d.t.geometry.RaycastingScene
    a = R.create_rays_pinhole(fov_deg=60, center=[0, 0, 0], eye=[1, 2, 3], up=[0, 1, 0], width_px=8, height_px=5)
    b = rtk.RaycastingScene.create_rays_pinhole(fov_deg=60, center=[0, 0, 0], eye=[1, 2, 3], up=[0, 1, 0],
                                                width_px=8, height_px=5)
    assert np.allclose(a.numpy(), b.numpy(), atol=1e-6)
    K = np.array([[100, 0, 4], [0, 100, 2.5], [0, 0, 1.0]])
    E = np.eye(4)
    E[:3, 3] = [0.1, 0.2, 0.3]
    a = R.create_rays_pinhole(intrinsic_matrix=K, extrinsic_matrix=E, width_px=8, height_px=5)
    b = rtk.RaycastingScene.create_rays_pinhole(K, E, 8, 5)
    assert np.allclose(a.numpy(), b.numpy(), atol=1e-6)


def test_one_ray_and_one_point_keep_their_shape(cube_scene):
    # a single ray (6,) or point (3,): the answers' shape is () per ray
    # and point, with the per-ray vectors' own last axis (2 and 3), as for
    # any (..., 6) input; np.ascontiguousarray once made t_hit (1,)
    s, v, t = cube_scene
    ans = s.cast_rays(np.array([0.5, 0.25, 5, 0, 0, -1], np.float32))
    assert ans["t_hit"].shape == () and ans["geometry_ids"].shape == ()
    assert ans["primitive_uvs"].shape == (2,) and ans["primitive_normals"].shape == (3,)
    assert float(ans["t_hit"]) == pytest.approx(5 - (-0.25))
    assert s.test_occlusions(np.array([0.5, 0.25, 5, 0, 0, -1], np.float32)).shape == ()
    assert s.count_intersections(np.array([0.5, 0.25, 5, 0, 0, -1], np.float32)).shape == ()
    assert s.compute_distance(np.array([0.5, 0.25, 5], np.float32)).shape == ()
    assert s.compute_closest_points(np.array([0.5, 0.25, 5], np.float32))["points"].shape == (3,)


def test_nthreads_per_call(cube_scene, monkeypatch):
    """A query's nthreads is the calling thread's limit on its batch calls
    (rtk_set_batch_threads) while it runs, put back after it, also when it
    raises; the answers do not depend on it."""
    s, v, t = cube_scene
    rng = np.random.default_rng(7)
    p = (rng.random((20000, 3)) * 3 - 1.5).astype(np.float32)
    r = np.concatenate([p, rng.random((20000, 3)).astype(np.float32) - 0.5], axis=1)
    ref = s.compute_signed_distance(p).numpy(), s.cast_rays(r)["t_hit"].numpy(), s.count_intersections(r).numpy()
    seen = []
    real = rtk._native.set_batch_threads

    def spy(n):
        seen.append(n)
        return real(n)

    monkeypatch.setattr(rtk._native, "set_batch_threads", spy)
    for n in (1, 2, 5, 0):
        seen.clear()
        got = (s.compute_signed_distance(p, nthreads=n).numpy(), s.cast_rays(r, nthreads=n)["t_hit"].numpy(),
               s.count_intersections(r, nthreads=n).numpy())
        for a, b in zip(ref, got):
            np.testing.assert_array_equal(a, b)
        assert seen == [n, 0] * 3
    seen.clear()
    with pytest.raises(ValueError):
        s.compute_distance(np.zeros((4, 2), np.float32), nthreads=1)
    assert seen == [1, 0]
    assert real(0) == 0


def test_query_arguments_checked_as_open3d(cube_scene):
    s, v, t = cube_scene
    p = np.array([[0.5, 0.25, -0.75]], np.float32)
    r = np.array([[0.5, 0.25, 5, 0, 0, -1]], np.float32)
    for bad in (-1, 1.5, "2", True):
        with pytest.raises(ValueError, match="nthreads"):
            s.compute_distance(p, nthreads=bad)
        with pytest.raises(ValueError, match="nthreads"):
            s.cast_rays(r, nthreads=bad)
    assert s.compute_distance(p, nthreads=2).shape == (1,)
    # nsamples: odd and at least 1 (Open3D's rule); 1 and 3 give the same exact answer
    for bad in (0, -1, 2, 1.0):
        with pytest.raises(ValueError, match="nsamples"):
            s.compute_occupancy(p, nsamples=bad)
        with pytest.raises(ValueError, match="nsamples"):
            s.compute_signed_distance(p, nsamples=bad)
    assert s.compute_occupancy(p, nsamples=3).numpy()[0] == 1
    assert s.compute_signed_distance(p, nsamples=1).numpy()[0] < 0


def test_pinhole_bad_cameras_are_errors():
    P = rtk.RaycastingScene.create_rays_pinhole
    cam = dict(fov_deg=60, center=[0, 0, 0], eye=[1, 2, 3], up=[0, 1, 0], width_px=8, height_px=5)
    # no pixels: no rays (as Open3D)
    assert P(**{**cam, "width_px": 0}).shape == (5, 0, 6)
    assert P(**{**cam, "height_px": 0}).shape == (0, 8, 6)
    # what would make NaN or infinite rays, or no camera at all
    for change, what in (({"width_px": -1}, "width_px"), ({"height_px": 2.5}, "height_px"),
                         ({"fov_deg": 0}, "fov_deg"), ({"fov_deg": 180}, "fov_deg"),
                         ({"fov_deg": float("nan")}, "fov_deg"), ({"eye": [0, 0, 0]}, "eye"),
                         ({"up": [2, 4, 6]}, "up"), ({"up": [0, np.inf, 0]}, "up"), ({"eye": [1, 2]}, "eye")):
        with pytest.raises(ValueError, match=what):
            P(**{**cam, **change})
    K = np.array([[100, 0, 4], [0, 100, 2.5], [0, 0, 1.0]])
    with pytest.raises(ValueError, match="intrinsic_matrix"):
        P(np.zeros((3, 3)), np.eye(4), 8, 5)
    with pytest.raises(ValueError, match="extrinsic_matrix"):
        P(K, np.eye(3), 8, 5)
    with pytest.raises(ValueError, match="intrinsic_matrix"):
        P(K, np.full((4, 4), np.nan), 8, 5)
    assert P(K, np.eye(4), 8, 5).shape == (5, 8, 6)


def test_open3d_tensors_in_and_out(cube_scene):
    o3d = pytest.importorskip("open3d")
    s, v, t = cube_scene
    q = o3d.core.Tensor(np.array([[2.0, 0.25, -0.75]], np.float32))
    d = s.compute_distance(q)
    assert isinstance(d, o3d.core.Tensor)
    assert abs(d.numpy()[0] - 1.0) < 1e-6
    ref = o3d.t.geometry.RaycastingScene()
    ref.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(t.astype(np.uint32)))
    assert np.allclose(ref.compute_distance(q).numpy(), d.numpy(), atol=1e-6)


def test_trimesh_interface():
    v, t = cube()
    m = rtk.RayMeshIntersector(v, t)
    c = np.array([0.5, 0.25, -0.75])
    o = np.array([c + [0, 0, 3], c + [5, 5, 5], c])
    d = np.array([[0, 0, -1], [1, 0, 0], [1, 0, 0]], np.float64)
    first = m.intersects_first(o, d)
    assert first[1] == -1 and first[0] >= 0 and first[2] >= 0
    assert np.array_equal(m.intersects_any(o, d), [True, False, True])
    loc, ray, tri = m.intersects_location(o, d)
    assert np.array_equal(ray, [0, 0, 2])  # through the cube: in and out; from inside: out
    assert np.allclose(loc[:2, 2], [c[2] + 0.5, c[2] - 0.5]) and np.allclose(loc[2], c + [0.5, 0, 0])
    tri1, ray1 = m.intersects_id(o, d, multiple_hits=False)
    assert np.array_equal(ray1, [0, 2]) and tri1[0] == first[0]
    assert np.array_equal(m.contains_points([c, c + [0.5, 0.5, 0.5], c + [0.6, 0, 0]]), [True, True, False])
    with pytest.raises(ValueError):
        m.intersects_first(o, d[:2])


def test_first_queries_from_threads_at_once():
    """Queries from several Python threads at once on a scene none has
    committed yet (the GIL lets go in rtk's calls): one of them commits, the
    others wait for it, and every thread gets the answers one thread gets;
    so again after more geometry is added."""
    import threading

    v, t = sphere(400, 200)  # 160,000 triangles: a commit long enough for the threads to meet in it
    rng = np.random.default_rng(3)
    p = (rng.random((2000, 3)) * 3 - 1.5).astype(np.float32)
    r = np.concatenate([p, rng.random((2000, 3)).astype(np.float32) - 0.5], axis=1)
    refs = []
    one = rtk.RaycastingScene()
    for scale in (1.0, 0.5):  # the answers one thread gets, after each round's geometry
        one.add_triangles(v * scale, t)
        refs.append((one.compute_distance(p).numpy(), one.cast_rays(r)["t_hit"].numpy()))
    for trial in range(4):
        s = rtk.RaycastingScene()
        s.add_triangles(v, t)
        for round_ in range(2):
            if round_:
                s.add_triangles(v * 0.5, t)
            got, errors = [None] * 4, []
            start = threading.Barrier(4)

            def query(k):
                try:
                    start.wait()
                    got[k] = s.compute_distance(p).numpy() if k % 2 == 0 else s.cast_rays(r)["t_hit"].numpy()
                except Exception as e:  # noqa: BLE001 (reported below)
                    errors.append(e)

            threads = [threading.Thread(target=query, args=(k,)) for k in range(4)]
            for th in threads:
                th.start()
            for th in threads:
                th.join()
            assert not errors, f"trial {trial}, round {round_}: {errors[0]}"
            for k in range(4):
                np.testing.assert_array_equal(got[k], refs[round_][k % 2])
