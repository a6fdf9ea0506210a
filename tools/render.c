#define _POSIX_C_SOURCE 200809L
#include "render.h"

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* ---- modes and cameras ---- */

static const char *const mode_names[] = {"eyelight", "normals", "ao", "diffuse"};

const char *render_mode_name(render_mode mode)
{
    return (unsigned)mode < 4 ? mode_names[mode] : NULL;
}

int render_mode_parse(const char *name, render_mode *mode)
{
    for (int i = 0; i < 4; i++)
        if (!strcmp(name, mode_names[i])) {
            *mode = (render_mode)i;
            return 0;
        }
    return 1;
}

static const char *const api_names[] = {"single", "packet4", "packet8", "packet16", "stream"};
static const int api_widths[] = {1, 4, 8, 16, RENDER_API_STREAM};

const char *render_api_name(int api)
{
    for (int i = 0; i < 5; i++)
        if (api == api_widths[i])
            return api_names[i];
    return NULL;
}

int render_api_parse(const char *name)
{
    for (int i = 0; i < 5; i++)
        if (!strcmp(name, api_names[i]))
            return api_widths[i];
    return 0;
}

static float dot3(const float a[3], const float b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross3(const float a[3], const float b[3], float c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

/* Normalises v in place; its old length (0 leaves v alone). */
static float normalize3(float v[3])
{
    const float l = sqrtf(dot3(v, v));
    if (l > 0.0f)
        for (int k = 0; k < 3; k++)
            v[k] /= l;
    return l;
}

int render_camera_look(render_camera *cam, const float eye[3], const float target[3], const float up[3], float fov,
                       int w, int h, char *err, size_t err_size)
{
    for (int k = 0; k < 3; k++)
        if (!isfinite(eye[k]) || !isfinite(target[k]) || !isfinite(up[k])) {
            snprintf(err, err_size, "the camera's eye, target and up must be finite");
            return 1;
        }
    if (!(fov > 0.0f && fov < 180.0f)) {
        snprintf(err, err_size, "the camera's field of view must be between 0 and 180 degrees");
        return 1;
    }
    float fwd[3] = {target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]}, u[3] = {up[0], up[1], up[2]};
    float right[3], vup[3];
    if (!(normalize3(fwd) > 0.0f) || !isfinite(fwd[0] + fwd[1] + fwd[2])) {
        snprintf(err, err_size, "the camera's eye and target must differ");
        return 1;
    }
    normalize3(u);
    cross3(fwd, u, right);
    if (!(normalize3(right) > 1e-6f)) {
        snprintf(err, err_size, "the camera's up must not be parallel to its view");
        return 1;
    }
    cross3(right, fwd, vup);
    const float half_h = tanf(0.5f * fov * 3.14159265f / 180.0f), half_w = half_h * (float)w / (float)h;
    for (int k = 0; k < 3; k++) {
        cam->eye[k] = eye[k];
        cam->target[k] = target[k];
        cam->up[k] = up[k];
        cam->du[k] = right[k] * (2.0f * half_w / (float)w);
        cam->dv[k] = -vup[k] * (2.0f * half_h / (float)h);
        cam->corner[k] = fwd[k] - right[k] * half_w + vup[k] * half_h;
    }
    cam->fov = fov;
    return 0;
}

void render_camera_frame(render_camera *cam, const float lo[3], const float hi[3], int w, int h)
{
    float center[3], extent = 0.0f;
    int finite = 1;
    for (int k = 0; k < 3; k++) {
        finite &= isfinite(lo[k]) && isfinite(hi[k]) && lo[k] <= hi[k];
        center[k] = finite ? 0.5f * (lo[k] + hi[k]) : 0.0f;
        extent = finite ? fmaxf(extent, hi[k] - lo[k]) : 1.0f;
    }
    if (!(extent > 0.0f))
        extent = 1.0f;
    const float fov = 40.0f, half_h = tanf(0.5f * fov * 3.14159265f / 180.0f), half_w = half_h * (float)w / (float)h;
    float view[3] = {0.35f, 0.3f, 1.0f}, up[3] = {0, 1, 0}, right[3], vup[3];
    normalize3(view);
    float fwd[3] = {-view[0], -view[1], -view[2]};
    cross3(fwd, up, right);
    normalize3(right);
    cross3(right, fwd, vup);
    /* At depth dist + z, a corner at (x, y) across the view fits when |x| <=
     * (dist + z) * half_w and |y| <= (dist + z) * half_h. */
    float dist = 0.0f;
    for (int i = 0; i < 8 && finite; i++) {
        const float p[3] = {(i & 1 ? hi[0] : lo[0]) - center[0], (i & 2 ? hi[1] : lo[1]) - center[1],
                            (i & 4 ? hi[2] : lo[2]) - center[2]};
        const float x = dot3(p, right), y = dot3(p, vup), z = dot3(p, fwd);
        dist = fmaxf(dist, fabsf(x) / (0.95f * half_w) - z);
        dist = fmaxf(dist, fabsf(y) / (0.95f * half_h) - z);
    }
    if (!(dist > 0.0f))
        dist = extent;
    float eye[3];
    for (int k = 0; k < 3; k++)
        eye[k] = center[k] + view[k] * dist;
    char err[128];
    if (render_camera_look(cam, eye, center, up, fov, w, h, err, sizeof err))
        render_camera_look(cam, (const float[3]){0, 0, 1}, (const float[3]){0, 0, 0}, up, fov, w, h, err,
                           sizeof err);
}

/* "x,y,z" into v; the end of what it read, NULL when malformed. */
static const char *parse_vec3(const char *s, float v[3])
{
    for (int k = 0; k < 3; k++) {
        char *end;
        v[k] = strtof(s, &end);
        if (end == s || (k < 2 && *end != ','))
            return NULL;
        s = k < 2 ? end + 1 : end;
    }
    return s;
}

int render_camera_parse(render_camera *cam, const char *spec, int w, int h, char *err, size_t err_size)
{
    float eye[3], target[3], up[3] = {0, 1, 0}, fov = 40.0f;
    const char *s = parse_vec3(spec, eye);
    if (s && *s == '/')
        s = parse_vec3(s + 1, target);
    else
        s = NULL;
    if (s && *s == '/')
        s = parse_vec3(s + 1, up);
    if (s && *s == '/') {
        char *end;
        fov = strtof(s + 1, &end);
        s = end == s + 1 ? NULL : end;
    }
    if (!s || *s) {
        snprintf(err, err_size, "--camera wants EX,EY,EZ/TX,TY,TZ[/UX,UY,UZ[/FOV]], e.g. 0,1,3/0,0,0/0,1,0/40");
        return 1;
    }
    return render_camera_look(cam, eye, target, up, fov, w, h, err, err_size);
}

/* ---- the tracer table for rtk ---- */

static void rtk_i1(void *s, rtk_rayhit *rh)
{
    rtk_intersect1(s, rh);
}
static void rtk_o1(void *s, rtk_ray *r)
{
    rtk_occluded1(s, r);
}
#define RTK_PACKET_WRAPPERS_(N)                                                                                        \
    static void rtk_i##N(void *s, const int *valid, rtk_rayhit##N *rh)                                                 \
    {                                                                                                                  \
        rtk_intersect##N(s, valid, rh);                                                                                \
    }                                                                                                                  \
    static void rtk_o##N(void *s, const int *valid, rtk_ray##N *r)                                                     \
    {                                                                                                                  \
        rtk_occluded##N(s, valid, r);                                                                                  \
    }
RTK_PACKET_WRAPPERS_(4)
RTK_PACKET_WRAPPERS_(8)
RTK_PACKET_WRAPPERS_(16)
static void rtk_i1M(void *s, rtk_rayhit *rh, unsigned n, size_t stride)
{
    rtk_intersect1M(s, rh, n, stride);
}
static void rtk_o1M(void *s, rtk_ray *r, unsigned n, size_t stride)
{
    rtk_occluded1M(s, r, n, stride);
}

render_tracer render_tracer_rtk(rtk_scene scene)
{
    return (render_tracer){scene, rtk_i1, rtk_o1, rtk_i4, rtk_o4, rtk_i8, rtk_o8, rtk_i16, rtk_o16, rtk_i1M, rtk_o1M};
}

/* ---- settings ---- */

void render_defaults(render_settings *s, const float lo[3], const float hi[3], int w, int h)
{
    float diag = 0.0f, far = 0.0f;
    for (int k = 0; k < 3; k++) {
        const float e = hi[k] - lo[k];
        if (isfinite(e) && e > 0.0f)
            diag += e * e;
        if (isfinite(lo[k]) && isfinite(hi[k]))
            far = fmaxf(far, fmaxf(fabsf(lo[k]), fabsf(hi[k])));
    }
    diag = diag > 0.0f ? sqrtf(diag) : 1.0f;
    *s = (render_settings){
        .width = w,
        .height = h,
        .spp = 1,
        .mode = RENDER_EYELIGHT,
        .api = 1,
        .threads = 1,
        .max_bounces = 4,
        .rr_depth = 2,
        .ao_samples = 8,
        .ao_distance = 0.1f * diag,
        .eps = 1e-5f * fmaxf(far, 1e-3f * diag),
        .albedo = {0.75f, 0.75f, 0.75f},
        .sky_zenith = {0.25f, 0.35f, 0.6f},
        .sky_horizon = {0.65f, 0.65f, 0.65f},
        .ground = {0.2f, 0.19f, 0.18f},
        .up = {0, 1, 0},
        .sun_dir = {0.5f, 1.0f, 0.7f},
        .sun = {1.8f, 1.65f, 1.4f},
        .background = {24.0f / 255, 26.0f / 255, 32.0f / 255},
        .seed = 1,
    };
    render_camera_frame(&s->camera, lo, hi, w, h);
}

uint64_t render_stats_rays(const render_stats *st)
{
    return st->primary + st->bounce + st->shadow + st->ao;
}

/* ---- one path: the code every lane of every API runs ---- */

/* PCG32 (O'Neill), one stream per path. */
typedef struct rng {
    uint64_t state;
} rng;

static uint32_t rng_next(rng *g)
{
    const uint64_t old = g->state;
    g->state = old * 6364136223846793005ull + 1442695040888963407ull;
    const uint32_t x = (uint32_t)(((old >> 18) ^ old) >> 27), r = (uint32_t)(old >> 59);
    return (x >> r) | (x << ((32 - r) & 31));
}

static float rng_float(rng *g)
{
    return (float)(rng_next(g) >> 8) * 0x1p-24f;
}

static uint64_t mix64(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

typedef struct path {
    rng g;
    rtk_ray ray;        /* the next closest-hit ray, while alive */
    rtk_ray side;       /* the pending any-hit ray (shadow or ao), while side_pending */
    float thr[3], L[3]; /* throughput and radiance so far */
    float sun_L[3];     /* what the sun adds when the shadow ray is not blocked */
    float p[3], n[3];   /* ao: the hit and its normal facing the camera */
    int depth;          /* surface hits so far */
    int alive, side_pending, ao_hit, ao_open;
} path;

typedef struct hit_info {
    int hit;
    float t, Ng[3];
} hit_info;

typedef struct ctx {
    const render_tracer *tracer;
    const render_settings *s;
    float sun_dir[3], up[3], inv_pi_albedo[3];
    int sun_on; /* a sun that is not black: shadow rays */
} ctx;

static void make_ray(rtk_ray *r, const float org[3], const float dir[3], float tfar)
{
    *r = (rtk_ray){.org_x = org[0], .org_y = org[1], .org_z = org[2], .dir_x = dir[0], .dir_y = dir[1],
                   .dir_z = dir[2], .tfar = tfar, .mask = ~0u};
}

static void path_start(const ctx *c, path *q, int x, int y, int sample)
{
    const render_settings *s = c->s;
    memset(q, 0, sizeof *q);
    q->g.state = mix64(mix64(((uint64_t)s->seed << 32) ^ ((uint64_t)y * (uint64_t)s->width + (uint64_t)x)) +
                       (uint64_t)sample);
    rng_next(&q->g);
    float jx = 0.5f, jy = 0.5f;
    if (s->spp > 1) {
        jx = rng_float(&q->g);
        jy = rng_float(&q->g);
    }
    const render_camera *cam = &s->camera;
    float d[3];
    for (int k = 0; k < 3; k++) {
        d[k] = cam->corner[k] + ((float)x + jx) * cam->du[k] + ((float)y + jy) * cam->dv[k];
        q->thr[k] = 1.0f;
    }
    make_ray(&q->ray, cam->eye, d, INFINITY);
    q->alive = 1;
}

void render_cosine_dir(const float n[3], float u1, float u2, float out[3])
{
    float a[3] = {0, 0, 0}, t[3], b[3];
    a[fabsf(n[0]) > 0.9f ? 1 : 0] = 1.0f;
    cross3(a, n, t);
    normalize3(t);
    cross3(n, t, b);
    const float r = sqrtf(u1), phi = 6.2831853f * u2;
    const float x = r * cosf(phi), y = r * sinf(phi), z = sqrtf(fmaxf(0.0f, 1.0f - x * x - y * y));
    for (int k = 0; k < 3; k++)
        out[k] = x * t[k] + y * b[k] + z * n[k];
}

static void cosine_dir(rng *g, const float n[3], float out[3])
{
    const float u1 = rng_float(g);
    render_cosine_dir(n, u1, rng_float(g), out);
}

static void sky(const ctx *c, const float dir[3], float out[3])
{
    const render_settings *s = c->s;
    float d[3] = {dir[0], dir[1], dir[2]};
    normalize3(d);
    const float h = dot3(d, c->up);
    for (int k = 0; k < 3; k++)
        out[k] = h < 0.0f ? s->ground[k] : s->sky_horizon[k] + (s->sky_zenith[k] - s->sky_horizon[k]) * h;
}

/* The hit point, offset by eps along the normal that faces the incoming
 * ray (returned in n). */
static void surface(const ctx *c, const path *q, const hit_info *h, float p[3], float n[3])
{
    const float d[3] = {q->ray.dir_x, q->ray.dir_y, q->ray.dir_z}, o[3] = {q->ray.org_x, q->ray.org_y, q->ray.org_z};
    memcpy(n, h->Ng, sizeof h->Ng);
    normalize3(n);
    const float side = dot3(n, d) > 0.0f ? -1.0f : 1.0f;
    for (int k = 0; k < 3; k++) {
        n[k] *= side;
        p[k] = o[k] + h->t * d[k] + c->s->eps * n[k];
    }
}

/* What happens at the end of q->ray: colour for the primary-only modes,
 * the ao hit, or a path tracer step (the sun's shadow ray, the next ray). */
static void path_shade(const ctx *c, path *q, const hit_info *h)
{
    const render_settings *s = c->s;
    q->alive = 0;
    if (s->mode != RENDER_DIFFUSE && !h->hit) {
        memcpy(q->L, s->background, sizeof q->L);
        return;
    }
    if (s->mode == RENDER_EYELIGHT || s->mode == RENDER_NORMALS) {
        float n[3] = {h->Ng[0], h->Ng[1], h->Ng[2]}, d[3] = {q->ray.dir_x, q->ray.dir_y, q->ray.dir_z};
        normalize3(n);
        normalize3(d);
        static const float tint[3] = {0.95f, 0.85f, 0.70f};
        const float v = 0.1f + 0.9f * fabsf(dot3(n, d));
        for (int k = 0; k < 3; k++)
            q->L[k] = s->mode == RENDER_NORMALS ? 0.5f + 0.5f * n[k] : v * tint[k];
        return;
    }
    if (s->mode == RENDER_AO) {
        surface(c, q, h, q->p, q->n);
        q->ao_hit = 1;
        return;
    }
    if (!h->hit) {
        const float d[3] = {q->ray.dir_x, q->ray.dir_y, q->ray.dir_z};
        float L[3];
        sky(c, d, L);
        for (int k = 0; k < 3; k++)
            q->L[k] += q->thr[k] * L[k];
        return;
    }
    q->depth++;
    float p[3], n[3], d[3];
    surface(c, q, h, p, n);
    const float cos_sun = dot3(n, c->sun_dir);
    if (cos_sun > 0.0f && c->sun_on) {
        for (int k = 0; k < 3; k++)
            q->sun_L[k] = q->thr[k] * c->inv_pi_albedo[k] * s->sun[k] * cos_sun;
        make_ray(&q->side, p, c->sun_dir, INFINITY);
        q->side_pending = 1;
    }
    if (q->depth > s->max_bounces)
        return;
    /* cosine-weighted sampling: the BRDF's albedo / pi times cos over the
     * density cos / pi leaves the albedo */
    cosine_dir(&q->g, n, d);
    for (int k = 0; k < 3; k++)
        q->thr[k] *= s->albedo[k];
    if (q->depth >= s->rr_depth) {
        const float keep = fminf(0.95f, fmaxf(q->thr[0], fmaxf(q->thr[1], q->thr[2])));
        if (!(rng_float(&q->g) < keep))
            return;
        for (int k = 0; k < 3; k++)
            q->thr[k] /= keep;
    }
    make_ray(&q->ray, p, d, INFINITY);
    q->alive = 1;
}

/* The sun's shadow ray came back. */
static void path_side_done(path *q, int occluded)
{
    q->side_pending = 0;
    if (!occluded)
        for (int k = 0; k < 3; k++)
            q->L[k] += q->sun_L[k];
}

static void ao_ray(const ctx *c, path *q)
{
    float d[3];
    cosine_dir(&q->g, q->n, d);
    make_ray(&q->side, q->p, d, c->s->ao_distance);
}

static void path_finish(const ctx *c, path *q)
{
    if (c->s->mode == RENDER_AO && q->ao_hit) {
        const float v = (float)q->ao_open / (float)c->s->ao_samples;
        q->L[0] = q->L[1] = q->L[2] = v;
    }
}

/* ---- single rays ---- */

typedef struct counts {
    uint64_t primary, primary_hits, bounce, shadow, ao;
} counts;

static hit_info hit_of(const rtk_rayhit *rh)
{
    return (hit_info){rh->hit.geomID != RTK_INVALID_GEOMETRY_ID, rh->ray.tfar, {rh->hit.Ng_x, rh->hit.Ng_y, rh->hit.Ng_z}};
}

static void render_path1(const ctx *c, path *q, counts *n)
{
    const render_tracer *t = c->tracer;
    while (q->alive) {
        _Alignas(16) rtk_rayhit rh = {.ray = q->ray, .hit = {.geomID = RTK_INVALID_GEOMETRY_ID,
                                                             .instID = RTK_INVALID_GEOMETRY_ID}};
        t->intersect1(t->scene, &rh);
        const hit_info h = hit_of(&rh);
        if (q->depth == 0) {
            n->primary++;
            n->primary_hits += (uint64_t)h.hit;
        } else
            n->bounce++;
        path_shade(c, q, &h);
        if (q->side_pending) {
            _Alignas(16) rtk_ray r = q->side;
            t->occluded1(t->scene, &r);
            n->shadow++;
            path_side_done(q, r.tfar == -INFINITY);
        }
    }
    for (int i = 0; q->ao_hit && i < c->s->ao_samples; i++) {
        ao_ray(c, q);
        _Alignas(16) rtk_ray r = q->side;
        t->occluded1(t->scene, &r);
        n->ao++;
        q->ao_open += r.tfar != -INFINITY;
    }
    path_finish(c, q);
}

/* ---- packets: the same paths, N lanes at a time ---- */

#define LOAD_LANE_(P, k, r)                                                                                            \
    do {                                                                                                               \
        (P).org_x[k] = (r)->org_x, (P).org_y[k] = (r)->org_y, (P).org_z[k] = (r)->org_z, (P).tnear[k] = (r)->tnear;     \
        (P).dir_x[k] = (r)->dir_x, (P).dir_y[k] = (r)->dir_y, (P).dir_z[k] = (r)->dir_z, (P).time[k] = (r)->time;      \
        (P).tfar[k] = (r)->tfar, (P).mask[k] = (r)->mask, (P).id[k] = (r)->id, (P).flags[k] = (r)->flags;              \
    } while (0)

#define PACKET_CALL_(N)                                                                                                \
    if (!occluded) {                                                                                                   \
        rtk_rayhit##N P;                                                                                               \
        for (int k = 0; k < N; k++) {                                                                                  \
            const rtk_hit *h_ = &rh[k].hit;                                                                            \
            LOAD_LANE_(P.ray, k, &rh[k].ray);                                                                          \
            P.hit.Ng_x[k] = h_->Ng_x, P.hit.Ng_y[k] = h_->Ng_y, P.hit.Ng_z[k] = h_->Ng_z, P.hit.u[k] = h_->u;          \
            P.hit.v[k] = h_->v, P.hit.primID[k] = h_->primID, P.hit.geomID[k] = h_->geomID;                            \
            P.hit.instID[k] = h_->instID;                                                                              \
        }                                                                                                              \
        t->intersect##N(t->scene, valid, &P);                                                                          \
        for (int k = 0; k < N; k++)                                                                                    \
            if (valid[k]) {                                                                                            \
                rh[k].ray.tfar = P.ray.tfar[k];                                                                        \
                rh[k].hit = (rtk_hit){P.hit.Ng_x[k], P.hit.Ng_y[k], P.hit.Ng_z[k], P.hit.u[k],                         \
                                      P.hit.v[k],    P.hit.primID[k], P.hit.geomID[k], P.hit.instID[k]};               \
            }                                                                                                          \
    } else {                                                                                                           \
        rtk_ray##N P;                                                                                                  \
        for (int k = 0; k < N; k++)                                                                                    \
            LOAD_LANE_(P, k, &rh[k].ray);                                                                              \
        t->occluded##N(t->scene, valid, &P);                                                                           \
        for (int k = 0; k < N; k++)                                                                                    \
            rh[k].ray.tfar = valid[k] ? P.tfar[k] : rh[k].ray.tfar;                                                    \
    }

void render_trace(const render_tracer *t, int n, const int *valid, rtk_rayhit *rh, int occluded)
{
    if (n == 1) {
        if (!valid[0])
            return;
        if (occluded)
            t->occluded1(t->scene, &rh->ray);
        else
            t->intersect1(t->scene, rh);
    } else if (n == 4) {
        PACKET_CALL_(4)
    } else if (n == 8) {
        PACKET_CALL_(8)
    } else {
        PACKET_CALL_(16)
    }
}

enum { MAXN = 16 };

static void render_packet(const ctx *c, path *q, int n, counts *cnt)
{
    const render_tracer *t = c->tracer;
    _Alignas(16) rtk_rayhit rh[MAXN];
    _Alignas(64) int valid[MAXN]; /* Embree wants the mask aligned like the packet */
    for (;;) {
        int any = 0;
        for (int k = 0; k < n; k++) {
            valid[k] = q[k].alive ? -1 : 0;
            any |= q[k].alive;
            rh[k] = (rtk_rayhit){.ray = q[k].ray,
                                 .hit = {.geomID = RTK_INVALID_GEOMETRY_ID, .instID = RTK_INVALID_GEOMETRY_ID}};
        }
        if (!any)
            break;
        render_trace(t, n, valid, rh, 0);
        int side = 0;
        for (int k = 0; k < n; k++) {
            if (!valid[k])
                continue;
            const hit_info h = hit_of(&rh[k]);
            if (q[k].depth == 0) {
                cnt->primary++;
                cnt->primary_hits += (uint64_t)h.hit;
            } else
                cnt->bounce++;
            path_shade(c, &q[k], &h);
            side |= q[k].side_pending;
        }
        if (!side)
            continue;
        for (int k = 0; k < n; k++) {
            valid[k] = q[k].side_pending ? -1 : 0;
            rh[k].ray = q[k].side;
            cnt->shadow += (uint64_t)q[k].side_pending;
        }
        render_trace(t, n, valid, rh, 1);
        for (int k = 0; k < n; k++)
            if (valid[k])
                path_side_done(&q[k], rh[k].ray.tfar == -INFINITY);
    }
    int any_ao = 0;
    for (int k = 0; k < n; k++) {
        valid[k] = q[k].ao_hit ? -1 : 0;
        any_ao |= q[k].ao_hit;
    }
    for (int i = 0; any_ao && i < c->s->ao_samples; i++) {
        for (int k = 0; k < n; k++)
            if (valid[k]) {
                ao_ray(c, &q[k]);
                rh[k].ray = q[k].side;
                cnt->ao++;
            }
        render_trace(t, n, valid, rh, 1);
        for (int k = 0; k < n; k++)
            q[k].ao_open += valid[k] && rh[k].ray.tfar != -INFINITY;
    }
    for (int k = 0; k < n; k++)
        path_finish(c, &q[k]);
}

/* ---- streams: the same paths, a wavefront of a tile at a time ---- */

/* n paths (a tile's, for one sample) traced together: every alive path's
 * next ray in one stream, then every pending shadow ray in another, until
 * none is alive; then each ao sample's rays as one stream.  rh holds n
 * rays; idx the path of each ray in the stream. */
static void render_stream(const ctx *c, path *q, int n, rtk_rayhit *rh, int *idx, counts *cnt)
{
    const render_tracer *t = c->tracer;
    for (;;) {
        int m = 0;
        for (int k = 0; k < n; k++)
            if (q[k].alive) {
                rh[m] = (rtk_rayhit){.ray = q[k].ray,
                                     .hit = {.geomID = RTK_INVALID_GEOMETRY_ID, .instID = RTK_INVALID_GEOMETRY_ID}};
                idx[m++] = k;
            }
        if (!m)
            break;
        t->intersect1M(t->scene, rh, (unsigned)m, sizeof *rh);
        int side = 0;
        for (int j = 0; j < m; j++) {
            path *p = &q[idx[j]];
            const hit_info h = hit_of(&rh[j]);
            if (p->depth == 0) {
                cnt->primary++;
                cnt->primary_hits += (uint64_t)h.hit;
            } else
                cnt->bounce++;
            path_shade(c, p, &h);
            if (p->side_pending) {
                rh[side].ray = p->side;
                idx[side++] = idx[j];
            }
        }
        if (!side)
            continue;
        t->occluded1M(t->scene, &rh[0].ray, (unsigned)side, sizeof *rh);
        cnt->shadow += (uint64_t)side;
        for (int j = 0; j < side; j++)
            path_side_done(&q[idx[j]], rh[j].ray.tfar == -INFINITY);
    }
    for (int i = 0; i < c->s->ao_samples; i++) {
        int m = 0;
        for (int k = 0; k < n; k++)
            if (q[k].ao_hit) {
                ao_ray(c, &q[k]);
                rh[m].ray = q[k].side;
                idx[m++] = k;
            }
        if (!m)
            break;
        t->occluded1M(t->scene, &rh[0].ray, (unsigned)m, sizeof *rh);
        cnt->ao += (uint64_t)m;
        for (int j = 0; j < m; j++)
            q[idx[j]].ao_open += rh[j].ray.tfar != -INFINITY;
    }
    for (int k = 0; k < n; k++)
        path_finish(c, &q[k]);
}

/* ---- tiles over threads ---- */

enum { TILE = 16 };
/* The stream API's tiles: 32 x 32 paths a stream, so that few of a
 * stream's rays are the last ones in flight; a worker's room for them. */
enum { STREAM_TILE = 32 };
typedef struct stream_buf {
    path q[STREAM_TILE * STREAM_TILE];
    _Alignas(16) rtk_rayhit rh[STREAM_TILE * STREAM_TILE];
    int idx[STREAM_TILE * STREAM_TILE];
    float acc[STREAM_TILE * STREAM_TILE][3];
} stream_buf;

typedef struct shared {
    ctx c;
    float *rgb;
    int tiles_x, tiles;
    int next, done; /* atomics */
} shared;

typedef struct worker {
    shared *sh;
    stream_buf *sb; /* the stream API's */
    counts n;
    int report; /* the calling thread: calls progress */
    struct timespec last;
} worker;

static double seconds_since(const struct timespec *t0)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)(t.tv_sec - t0->tv_sec) + 1e-9 * (double)(t.tv_nsec - t0->tv_nsec);
}

/* A tile of the stream API: each sample's paths of the whole tile as
 * one wavefront. */
static void render_tile_stream(shared *sh, int tile, stream_buf *sb, counts *cnt)
{
    const render_settings *s = sh->c.s;
    const int x0 = tile % sh->tiles_x * STREAM_TILE, y0 = tile / sh->tiles_x * STREAM_TILE;
    const int w = s->width - x0 < STREAM_TILE ? s->width - x0 : STREAM_TILE;
    const int h = s->height - y0 < STREAM_TILE ? s->height - y0 : STREAM_TILE;
    const float inv_spp = 1.0f / (float)s->spp;
    path *q = sb->q;
    float(*acc)[3] = sb->acc;
    const int n = w * h;
    memset(acc, 0, sizeof sb->acc);
    for (int sample = 0; sample < s->spp; sample++) {
        for (int k = 0; k < n; k++)
            path_start(&sh->c, &q[k], x0 + k % w, y0 + k / w, sample);
        render_stream(&sh->c, q, n, sb->rh, sb->idx, cnt);
        for (int k = 0; k < n; k++)
            for (int j = 0; j < 3; j++)
                acc[k][j] += q[k].L[j];
    }
    for (int k = 0; k < n; k++)
        for (int j = 0; j < 3; j++)
            sh->rgb[((size_t)(y0 + k / w) * (size_t)s->width + (size_t)(x0 + k % w)) * 3 + (size_t)j] =
                acc[k][j] * inv_spp;
}

static void render_tile(shared *sh, int tile, counts *cnt)
{
    const render_settings *s = sh->c.s;
    const int x0 = tile % sh->tiles_x * TILE, y0 = tile / sh->tiles_x * TILE;
    const int pw = s->api == 4 ? 2 : 4, ph = s->api == 16 ? 4 : s->api / pw;
    const float inv_spp = 1.0f / (float)s->spp;
    path q[MAXN];
    for (int by = y0; by < y0 + TILE && by < s->height; by += (s->api == 1 ? 1 : ph))
        for (int bx = x0; bx < x0 + TILE && bx < s->width; bx += (s->api == 1 ? 1 : pw)) {
            const int n = s->api == 1 ? 1 : s->api;
            float acc[MAXN][3];
            memset(acc, 0, sizeof acc);
            for (int sample = 0; sample < s->spp; sample++) {
                for (int k = 0; k < n; k++) {
                    const int x = s->api == 1 ? bx : bx + k % pw, y = s->api == 1 ? by : by + k / pw;
                    path_start(&sh->c, &q[k], x, y, sample);
                    q[k].alive = x < s->width && y < s->height;
                }
                if (s->api == 1)
                    render_path1(&sh->c, &q[0], cnt);
                else
                    render_packet(&sh->c, q, n, cnt);
                for (int k = 0; k < n; k++)
                    for (int j = 0; j < 3; j++)
                        acc[k][j] += q[k].L[j];
            }
            for (int k = 0; k < n; k++) {
                const int x = s->api == 1 ? bx : bx + k % pw, y = s->api == 1 ? by : by + k / pw;
                if (x < s->width && y < s->height)
                    for (int j = 0; j < 3; j++)
                        sh->rgb[((size_t)y * (size_t)s->width + (size_t)x) * 3 + (size_t)j] = acc[k][j] * inv_spp;
            }
        }
}

