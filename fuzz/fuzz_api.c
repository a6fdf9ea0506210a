/* libFuzzer target: sequences of API calls read from the input (scenes,
 * triangle and quad geometry with vertex and index data taken from the input — NaN,
 * infinite and huge values, indices out of range —, time steps, instances,
 * attach and detach, flags and qualities, vertex updates, commits, single
 * rays and packets, masks, culling, filters and user geometry whose
 * callbacks answer in and out of range).  Every call must return an error code or succeed,
 * never crash, hang or leak; an error must come with a message. */
#include <math.h>
#include <string.h>

#include "fuzz_device.h"

typedef struct input {
    const uint8_t *p;
    size_t n;
} input;

static uint8_t u8(input *in)
{
    if (!in->n)
        return 0;
    in->n--;
    return *in->p++;
}

static uint32_t u32(input *in)
{
    uint32_t v = 0;
    for (int i = 0; i < 4; i++)
        v = v << 8 | u8(in);
    return v;
}

/* A float: mostly small values on a grid (so triangles and rays meet), some
 * raw bit patterns (NaN, infinities, denormals, huge). */
static float f32(input *in)
{
    const uint8_t k = u8(in);
    if (k < 200)
        return (float)((int)u8(in) - 128) / 16.0f;
    const uint32_t bits = u32(in);
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

#define SCENES 3
#define GEOMS 6

static void checked_(rtk_device dev, rtk_error e, int line)
{
    /* (a NULL handle's error is the thread's, not the device's) */
    if (e != RTK_OK && !rtk_device_get_error_message(dev)[0] && !rtk_device_get_error_message(NULL)[0]) {
        fprintf(stderr, "fuzz_api.c:%d: error %d without a message\n", line, (int)e);
        abort(); /* an error always says why */
    }
}
#define checked(dev, e) checked_(dev, e, __LINE__)

static void fill_geometry(rtk_device dev, rtk_geometry g, int quads, input *in)
{
    const unsigned steps = 1 + u8(in) % 3;
    if (steps > 1)
        checked(dev, rtk_geometry_set_time_step_count(g, steps));
    const size_t nv = u8(in) % 24, nt = u8(in) % 24;
    for (unsigned s = 0; s < steps; s++) {
        float *v = NULL;
        const rtk_error e = rtk_geometry_set_new_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, s, 12, nv, (void **)&v);
        checked(dev, e);
        for (size_t i = 0; e == RTK_OK && v && i < 3 * nv; i++)
            v[i] = f32(in);
    }
    uint32_t *idx = NULL;
    const size_t corners = quads ? 4 : 3;
    const rtk_error e = rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_INDEX, 4 * corners, nt, (void **)&idx);
    checked(dev, e);
    for (size_t i = 0; e == RTK_OK && idx && i < corners * nt; i++)
        idx[i] = u8(in) % (uint32_t)(nv + 2); /* some out of range */
}

/* Filters and user geometry driven by the input too: a filter's answer
 * by the primitive, and user primitives' boxes and hit distances from
 * `user_box` (filled from the input at the start of each run). */
static int fuzz_filter(const rtk_filter_args *a)
{
    return (a->hit->primID + a->ray->id) % 3 != 0;
}

static float user_box[16][7]; /* lower, upper, and the t a callback answers (from the input as it goes) */

static void fuzz_bounds(const rtk_bounds_args *a)
{
    for (int k = 0; k < 3; k++) {
        a->lower[k] = user_box[a->prim_id % 16][k];
        a->upper[k] = user_box[a->prim_id % 16][3 + k];
    }
}

static void fuzz_user_query(const rtk_user_query_args *a, int occluded)
{
    for (uint32_t i = 0; i < a->N; i++) {
        if (!a->valid[i])
            continue;
        float *tfar = (float *)a->rays + 8 * a->N + i;
        const float t = user_box[a->prim_id % 16][6];
        *tfar = occluded && t > 0.0f ? -INFINITY : t; /* anything: NaN, beyond tfar, before tnear */
        if (!occluded) /* (occluded rays have no hit fields) */
            ((float *)a->rays)[15 * a->N + i] = t; /* u */
    }
}
static void fuzz_user_intersect(const rtk_user_query_args *a) { fuzz_user_query(a, 0); }
static void fuzz_user_occluded(const rtk_user_query_args *a) { fuzz_user_query(a, 1); }

