/*
 * The program of docs/GUIDE.md: a small scene (a ground of two triangles,
 * an alpha-tested fence, spheres as user geometry) traced the way a
 * renderer does it: camera rays in packets of 8, shadow rays in packets of
 * 8 toward a point light, printed as a picture in characters.  Links only
 * the core; the best backend installed is loaded at run time.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include <rtk/rtk.h>

enum { W = 64, H = 24 };

/* ---- spheres: user geometry ---- */
typedef struct sphere {
    float c[3], r;
} sphere;
static const sphere spheres[] = {{{-1.2f, 0.6f, 0.0f}, 0.6f}, {{0.4f, 0.4f, -0.6f}, 0.4f}, {{1.4f, 0.3f, 0.5f}, 0.3f}};

static void sphere_bounds(const rtk_bounds_args *a)
{
    const sphere *s = (const sphere *)a->geometry_user + a->prim_id;
    for (int k = 0; k < 3; k++) {
        a->lower[k] = s->c[k] - s->r;
        a->upper[k] = s->c[k] + s->r;
    }
}

/* Field f of lane i of N rays (N = 1: an rtk_rayhit or rtk_ray): the ray
 * types are structures of 4-byte arrays in rtk_rayhit's field order. */
#define FIELD(rays, n, f, i) (((float *)(rays))[(f) * (n) + (i)])

static void sphere_query(const rtk_user_query_args *a, int occluded)
{
    const sphere *s = (const sphere *)a->geometry_user + a->prim_id;
    for (uint32_t i = 0; i < a->N; i++) {
        if (!a->valid[i])
            continue;
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            o[k] = FIELD(a->rays, a->N, k, i) - s->c[k];
            d[k] = FIELD(a->rays, a->N, 4 + k, i);
        }
        const float A = d[0] * d[0] + d[1] * d[1] + d[2] * d[2], B = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
        const float C = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - s->r * s->r, disc = B * B - A * C;
        if (disc < 0.0f)
            continue;
        const float tnear = FIELD(a->rays, a->N, 3, i), tfar = FIELD(a->rays, a->N, 8, i);
        float t = (-B - sqrtf(disc)) / A;
        if (t < tnear)
            t = (-B + sqrtf(disc)) / A;
        if (t < tnear || t > tfar)
            continue;
        FIELD(a->rays, a->N, 8, i) = occluded ? -INFINITY : t; /* tfar */
        if (!occluded)
            for (int k = 0; k < 3; k++) /* Ng; rtk fills geomID, primID, instID */
                FIELD(a->rays, a->N, 12 + k, i) = o[k] + t * d[k];
    }
}
static void sphere_intersect(const rtk_user_query_args *a) { sphere_query(a, 0); }
static void sphere_occluded(const rtk_user_query_args *a) { sphere_query(a, 1); }

/* ---- the fence: a filter makes it a set of slats ---- */
static int fence_filter(const rtk_filter_args *a)
{
    /* slats a quarter wide, a quarter apart, by where along x the ray
     * meets the fence: rays through the gaps go on */
    const float x = (a->ray->org_x + a->t * a->ray->dir_x) * 2.0f;
    return x - floorf(x) < 0.5f;
}

static rtk_scene build_scene(rtk_device dev)
{
    rtk_scene scene;
    rtk_scene_new(dev, &scene);
    /* the ground, y = 0 */
    static const float ground_v[] = {-4, 0, -4, 4, 0, -4, 4, 0, 4, -4, 0, 4};
    static const uint32_t ground_i[] = {0, 2, 1, 0, 3, 2};
    rtk_geometry g;
    rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g);
    rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, ground_v, 0, 12, 4);
    rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, ground_i, 0, 12, 2);
    rtk_geometry_commit(g);
    rtk_scene_attach_geometry(scene, g, NULL);
    rtk_geometry_release(g);
    /* the fence behind the spheres, z = -1.5 */
    static const float fence_v[] = {-3, 0, -1.5f, 3, 0, -1.5f, -3, 1.5f, -1.5f, 3, 1.5f, -1.5f};
    static const uint32_t fence_i[] = {0, 1, 2, 3, 2, 1};
    rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g);
    rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, fence_v, 0, 12, 4);
    rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, fence_i, 0, 12, 2);
    rtk_geometry_set_intersect_filter(g, fence_filter);
    rtk_geometry_set_occluded_filter(g, fence_filter);
    rtk_geometry_commit(g);
    rtk_scene_attach_geometry(scene, g, NULL);
    rtk_geometry_release(g);
    /* the spheres */
    rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_USER, &g);
    rtk_geometry_set_user_primitive_count(g, sizeof spheres / sizeof spheres[0]);
    rtk_geometry_set_user_data(g, (void *)spheres);
    rtk_geometry_set_bounds_function(g, sphere_bounds);
    rtk_geometry_set_intersect_function(g, sphere_intersect);
    rtk_geometry_set_occluded_function(g, sphere_occluded);
    rtk_geometry_commit(g);
    rtk_scene_attach_geometry(scene, g, NULL);
    rtk_geometry_release(g);
    return scene;
}

