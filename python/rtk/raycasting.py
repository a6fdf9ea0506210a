"""RaycastingScene: Open3D's open3d.t.geometry.RaycastingScene over rtk.

The same methods, arguments and returned keys, so that moving over is one
changed import.  Inputs are numpy arrays (or Open3D tensors, or anything
numpy.asarray takes); results are numpy arrays with a .numpy() method (as
Open3D's tensors have), or Open3D tensors when the input was one.

What rtk does differently, on purpose:
- the scene is built robust (RTK_SCENE_FLAG_ROBUST): a ray through an edge or
  vertex shared by triangles of a closed mesh meets exactly one of them, so
  count_intersections, list_intersections and compute_occupancy count each
  crossing once, and inside/outside is exact (no voting over several rays);
- closest points and distances are computed in double precision: float64
  query points get float64 distances and points back;
- triangles of zero area are left out (rays never hit them) instead of
  crashing (Open3D 0.16 aborts on a mesh that has one).

Queries may come from several Python threads at once (rtk's calls let the
GIL go): the first query after add_triangles commits the scene while the
others wait for it.
"""
import contextlib
import ctypes
import functools
import inspect
import math
import threading

import numpy as np

from . import _native as N

INVALID_ID = N.INVALID_ID


class Array(np.ndarray):
    """A numpy array with .numpy(), as Open3D's tensors have."""

    def numpy(self):
        return self.view(np.ndarray)


def _out(a, like_o3d):
    a = np.asarray(a)
    if not a.flags.c_contiguous:  # (np.ascontiguousarray would make a 0-d array 1-d)
        a = a.copy(order="C")
    if like_o3d:
        import open3d as o3d  # only when the caller handed Open3D tensors

        return o3d.core.Tensor.from_numpy(a)
    return a.view(Array)


def _is_o3d(x):
    return type(x).__module__.startswith("open3d")


def _as_array(x, name):
    if _is_o3d(x) and hasattr(x, "numpy"):
        x = x.numpy()
    try:
        return np.asarray(x)
    except Exception as e:  # a clear error, not a crash
        raise TypeError(f"{name}: expected an array, got {type(x).__name__}") from e


def _is_whole(v, least):
    """Whether v is a whole number (a Python or numpy integer, not a bool)
    of at least `least`."""
    return not isinstance(v, bool) and isinstance(v, (int, np.integer)) and v >= least


def _nthreads(n):
    """nthreads as Open3D takes it: a whole number, 0 for every core."""
    if not _is_whole(n, 0):
        raise ValueError(f"nthreads: expected a whole number >= 0, got {n!r}")
    return int(n)


@contextlib.contextmanager
def _batch_limit(n):
    """n as the most threads the batch calls made inside the block run on
    (rtk_set_batch_threads: the calling thread's own limit, 0 for every
    thread of the device), put back after it."""
    was = N.set_batch_threads(n)
    try:
        yield
    finally:
        N.set_batch_threads(was)


def _batch_threads(method):
    """method with its nthreads argument (checked as Open3D checks it) as
    its _batch_limit."""
    sig = inspect.signature(method)

    @functools.wraps(method)
    def call(*args, **kw):
        with _batch_limit(_nthreads(sig.bind(*args, **kw).arguments.get("nthreads", 0))):
            return method(*args, **kw)
    return call


def _nsamples(n):
    """nsamples as Open3D takes it: odd and at least 1."""
    if not _is_whole(n, 1) or n % 2 != 1:
        raise ValueError(f"nsamples: expected an odd whole number >= 1, got {n!r}")
    return int(n)


