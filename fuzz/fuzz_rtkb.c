/* libFuzzer target: the .rtkb reader (tools/rtkb.c) and, for what it
 * accepts, the core's checks on a tree handed in: rtk_bvh_check and
 * rtk_scene_commit_bvh over a small fixed mesh (a tree that does not fit it
 * must be refused with a message, never trusted). */
#include <stdlib.h>

#include "fuzz_common.h"
#include "fuzz_device.h"
#include "rtkb.h"

/* 8 x 8 quads in the plane z = 0: 128 triangles */
#define GRID 8
static float grid_v[(GRID + 1) * (GRID + 1) * 3];
static uint32_t grid_i[GRID * GRID * 6];

static void grid_init(void)
{
    for (int y = 0; y <= GRID; y++)
        for (int x = 0; x <= GRID; x++) {
            float *p = grid_v + 3 * (y * (GRID + 1) + x);
            p[0] = (float)x, p[1] = (float)y, p[2] = (float)(0.1 * ((x * y) % 3)); /* as fuzz/corpus/rtkb was made */
        }
    uint32_t *t = grid_i;
    for (uint32_t y = 0; y < GRID; y++)
        for (uint32_t x = 0; x < GRID; x++) {
            const uint32_t a = y * (GRID + 1) + x;
            *t++ = a, *t++ = a + 1, *t++ = a + GRID + 1;
            *t++ = a + 1, *t++ = a + GRID + 2, *t++ = a + GRID + 1;
        }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;
    if (!ready) {
        grid_init();
        ready = 1;
    }
    char path[256], err[256];
    if (!fuzz_file(data, size, ".rtkb", path, sizeof path))
        return 0;
    rtkb_file file;
    err[0] = 0;
    const int rc = rtkb_load(path, &file, err, sizeof err);
    unlink(path);
    if (rc) {
        if (!err[0])
            abort();
        return 0;
    }
    char msg[256];
    if (rtk_bvh_check(&file.tree, msg, sizeof msg) == RTK_OK) {
        rtk_device dev = fuzz_device(NULL);
        rtk_scene scene = NULL;
        rtk_geometry g = NULL;
        if (rtk_scene_new(dev, &scene) == RTK_OK && rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g) == RTK_OK &&
            rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, grid_v, 0, 12, (GRID + 1) * (GRID + 1)) ==
                RTK_OK &&
            rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, grid_i, 0, 12, GRID * GRID * 2) == RTK_OK &&
            rtk_geometry_commit(g) == RTK_OK && rtk_scene_attach_geometry(scene, g, NULL) == RTK_OK &&
            rtk_scene_commit_bvh(scene, &file.tree) == RTK_OK) {
            /* accepted: it must trace */
            if (getenv("RTK_FUZZ_DEBUG"))
                fprintf(stderr, "tree accepted\n");
            rtk_rayhit rh = {.ray = {.org_x = 3.3f, .org_y = 4.1f, .org_z = 5, .dir_z = -1, .tfar = 1e30f,
                                     .mask = ~0u}};
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            rtk_intersect1(scene, &rh);
            if (rh.hit.geomID != 0)
                abort(); /* the grid is under every such ray */
        }
        rtk_geometry_release(g);
        rtk_scene_release(scene);
    }
    rtkb_free(&file);
    return 0;
}