int main(void)
{
    rtk_device dev;
    if (rtk_device_new(NULL, &dev) != RTK_OK) {
        fprintf(stderr, "rtk: %s\n", rtk_device_get_error_message(NULL));
        return 1;
    }
    rtk_scene scene = build_scene(dev);
    if (rtk_scene_commit(scene) != RTK_OK) {
        fprintf(stderr, "rtk: %s\n", rtk_device_get_error_message(dev));
        return 1;
    }
    const float eye[3] = {0.0f, 1.1f, 3.2f}, light[3] = {3.0f, 6.0f, 4.0f};
    char image[H][W + 1];
    unsigned hits = 0, shadowed = 0, by_geom[3] = {0, 0, 0};
    for (int y = 0; y < H; y += 2) {
        for (int x = 0; x < W; x += 4) {
            /* camera rays of a 4x2 pixel block, one packet */
            rtk_rayhit8 cam;
            for (int k = 0; k < 8; k++) {
                const float px = ((float)(x + k % 4) + 0.5f) / W * 2.0f - 1.0f;
                const float py = 1.0f - ((float)(y + k / 4) + 0.5f) / H * 2.0f;
                cam.ray.org_x[k] = eye[0], cam.ray.org_y[k] = eye[1], cam.ray.org_z[k] = eye[2];
                cam.ray.dir_x[k] = px * 1.3f, cam.ray.dir_y[k] = py * 0.55f - 0.15f, cam.ray.dir_z[k] = -1.0f;
                cam.ray.tnear[k] = 0.0f, cam.ray.tfar[k] = INFINITY, cam.ray.time[k] = 0.0f;
                cam.ray.mask[k] = ~0u, cam.ray.id[k] = (uint32_t)k, cam.ray.flags[k] = 0;
                cam.hit.geomID[k] = RTK_INVALID_GEOMETRY_ID;
            }
            rtk_intersect8(scene, NULL, &cam);
            /* shadow rays from the hit points toward the light, one packet */
            rtk_ray8 sh;
            int valid[8];
            for (int k = 0; k < 8; k++) {
                valid[k] = cam.hit.geomID[k] != RTK_INVALID_GEOMETRY_ID;
                const float t = cam.ray.tfar[k];
                const float p[3] = {eye[0] + t * cam.ray.dir_x[k], eye[1] + t * cam.ray.dir_y[k],
                                    eye[2] + t * cam.ray.dir_z[k]};
                sh.org_x[k] = p[0], sh.org_y[k] = p[1], sh.org_z[k] = p[2];
                sh.dir_x[k] = light[0] - p[0], sh.dir_y[k] = light[1] - p[1], sh.dir_z[k] = light[2] - p[2];
                /* start a little off the surface, stop short of the light */
                sh.tnear[k] = 1e-3f, sh.tfar[k] = 1.0f, sh.time[k] = 0.0f;
                sh.mask[k] = ~0u, sh.id[k] = (uint32_t)k, sh.flags[k] = 0;
            }
            rtk_occluded8(scene, valid, &sh);
            for (int k = 0; k < 8; k++) {
                char c = ' ';
                if (valid[k]) {
                    const int dark = sh.tfar[k] == -INFINITY;
                    static const char lit[3] = {'.', '#', 'O'}, shade[3] = {',', '+', 'o'};
                    const uint32_t g = cam.hit.geomID[k];
                    c = dark ? shade[g] : lit[g];
                    hits++;
                    shadowed += (unsigned)dark;
                    by_geom[g]++;
                }
                image[y + k / 4][x + k % 4] = c;
            }
        }
    }
    for (int y = 0; y < H; y++) {
        image[y][W] = '\0';
        printf("|%s|\n", image[y]);
    }
    printf("guide: backend %s, %d rays, %u hits (ground %u, fence %u, spheres %u), %u in shadow\n",
           rtk_device_get_backend_name(dev), W * H, hits, by_geom[0], by_geom[1], by_geom[2], shadowed);
    rtk_scene_release(scene);
    rtk_device_release(dev);
    return hits == 0;
}
