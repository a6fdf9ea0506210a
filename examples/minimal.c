/* The smallest rtk program: one triangle, one ray.  Links only the core;
 * the core loads the best backend it finds next to itself at run time. */
#include <math.h>
#include <stdio.h>

#include <rtk/rtk.h>

int main(void)
{
    rtk_device dev = NULL;
    if (rtk_device_new(NULL, &dev) != RTK_OK) {
        fprintf(stderr, "rtk: %s\n", rtk_device_get_error_message(NULL));
        return 1;
    }
    static const float vertices[] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    static const uint32_t indices[] = {0, 1, 2};
    rtk_scene scene = NULL;
    rtk_geometry mesh = NULL;
    rtk_scene_new(dev, &scene);
    rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &mesh);
    rtk_geometry_set_shared_buffer(mesh, RTK_BUFFER_TYPE_VERTEX, vertices, 0, 3 * sizeof(float), 3);
    rtk_geometry_set_shared_buffer(mesh, RTK_BUFFER_TYPE_INDEX, indices, 0, 3 * sizeof(uint32_t), 1);
    rtk_geometry_commit(mesh);
    rtk_scene_attach_geometry(scene, mesh, NULL);
    rtk_geometry_release(mesh);
    if (rtk_scene_commit(scene) != RTK_OK) {
        fprintf(stderr, "rtk: %s\n", rtk_device_get_error_message(dev));
        return 1;
    }

    rtk_rayhit rh = {.ray = {.org_x = 0.25f, .org_y = 0.25f, .org_z = 1.0f, .dir_z = -1.0f,
                             .tnear = 0.0f, .tfar = INFINITY, .mask = 0xffffffffu},
                     .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
    rtk_intersect1(scene, &rh);
    printf("rtk %s, backend %s: ", rtk_version_string(), rtk_device_get_backend_name(dev));
    if (rh.hit.geomID == RTK_INVALID_GEOMETRY_ID)
        printf("miss\n");
    else
        printf("hit primitive %u at t = %g (u = %g, v = %g)\n", rh.hit.primID, rh.ray.tfar, rh.hit.u, rh.hit.v);
    rtk_scene_release(scene);
    rtk_device_release(dev);
    return rh.hit.geomID == RTK_INVALID_GEOMETRY_ID;
}