static void trace(rtk_device dev, rtk_scene s, input *in)
{
    rtk_rayhit rh = {.ray = {.org_x = f32(in), .org_y = f32(in), .org_z = f32(in), .tnear = u8(in) & 1 ? 0.0f : f32(in),
                             .dir_x = f32(in), .dir_y = f32(in), .dir_z = f32(in), .time = (float)u8(in) / 200.0f,
                             .tfar = u8(in) & 1 ? 1e30f : f32(in), .mask = ~0u}};
    if (u8(in) & 1) {
        rh.ray.mask = u8(in);
        rh.ray.flags = u8(in);
        rh.ray.id = u8(in);
    }
    rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
    rtk_ray shadow = rh.ray;
    rtk_query_context ctx = {.user = NULL};
    const rtk_query_context *c = u8(in) & 1 ? &ctx : NULL;
    checked(dev, rtk_intersect1_ctx(s, &rh, c));
    checked(dev, rtk_occluded1_ctx(s, &shadow, c));
    rtk_rayhit8 p8;
    memset(&p8, 0, sizeof p8);
    int valid[8];
    for (int l = 0; l < 8; l++) {
        valid[l] = u8(in) & 1 ? -1 : 0;
        p8.ray.org_x[l] = rh.ray.org_x + 0.01f * (float)l;
        p8.ray.org_y[l] = rh.ray.org_y;
        p8.ray.org_z[l] = rh.ray.org_z;
        p8.ray.dir_x[l] = shadow.dir_x;
        p8.ray.dir_y[l] = shadow.dir_y;
        p8.ray.dir_z[l] = shadow.dir_z;
        p8.ray.tnear[l] = shadow.tnear;
        p8.ray.tfar[l] = shadow.tfar;
        p8.ray.time[l] = shadow.time;
        p8.ray.mask[l] = shadow.mask;
        p8.ray.flags[l] = shadow.flags;
        p8.hit.geomID[l] = RTK_INVALID_GEOMETRY_ID;
    }
    checked(dev, rtk_intersect8_ctx(s, valid, &p8, c));
    checked(dev, rtk_occluded8_ctx(s, valid, &p8.ray, c));
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    rtk_device dev = fuzz_device("threads=2");
    input in = {data, size};
    rtk_scene scenes[SCENES] = {0};
    rtk_geometry geoms[GEOMS] = {0};
    memset(user_box, 0, sizeof user_box);
    unsigned boxes = 0;
    for (int op = 0; in.n && op < 64; op++) {
        const uint8_t code = u8(&in);
        rtk_scene *s = &scenes[u8(&in) % SCENES];
        rtk_geometry *g = &geoms[u8(&in) % GEOMS];
        switch (code % 14) {
        case 0: /* a new scene */
            rtk_scene_release(*s);
            *s = NULL;
            checked(dev, rtk_scene_new(dev, s));
            checked(dev, rtk_scene_set_flags(*s, u8(&in) % 9));
            checked(dev, rtk_scene_set_build_quality(*s, (rtk_build_quality)(u8(&in) % 5)));
            break;
        case 1: { /* a new triangle geometry, or (code 15, 43, ...) quads */
            const int quads = (code / 14) % 2;
            rtk_geometry_release(*g);
            *g = NULL;
            checked(dev, rtk_geometry_new(dev, quads ? RTK_GEOMETRY_TYPE_QUAD : RTK_GEOMETRY_TYPE_TRIANGLE, g));
            fill_geometry(dev, *g, quads, &in);
            checked(dev, rtk_geometry_set_build_quality(*g, (rtk_build_quality)(u8(&in) % 5)));
            checked(dev, rtk_geometry_commit(*g));
            break;
        }
        case 2: { /* a new instance of another scene (perhaps this one) */
            rtk_geometry_release(*g);
            *g = NULL;
            checked(dev, rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_INSTANCE, g));
            checked(dev, rtk_geometry_set_instanced_scene(*g, scenes[u8(&in) % SCENES]));
            float m[16];
            for (int i = 0; i < 16; i++)
                m[i] = u8(&in) & 1 ? (i % 5 == 0 ? 1.0f : 0.0f) : f32(&in);
            checked(dev, rtk_geometry_set_transform(*g, (rtk_format)(u8(&in) % 4), m));
            checked(dev, rtk_geometry_commit(*g));
            break;
        }
        case 3:
            checked(dev, rtk_scene_attach_geometry(*s, *g, NULL));
            break;
        case 4:
            checked(dev, rtk_scene_detach_geometry(*s, u8(&in) % 8));
            break;
        case 5:
            checked(dev, rtk_scene_commit(*s));
            break;
        case 6:
            if (*s)
                trace(dev, *s, &in);
            break;
        case 7: /* new vertex positions, as a deforming geometry gets them */
            if (*g) {
                checked(dev, rtk_geometry_update_buffer(*g, RTK_BUFFER_TYPE_VERTEX));
                checked(dev, rtk_geometry_commit(*g));
            }
            break;
        case 8:
            checked(dev, u8(&in) & 1 ? rtk_geometry_enable(*g) : rtk_geometry_disable(*g));
            checked(dev, rtk_geometry_commit(*g));
            break;
        case 9: {
            rtk_scene_info info = {.struct_size = sizeof info};
            checked(dev, rtk_scene_get_info(*s, &info));
            rtk_bvh tree;
            if (rtk_scene_get_bvh(*s, &tree) == RTK_OK) {
                char msg[128];
                if (rtk_bvh_check(&tree, msg, sizeof msg) != RTK_OK) {
                    fprintf(stderr, "rtk_scene_get_bvh gave a tree that fails rtk_bvh_check: %s\n", msg);
                    abort(); /* rtk's own trees pass its checks */
                }
                checked(dev, rtk_scene_commit_bvh(*s, &tree));
                rtk_bvh_free(&tree);
            }
            break;
        }
        case 10:
            rtk_scene_release(*s);
            *s = NULL;
            break;
        case 12: /* a mask and filters (refused on instances and user geometry) */
            checked(dev, rtk_geometry_set_mask(*g, u8(&in)));
            checked(dev, rtk_geometry_set_intersect_filter(*g, u8(&in) & 1 ? fuzz_filter : NULL));
            checked(dev, rtk_geometry_set_occluded_filter(*g, u8(&in) & 1 ? fuzz_filter : NULL));
            checked(dev, rtk_geometry_commit(*g));
            break;
        case 13: /* a new user geometry; some callbacks missing */
            rtk_geometry_release(*g);
            *g = NULL;
            checked(dev, rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_USER, g));
            for (int k = 0; k < 7; k++, boxes++) /* one more primitive's box and answer */
                user_box[boxes / 7 % 16][k] = f32(&in);
            checked(dev, rtk_geometry_set_user_primitive_count(*g, u8(&in) % 40));
            if (u8(&in) % 8)
                checked(dev, rtk_geometry_set_bounds_function(*g, fuzz_bounds));
            checked(dev, rtk_geometry_set_intersect_function(*g, fuzz_user_intersect));
            if (u8(&in) % 8)
                checked(dev, rtk_geometry_set_occluded_function(*g, fuzz_user_occluded));
            checked(dev, rtk_geometry_commit(*g));
            break;
        default:
            rtk_geometry_release(*g);
            *g = NULL;
            break;
        }
    }
    for (int i = 0; i < SCENES; i++)
        rtk_scene_release(scenes[i]);
    for (int i = 0; i < GEOMS; i++)
        rtk_geometry_release(geoms[i]);
    return 0;
}
