"""Embree 3 (libembree3, Debian's libembree-dev or libembree3-3) through
ctypes, for the bench only: one triangle mesh, and rtcIntersect1M over the
same rtk_rayhit records rtk traces (Embree's RTCRayHit has the same 80-byte
layout), so that the rays through Python can be set beside Embree's own C
call on the same rays in the same run.  Nothing of rtk uses Embree."""
import ctypes
import ctypes.util
import threading

import numpy as np

from . import _native as N

RTC_GEOMETRY_TYPE_TRIANGLE = 0
RTC_BUFFER_TYPE_INDEX, RTC_BUFFER_TYPE_VERTEX = 0, 1
RTC_FORMAT_UINT3, RTC_FORMAT_FLOAT3 = 0x5003, 0x9003
RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT, RTC_INTERSECT_CONTEXT_FLAG_COHERENT = 0, 1


class _Context(ctypes.Structure):
    # RTCIntersectContext with RTC_MAX_INSTANCE_LEVEL_COUNT 1 (Debian's build)
    _fields_ = [("flags", ctypes.c_int), ("filter", ctypes.c_void_p), ("instID", ctypes.c_uint * 1)]


def _load():
    for name in (ctypes.util.find_library("embree3"), "libembree3.so.3"):
        if name:
            try:
                return ctypes.CDLL(name)
            except OSError:
                pass
    return None


class EmbreeScene:
    """A committed Embree 3 scene of one triangle mesh (v float32 (n, 3),
    t integers (m, 3)); None from create() where libembree3 is missing."""

    @classmethod
    def create(cls, v, t):
        lib = _load()
        return cls(lib, v, t) if lib else None

    def __init__(self, lib, v, t):
        P = ctypes.c_void_p
        self.lib = lib
        for name, args, ret in (("rtcNewDevice", [ctypes.c_char_p], P), ("rtcReleaseDevice", [P], None),
                                ("rtcNewScene", [P], P), ("rtcReleaseScene", [P], None),
                                ("rtcNewGeometry", [P, ctypes.c_int], P), ("rtcReleaseGeometry", [P], None),
                                ("rtcSetNewGeometryBuffer", [P, ctypes.c_int, ctypes.c_uint, ctypes.c_int,
                                                             ctypes.c_size_t, ctypes.c_size_t], P),
                                ("rtcCommitGeometry", [P], None), ("rtcAttachGeometry", [P, P], ctypes.c_uint),
                                ("rtcCommitScene", [P], None),
                                ("rtcIntersect1M", [P, P, P, ctypes.c_uint, ctypes.c_size_t], None),
                                ("rtcGetDeviceError", [P], ctypes.c_int)):
            f = getattr(lib, name)
            f.argtypes, f.restype = args, ret
        self.device = lib.rtcNewDevice(None)
        if not self.device:
            raise RuntimeError("Embree: rtcNewDevice failed")
        self.scene = lib.rtcNewScene(self.device)
        g = lib.rtcNewGeometry(self.device, RTC_GEOMETRY_TYPE_TRIANGLE)
        vb = lib.rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 12, len(v))
        ib = lib.rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 12, len(t))
        if not vb or not ib:
            raise RuntimeError(f"Embree: no geometry buffers (error {lib.rtcGetDeviceError(self.device)})")
        ctypes.memmove(vb, np.ascontiguousarray(v, np.float32).ctypes.data, 12 * len(v))
        ctypes.memmove(ib, np.ascontiguousarray(t, np.uint32).ctypes.data, 12 * len(t))
        lib.rtcCommitGeometry(g)
        lib.rtcAttachGeometry(self.scene, g)
        lib.rtcReleaseGeometry(g)
        lib.rtcCommitScene(self.scene)

    def intersect1M(self, records, threads=1, coherent=True):
        """rtcIntersect1M over records (N.RAYHIT, modified in place), cut
        into `threads` slices traced at once on as many Python threads
        (ctypes lets go of the GIL during the call)."""
        ctx = _Context(RTC_INTERSECT_CONTEXT_FLAG_COHERENT if coherent else RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT,
                       None, (ctypes.c_uint * 1)(N.INVALID_ID))
        n, size = len(records), N.RAYHIT.itemsize
        cuts = np.linspace(0, n, threads + 1).astype(np.int64)
        base = records.ctypes.data

        def run(a, b):
            # rtcIntersect1M takes up to 2^32 - 1 rays a call
            for s in range(a, b, 1 << 30):
                e = min(b, s + (1 << 30))
                self.lib.rtcIntersect1M(self.scene, ctypes.byref(ctx), base + s * size, e - s, size)

        if threads == 1:
            run(0, n)
            return
        workers = [threading.Thread(target=run, args=(int(cuts[i]), int(cuts[i + 1]))) for i in range(threads)]
        for w in workers:
            w.start()
        for w in workers:
            w.join()

    def close(self):
        if self.scene:
            self.lib.rtcReleaseScene(self.scene)
            self.lib.rtcReleaseDevice(self.device)
            self.scene = self.device = None

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass
