"""python3 -m rtk.bench [MESH.ply | sphere:N | torus:N ...] [--threads 1,2] [--points N]

rtk.RaycastingScene beside Open3D's open3d.t.geometry.RaycastingScene
(python3-open3d), same meshes, same rays and points, same run: rates,
ratios to Open3D, and whether the answers agree.  Where Open3D's answers
are wrong (no hits at all, no negative signed distance inside a closed
mesh) the table says so instead of crediting its speed; where Open3D would
abort the process (its point queries on a mesh with zero-area triangles) it
is not run, and the table says why.  Without Open3D, rtk alone.

The camera rays also go through C, same rays, same run: rtk's
rtk_intersect_batch on records built beforehand (what the binding is
measured against: the cast_rays row says what share of it Python keeps)
and, where libembree3 is installed, Embree 3's rtcIntersect1M on the same
records (rtk's cast_rays from Python set beside Embree's C call).

sphere:N and torus:N are closed meshes of about N triangles (1.3M, 300K)
made on the spot: a UV sphere of radius 1 and a torus of radii 1 and 0.3.
"""
import argparse
import os
import platform
import sys
import time

import numpy as np

from . import _native as N
from ._embree import EmbreeScene
from .raycasting import INVALID_ID, RaycastingScene, _batch_limit

