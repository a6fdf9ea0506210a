/* The renderer of rtktool trace and rtktool bench: images that do not depend
 * on threads or API, the light transport checked where it has an exact
 * answer (a white furnace, a sunlit plane and its shadow, normals by
 * winding), Russian roulette unbiased, cameras and settings refused when
 * they make no sense, and the bunny in every mode against reference images.
 *
 * RTK_UPDATE_REFERENCE=1 rewrites the reference images in the source tree
 * (after a deliberate change to the renderer; look at them before
 * committing). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_import.h"
#include "png_io.h"
#include "render.h"
#include "testlib.h"

#ifndef RTK_TEST_REFERENCE
#error "RTK_TEST_REFERENCE: the directory of the reference images"
#endif

static float *render_new(rtk_scene scene, const render_settings *s, render_stats *st)
{
    float *rgb = malloc((size_t)s->width * (size_t)s->height * 3 * sizeof *rgb);
    assert_non_null(rgb);
    const render_tracer t = render_tracer_rtk(scene);
    char err[256] = "";
    render_stats local;
    if (render_image(&t, s, rgb, st ? st : &local, err, sizeof err))
        fail_msg("render_image: %s", err);
    return rgb;
}

static size_t pixels(const render_settings *s)
{
    return (size_t)s->width * (size_t)s->height;
}

/* Pixels whose colour differs at all. */
static size_t differing(const render_settings *s, const float *a, const float *b)
{
    size_t n = 0;
    for (size_t i = 0; i < pixels(s); i++)
        n += memcmp(&a[3 * i], &b[3 * i], 3 * sizeof(float)) != 0;
    return n;
}

static rtk_mesh bunny;
static rtk_device best;
static rtk_scene best_scene;
static char backend_names[TEST_MAX_BACKENDS][32];
static size_t backends;

static int setup(void **state)
{
    (void)state;
    char err[256];
    if (rtk_mesh_load(RTK_TEST_DATA "/bunny.ply", &bunny, err, sizeof err)) {
        fprintf(stderr, "%s\n", err);
        return -1;
    }
    backends = test_backend_names(backend_names, TEST_MAX_BACKENDS);
    if (rtk_device_new("", &best))
        return -1;
    best_scene = test_scene(best, bunny.vertices, bunny.vertex_count, bunny.indices, bunny.triangle_count);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    rtk_scene_release(best_scene);
    rtk_device_release(best);
    rtk_mesh_free(&bunny);
    return 0;
}

static void bunny_settings(rtk_scene scene, render_settings *s, int w, int h, render_mode mode)
{
    rtk_scene_info info = {.struct_size = sizeof info};
    assert_int_equal(rtk_scene_get_info(scene, &info), RTK_OK);
    render_defaults(s, info.bounds_lower, info.bounds_upper, w, h);
    s->mode = mode;
    s->spp = mode == RENDER_AO || mode == RENDER_DIFFUSE ? 2 : 1;
}

/* Every API in turn: single, packets of 4, 8, 16, streams; then 0. */
static int next_api(int api)
{
    return api == 1 ? 4 : api == 16 ? RENDER_API_STREAM : api == RENDER_API_STREAM ? 0 : api * 2;
}

/* Threads never change the image, nor do streams (each ray gets its single
 * call's answer, to the bit); on scalar (packets traced ray by ray) the
 * API never does either; on the SIMD backends only where a ray hits two
 * triangles at exactly the same distance (an edge between them) and the
 * packet kernel reports the other one, which is rare. */
