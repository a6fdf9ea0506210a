/*
 * Short shadow rays through one mesh with rtk_occluded1, for counting the
 * instructions a query costs (the machine's timings drift by more than the
 * differences looked for).  Rays start at the centre of random triangles
 * (seeded) and go along (0.3, 0.8, 0.5) over [1e-4, 1]:
 *
 *   valgrind --tool=callgrind --callgrind-out-file=cg.out \
 *       build/bin/occluded_instructions ../shared/meshes/dragon.ply 20000
 *   callgrind_annotate --inclusive=yes cg.out | grep -E "occluded1|any_from"
 *
 * then divide by the ray count.  It uses only the public API, so the same
 * source builds against an older rtk to compare.  Not a speed benchmark:
 * speed is measured beside Embree by rtktool bench.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "mesh_import.h"
#include "rtk/rtk.h"

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: occluded_instructions MESH RAYS\n");
        return 2;
    }
    rtk_mesh m;
    char err[512];
    if (rtk_mesh_load(argv[1], &m, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    rtk_device d;
    rtk_scene s;
    rtk_geometry g;
    if (rtk_device_new("isa=avx2", &d) || rtk_scene_new(d, &s) ||
        rtk_geometry_new(d, RTK_GEOMETRY_TYPE_TRIANGLE, &g) ||
        rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, m.vertices, 0, 12, m.vertex_count) ||
        rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, m.indices, 0, 12, m.triangle_count) ||
        rtk_geometry_commit(g) || rtk_scene_attach_geometry(s, g, NULL) || rtk_scene_commit(s)) {
        fprintf(stderr, "rtk: %s %s\n", rtk_device_get_error_message(NULL), d ? rtk_device_get_error_message(d) : "");
        return 1;
    }
    const int n = atoi(argv[2]);
    int hits = 0;
    srand(1);
    for (int i = 0; i < n; i++) {
        const uint32_t t = (uint32_t)rand() % (uint32_t)m.triangle_count;
        const float *a = m.vertices + 3 * m.indices[3 * t], *b = m.vertices + 3 * m.indices[3 * t + 1],
                    *c = m.vertices + 3 * m.indices[3 * t + 2];
        float p[3];
        for (int k = 0; k < 3; k++)
            p[k] = (a[k] + b[k] + c[k]) / 3.0f;
        rtk_ray r = {.org_x = p[0], .org_y = p[1], .org_z = p[2], .tnear = 1e-4f, .dir_x = 0.3f, .dir_y = 0.8f,
                     .dir_z = 0.5f, .tfar = 1.0f, .mask = ~0u};
        rtk_occluded1(s, &r);
        hits += r.tfar == -INFINITY;
    }
    printf("%d of %d occluded\n", hits, n);
    rtk_geometry_release(g);
    rtk_scene_release(s);
    rtk_device_release(d);
    rtk_mesh_free(&m);
    return 0;
}