def _last_dim(a, k, name):
    if a.ndim < 1 or a.shape[-1] != k:
        raise ValueError(f"{name}: expected shape (..., {k}), got {a.shape}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise TypeError(f"{name}: expected numbers, got dtype {a.dtype}")


def _pixels(w, h):
    """width_px and height_px: whole numbers >= 0."""
    for v, name in ((w, "width_px"), (h, "height_px")):
        if not _is_whole(v, 0):
            raise ValueError(f"{name}: expected a whole number >= 0, got {v!r}")
    return int(w), int(h)


def _vec3(x, name):
    v = np.asarray(_as_array(x, name), dtype=np.float64)
    if v.size != 3 or not np.isfinite(v).all():
        raise ValueError(f"{name}: expected 3 finite numbers, got {v.tolist()!r}")
    return v.reshape(3)


def _matrix(x, name, k):
    m = np.asarray(_as_array(x, name), dtype=np.float64)
    if m.shape != (k, k):
        raise ValueError(f"{name}: expected shape ({k}, {k}), got {m.shape}")
    return m


class RaycastingScene:
    """A scene of triangle meshes and the queries of Open3D's
    RaycastingScene: cast_rays, test_occlusions, count_intersections,
    list_intersections, compute_closest_points, compute_distance,
    compute_signed_distance, compute_occupancy."""

    INVALID_ID = N.INVALID_ID

    def __init__(self, nthreads=0, device=None):
        """nthreads: the threads the scene's queries may run on (0: every
        core).  The queries' own nthreads argument, as Open3D's, limits one
        call further (0: the scene's); it cannot raise the scene's."""
        dev = ctypes.c_void_p()
        cfg = f"threads={_nthreads(nthreads)}".encode()
        if N.device_new(cfg, ctypes.byref(dev)) != 0:
            msg = N.device_get_error_message(None)
            raise RuntimeError("rtk: device: " + (msg.decode() if msg else "failed"))
        self._dev = dev
        scene = ctypes.c_void_p()
        N.check(N.scene_new(dev, ctypes.byref(scene)), dev, "scene")
        self._scene = scene
        N.check(N.scene_set_flags(scene, N.SCENE_FLAG_ROBUST), dev, "scene flags")
        self._arrays = []  # the buffers rtk reads at the commit
        self._dirty = True
        self._count = 0
        # The scene is committed by the first query after a change.  Queries
        # from several Python threads at once are fine (rtk's queries are,
        # and ctypes lets the GIL go), but only one of them may commit: the
        # others wait for it here, as do geometry added meanwhile.
        self._lock = threading.Lock()

    def __del__(self):
        scene = getattr(self, "_scene", None)
        if scene:
            N.scene_release(scene)
            self._scene = None
        dev = getattr(self, "_dev", None)
        if dev:
            N.device_release(dev)
            self._dev = None

    @property
    def backend(self):
        """The rtk backend in use (avx2, avx, sse41, scalar)."""
        return N.device_get_backend_name(self._dev).decode()

    # ---- building ----

    def add_triangles(self, vertex_positions, triangle_indices=None):
        """Adds a triangle mesh: vertex_positions (N, 3) and triangle_indices
        (M, 3), or an Open3D TriangleMesh (legacy or tensor).  Returns the
        geometry id its hits report."""
        if triangle_indices is None:
            mesh = vertex_positions
            if hasattr(mesh, "vertex") and hasattr(mesh, "triangle"):  # open3d.t.geometry.TriangleMesh
                vertex_positions, triangle_indices = mesh.vertex.positions, mesh.triangle.indices
            elif hasattr(mesh, "vertices") and hasattr(mesh, "triangles"):  # legacy, or trimesh
                vertex_positions, triangle_indices = mesh.vertices, mesh.triangles
            else:
                raise TypeError("add_triangles: expected vertex_positions and triangle_indices, or a triangle mesh")
        v = _as_array(vertex_positions, "vertex_positions")
        t = _as_array(triangle_indices, "triangle_indices")
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertex_positions: expected shape (N, 3), got {v.shape}")
        if t.ndim != 2 or t.shape[1] != 3:
            raise ValueError(f"triangle_indices: expected shape (M, 3), got {t.shape}")
        if not np.issubdtype(v.dtype, np.floating):
            raise TypeError(f"vertex_positions: expected floats, got dtype {v.dtype}")
        if not np.issubdtype(t.dtype, np.integer):
            raise TypeError(f"triangle_indices: expected integers, got dtype {t.dtype}")
        if t.size and (t.min() < 0 or t.max() >= len(v)):
            raise ValueError(f"triangle_indices: an index outside [0, {len(v)})")
        v = np.ascontiguousarray(v, dtype=np.float32)
        t = np.ascontiguousarray(t, dtype=np.uint32)
        g = ctypes.c_void_p()
        N.check(N.geometry_new(self._dev, N.GEOMETRY_TYPE_TRIANGLE, ctypes.byref(g)), self._dev, "geometry")
        try:
            N.check(N.geometry_set_shared_buffer(g, N.BUFFER_VERTEX, N.ptr(v), 0, 12, len(v)), self._dev,
                    "vertex_positions")
            N.check(N.geometry_set_shared_buffer(g, N.BUFFER_INDEX, N.ptr(t), 0, 12, len(t)), self._dev,
                    "triangle_indices")
            N.check(N.geometry_commit(g), self._dev, "add_triangles")
            gid = ctypes.c_uint32()
            with self._lock:
                N.check(N.scene_attach_geometry(self._scene, g, ctypes.byref(gid)), self._dev, "add_triangles")
                self._arrays.append((v, t))
                self._dirty = True
                self._count += 1
        finally:
            N.geometry_release(g)
        return int(gid.value)

    def _commit(self):
        if not self._dirty:
            return
        with self._lock:
            if self._dirty:
                N.check(N.scene_commit(self._scene), self._dev, "commit")
                self._dirty = False

    # ---- rays ----

    def _rays(self, rays, tnear=0.0, tfar=math.inf, hits=True):
        """rtk_rayhit records for rays (..., 6) (hits=False: rtk_ray
        records alone), built as one float32 block of 20 columns (rtk_ray's
        12 words, rtk_hit's 8): column copies, not structured-field ones
        (which cost more than the tracing)."""
        r = _as_array(rays, "rays")
        _last_dim(r, 6, "rays")
        shape = r.shape[:-1]
        flat = r.reshape(-1, 6)
        n = flat.shape[0]
        block = np.empty((n, 20 if hits else 12), dtype=np.float32)
        words = block.view(np.uint32)
        block[:, 0:3] = flat[:, 0:3]
        block[:, 3] = tnear
        block[:, 4:7] = flat[:, 3:6]
        block[:, 7] = 0.0                 # time
        block[:, 8] = tfar
        words[:, 9] = 0xFFFFFFFF          # mask
        words[:, 10:12] = 0               # id, flags
        if not hits:
            return block.view(N.RAY).reshape(n), shape, _is_o3d(rays)
        block[:, 12:17] = 0.0             # Ng, u, v
        words[:, 17:20] = N.INVALID_ID    # primID, geomID, instID
        return block.view(N.RAYHIT).reshape(n), shape, _is_o3d(rays)

    def _ray_arrays(self, rays, tnear, tfar):
        """rtk_ray_arrays over rays (..., 6) as they are where they can be
        (float32 or float64, C-contiguous), else a float32 copy."""
        r = _as_array(rays, "rays")
        _last_dim(r, 6, "rays")
        if r.dtype not in (np.float32, np.float64) or not r.flags.c_contiguous:
            r = np.ascontiguousarray(r, dtype=np.float64 if r.dtype == np.float64 else np.float32)
        tnear, tfar = float(tnear), float(tfar)
        if not (0.0 <= tnear <= tfar):
            raise ValueError(f"tnear {tnear} and tfar {tfar}: tnear must be at least 0 and at most tfar")
        # rays (..., W, 6) are taken for an image's rows of W (the packets
        # then take 4x2 blocks of pixels); only the speed depends on it
        a = N.RayArrays(rays=N.ptr(r), rays_double=int(r.dtype == np.float64), ray_stride=0, tnear=tnear, tfar=tfar,
                        row_length=r.shape[-2] if r.ndim >= 3 else 0)
        return r, a, r.shape[:-1]

    @_batch_threads
    def cast_rays(self, rays, nthreads=0):
        """The first hit of each ray (..., 6): origin and direction.  Keys
        t_hit (inf for a miss, in units of the direction's length),
        geometry_ids, primitive_ids (INVALID_ID for a miss), primitive_uvs,
        primitive_normals (unit)."""
        r, a, shape = self._ray_arrays(rays, 0.0, math.inf)
        n = int(np.prod(shape, dtype=np.int64))
        t = np.empty(n, np.float32)
        geom, prim = np.empty(n, np.uint32), np.empty(n, np.uint32)
        uv, ng = np.empty((n, 2), np.float32), np.empty((n, 3), np.float32)
        a.t_hit, a.geom_ids, a.prim_ids, a.uvs, a.normals = N.ptr(t), N.ptr(geom), N.ptr(prim), N.ptr(uv), N.ptr(ng)
        self._commit()
        N.check(N.intersect_arrays(self._scene, ctypes.byref(a), n), self._dev, "cast_rays")
        o3 = _is_o3d(rays)
        return {"t_hit": _out(t.reshape(shape), o3),
                "geometry_ids": _out(geom.reshape(shape), o3),
                "primitive_ids": _out(prim.reshape(shape), o3),
                "primitive_uvs": _out(uv.reshape(shape + (2,)), o3),
                "primitive_normals": _out(ng.reshape(shape + (3,)), o3)}

    @_batch_threads
    def test_occlusions(self, rays, tnear=0.0, tfar=math.inf, nthreads=0):
        """Whether anything lies along each ray within [tnear, tfar]."""
        r, a, shape = self._ray_arrays(rays, tnear, tfar)
        n = int(np.prod(shape, dtype=np.int64))
        hit = np.empty(n, np.uint8)
        a.occluded = N.ptr(hit)
        self._commit()
        N.check(N.occluded_arrays(self._scene, ctypes.byref(a), n), self._dev, "test_occlusions")
        return _out(hit.view(np.bool_).reshape(shape), _is_o3d(rays))

    @_batch_threads
    def count_intersections(self, rays, nthreads=0):
        """How many times each ray crosses the surface (each crossing once:
        the scene is robust)."""
        ray, shape, o3 = self._rays(rays, hits=False)
        counts = self._counts(ray, "count_intersections")
        return _out(counts.astype(np.int32).reshape(shape), o3)

    def _counts(self, ray, what):
        """Each ray's crossings counted (ray: rtk_ray records, _rays(hits=False)),
        straight from the records _rays built: no copy of their ray fields."""
        counts = np.zeros(len(ray), dtype=np.uint32)
        self._commit()
        if len(ray):
            N.check(N.count_intersections(self._scene, N.ptr(ray), len(ray), N.RAY.itemsize, N.ptr(counts)),
                    self._dev, what)
        return counts

    @_batch_threads
    def list_intersections(self, rays, nthreads=0):
        """Every crossing of every ray, sorted by t per ray.  Keys ray_splits
        (ray i's crossings are [ray_splits[i], ray_splits[i + 1])), ray_ids,
        geometry_ids, primitive_ids, primitive_uvs, t_hit."""
        ray, shape, o3 = self._rays(rays, hits=False)
        counts = self._counts(ray, "list_intersections")
        splits = np.zeros(len(ray) + 1, dtype=np.uint64)
        np.cumsum(counts, out=splits[1:])
        c = np.zeros(int(splits[-1]), dtype=N.CROSSING)
        if len(ray):
            N.check(N.list_intersections(self._scene, N.ptr(ray), len(ray), N.RAY.itemsize, N.ptr(splits),
                                         N.ptr(c) if len(c) else None), self._dev, "list_intersections")
        ray_ids = np.repeat(np.arange(len(ray), dtype=np.uint32), counts)
        return {"ray_splits": _out(splits.astype(np.int32 if splits[-1] < 2**31 else np.int64), o3),
                "ray_ids": _out(ray_ids, o3),
                "geometry_ids": _out(c["geomID"], o3),
                "primitive_ids": _out(c["primID"], o3),
                "primitive_uvs": _out(np.stack([c["u"], c["v"]], axis=1).astype(np.float32), o3),
                "t_hit": _out(c["t"].astype(np.float32), o3)}

    # ---- points ----

    def _points(self, query_points):
        """rtk_point_arrays over points (..., 3) as they are where they can
        be (float32 or float64, C-contiguous), else a copy (float64 for
        other types, whose answers are then float32 as float32 points'):
        the points, the arrays, their shape, the answers' dtype and whether
        they go back as Open3D tensors."""
        p = _as_array(query_points, "query_points")
        _last_dim(p, 3, "query_points")
        dtype = np.float64 if p.dtype == np.float64 else np.float32
        if p.dtype not in (np.float32, np.float64) or not p.flags.c_contiguous:
            p = np.ascontiguousarray(p, dtype=np.float32 if p.dtype == np.float32 else np.float64)
        a = N.PointArrays(points=N.ptr(p), points_double=int(p.dtype == np.float64), point_stride=0,
                          radius=math.inf, time=0.0)
        return p, a, p.shape[:-1], dtype, _is_o3d(query_points)

    # what rtk_closest_point_arrays writes, per point: its shape and dtype
    # (None: the points')
    _ANSWERS = {"distances": ((), None), "closest": ((3,), None), "geom_ids": ((), np.uint32),
                "prim_ids": ((), np.uint32), "uvs": ((2,), np.float32), "normals": ((3,), np.float32)}

    def _closest(self, p, a, shape, *keys):
        """The answers named (_ANSWERS) of rtk_closest_point_arrays over
        the points of _points, each an array of shape + its own."""
        out = {}
        for k in keys:
            tail, t = self._ANSWERS[k]
            out[k] = np.empty(shape + tail, t or p.dtype)
            setattr(a, k, N.ptr(out[k]))
        self._commit()
        n = int(np.prod(shape, dtype=np.int64))
        if n:
            N.check(N.closest_point_arrays(self._scene, ctypes.byref(a), n), self._dev, "compute_closest_points")
        return out

    @_batch_threads
    def compute_closest_points(self, query_points, nthreads=0):
        """The nearest point of the surface to each point (..., 3).  Keys
        points, geometry_ids, primitive_ids, primitive_uvs,
        primitive_normals (unit); points keep float64 when given it.  Of
        triangles at exactly the same distance (a point nearest to a
        vertex they share), the least geometry id, then triangle index, is
        reported, on every machine and thread count."""
        p, a, shape, dtype, o3 = self._points(query_points)
        r = self._closest(p, a, shape, "closest", "geom_ids", "prim_ids", "uvs", "normals")
        return {"points": _out(r["closest"].astype(dtype, copy=False), o3),
                "geometry_ids": _out(r["geom_ids"], o3),
                "primitive_ids": _out(r["prim_ids"], o3),
                "primitive_uvs": _out(r["uvs"], o3),
                "primitive_normals": _out(r["normals"], o3)}

    @_batch_threads
    def compute_distance(self, query_points, nthreads=0):
        """The distance from each point to the surface (float64 for float64
        points)."""
        p, a, shape, dtype, o3 = self._points(query_points)
        return _out(self._closest(p, a, shape, "distances")["distances"].astype(dtype, copy=False), o3)

    def _inside(self, p, a, shape):
        """rtk_occupancy_arrays over the points of _points."""
        inside = np.empty(shape, np.uint8)
        a.inside = N.ptr(inside)
        self._commit()
        n = int(np.prod(shape, dtype=np.int64))
        if n:
            N.check(N.occupancy_arrays(self._scene, ctypes.byref(a), n), self._dev, "compute_occupancy")
        return inside

    @_batch_threads
    def compute_occupancy(self, query_points, nthreads=0, nsamples=1):
        """1 for a point inside the closed surface or on it, 0 outside: the
        exact parity of one ray's crossings in the robust scene (nsamples,
        Open3D's vote over rays, is checked as Open3D's, odd, and not
        needed)."""
        _nsamples(nsamples)
        p, a, shape, dtype, o3 = self._points(query_points)
        inside = self._inside(p, a, shape)
        return _out(np.where(inside == 255, np.nan, inside).astype(dtype), o3)

    @_batch_threads
    def compute_signed_distance(self, query_points, nthreads=0, nsamples=1):
        """The distance to the surface, negative inside (see
        compute_occupancy); 0 on the surface."""
        _nsamples(nsamples)
        p, a, shape, dtype, o3 = self._points(query_points)
        d = self._closest(p, a, shape, "distances")["distances"]
        inside = self._inside(p, a, shape)
        sd = np.where(inside == 1, -d, d)
        return _out(np.where(inside == 255, np.nan, sd).astype(dtype, copy=False), o3)

    # ---- cameras ----

    @staticmethod
    def create_rays_pinhole(*args, **kw):
        """Rays through the pixel centres of a pinhole camera, shape
        (height_px, width_px, 6): either (fov_deg, center, eye, up, width_px,
        height_px) or (intrinsic_matrix, extrinsic_matrix, width_px,
        height_px), as Open3D's.  A width or height of 0 gives no rays, as
        Open3D's; what would give NaN or infinite rays (the eye at the
        centre, up along the view, a field of view outside (0, 180), a
        singular intrinsic matrix) is a ValueError."""
        names_fov = ["fov_deg", "center", "eye", "up", "width_px", "height_px"]
        names_k = ["intrinsic_matrix", "extrinsic_matrix", "width_px", "height_px"]
        if "fov_deg" in kw or (len(args) == 6):
            a = dict(zip(names_fov, args))
            a.update(kw)
            w, h = _pixels(a["width_px"], a["height_px"])
            fov = float(a["fov_deg"])
            if not 0.0 < fov < 180.0:
                raise ValueError(f"fov_deg: expected an angle in (0, 180), got {fov}")
            f = 0.5 * max(w, 1) / math.tan(math.radians(fov) / 2)
            K = np.array([[f, 0, 0.5 * w], [0, f, 0.5 * h], [0, 0, 1.0]])
            eye = _vec3(a["eye"], "eye")
            z = _vec3(a["center"], "center") - eye
            if not np.linalg.norm(z) > 0:
                raise ValueError("center and eye: expected two different points")
            z /= np.linalg.norm(z)
            x = np.cross(_vec3(a["up"], "up"), z)
            if not np.linalg.norm(x) > 1e-12:
                raise ValueError("up: expected a direction not along the view (center - eye)")
            x /= np.linalg.norm(x)
            y = np.cross(z, x)
            R = np.stack([x, y, z])
            origin = eye
            o3 = any(_is_o3d(a[k]) for k in ("center", "eye", "up"))
        else:
            a = dict(zip(names_k, args))
            a.update(kw)
            w, h = _pixels(a["width_px"], a["height_px"])
            K = _matrix(a["intrinsic_matrix"], "intrinsic_matrix", 3)
            E = _matrix(a["extrinsic_matrix"], "extrinsic_matrix", 4)
            if not (np.isfinite(K).all() and np.isfinite(E).all()) or abs(np.linalg.det(K)) == 0.0 or \
                    abs(np.linalg.det(E[:3, :3])) == 0.0:
                raise ValueError("intrinsic_matrix and extrinsic_matrix: expected finite, invertible matrices")
            R, t = E[:3, :3], E[:3, 3]
            origin = -R.T @ t
            o3 = _is_o3d(a["intrinsic_matrix"]) or _is_o3d(a["extrinsic_matrix"])
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        pix = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3)
        d = (R.T @ np.linalg.solve(K, pix.T)).T
        rays = np.concatenate([np.broadcast_to(origin, d.shape), d], axis=1).astype(np.float32)
        return _out(rays.reshape(h, w, 6), o3)