static void test_threads_and_api_agree(void **state)
{
    (void)state;
    for (size_t b = 0; b < backends; b++) {
        rtk_device dev = test_device(backend_names[b]);
        rtk_scene scene = test_scene(dev, bunny.vertices, bunny.vertex_count, bunny.indices, bunny.triangle_count);
        for (int mode = RENDER_EYELIGHT; mode <= RENDER_DIFFUSE; mode++) {
            render_settings s;
            bunny_settings(scene, &s, 97, 61, (render_mode)mode); /* edges cut through tiles and packets */
            render_stats st1, st;
            float *ref = render_new(scene, &s, &st1);
            assert_true(st1.primary == pixels(&s) * (size_t)s.spp);
            assert_true(st1.primary_hits > st1.primary / 10);
            if (mode == RENDER_AO)
                assert_true(st1.ao == st1.primary_hits * (uint64_t)s.ao_samples);
            if (mode == RENDER_DIFFUSE)
                assert_true(st1.bounce > 0 && st1.shadow > 0);
            s.threads = 3;
            float *img = render_new(scene, &s, &st);
            assert_int_equal(differing(&s, ref, img), 0);
            assert_true(memcmp(&st, &st1, offsetof(render_stats, seconds)) == 0);
            free(img);
            s.threads = 2;
            s.api = RENDER_API_STREAM;
            img = render_new(scene, &s, &st);
            if (differing(&s, ref, img))
                fail_msg("%s %s stream: %zu of %zu pixels differ from single rays", backend_names[b],
                         render_mode_name((render_mode)mode), differing(&s, ref, img), pixels(&s));
            assert_true(memcmp(&st, &st1, offsetof(render_stats, seconds)) == 0);
            free(img);
            for (int api = 4; api <= 16; api *= 2) {
                s.api = api;
                img = render_new(scene, &s, &st);
                const size_t diff = differing(&s, ref, img);
                if (!strcmp(backend_names[b], "scalar"))
                    assert_int_equal(diff, 0);
                else if (diff * 1000 > pixels(&s))
                    fail_msg("%s %s packet%d: %zu of %zu pixels differ from single rays", backend_names[b],
                             render_mode_name((render_mode)mode), api, diff, pixels(&s));
                assert_true(st.primary == st1.primary);
                free(img);
            }
            free(ref);
        }
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
}

/* A cube: 12 triangles, outward winding. */
static const float cube_v[8 * 3] = {-1, -1, -1, 1, -1, -1, 1, 1, -1, -1, 1, -1,
                                    -1, -1, 1,  1, -1, 1,  1, 1, 1,  -1, 1, 1};
static const uint32_t cube_i[12 * 3] = {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
                                        3, 7, 6, 3, 6, 2, 0, 4, 7, 0, 7, 3, 1, 2, 6, 1, 6, 5};

/* A white furnace: sky and ground of radiance 1, no sun, albedo a.  A ray
 * leaving a convex object never comes back, so a pixel on the cube is
 * exactly a (one bounce escapes with throughput a), and 0 when no bounce
 * is allowed; with Russian roulette from the first bounce, paths end or
 * carry a / keep, and the mean must still be a. */
static void test_white_furnace(void **state)
{
    (void)state;
    rtk_scene scene = test_scene(best, cube_v, 8, cube_i, 12);
    render_settings s;
    render_defaults(&s, (const float[3]){-1, -1, -1}, (const float[3]){1, 1, 1}, 40, 30);
    s.mode = RENDER_DIFFUSE;
    for (int k = 0; k < 3; k++) {
        s.sky_zenith[k] = s.sky_horizon[k] = s.ground[k] = 1.0f;
        s.sun[k] = 0.0f;
        s.albedo[k] = 0.6f;
    }
    for (int api = 1; api; api = next_api(api)) {
        s.api = api;
        s.max_bounces = 4;
        render_stats st;
        float *img = render_new(scene, &s, &st);
        size_t hits = 0;
        for (size_t i = 0; i < pixels(&s) * 3; i++) {
            const float v = img[i];
            if (fabsf(v - 1.0f) > 1e-6f) {
                assert_float_equal(v, 0.6f, 1e-6f);
                hits++;
            }
        }
        assert_true(hits / 3 == st.primary_hits);
        assert_true(st.bounce == st.primary_hits && st.shadow == 0);
        free(img);

        s.max_bounces = 0;
        img = render_new(scene, &s, &st);
        size_t dark = 0;
        for (size_t i = 0; i < pixels(&s) * 3; i++)
            dark += img[i] == 0.0f;
        assert_true(dark / 3 == st.primary_hits && st.bounce == 0);
        free(img);
    }

    /* the cube's pixels: black without bounces (one sample per pixel, at
     * its centre, so no pixel is partly sky) */
    s.api = 8;
    s.max_bounces = 0;
    float *mask = render_new(scene, &s, NULL);
    s.max_bounces = 4;
    s.rr_depth = 1;
    double sum = 0.0;
    size_t n = 0;
    uint64_t bounces = 0, hits = 0;
    for (uint32_t seed = 1; seed <= 64; seed++) {
        s.seed = seed;
        render_stats st;
        float *img = render_new(scene, &s, &st);
        for (size_t i = 0; i < pixels(&s) * 3; i++)
            if (mask[i] == 0.0f) {
                assert_true(img[i] == 0.0f || img[i] == 1.0f);
                sum += img[i];
                n++;
            }
        bounces += st.bounce;
        hits += st.primary_hits;
        free(img);
    }
    /* each sample is 0, or 0.6 / 0.6 = 1 with probability 0.6: over 64
     * samples of every cube pixel the standard error is near 0.003 */
    printf("furnace with Russian roulette from the first bounce: mean %.4f over %zu samples\n", sum / (double)n, n);
    assert_true(n > 1000 && bounces < hits);
    assert_float_equal(sum / (double)n, 0.6, 0.015);
    free(mask);
    rtk_scene_release(scene);
}

/* Where the ray through the centre of pixel (x, y) would go, inverted: the
 * pixel position at which point p is seen. */
static void project(const render_camera *c, int w, int h, const float p[3], float *x, float *y)
{
    float d[3], fwd[3], r[3], dn[3];
    float lu = 0, lv = 0;
    for (int k = 0; k < 3; k++) {
        d[k] = p[k] - c->eye[k];
        fwd[k] = c->corner[k] + 0.5f * (float)w * c->du[k] + 0.5f * (float)h * c->dv[k];
        lu += c->du[k] * c->du[k];
        lv += c->dv[k] * c->dv[k];
    }
    float df = 0, dr = 0, dd = 0;
    for (int k = 0; k < 3; k++) {
        r[k] = c->du[k] / sqrtf(lu);
        dn[k] = c->dv[k] / sqrtf(lv);
        df += d[k] * fwd[k];
        dr += d[k] * r[k];
        dd += d[k] * dn[k];
    }
    *x = 0.5f * (float)w + dr / df / sqrtf(lu);
    *y = 0.5f * (float)h + dd / df / sqrtf(lv);
}

static const float *pixel_at(const render_settings *s, const float *img, const float p[3])
{
    float x, y;
    project(&s->camera, s->width, s->height, p, &x, &y);
    assert_true(x >= 0 && y >= 0 && x < (float)s->width && y < (float)s->height);
    return &img[((size_t)y * (size_t)s->width + (size_t)x) * 3];
}

/* A ground square (y = 0) and, half a unit above it, a small square that
 * shades it; the sun at 45 degrees from +x, sky black, direct light only:
 * lit ground is albedo / pi * sun * cos 45 exactly, the shadow (shifted
 * half a unit towards -x) is black, the occluder's top lit like the
 * ground. */
static void test_sun_and_shadow(void **state)
{
    (void)state;
    const float v[8 * 3] = {-2, 0, -2, 2, 0, -2, 2, 0, 2, -2, 0, 2, -0.25f, 0.5f, -0.25f, 0.25f, 0.5f, -0.25f,
                            0.25f, 0.5f, 0.25f, -0.25f, 0.5f, 0.25f};
    const uint32_t idx[4 * 3] = {0, 2, 1, 0, 3, 2, 4, 6, 5, 4, 7, 6};
    rtk_scene scene = test_scene(best, v, 8, idx, 4);
    render_settings s;
    render_defaults(&s, (const float[3]){-2, 0, -2}, (const float[3]){2, 0.5f, 2}, 64, 64);
    char err[256];
    assert_int_equal(render_camera_look(&s.camera, (const float[3]){0, 4, 0}, (const float[3]){0, 0, 0},
                                        (const float[3]){0, 0, -1}, 70, 64, 64, err, sizeof err),
                     0);
    s.mode = RENDER_DIFFUSE;
    s.max_bounces = 0;
    for (int k = 0; k < 3; k++) {
        s.sky_zenith[k] = s.sky_horizon[k] = s.ground[k] = 0.0f;
        s.sun[k] = 1.0f;
        s.albedo[k] = 0.5f;
    }
    memcpy(s.sun_dir, (const float[3]){1, 1, 0}, sizeof s.sun_dir);
    const float lit = 0.5f / 3.14159265f * sqrtf(0.5f);
    for (int api = 1; api; api = next_api(api)) {
        s.api = api;
        render_stats st;
        float *img = render_new(scene, &s, &st);
        const float *sunny = pixel_at(&s, img, (const float[3]){1.0f, 0, 0.3f});
        const float *shade = pixel_at(&s, img, (const float[3]){-0.5f, 0, 0});
        const float *top = pixel_at(&s, img, (const float[3]){0, 0.5f, 0});
        const float *sky = pixel_at(&s, img, (const float[3]){2.5f, 0, 0});
        for (int k = 0; k < 3; k++) {
            assert_float_equal(sunny[k], lit, 1e-5f);
            assert_float_equal(shade[k], 0.0f, 0.0f);
            assert_float_equal(top[k], lit, 1e-5f);
            assert_float_equal(sky[k], 0.0f, 0.0f);
        }
        assert_true(st.shadow == st.primary_hits && st.bounce == 0);
        free(img);
    }
    rtk_scene_release(scene);
}

/* Eye light and normals on a square facing the camera: the centre is lit
 * by cos 1; the normal follows the winding (reversed winding, reversed
 * normal), the eye light does not; misses are the background. */
static void test_eyelight_and_normals(void **state)
{
    (void)state;
    const float v[4 * 3] = {-1, 0, -1, 1, 0, -1, 1, 0, 1, -1, 0, 1};
    const uint32_t up[2 * 3] = {0, 2, 1, 0, 3, 2}, down[2 * 3] = {0, 1, 2, 0, 2, 3};
    for (int w = 0; w < 2; w++) {
        rtk_scene scene = test_scene(best, v, 4, w ? down : up, 2);
        render_settings s;
        render_defaults(&s, (const float[3]){-1, 0, -1}, (const float[3]){1, 0, 1}, 32, 32);
        char err[256];
        assert_int_equal(render_camera_look(&s.camera, (const float[3]){0, 3, 0}, (const float[3]){0, 0, 0},
                                            (const float[3]){0, 0, -1}, 60, 32, 32, err, sizeof err),
                         0);
        s.mode = RENDER_NORMALS;
        float *img = render_new(scene, &s, NULL);
        const float *c = pixel_at(&s, img, (const float[3]){0, 0, 0});
        assert_float_equal(c[0], 0.5f, 1e-6f);
        assert_float_equal(c[1], w ? 0.0f : 1.0f, 1e-6f);
        assert_float_equal(c[2], 0.5f, 1e-6f);
        free(img);
        s.mode = RENDER_EYELIGHT;
        img = render_new(scene, &s, NULL);
        c = pixel_at(&s, img, (const float[3]){0.05f, 0, 0.05f});
        assert_float_equal(c[0], 0.95f, 1e-3f);
        assert_float_equal(c[1], 0.85f, 1e-3f);
        assert_float_equal(c[2], 0.70f, 1e-3f);
        assert_memory_equal(img, s.background, sizeof s.background); /* the corner misses */
        free(img);
        rtk_scene_release(scene);
    }
}

/* Ambient occlusion: a square seen from above is never occluded (exactly
 * 1), nor is its underside with a lid 0.1 above it (the rays go down); the
 * top under that lid, with rays 1 long and the lid's edge 1.5 away, is
 * open only to rays flatter than asin(0.1): about 1% of them. */
static void test_ao(void **state)
{
    (void)state;
    const float v[8 * 3] = {-2, 0, -2, 2, 0, -2, 2, 0, 2, -2, 0, 2, -2, 0.1f, -2, 2, 0.1f, -2, 2, 0.1f, 2, -2, 0.1f, 2};
    const uint32_t idx[4 * 3] = {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7};
    static const struct {
        int lid;
        float eye[3], up[3], at[3], fov, low, high;
    } views[] = {
        {0, {0, 3, 0}, {0, 0, -1}, {0.5f, 0, 0}, 40, 1.0f, 1.0f},
        {1, {0, -3, 0}, {0, 0, -1}, {0.5f, 0, 0}, 40, 1.0f, 1.0f},
        {1, {-1, 0.09f, 0}, {0, 1, 0}, {0.5f, 0, 0}, 20, 0.0f, 0.05f},
    };
    for (size_t i = 0; i < sizeof views / sizeof *views; i++) {
        rtk_scene scene = test_scene(best, v, views[i].lid ? 8 : 4, idx, views[i].lid ? 4 : 2);
        render_settings s;
        render_defaults(&s, (const float[3]){-2, 0, -2}, (const float[3]){2, 0.1f, 2}, 16, 16);
        char err[256];
        assert_int_equal(render_camera_look(&s.camera, views[i].eye, (const float[3]){0, 0, 0}, views[i].up,
                                            views[i].fov, 16, 16, err, sizeof err),
                         0);
        s.mode = RENDER_AO;
        s.ao_distance = 1.0f;
        s.ao_samples = 64;
        for (int api = 1; api; api = next_api(api)) {
            s.api = api;
            render_stats st;
            float *img = render_new(scene, &s, &st);
            const float *c = pixel_at(&s, img, views[i].at);
            assert_true(c[0] >= views[i].low && c[0] <= views[i].high);
            assert_true(c[0] == c[1] && c[1] == c[2]);
            if (i < 2) {
                assert_true(st.primary_hits == pixels(&s));
                for (size_t p = 0; p < pixels(&s) * 3; p++)
                    assert_true(img[p] == 1.0f);
            }
            free(img);
        }
        rtk_scene_release(scene);
    }
}

static void test_camera_parse(void **state)
{
    (void)state;
    render_camera c;
    char err[256];
    assert_int_equal(render_camera_parse(&c, "0,1,3/0,0,0/0,1,0/35", 10, 10, err, sizeof err), 0);
    assert_float_equal(c.fov, 35.0f, 0.0f);
    assert_float_equal(c.eye[2], 3.0f, 0.0f);
    assert_int_equal(render_camera_parse(&c, "0,1,3/0,0,0", 10, 10, err, sizeof err), 0);
    assert_float_equal(c.fov, 40.0f, 0.0f);
    assert_float_equal(c.up[1], 1.0f, 0.0f);
    assert_int_equal(render_camera_parse(&c, "0,1,3/0,0,0/1,0,0", 10, 10, err, sizeof err), 0);
    static const char *const bad[] = {"",          "0,1,3",        "0,1/0,0,0",       "0,1,3/0,0,0/",
                                      "0,1,3/0,0", "1,1,1/1,1,1",  "0,1,0/0,0,0",     "0,1,3/0,0,0/0,1,0/0",
                                      "a,b,c/0,0,0", "0,1,3/0,0,0/0,1,0/180", "nan,0,0/0,0,0", "0,1,3/0,0,0/0,1,0/40x",
                                      "0,0,1e39/0,0,0"};
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        err[0] = 0;
        if (!render_camera_parse(&c, bad[i], 10, 10, err, sizeof err))
            fail_msg("camera '%s' accepted", bad[i]);
        assert_true(strlen(err) > 10);
    }
}