static void *work(void *arg)
{
    worker *w = arg;
    shared *sh = w->sh;
    for (;;) {
        const int tile = __atomic_fetch_add(&sh->next, 1, __ATOMIC_RELAXED);
        if (tile >= sh->tiles)
            break;
        if (w->sb)
            render_tile_stream(sh, tile, w->sb, &w->n);
        else
            render_tile(sh, tile, &w->n);
        const int done = __atomic_add_fetch(&sh->done, 1, __ATOMIC_RELAXED);
        if (w->report && sh->c.s->progress && seconds_since(&w->last) > 0.1) {
            sh->c.s->progress(sh->c.s->progress_user, (double)done / sh->tiles);
            clock_gettime(CLOCK_MONOTONIC, &w->last);
        }
    }
    return NULL;
}

int render_image(const render_tracer *t, const render_settings *s, float *rgb, render_stats *st, char *err,
                 size_t err_size)
{
    memset(st, 0, sizeof *st);
    if (s->width < 1 || s->height < 1 || s->width > 65536 || s->height > 65536 || s->spp < 1 || s->threads < 1 ||
        s->threads > 1024 || s->max_bounces < 0 || s->ao_samples < 1 || (unsigned)s->mode > RENDER_DIFFUSE) {
        snprintf(err, err_size, "render settings out of range");
        return 1;
    }
    const int need = s->api == 1    ? t->intersect1 && t->occluded1
                     : s->api == 4  ? t->intersect4 && t->occluded4
                     : s->api == 8  ? t->intersect8 && t->occluded8
                     : s->api == 16 ? t->intersect16 && t->occluded16
                     : s->api == RENDER_API_STREAM ? t->intersect1M && t->occluded1M
                                    : -1;
    if (need != 1) {
        snprintf(err, err_size, need < 0 ? "the API must be single, packet4, packet8, packet16 or stream"
                                         : "the ray tracer has no functions for this API");
        return 1;
    }
    shared sh = {.c = {.tracer = t, .s = s}, .rgb = rgb};
    memcpy(sh.c.sun_dir, s->sun_dir, sizeof sh.c.sun_dir);
    memcpy(sh.c.up, s->up, sizeof sh.c.up);
    normalize3(sh.c.sun_dir);
    normalize3(sh.c.up);
    for (int k = 0; k < 3; k++) {
        sh.c.inv_pi_albedo[k] = s->albedo[k] / 3.14159265f;
        sh.c.sun_on |= s->sun[k] > 0.0f;
    }
    const int tile = s->api == RENDER_API_STREAM ? STREAM_TILE : TILE;
    sh.tiles_x = (s->width + tile - 1) / tile;
    sh.tiles = sh.tiles_x * ((s->height + tile - 1) / tile);

    worker *w = calloc((size_t)s->threads, sizeof *w);
    pthread_t *tid = calloc((size_t)s->threads, sizeof *tid);
    int oom = !w || !tid;
    for (int i = 0; !oom && s->api == RENDER_API_STREAM && i < s->threads; i++)
        oom = !(w[i].sb = malloc(sizeof *w[i].sb));
    if (oom) {
        for (int i = 0; w && i < s->threads; i++)
            free(w[i].sb);
        free(w);
        free(tid);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    struct timespec t0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    int started = 1;
    for (int i = 0; i < s->threads; i++) {
        w[i].sh = &sh;
        w[i].last = t0;
    }
    w[0].report = 1;
    for (; started < s->threads; started++)
        if (pthread_create(&tid[started], NULL, work, &w[started]))
            break;
    work(&w[0]);
    for (int i = 1; i < started; i++)
        pthread_join(tid[i], NULL);
    st->seconds = seconds_since(&t0);
    if (s->progress)
        s->progress(s->progress_user, 1.0);
    for (int i = 0; i < started; i++) {
        st->primary += w[i].n.primary;
        st->primary_hits += w[i].n.primary_hits;
        st->bounce += w[i].n.bounce;
        st->shadow += w[i].n.shadow;
        st->ao += w[i].n.ao;
    }
    for (int i = 0; i < s->threads; i++)
        free(w[i].sb);
    free(w);
    free(tid);
    return 0;
}

static unsigned char to8(float v, int srgb)
{
    if (!(v > 0.0f))
        return 0;
    if (v >= 1.0f)
        return 255;
    if (srgb)
        v = v <= 0.0031308f ? 12.92f * v : 1.055f * powf(v, 1.0f / 2.4f) - 0.055f;
    return (unsigned char)(v * 255.0f + 0.5f);
}

void render_to_rgb8(const render_settings *s, const float *rgb, unsigned char *out)
{
    const size_t n = (size_t)s->width * (size_t)s->height * 3;
    for (size_t i = 0; i < n; i++)
        out[i] = to8(rgb[i], s->mode == RENDER_DIFFUSE);
}