class RayMeshIntersector:
    """trimesh's ray interface (trimesh.ray.ray_triangle and the embreex
    one) over rtk, for one mesh: intersects_first, intersects_any,
    intersects_id, intersects_location, contains_points.  Each crossing is
    listed once (the scene is robust), so multiple hits need no re-casting
    from just past the last one."""

    def __init__(self, vertices, faces, nthreads=0):
        self._scene = RaycastingScene(nthreads)
        self._scene.add_triangles(vertices, faces)
        self._v = np.asarray(vertices, dtype=np.float64)

    def _rays(self, ray_origins, ray_directions):
        o = np.asarray(ray_origins, dtype=np.float32)
        d = np.asarray(ray_directions, dtype=np.float32)
        if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
            raise ValueError(f"ray_origins and ray_directions: expected two (N, 3) arrays, got {o.shape} and "
                             f"{d.shape}")
        return np.concatenate([o, d], axis=1)

    def intersects_first(self, ray_origins, ray_directions):
        """The index of the first triangle each ray hits, -1 for none."""
        ids = self._scene.cast_rays(self._rays(ray_origins, ray_directions))["primitive_ids"].numpy()
        return np.where(ids == INVALID_ID, -1, ids.astype(np.int64))

    def intersects_any(self, ray_origins, ray_directions):
        """Whether each ray hits anything."""
        return self._scene.test_occlusions(self._rays(ray_origins, ray_directions)).numpy()

    def intersects_id(self, ray_origins, ray_directions, multiple_hits=True, max_hits=20, return_locations=False):
        """index_tri, index_ray (and locations): every crossing of every
        ray (the first only without multiple_hits), at most max_hits per
        ray, ordered by ray and then by distance."""
        rays = self._rays(ray_origins, ray_directions)
        if multiple_hits:
            lst = self._scene.list_intersections(rays)
            ray_ids = lst["ray_ids"].numpy().astype(np.int64)
            tri = lst["primitive_ids"].numpy().astype(np.int64)
            t = lst["t_hit"].numpy().astype(np.float64)
            splits = lst["ray_splits"].numpy().astype(np.int64)
            rank = np.arange(len(ray_ids)) - splits[ray_ids]
            keep = rank < max_hits
            ray_ids, tri, t = ray_ids[keep], tri[keep], t[keep]
        else:
            ans = self._scene.cast_rays(rays)
            hit = ans["geometry_ids"].numpy() != INVALID_ID
            ray_ids = np.nonzero(hit)[0]
            tri = ans["primitive_ids"].numpy()[hit].astype(np.int64)
            t = ans["t_hit"].numpy()[hit].astype(np.float64)
        if not return_locations:
            return tri, ray_ids
        loc = rays[ray_ids, :3].astype(np.float64) + t[:, None] * rays[ray_ids, 3:].astype(np.float64)
        return tri, ray_ids, loc

    def intersects_location(self, ray_origins, ray_directions, multiple_hits=True):
        """locations, index_ray, index_tri: every crossing's point."""
        tri, ray_ids, loc = self.intersects_id(ray_origins, ray_directions, multiple_hits=multiple_hits,
                                               max_hits=np.iinfo(np.int64).max, return_locations=True)
        return loc, ray_ids, tri

    def contains_points(self, points):
        """Whether each point lies inside the (closed) mesh, or on it:
        exact, one ray's crossing parity in the robust scene."""
        return self._scene.compute_occupancy(np.asarray(points, dtype=np.float64)).numpy() == 1
