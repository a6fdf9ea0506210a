/*
 * Mesh import through OpenMesh, behind a C interface (the only C++ in rtk).
 *
 * Reads OBJ, PLY (ascii and binary), OFF, STL (ascii and binary) and OM with
 * OpenMesh's readers into a triangle soup: polygons are split into fans, and
 * every input face is kept exactly as written.  OpenMesh's own mesh importer
 * drops faces with a repeated vertex and splits non-manifold faces off onto
 * duplicated vertices; rtk plugs its own importer into the readers instead, so
 * no face is dropped and no vertex duplicated (vertices_duplicated reports 0,
 * and counts what was duplicated should that ever change).  One exception
 * lies in OpenMesh's OBJ reader itself, which drops faces that repeat a
 * vertex before rtk sees them (they have no area and could never be hit);
 * the PLY and OFF readers pass them on, and they are kept and counted.
 * OpenMesh's own OM files hold its halfedge structure, so they can only hold
 * what its mesh accepted; they are read through a PolyMesh.  Files named
 * *.rtkm are rtk's own mesh files (rtkm.h), read without OpenMesh.
 */
#ifndef RTK_TOOLS_MESH_IMPORT_H
#define RTK_TOOLS_MESH_IMPORT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct rtk_mesh {
    float *vertices;   /* x, y, z per vertex */
    uint32_t *indices; /* v0, v1, v2 per triangle */
    size_t vertex_count;
    size_t triangle_count;
    size_t faces_read;             /* faces in the file */
    size_t polygons_triangulated;  /* faces with more than three vertices */
    size_t faces_repeated_vertex;  /* kept, though they have no area */
    size_t vertices_duplicated;
} rtk_mesh;

/* Returns 0 on success; otherwise non-zero, *mesh is empty and err says why.
 * Not thread-safe (OpenMesh's reader diagnostics go through global streams);
 * calls are serialised internally. */
int rtk_mesh_load(const char *path, rtk_mesh *mesh, char *err, size_t err_size);
void rtk_mesh_free(rtk_mesh *mesh);

/* Checks through OpenMesh that triangles [0, count) of the mesh make a
 * closed 2-manifold: every face accepted by its halfedge structure (no
 * complex edge or vertex, consistently oriented) and no boundary edge.
 * Returns 1 if closed; *boundary_edges and *faces_rejected say what was
 * found (either may be NULL).  Returns -1 when out of memory. */
int rtk_mesh_is_closed(const rtk_mesh *mesh, size_t count, size_t *boundary_edges, size_t *faces_rejected);
/* Bounds of the vertices and the length of their diagonal (0 for no vertices). */
float rtk_mesh_bounds(const rtk_mesh *mesh, float lower[3], float upper[3]);

#ifdef __cplusplus
}
#endif
#endif