_PLY_TYPES = {"char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1", "short": "i2", "ushort": "u2",
              "int16": "i2", "uint16": "u2", "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply(path):
    """Vertices (N, 3) float32 and triangles (M, 3) of a binary
    little-endian PLY whose faces are triangles (the shared meshes)."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise ValueError(f"{path}: not a PLY file")
        elements, fmt = [], None
        while True:
            line = f.readline()
            if not line:
                raise ValueError(f"{path}: no end_header")
            w = line.split()
            if not w:
                continue
            if w[0] == b"format":
                fmt = w[1].decode()
            elif w[0] == b"element":
                elements.append([w[1].decode(), int(w[2]), []])
            elif w[0] == b"property":
                elements[-1][2].append([x.decode() for x in w[1:]])
            elif w[0] == b"end_header":
                break
        if fmt != "binary_little_endian":
            raise ValueError(f"{path}: only binary_little_endian PLY is read here (got {fmt})")
        data = f.read()
    off, v, t = 0, None, None
    for name, count, props in elements:
        if all(p[0] != "list" for p in props):
            dt = np.dtype([(p[1], "<" + _PLY_TYPES[p[0]]) for p in props])
            arr = np.frombuffer(data, dt, count, off)
            off += dt.itemsize * count
            if name == "vertex":
                v = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float32)
        else:
            p = props[0]
            ct, it = np.dtype("<" + _PLY_TYPES[p[1]]), np.dtype("<" + _PLY_TYPES[p[2]])
            if len(props) != 1:
                raise ValueError(f"{path}: faces with more than the index list")
            n0 = int(np.frombuffer(data, ct, 1, off)[0])
            rec = np.dtype([("n", ct), ("i", it, n0)])
            arr = np.frombuffer(data, rec, count, off)
            if name == "face":
                if np.any(arr["n"] != 3):
                    raise ValueError(f"{path}: faces other than triangles")
                t = arr["i"].astype(np.int64)
            off += rec.itemsize * count
    return v, t


def _count(text):
    mult = {"K": 1e3, "M": 1e6}.get(text[-1:].upper(), 1)
    return int(float(text[:-1] if mult != 1 else text) * mult)


def procedural(spec):
    """sphere:N or torus:N (closed, every vertex shared): vertices (n, 3)
    float32 and triangles (m, 3) int64."""
    kind, n = spec.split(":", 1)
    n = _count(n)
    if kind == "sphere":
        rings = max(3, int(round(np.sqrt(n / 4))))
        seg = 2 * rings
        th = np.pi * np.arange(1, rings) / rings
        ph = 2 * np.pi * np.arange(seg) / seg
        ring = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph),
                         np.cos(th)[:, None] * np.ones_like(ph)], axis=-1).reshape(-1, 3)
        v = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]).astype(np.float32)
        ids = 1 + np.arange((rings - 1) * seg).reshape(rings - 1, seg)
        nxt = np.roll(ids, -1, axis=1)
        a, b, c, d = ids[:-1], nxt[:-1], ids[1:], nxt[1:]
        quads = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
        top = np.stack([np.zeros(seg, np.int64), ids[0], nxt[0]], -1)
        bottom = np.stack([np.full(seg, len(v) - 1), nxt[-1], ids[-1]], -1)
        return v, np.concatenate([top, quads, bottom]).astype(np.int64)
    if kind == "torus":
        nv = max(3, int(round(np.sqrt(n / 4))))
        nu = 2 * nv
        u = 2 * np.pi * np.arange(nu) / nu
        w = 2 * np.pi * np.arange(nv) / nv
        rad = 1.0 + 0.3 * np.cos(w)
        v = np.stack([rad[None, :] * np.cos(u)[:, None], rad[None, :] * np.sin(u)[:, None],
                      0.3 * np.sin(w)[None, :] * np.ones((nu, 1))], -1).reshape(-1, 3).astype(np.float32)
        ids = np.arange(nu * nv).reshape(nu, nv)
        a, b = ids, np.roll(ids, -1, axis=0)
        c, d = np.roll(ids, -1, axis=1), np.roll(np.roll(ids, -1, axis=0), -1, axis=1)
        t = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
        return v, t.astype(np.int64)
    raise ValueError(f"{spec}: not a mesh file, sphere:N or torus:N")


def cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def best_of(fn, repeat):
    """The least time of `repeat` runs after one untimed (the first calls
    of a query pay for fresh memory: numpy's output arrays and the
    allocator's first large blocks, at either library)."""
    best, out = float("inf"), fn()
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None):
    here = os.path.dirname(os.path.abspath(__file__))
    shared = os.path.normpath(os.path.join(here, "..", "..", "..", "shared", "meshes"))
    ap = argparse.ArgumentParser(prog="python3 -m rtk.bench", description=__doc__.split("\n\n")[1])
    ap.add_argument("meshes", nargs="*", default=[os.path.join(shared, m) for m in ("bunny.ply", "dragon.ply")])
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--points", type=int, default=200000)
    ap.add_argument("--size", default="512x384", help="camera rays, WxH")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    threads = [int(x) for x in a.threads.split(",")]
    w, h = (int(x) for x in a.size.split("x"))
    try:
        import open3d as o3d
    except ImportError:
        o3d = None
    print(f"CPU: {cpu_model()}, {os.cpu_count()} logical cores; "
          f"Open3D {o3d.__version__ if o3d else 'not installed: rtk alone'}")
    rng = np.random.default_rng(7)
    for path in a.meshes:
        v, t = procedural(path) if path.split(":", 1)[0] in ("sphere", "torus") else read_ply(path)
        e1, e2 = v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]
        zero_area = int(np.sum(np.all(np.cross(e1.astype(np.float64), e2.astype(np.float64)) == 0, axis=1)))
        lo, hi = v.min(axis=0), v.max(axis=0)
        diag = float(np.linalg.norm(hi - lo))
        centre = 0.5 * (lo + hi)
        eye = centre + np.array([0.3, 0.4, 1.2]) * diag
        rays = RaycastingScene.create_rays_pinhole(45, centre, eye, [0, 1, 0], w, h).numpy()
        n = a.points
        tri = t[rng.integers(0, len(t), n)]
        bu, bv = rng.random(n), rng.random(n)
        flip = bu + bv > 1
        bu, bv = np.where(flip, 1 - bu, bu), np.where(flip, 1 - bv, bv)
        near = ((1 - bu - bv)[:, None] * v[tri[:, 0]] + bu[:, None] * v[tri[:, 1]] + bv[:, None] * v[tri[:, 2]]
                + rng.uniform(-0.01, 0.01, (n, 3)) * diag).astype(np.float32)
        box = (lo - 0.1 * (hi - lo) + rng.random((n, 3)) * 1.2 * (hi - lo)).astype(np.float32)
        print(f"\n{os.path.basename(path)}: {len(t):,} triangles ({zero_area:,} of zero area), "
              f"{w}x{h} camera rays, {n:,} points near the surface (1% of the diagonal) and {n:,} in the box")
        print(f"  {'query':28} {'threads':>7} {'rtk M/s':>9} {'Open3D M/s':>11} {'ratio':>7}  agreement")
        embree = EmbreeScene.create(v, t)
        # one scene each, as an application keeps it, and each call's
        # threads by its nthreads argument (Open3D's and rtk's alike)
        rs = RaycastingScene()
        rs.add_triangles(v, t)
        os_ = None
        if o3d:
            os_ = o3d.t.geometry.RaycastingScene()
            os_.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(t.astype(np.uint32)))
        rs.cast_rays(rays[:1])  # the build, outside the timings
        if os_:
            os_.cast_rays(o3d.core.Tensor(rays[:1]))
        for k in threads:
            jobs = [("cast_rays, camera", "cast_rays", rays), ("count_intersections, camera", "count_intersections",
                                                                 rays),
                    ("compute_distance, near", "compute_distance", near),
                    ("compute_distance, box", "compute_distance", box),
                    ("compute_signed_distance, box", "compute_signed_distance", box),
                    ("compute_occupancy, box", "compute_occupancy", box)]
            # rtk's runs (and C's) first, then Open3D's: its worker threads
            # spin for a while after each call, which would slow whatever
            # ran next on a machine of few cores
            mine, c_lines = [], []
            for label, method, arg in jobs:
                tr, ra = best_of(lambda: getattr(rs, method)(arg, nthreads=k), a.repeat)
                mine.append((tr, ra["t_hit"].numpy() if isinstance(ra, dict) else ra.numpy()))
                if method == "cast_rays":
                    c_lines = c_rows(rs, embree, arg, arg.size // 6, tr, k, a.repeat)
            for (label, method, arg), (tr, ra) in zip(jobs, mine):
                count = arg.shape[0] * (arg.shape[1] if arg.ndim == 3 else 1)
                cell, ratio, note = "", "", ""
                point_query = method.startswith("compute_")
                if os_ and point_query and zero_area:
                    note = f"Open3D not run: it aborts the process on a mesh with zero-area triangles"
                elif os_:
                    ta, oa = best_of(lambda: getattr(os_, method)(o3d.core.Tensor(arg), nthreads=k), a.repeat)
                    oa = oa["t_hit"].numpy() if isinstance(oa, dict) else oa.numpy()
                    cell = f"{count / ta * 1e-6:11.3f}"
                    note = agreement(method, ra, oa, diag)
                    # no ratio against answers that are wrong
                    ratio = "-" if note.startswith("Open3D WRONG") else f"{ta / tr:6.2f}x"
                print(f"  {label:28} {k:7d} {count / tr * 1e-6:9.3f} {cell:>11} {ratio:>7}  {note}")
                if method == "cast_rays":
                    for line in c_lines:
                        print(line)
    return 0


def c_rows(rs, embree, rays, count, t_python, k, repeat):
    """The camera rays through C, beside cast_rays from Python (t_python
    seconds): rtk_intersect_batch on records built beforehand, and Embree 3's
    rtcIntersect1M on the same records; the table's lines.  Each pass gets
    fresh records (their copy not timed)."""
    records, _, _ = rs._rays(rays)

    def timed(call):
        best = float("inf")
        for _ in range(repeat):
            r = records.copy()
            t0 = time.perf_counter()
            call(r)
            best = min(best, time.perf_counter() - t0)
        return best

    def batch(r):
        with _batch_limit(k):  # (cast_rays's nthreads)
            N.check(N.intersect_batch(rs._scene, N.ptr(r), len(r), N.RAYHIT.itemsize, None), rs._dev,
                    "rtk_intersect_batch")

    tc = timed(batch)
    lines = [f"  {'  C: rtk_intersect_batch':28} {k:7d} {count / tc * 1e-6:9.3f} {'':>11} {'':>7}  "
             f"cast_rays from Python runs at {tc / t_python:.3f}x of it"]
    if embree:
        te = timed(lambda r: embree.intersect1M(r, threads=k))
        lines.append(f"  {'  C: Embree rtcIntersect1M':28} {k:7d} {count / te * 1e-6:9.3f} {'':>11} {'':>7}  "
                     f"coherent flag; cast_rays from Python at {te / t_python:.3f}x of it, rtk's C batch at "
                     f"{te / tc:.3f}x")
    return lines


def agreement(method, r, o, diag):
    """How Open3D's answers compare with rtk's, and what is wrong with them."""
    r, o = r.ravel(), o.ravel()
    if method == "cast_rays":
        rh, oh = np.isfinite(r), np.isfinite(o)
        if rh.any() and not oh.any():
            return f"Open3D WRONG: no hits at all (rtk hits {rh.mean():.1%}): its speed is not credited"
        same = (rh == oh) & (~rh | (np.abs(r - o) <= 1e-4 * np.maximum(1, np.abs(r))))
        return f"{same.mean():.2%} same hit and t"
    if method == "count_intersections":
        if (r > 0).any() and not (o > 0).any():
            return f"Open3D WRONG: no crossings at all (rtk: {(r > 0).mean():.1%} of rays cross)"
        return f"{(r == o).mean():.2%} same count"
    if method == "compute_distance":
        return f"{(np.abs(r - o) <= 1e-5 * diag).mean():.2%} within 1e-5 of the diagonal"
    if method == "compute_signed_distance":
        if (r < 0).any() and not (o < 0).any():
            return f"Open3D WRONG: never negative (rtk: {(r < 0).mean():.1%} of points inside)"
        return f"{(np.sign(r) == np.sign(o)).mean():.2%} same sign, " \
               f"{(np.abs(np.abs(r) - np.abs(o)) <= 1e-5 * diag).mean():.2%} same distance"
    if method == "compute_occupancy":
        if (r > 0).any() and not (o > 0).any():
            return f"Open3D WRONG: nothing inside (rtk: {(r > 0).mean():.1%} of points inside)"
        return f"{(r == o).mean():.2%} same"
    return ""


if __name__ == "__main__":
    sys.exit(main())
