/* Clean-ups `rtktool convert` offers on an imported mesh. */
#ifndef RTK_TOOLS_MESH_TOOLS_H
#define RTK_TOOLS_MESH_TOOLS_H

#include "mesh_import.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Merges vertices at the same position (equal as floats: -0.0 and +0.0
 * merge, NaN never does) into the first of them, removes the others and
 * renumbers the indices, keeping the order of what is left.  Returns the
 * number of vertices removed, or (size_t)-1 when out of memory (the mesh
 * unchanged). */
size_t rtk_mesh_merge_vertices(rtk_mesh *mesh);
/* Drops the triangles rtk never hits: zero area in exact arithmetic
 * (rtk_triangle_is_degenerate: repeated or collinear vertices), counted in
 * *degenerate, and those with a NaN or infinite vertex, counted in
 * *non_finite.  Keeps the order of the others. */
void rtk_mesh_drop_unhittable(rtk_mesh *mesh, size_t *degenerate, size_t *non_finite);
/* Counts without dropping. */
void rtk_mesh_count_unhittable(const rtk_mesh *mesh, size_t *degenerate, size_t *non_finite);

/* An edge of a triangle: its vertex indices, a < b, and the triangle. */
typedef struct rtk_mesh_edge {
    uint32_t a, b;
    uint32_t tri;
} rtk_mesh_edge;
/* The edges of exactly two triangles (with distinct != 0, only those
 * joining two distinct vertices), sorted: entries 2k and 2k + 1 of *out
 * are edge k in its two triangles; returns the number of entries.  *out is
 * malloc'd (NULL when out of memory, the return then 0). */
size_t rtk_mesh_shared_edges(const rtk_mesh *mesh, int distinct, rtk_mesh_edge **out);

/* A procedural mesh of about `triangles` triangles (at least 2): a sphere
 * of radius 1 with bumps at several scales, as a grid of 2 R^2 triangles in
 * scanline order (as scans come).  What "procedural:N" names to the tools.
 * Returns 0, or non-zero when out of memory (*mesh then empty). */
int rtk_mesh_procedural(size_t triangles, rtk_mesh *mesh);
/* "procedural:N" (N a whole number from 2 to 2^31, with an optional k or M
 * suffix): 1 and N in *triangles; anything else 0. */
int rtk_mesh_procedural_name(const char *name, size_t *triangles);

#ifdef __cplusplus
}
#endif
#endif