static void test_bad_settings(void **state)
{
    (void)state;
    render_settings s;
    bunny_settings(best_scene, &s, 8, 8, RENDER_EYELIGHT);
    float rgb[8 * 8 * 3];
    render_stats st;
    char err[256];
    render_tracer t = render_tracer_rtk(best_scene);
    const render_settings good = s;
    s.api = 3;
    assert_int_not_equal(render_image(&t, &s, rgb, &st, err, sizeof err), 0);
    s = good;
    s.spp = 0;
    assert_int_not_equal(render_image(&t, &s, rgb, &st, err, sizeof err), 0);
    s = good;
    s.width = 0;
    assert_int_not_equal(render_image(&t, &s, rgb, &st, err, sizeof err), 0);
    s = good;
    s.mode = (render_mode)7;
    assert_int_not_equal(render_image(&t, &s, rgb, &st, err, sizeof err), 0);
    s = good;
    s.api = 16;
    t.occluded16 = NULL;
    assert_int_not_equal(render_image(&t, &s, rgb, &st, err, sizeof err), 0);
    assert_non_null(strstr(err, "no functions"));
    s.api = 8;
    assert_int_equal(render_image(&t, &s, rgb, &st, err, sizeof err), 0);
    render_mode m;
    assert_int_not_equal(render_mode_parse("pathtrace", &m), 0);
    assert_int_equal(render_mode_parse("ao", &m), 0);
    assert_int_equal(m, RENDER_AO);
}

