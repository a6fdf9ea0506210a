"""rtk from Python: the ray-tracing kernel library's geometry queries over
numpy arrays, with Open3D's RaycastingScene interface.

    import rtk
    scene = rtk.RaycastingScene()
    scene.add_triangles(vertices, triangles)      # (N, 3) float, (M, 3) int
    hits = scene.cast_rays(rays)                  # (..., 6): origin, direction
    d = scene.compute_signed_distance(points)     # (..., 3)

trimesh's ray interface too: rtk.RayMeshIntersector(vertices, faces) with
intersects_first, intersects_any, intersects_id, intersects_location and
contains_points.

The module loads librtk from the source tree's build (build/lib), from
$RTK_LIBRARY, or from the system's library path.
"""
from ._native import path as library_path
from .raycasting import INVALID_ID, Array, RaycastingScene, RayMeshIntersector

__all__ = ["RaycastingScene", "RayMeshIntersector", "INVALID_ID", "Array", "library_path"]
