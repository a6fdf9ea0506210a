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

#ifdef __cplusplus
}
#endif
#endif