/* ---- reference images ---- */

typedef struct image_diff {
    double mean;  /* mean absolute difference per channel, in 8-bit levels */
    double large; /* share of pixels with a channel more than 24 levels off */
} image_diff;

static image_diff compare8(const unsigned char *a, const unsigned char *b, size_t n)
{
    image_diff d = {0, 0};
    for (size_t i = 0; i < n; i++) {
        int worst = 0;
        for (int k = 0; k < 3; k++) {
            const int e = abs((int)a[3 * i + (size_t)k] - (int)b[3 * i + (size_t)k]);
            d.mean += e;
            worst = e > worst ? e : worst;
        }
        d.large += worst > 24;
    }
    d.mean /= 3.0 * (double)n;
    d.large /= (double)n;
    return d;
}

/* The bunny in each mode against tests/reference/render_MODE.png, within a
 * tolerance for other backends and CPUs (float rounding moves AO and
 * diffuse samples, never the picture): a mean difference of at most one
 * level and at most 1% of the pixels far off.  The same comparison between
 * two different modes must fail it, so the tolerance can fail. */
static void test_reference_images(void **state)
{
    (void)state;
    const int w = 96, h = 72;
    unsigned char *mine[4];
    const int update = getenv("RTK_UPDATE_REFERENCE") && !strcmp(getenv("RTK_UPDATE_REFERENCE"), "1");
    for (int mode = 0; mode < 4; mode++) {
        render_settings s;
        bunny_settings(best_scene, &s, w, h, (render_mode)mode);
        s.spp = mode == RENDER_EYELIGHT || mode == RENDER_NORMALS ? 1 : 16;
        s.threads = 2;
        s.api = 8;
        float *img = render_new(best_scene, &s, NULL);
        mine[mode] = malloc(pixels(&s) * 3);
        render_to_rgb8(&s, img, mine[mode]);
        free(img);
        char path[512], err[512];
        snprintf(path, sizeof path, "%s/render_%s.png", RTK_TEST_REFERENCE, render_mode_name((render_mode)mode));
        if (update) {
            if (rtk_png_write_rgb(path, mine[mode], w, h, err, sizeof err))
                fail_msg("%s", err);
            printf("wrote %s\n", path);
            continue;
        }
        unsigned char *ref;
        int rw, rh;
        if (rtk_png_read_rgb(path, &ref, &rw, &rh, err, sizeof err))
            fail_msg("%s", err);
        assert_int_equal(rw, w);
        assert_int_equal(rh, h);
        const image_diff d = compare8(mine[mode], ref, pixels(&s));
        printf("%s: mean difference %.3f levels, %.2f%% of pixels more than 24 off\n",
               render_mode_name((render_mode)mode), d.mean, 100.0 * d.large);
        if (d.mean > 1.0 || d.large > 0.01)
            fail_msg("render_%s differs from its reference: mean %.3f levels, %.2f%% far off", render_mode_name(
                         (render_mode)mode), d.mean, 100.0 * d.large);
        free(ref);
    }
    for (int mode = 1; mode < 4; mode++) {
        const image_diff d = compare8(mine[0], mine[mode], (size_t)w * h);
        assert_true(d.mean > 1.0 || d.large > 0.01);
    }
    for (int mode = 0; mode < 4; mode++)
        free(mine[mode]);
    unsigned char *ref;
    int rw, rh;
    char err[512];
    assert_int_not_equal(rtk_png_read_rgb(RTK_TEST_DATA "/bunny.ply", &ref, &rw, &rh, err, sizeof err), 0);
    assert_non_null(strstr(err, "not a PNG"));
    assert_int_not_equal(rtk_png_read_rgb("/nonexistent.png", &ref, &rw, &rh, err, sizeof err), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_threads_and_api_agree), cmocka_unit_test(test_white_furnace),
        cmocka_unit_test(test_sun_and_shadow),        cmocka_unit_test(test_eyelight_and_normals),
        cmocka_unit_test(test_ao),                    cmocka_unit_test(test_camera_parse),
        cmocka_unit_test(test_bad_settings),          cmocka_unit_test(test_reference_images),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
