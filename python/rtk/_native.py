"""librtk through ctypes: finding the library, its structs as numpy dtypes,
and the functions the module calls.  Nothing here is public."""
import ctypes
import ctypes.util
import os

import numpy as np

# The C structs (include/rtk/rtk.h), field for field.
RAY = np.dtype([("org", "<f4", 3), ("tnear", "<f4"), ("dir", "<f4", 3), ("time", "<f4"), ("tfar", "<f4"),
                ("mask", "<u4"), ("id", "<u4"), ("flags", "<u4")])
HIT = np.dtype([("Ng", "<f4", 3), ("u", "<f4"), ("v", "<f4"), ("primID", "<u4"), ("geomID", "<u4"),
                ("instID", "<u4")])
RAYHIT = np.dtype([("ray", RAY), ("hit", HIT)])
CROSSING = np.dtype([("t", "<f4"), ("u", "<f4"), ("v", "<f4"), ("Ng", "<f4", 3), ("primID", "<u4"),
                     ("geomID", "<u4"), ("instID", "<u4")])
assert RAY.itemsize == 48 and HIT.itemsize == 32 and CROSSING.itemsize == 36

INVALID_ID = 0xFFFFFFFF
GEOMETRY_TYPE_TRIANGLE = 0
BUFFER_VERTEX, BUFFER_INDEX = 0, 1
SCENE_FLAG_ROBUST = 2


def _candidates():
    env = os.environ.get("RTK_LIBRARY")
    if env:
        yield env
        return
    here = os.path.dirname(os.path.abspath(__file__))
    # in the source tree: python/rtk -> build/lib (README's build)
    yield os.path.join(here, "..", "..", "build", "lib", "librtk.so")
    found = ctypes.util.find_library("rtk")
    if found:
        yield found


def _load():
    tried = []
    for path in _candidates():
        try:
            return ctypes.CDLL(path), path
        except OSError as e:
            tried.append(f"{path}: {e}")
    raise ImportError("rtk: librtk not found (build it with the README's first command, or set RTK_LIBRARY "
                      "to its path); tried " + "; ".join(tried or ["nothing"]))


lib, path = _load()

P, U32, SZ, I = ctypes.c_void_p, ctypes.c_uint32, ctypes.c_size_t, ctypes.c_int


def _fn(name, args, ret=I):
    f = getattr(lib, name)
    f.argtypes = args
    f.restype = ret
    return f


device_new = _fn("rtk_device_new", [ctypes.c_char_p, ctypes.POINTER(P)])
device_release = _fn("rtk_device_release", [P], None)
device_get_error_message = _fn("rtk_device_get_error_message", [P], ctypes.c_char_p)
device_get_thread_count = _fn("rtk_device_get_thread_count", [P], U32)
set_batch_threads = _fn("rtk_set_batch_threads", [U32], U32)
device_get_backend_name = _fn("rtk_device_get_backend_name", [P], ctypes.c_char_p)
scene_new = _fn("rtk_scene_new", [P, ctypes.POINTER(P)])
scene_release = _fn("rtk_scene_release", [P], None)
scene_set_flags = _fn("rtk_scene_set_flags", [P, ctypes.c_uint])
scene_attach_geometry = _fn("rtk_scene_attach_geometry", [P, P, ctypes.POINTER(U32)])
scene_commit = _fn("rtk_scene_commit", [P])
geometry_new = _fn("rtk_geometry_new", [P, I, ctypes.POINTER(P)])
geometry_release = _fn("rtk_geometry_release", [P], None)
geometry_set_shared_buffer = _fn("rtk_geometry_set_shared_buffer", [P, I, P, SZ, SZ, SZ])
geometry_commit = _fn("rtk_geometry_commit", [P])
intersect_batch = _fn("rtk_intersect_batch", [P, P, SZ, SZ, P])
occluded_batch = _fn("rtk_occluded_batch", [P, P, SZ, SZ, P])
count_intersections = _fn("rtk_count_intersections", [P, P, SZ, SZ, P])
list_intersections = _fn("rtk_list_intersections", [P, P, SZ, SZ, P, P])


class RayArrays(ctypes.Structure):
    """rtk_ray_arrays (rtk.h)."""
    _fields_ = [("rays", P), ("rays_double", I), ("ray_stride", SZ), ("tnear", ctypes.c_float),
                ("tfar", ctypes.c_float), ("t_hit", P), ("geom_ids", P), ("prim_ids", P), ("inst_ids", P),
                ("uvs", P), ("normals", P), ("occluded", P), ("row_length", SZ)]


intersect_arrays = _fn("rtk_intersect_arrays", [P, ctypes.POINTER(RayArrays), SZ])
occluded_arrays = _fn("rtk_occluded_arrays", [P, ctypes.POINTER(RayArrays), SZ])


class PointArrays(ctypes.Structure):
    """rtk_point_arrays (rtk.h)."""
    _fields_ = [("points", P), ("points_double", I), ("point_stride", SZ), ("radius", ctypes.c_double),
                ("time", ctypes.c_float), ("distances", P), ("closest", P), ("geom_ids", P), ("prim_ids", P),
                ("inst_ids", P), ("uvs", P), ("normals", P), ("inside", P)]


closest_point_arrays = _fn("rtk_closest_point_arrays", [P, ctypes.POINTER(PointArrays), SZ])
occupancy_arrays = _fn("rtk_occupancy_arrays", [P, ctypes.POINTER(PointArrays), SZ])


def check(rc, device, what):
    if rc != 0:
        msg = device_get_error_message(device)
        raise RuntimeError(f"rtk: {what}: " + (msg.decode(errors="replace") if msg else f"error {rc}"))


def ptr(a):
    return ctypes.c_void_p(a.ctypes.data) if a.size else None
