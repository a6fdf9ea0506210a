/*
 * The conformance suite: every backend of this build, one device each in
 * this process, traces the same rays through intersect1, occluded1 and the
 * packet calls of every width (4, 8, 16), with the backend's default layout
 * and with the compact one (RTK_SCENE_FLAG_COMPACT), and through the Morton
 * builder's tree (low quality; single rays, 4 and 8), on every mesh of the shared test
 * set and on procedural scenes made to be hard (shared edges and vertices hit
 * dead on, needles and fans, overlapping soup; the soup also moving and
 * deforming, with motion blur, its rays at random times).  On a 32nd of the
 * rays each scene is traced again with masks, culling and a filter
 * (check_features), and on a 64th with balls as user geometry beside the
 * triangles (check_user).  The scalar backend's intersect1 / occluded1 answers are
 * the baseline.  Every one of these scenes (and the robust layouts) also
 * goes through the stream and batch calls, whose answers must be the same
 * backend's single-ray answers to the bit (check_streams).
 *
 * Rules, per ray:
 *   - hit or miss must equal the baseline's, for every backend and width;
 *   - on a hit, geomID and primID must equal the baseline's, unless the two
 *     primitives are a tie: the double-precision reference below finds both
 *     hit, give or take its tolerance, at distances it cannot tell apart;
 *   - with the same ids, t within 1e-6 relative of the baseline's, u and
 *     v within 1e-5 (all backends share the arithmetic, so in practice these
 *     are equal to the bit);
 *   - lanes switched off by the valid mask come back untouched, bit for bit.
 *
 * The double-precision reference (only consulted on a disagreement): the
 * Moeller-Trumbore test in double on the mesh's float vertices, over every
 * triangle, with tolerances of 16 times the forward error bound of a float
 * test of the same ray and triangle (see dref_one: tight for a ray through a
 * triangle's middle, wide for one grazing its plane).  A hit on triangle P is
 * consistent with it when P is hit give or take the tolerance and no
 * triangle is hit beyond doubt at a t nearer than P's by more than the
 * tolerances; a miss is consistent when no triangle is hit beyond doubt.  So
 * a ray through a shared edge or vertex may hit any triangle there or, with
 * the fast (non-watertight) test, none; a ray through the middle of a
 * triangle must hit it, and the nearest such one.
 *
 * With Embree 3 present (RTK_HAVE_EMBREE) the same rays go through
 * rtcIntersect1 / rtcOccluded1.  Where the answers differ, the reference
 * settles it: locally when it can (a tie between two hits; a hit on P against
 * a miss where P is grazed, hit within the tolerance but not beyond doubt),
 * else by searching every triangle.  Agreement (the same answer, or one
 * where the reference allows both) is printed and must be at least 99.99%,
 * and at every disagreement rtk's answer must be one the reference allows.
 *
 * Rays per mesh: RTK_CONFORMANCE_RAYS (default 1048576), a third each
 * primary (4x4 pixel tiles, so packets are coherent), random and shadow.
 * Every disagreement prints the ray in full (%a floats) for replay.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef RTK_HAVE_EMBREE
#include <embree3/rtcore.h>
#endif

#include "mesh_import.h"
#include "testlib.h"

#define MAX_REPORTS 10
#define MAX_ADJUDICATIONS 20000 /* per query: each searches every triangle in double */
#define T_REL 1e-6f
#define UV_ABS 1e-5f

typedef struct scene_data {
    char name[256];
    const float *v;
    /* Motion blur: NULL, or the vertices at time step 1 (v is step 0), the
     * scene then being two time steps and the rays carrying times. */
    const float *v1;
    size_t nv;
    const uint32_t *idx;
    size_t nt;
    double (*sphere)[4]; /* per triangle: centre and radius, to skip far triangles in the brute force */
    size_t brute_force;  /* adjudications that searched every triangle */
    /* User geometry: NULL, or nballs balls (centre, radius) beside the
     * triangles, geometry 1 of the scene, traced through callbacks
     * (check_user). */
    const float (*balls)[4];
    size_t nballs;
} scene_data;

typedef struct answer {
    float t, u, v;
    uint32_t geom, prim; /* prim RTK_INVALID_GEOMETRY_ID: miss */
    int occluded;
} answer;

static size_t ray_count(void)
{
    const char *e = getenv("RTK_CONFORMANCE_RAYS");
    size_t n = e && *e ? strtoull(e, NULL, 10) : (size_t)1 << 20;
    n -= n % 48;
    return n < 48 ? 48 : n;
}

/* ---- rays ---- */

/* The box of s's vertices (at time step 0); returns its diagonal. */
static float scene_box(const scene_data *s, float lo[3], float hi[3])
{
    for (int k = 0; k < 3; k++)
        lo[k] = INFINITY, hi[k] = -INFINITY;
    for (size_t i = 0; i < s->nv; i++)
        for (int k = 0; k < 3; k++) {
            lo[k] = fminf(lo[k], s->v[3 * i + k]);
            hi[k] = fmaxf(hi[k], s->v[3 * i + k]);
        }
    float diag = 0.0f;
    for (int k = 0; k < 3; k++)
        diag += (hi[k] - lo[k]) * (hi[k] - lo[k]);
    return sqrtf(diag);
}

static void make_rays(const scene_data *s, rtk_ray *rays, size_t n, uint64_t seed)
{
    float lo[3], hi[3], c[3];
    const float diag = scene_box(s, lo, hi);
    for (int k = 0; k < 3; k++)
        c[k] = 0.5f * (lo[k] + hi[k]);
    /* grow the box by a tenth of the diagonal on every side, so flat scenes
     * get a volume (origins on a surface are test_rays.c's business) */
    for (int k = 0; k < 3; k++) {
        lo[k] -= 0.1f * diag;
        hi[k] += 0.1f * diag;
    }
    rng r = {seed};
    const size_t third = n / 3;
    /* primary: a camera at 1.2 diagonals framing the box, pixels in 4x4
     * tiles, so ray i..i+15 are one tile */
    const size_t tiled = third / 4 * 3;
    size_t side = 4;
    while ((side + 4) * (side + 4) <= tiled)
        side += 4;
    const float eye[3] = {c[0] + 0.45f * diag, c[1] + 0.35f * diag, c[2] + 1.1f * diag};
    float fwd[3] = {c[0] - eye[0], c[1] - eye[1], c[2] - eye[2]};
    float fl = sqrtf(fwd[0] * fwd[0] + fwd[1] * fwd[1] + fwd[2] * fwd[2]);
    for (int k = 0; k < 3; k++)
        fwd[k] /= fl;
    float right[3] = {fwd[2], 0.0f, -fwd[0]}; /* fwd x up(0,1,0) */
    float rl = sqrtf(right[0] * right[0] + right[2] * right[2]);
    right[0] /= rl;
    right[2] /= rl;
    const float up[3] = {right[1] * fwd[2] - right[2] * fwd[1], right[2] * fwd[0] - right[0] * fwd[2],
                         right[0] * fwd[1] - right[1] * fwd[0]};
    const float half = 0.5f * diag / fl; /* tan of the half field of view */
    size_t i = 0;
    for (size_t ty = 0; ty < side; ty += 4)
        for (size_t tx = 0; tx < side; tx += 4)
            for (size_t p = 0; p < 16; p++) {
                const float sx = (2.0f * ((float)(tx + p % 4) + 0.5f) / (float)side - 1.0f) * half;
                const float sy = (1.0f - 2.0f * ((float)(ty + p / 4) + 0.5f) / (float)side) * half;
                rays[i++] = test_ray(eye[0], eye[1], eye[2], fwd[0] + sx * right[0] + sy * up[0],
                                     fwd[1] + sx * right[1] + sy * up[1], fwd[2] + sx * right[2] + sy * up[2], 0.0f,
                                     INFINITY);
            }
    /* the rest of the primary third (at least a quarter): aimed exactly at
     * vertices and edge midpoints, the hard cases */
    rng rv = {seed ^ 0x5555u};
    for (; i < third; i++) {
        const uint32_t tri = rng_u32(&rv) % (uint32_t)s->nt;
        const float *a = s->v + 3 * (size_t)s->idx[3 * tri], *b = s->v + 3 * (size_t)s->idx[3 * tri + 1];
        const int mid = rng_u32(&rv) & 1;
        float target[3];
        for (int k = 0; k < 3; k++)
            target[k] = mid ? 0.5f * (a[k] + b[k]) : a[k];
        rays[i] = test_ray(eye[0], eye[1], eye[2], target[0] - eye[0], target[1] - eye[1], target[2] - eye[2], 0.0f,
                           INFINITY);
    }
    /* random: origins in the grown box, uniform directions; then shadow
     * segments between two random points of that box */
    for (; i < n; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++)
            o[k] = lo[k] + (hi[k] - lo[k]) * rng_float(&r);
        float tfar = INFINITY;
        if (i < 2 * third) {
            const float z = 2.0f * rng_float(&r) - 1.0f, phi = 6.2831853f * rng_float(&r), rr = sqrtf(1.0f - z * z);
            d[0] = rr * cosf(phi);
            d[1] = rr * sinf(phi);
            d[2] = z;
        } else {
            for (int k = 0; k < 3; k++)
                d[k] = lo[k] + (hi[k] - lo[k]) * rng_float(&r) - o[k];
            tfar = 1.0f;
        }
        rays[i] = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, tfar);
    }
    /* motion blur: random times, except for the rays aimed at vertices and
     * edges (time 0, where those are where they were aimed) and a few at
     * the other end, time 1 */
    rng rt = {seed ^ 0x7777u};
    for (i = 0; s->v1 && i < n; i++)
        rays[i].time = i >= tiled && i < third ? 0.0f : i % 97 == 0 ? 1.0f : rng_float(&rt);
}

static void print_ray(const char *what, const scene_data *s, size_t i, const rtk_ray *r)
{
    print_message("%s: %s ray %zu: org %a %a %a dir %a %a %a tnear %a tfar %a time %a\n", s->name, what, i, r->org_x,
                  r->org_y, r->org_z, r->dir_x, r->dir_y, r->dir_z, r->tnear, r->tfar, r->time);
}

/* Vertex j of triangle prim as the ray sees it: at the ray's time, in
 * double, for a moving scene. */
static void vertex_at_time(const scene_data *s, uint32_t prim, int j, const rtk_ray *r, double out[3])
{
    const size_t vi = 3 * (size_t)s->idx[3 * prim + j];
    const double f = s->v1 ? r->time : 0.0;
    for (int k = 0; k < 3; k++)
        out[k] = s->v1 ? (1.0 - f) * s->v[vi + k] + f * s->v1[vi + k] : s->v[vi + k];
}

/* ---- the double-precision reference ---- */

/* One triangle in double: the exact-arithmetic answer (up to double
 * rounding) and how far a float test of the same ray could be off.  The
 * barycentrics u = s.(d x e2)/det, v = d.(s x e1)/det, w = 1 - u - v carry
 * float errors of about eps |s| |d| |e| / |det| (large for rays grazing the
 * plane, where det is small), s = org - v0 itself off by eps (|org| + |v0|);
 * the tolerances are 16 times that bound, so they cover any float
 * Moeller-Trumbore-like test, rtk's or Embree's. */
typedef struct dref {
    double t, u, v, w;
    double tol_u, tol_v, tol_t;
} dref;

static double norm3(const double a[3])
{
    return sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
}

static int dref_one(const scene_data *s, uint32_t prim, const rtk_ray *r, dref *h)
{
    double a[3], b[3], c[3];
    vertex_at_time(s, prim, 0, r, a);
    vertex_at_time(s, prim, 1, r, b);
    vertex_at_time(s, prim, 2, r, c);
    const double o[3] = {r->org_x, r->org_y, r->org_z}, d[3] = {r->dir_x, r->dir_y, r->dir_z};
    const double v0[3] = {a[0], a[1], a[2]};
    double e1[3], e2[3], sv[3], p[3], q[3];
    for (int k = 0; k < 3; k++) {
        e1[k] = b[k] - a[k];
        e2[k] = c[k] - a[k];
        sv[k] = o[k] - a[k];
    }
    p[0] = d[1] * e2[2] - d[2] * e2[1];
    p[1] = d[2] * e2[0] - d[0] * e2[2];
    p[2] = d[0] * e2[1] - d[1] * e2[0];
    const double det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
    if (det == 0.0 || !isfinite(det))
        return 0;
    q[0] = sv[1] * e1[2] - sv[2] * e1[1];
    q[1] = sv[2] * e1[0] - sv[0] * e1[2];
    q[2] = sv[0] * e1[1] - sv[1] * e1[0];
    h->u = (sv[0] * p[0] + sv[1] * p[1] + sv[2] * p[2]) / det;
    h->v = (d[0] * q[0] + d[1] * q[1] + d[2] * q[2]) / det;
    h->w = 1.0 - h->u - h->v;
    h->t = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) / det;
    const double k = 16.0 * 0x1p-24 / fabs(det);
    const double sl = norm3(sv) + norm3(o) + norm3(v0), dl = norm3(d), l1 = norm3(e1), l2 = norm3(e2);
    h->tol_u = k * sl * dl * l2;
    h->tol_v = k * sl * dl * l1;
    h->tol_t = k * sl * l1 * l2 + 16.0 * 0x1p-24 * fabs(h->t);
    return h->t >= (double)r->tnear - h->tol_t && h->t <= (double)r->tfar + h->tol_t;
}

/* Hit, give or take the tolerance / hit beyond doubt. */
static int dref_within(const dref *h)
{
    return h->u >= -h->tol_u && h->v >= -h->tol_v && h->w >= -(h->tol_u + h->tol_v);
}

static int dref_clear(const dref *h)
{
    return h->u > h->tol_u && h->v > h->tol_v && h->w > h->tol_u + h->tol_v && h->t >= 0.0;
}

/* Primitive prim of geometry geom (0: the triangles, 1: the balls) in the
 * reference.  A ball is its callback's arithmetic (test_sphere_hit), so
 * the reference knows it exactly: hit beyond doubt, at the callback's t
 * give or take the float rounding. */
static int dref_prim(const scene_data *s, uint32_t geom, uint32_t prim, const rtk_ray *r, dref *h)
{
    if (geom == 0)
        return dref_one(s, prim, r, h);
    const float o[3] = {r->org_x, r->org_y, r->org_z}, d[3] = {r->dir_x, r->dir_y, r->dir_z};
    float t;
    if (geom != 1 || prim >= s->nballs || !test_sphere_hit(s->balls[prim], s->balls[prim][3], o, d, r->tnear, r->tfar, &t))
        return 0;
    *h = (dref){.t = t, .u = 1.0 / 3, .v = 1.0 / 3, .w = 1.0 / 3, .tol_t = 0x1p-24 * fabs((double)t)};
    return 1;
}

static void make_spheres(scene_data *s)
{
    s->sphere = malloc((s->nt ? s->nt : 1) * sizeof *s->sphere);
    assert_non_null(s->sphere);
    /* (a moving triangle: a sphere around it at both ends, and so at
     * every time between) */
    const int ends = s->v1 ? 2 : 1;
    for (size_t i = 0; i < s->nt; i++) {
        double c[3] = {0, 0, 0}, r = 0.0;
        for (int e = 0; e < ends; e++)
            for (int j = 0; j < 3; j++)
                for (int k = 0; k < 3; k++)
                    c[k] += (e ? s->v1 : s->v)[3 * (size_t)s->idx[3 * i + j] + k] / (3.0 * ends);
        for (int e = 0; e < ends; e++)
            for (int j = 0; j < 3; j++) {
                const float *p = (e ? s->v1 : s->v) + 3 * (size_t)s->idx[3 * i + j];
                const double d[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
                r = fmax(r, norm3(d));
            }
        memcpy(s->sphere[i], c, sizeof c);
        s->sphere[i][3] = r;
    }
}

/* Triangles the ray's line passes within twice their bounding radius of:
 * every triangle hit beyond doubt is among them, and so is any hit within
 * the tolerance unless the tolerance exceeds the triangle's own size. */
static int near_line(const scene_data *s, size_t i, const rtk_ray *r)
{
    const double *c = s->sphere[i];
    const double d[3] = {r->dir_x, r->dir_y, r->dir_z};
    const double w[3] = {c[0] - r->org_x, c[1] - r->org_y, c[2] - r->org_z};
    const double x[3] = {w[1] * d[2] - w[2] * d[1], w[2] * d[0] - w[0] * d[2], w[0] * d[1] - w[1] * d[0]};
    const double dist = norm3(x) / norm3(d);
    return dist <= 2.0 * c[3] + 1e-6 * (norm3(w) + norm3(c));
}

/* How far the nearest hit beyond doubt can be: min of t + tolerance over
 * the triangles and balls hit beyond doubt, or +inf. */
static double dref_clear_nearest(const scene_data *s, const rtk_ray *r)
{
    double best = INFINITY;
    for (size_t i = 0; i < s->nt; i++) {
        dref h;
        if (near_line(s, i, r) && dref_one(s, (uint32_t)i, r, &h) && dref_clear(&h) && h.t + h.tol_t < best)
            best = h.t + h.tol_t;
    }
    for (size_t i = 0; i < s->nballs; i++) {
        dref h;
        if (dref_prim(s, 1, (uint32_t)i, r, &h) && h.t >= 0.0 && h.t + h.tol_t < best)
            best = h.t + h.tol_t;
    }
    return best;
}

/* Is this answer one the reference allows?  A hit: its triangle is hit give
 * or take the tolerance, and no triangle is hit beyond doubt surely nearer
 * (their t intervals of +-tolerance do not overlap).
 * A miss: no triangle is hit beyond doubt.  Occluded: some triangle is hit
 * give or take the tolerance. */
static int consistent(scene_data *s, const rtk_ray *r, const answer *a, int occluded)
{
    s->brute_force++;
    const double clear = dref_clear_nearest(s, r);
    if (occluded) {
        if (!a->occluded)
            return isinf(clear);
        for (size_t i = 0; i < s->nt; i++) {
            dref h;
            if (near_line(s, i, r) && dref_one(s, (uint32_t)i, r, &h) && dref_within(&h))
                return 1;
        }
        return !isinf(clear); /* a ball */
    }
    if (a->prim == RTK_INVALID_GEOMETRY_ID)
        return isinf(clear);
    dref h;
    return dref_prim(s, a->geom, a->prim, r, &h) && dref_within(&h) && h.t - h.tol_t <= clear;
}

/* Two hits on different primitives are a tie when the reference finds both
 * hit (give or take the tolerances) at overlapping distances. */
static int tie(const scene_data *s, const rtk_ray *r, const answer *a, const answer *b)
{
    dref ha, hb;
    return dref_prim(s, a->geom, a->prim, r, &ha) && dref_prim(s, b->geom, b->prim, r, &hb) && dref_within(&ha) &&
           dref_within(&hb) && fabs(ha.t - hb.t) <= ha.tol_t + hb.tol_t;
}

/* ---- tracing ---- */

static answer hit_answer(const rtk_rayhit *rh)
{
    if (rh->hit.geomID == RTK_INVALID_GEOMETRY_ID)
        return (answer){.geom = RTK_INVALID_GEOMETRY_ID, .prim = RTK_INVALID_GEOMETRY_ID};
    return (answer){.t = rh->ray.tfar, .u = rh->hit.u, .v = rh->hit.v, .geom = rh->hit.geomID, .prim = rh->hit.primID};
}

static void trace1(rtk_scene scene, const rtk_ray *rays, size_t n, int occluded, answer *out)
{
    for (size_t i = 0; i < n; i++) {
        if (occluded) {
            rtk_ray r = rays[i];
            assert_int_equal(rtk_occluded1(scene, &r), RTK_OK);
            out[i] = (answer){.occluded = r.tfar == -INFINITY, .geom = RTK_INVALID_GEOMETRY_ID,
                              .prim = RTK_INVALID_GEOMETRY_ID};
        } else {
            rtk_rayhit rh = {.ray = rays[i]};
            rh.hit.geomID = rh.hit.primID = RTK_INVALID_GEOMETRY_ID;
            assert_int_equal(rtk_intersect1(scene, &rh), RTK_OK);
            out[i] = hit_answer(&rh);
        }
    }
}

/* Packets of w: lane j of field f lives at f * w + j (rtk.h's layout).  Lanes
 * whose global index is 5 mod 13 are switched off and must come back as
 * they went in; they are then traced alone so every ray has an answer. */
static int trace_packets(rtk_scene scene, const rtk_ray *rays, size_t n, unsigned w, int occluded, answer *out,
                         const scene_data *s, const char *backend)
{
    _Alignas(64) uint32_t pk[20 * 16], before[20 * 16];
    const size_t fields = occluded ? 12 : 20;
    int failures = 0;
    for (size_t base = 0; base < n; base += w) {
        int valid[16];
        for (unsigned j = 0; j < w; j++) {
            rtk_rayhit rh = {.ray = rays[base + j]};
            rh.hit.geomID = rh.hit.primID = RTK_INVALID_GEOMETRY_ID;
            test_packet_put(pk, w, j, &rh, occluded);
            valid[j] = (base + j) % 13 != 5;
        }
        memcpy(before, pk, fields * w * 4);
        assert_int_equal(test_trace_packet(scene, w, occluded, valid, pk), RTK_OK);
        for (unsigned j = 0; j < w; j++) {
            const size_t i = base + j;
            if (!valid[j]) {
                for (size_t f = 0; f < fields; f++)
                    if (pk[f * w + j] != before[f * w + j]) {
                        if (failures++ < MAX_REPORTS)
                            print_message("%s [%s] packet %u: inactive lane %u was written (field %zu)\n", s->name,
                                          backend, w, j, f);
                        break;
                    }
                trace1(scene, &rays[i], 1, occluded, &out[i]);
                continue;
            }
            rtk_rayhit rh;
            test_packet_get(pk, w, j, &rh, occluded);
            if (occluded)
                out[i] = (answer){.occluded = rh.ray.tfar == -INFINITY, .geom = RTK_INVALID_GEOMETRY_ID,
                                  .prim = RTK_INVALID_GEOMETRY_ID};
            else
                out[i] = hit_answer(&rh);
        }
    }
    return failures;
}

/* Compares one pass against the baseline; returns the failures. */
static int compare(const scene_data *s, const rtk_ray *rays, size_t n, int occluded, const answer *base,
                   const answer *got, const char *what, size_t *ties)
{
    int failures = 0;
    for (size_t i = 0; i < n; i++) {
        const answer *a = &base[i], *b = &got[i];
        const char *why = NULL;
        if (occluded) {
            if (a->occluded != b->occluded)
                why = "occluded differs";
        } else if ((a->prim == RTK_INVALID_GEOMETRY_ID) != (b->prim == RTK_INVALID_GEOMETRY_ID)) {
            why = "hit/miss differs";
        } else if (a->prim != RTK_INVALID_GEOMETRY_ID) {
            if (a->prim != b->prim || a->geom != b->geom) {
                /* a tie in t; or, for a ray grazing both triangles' planes,
                 * two hits at distances the reference cannot tell apart */
                if (tie(s, &rays[i], a, b))
                    ++*ties;
                else
                    why = "primID differs and the reference does not call it a tie";
            } else if (!(fabsf(a->t - b->t) <= T_REL * fabsf(a->t))) {
                why = "t differs";
            } else if (!(fabsf(a->u - b->u) <= UV_ABS && fabsf(a->v - b->v) <= UV_ABS)) {
                why = "u/v differ";
            }
        }
        if (why && failures++ < MAX_REPORTS) {
            print_ray(what, s, i, &rays[i]);
            print_message("    %s: baseline geom %u prim %u t %a u %a v %a occ %d; got geom %u prim %u t %a u %a v %a "
                          "occ %d\n",
                          why, a->geom, a->prim, a->t, a->u, a->v, a->occluded, b->geom, b->prim, b->t, b->u, b->v,
                          b->occluded);
        }
    }
    return failures;
}

#ifdef RTK_HAVE_EMBREE
/* The balls as Embree user geometry: the same arithmetic as rtk's callbacks. */
static void embree_ball_bounds(const struct RTCBoundsFunctionArguments *a)
{
    const float *b = ((const float (*)[4])a->geometryUserPtr)[a->primID];
    a->bounds_o->lower_x = b[0] - b[3], a->bounds_o->lower_y = b[1] - b[3], a->bounds_o->lower_z = b[2] - b[3];
    a->bounds_o->upper_x = b[0] + b[3], a->bounds_o->upper_y = b[1] + b[3], a->bounds_o->upper_z = b[2] + b[3];
}

static void embree_ball_query(const int *valid, void *user, unsigned prim, unsigned geom, void *rays, unsigned n,
                              int occluded)
{
    const float *b = ((const float (*)[4])user)[prim];
    for (unsigned i = 0; i < n; i++) {
        if (!valid[i])
            continue;
        const float o[3] = {TEST_LANE(rays, n, 0, i), TEST_LANE(rays, n, 1, i), TEST_LANE(rays, n, 2, i)};
        const float d[3] = {TEST_LANE(rays, n, 4, i), TEST_LANE(rays, n, 5, i), TEST_LANE(rays, n, 6, i)};
        float t;
        if (!test_sphere_hit(b, b[3], o, d, TEST_LANE(rays, n, 3, i), TEST_LANE(rays, n, 8, i), &t))
            continue;
        TEST_LANE(rays, n, 8, i) = occluded ? -INFINITY : t;
        if (occluded)
            continue;
        /* RTCRayHitN's hit fields follow the ray's 12 as rtk's do (Ng, u,
         * v, primID, geomID, instID[0]); rtcore_ray.h's accessors are C++ */
        for (int k = 0; k < 3; k++)
            TEST_LANE(rays, n, 12 + k, i) = o[k] + t * d[k] - b[k];
        TEST_LANE(rays, n, 15, i) = TEST_LANE(rays, n, 16, i) = 0.0f;
        uint32_t *ids = (uint32_t *)rays;
        ids[17 * n + i] = prim;
        ids[18 * n + i] = geom;
        ids[19 * n + i] = RTC_INVALID_GEOMETRY_ID;
    }
}

static void embree_ball_intersect(const struct RTCIntersectFunctionNArguments *a)
{
    embree_ball_query(a->valid, a->geometryUserPtr, a->primID, a->geomID, a->rayhit, a->N, 0);
}

static void embree_ball_occluded(const struct RTCOccludedFunctionNArguments *a)
{
    embree_ball_query(a->valid, a->geometryUserPtr, a->primID, a->geomID, a->ray, a->N, 1);
}

/* The same rays through Embree; returns rtk's answers inconsistent with the
 * reference where the two disagree. */
static int versus_embree(scene_data *s, const rtk_ray *rays, size_t n, const answer *base_hit,
                         const answer *base_occ)
{
    RTCDevice dev = rtcNewDevice(NULL);
    assert_non_null(dev);
    RTCScene scene = rtcNewScene(dev);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    if (s->v1)
        rtcSetGeometryTimeStepCount(g, 2);
    for (unsigned step = 0; step < (s->v1 ? 2u : 1u); step++) {
        float *vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, step, RTC_FORMAT_FLOAT3, 12, s->nv);
        memcpy(vb, step ? s->v1 : s->v, s->nv * 12);
    }
    uint32_t *ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 12, s->nt);
    memcpy(ib, s->idx, s->nt * 12);
    rtcCommitGeometry(g);
    assert_int_equal(rtcAttachGeometry(scene, g), 0);
    rtcReleaseGeometry(g);
    if (s->nballs) {
        g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_USER);
        rtcSetGeometryUserPrimitiveCount(g, (unsigned)s->nballs);
        rtcSetGeometryUserData(g, (void *)s->balls);
        rtcSetGeometryBoundsFunction(g, embree_ball_bounds, NULL);
        rtcSetGeometryIntersectFunction(g, embree_ball_intersect);
        rtcSetGeometryOccludedFunction(g, embree_ball_occluded);
        rtcCommitGeometry(g);
        assert_int_equal(rtcAttachGeometry(scene, g), 1);
        rtcReleaseGeometry(g);
    }
    rtcCommitScene(scene);
    struct RTCIntersectContext ctx;
    answer *embree_hit = malloc(n * sizeof *embree_hit);
    assert_non_null(embree_hit);
    size_t agree[2] = {0, 0}, rtk_ok[2] = {0, 0}, embree_ok[2] = {0, 0}, both_ok[2] = {0, 0}, judged[2] = {0, 0};
    int failures = 0;
    for (int occluded = 0; occluded < 2; occluded++)
        for (size_t i = 0; i < n; i++) {
            const rtk_ray *r = &rays[i];
            struct RTCRayHit rh;
            memset(&rh, 0, sizeof rh);
            rh.ray.org_x = r->org_x, rh.ray.org_y = r->org_y, rh.ray.org_z = r->org_z;
            rh.ray.dir_x = r->dir_x, rh.ray.dir_y = r->dir_y, rh.ray.dir_z = r->dir_z;
            rh.ray.tnear = r->tnear, rh.ray.tfar = r->tfar, rh.ray.mask = 0xffffffffu, rh.ray.time = r->time;
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rtcInitIntersectContext(&ctx);
            answer e = {.geom = RTK_INVALID_GEOMETRY_ID, .prim = RTK_INVALID_GEOMETRY_ID};
            if (occluded) {
                rtcOccluded1(scene, &ctx, &rh.ray);
                e.occluded = rh.ray.tfar == -INFINITY;
            } else {
                rtcIntersect1(scene, &ctx, &rh);
                if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID)
                    e = (answer){.t = rh.ray.tfar, .u = rh.hit.u, .v = rh.hit.v, .geom = rh.hit.geomID,
                                 .prim = rh.hit.primID};
            }
            const answer *a = occluded ? &base_occ[i] : &base_hit[i];
            if (!occluded)
                embree_hit[i] = e;
            if (occluded ? a->occluded == e.occluded : a->prim == e.prim && a->geom == e.geom) {
                agree[occluded]++;
                continue;
            }
            /* Settled locally first.  Two hits on different triangles: a tie?
             * A hit on P against a miss (for occluded, P is the closest hit
             * of the side that says hit): both allowed when P is hit within
             * the tolerance but not beyond doubt, a graze. */
            int local = 0;
            if (!occluded && a->prim != RTK_INVALID_GEOMETRY_ID && e.prim != RTK_INVALID_GEOMETRY_ID) {
                local = tie(s, r, a, &e);
            } else {
                const answer *p = occluded ? (a->occluded ? &base_hit[i] : &embree_hit[i])
                                           : (a->prim != RTK_INVALID_GEOMETRY_ID ? a : &e);
                dref h;
                local = p->prim != RTK_INVALID_GEOMETRY_ID && dref_prim(s, p->geom, p->prim, r, &h) &&
                        dref_within(&h) && !dref_clear(&h);
            }
            if (local) {
                rtk_ok[occluded]++, embree_ok[occluded]++, both_ok[occluded]++;
                continue;
            }
            if (judged[occluded]++ >= MAX_ADJUDICATIONS)
                continue;
            const int ok_rtk = consistent(s, r, a, occluded), ok_embree = consistent(s, r, &e, occluded);
            rtk_ok[occluded] += (size_t)ok_rtk;
            embree_ok[occluded] += (size_t)ok_embree;
            both_ok[occluded] += (size_t)(ok_rtk && ok_embree);
            if (!ok_rtk && failures++ < MAX_REPORTS) {
                print_ray(occluded ? "occluded1 vs Embree" : "intersect1 vs Embree", s, i, r);
                print_message("    rtk geom %u prim %u t %a occ %d; Embree geom %u prim %u t %a occ %d; the reference "
                              "sides with %s\n",
                              a->geom, a->prim, a->t, a->occluded, e.geom, e.prim, e.t, e.occluded,
                              ok_embree ? "Embree" : "neither");
            }
        }
    for (int q = 0; q < 2; q++) {
        /* agreement: the same answer, or a tie (both answers allowed by the reference) */
        const double same = 100.0 * (double)agree[q] / (double)n;
        const double rate = 100.0 * (double)(agree[q] + both_ok[q]) / (double)n;
        print_message("%s%s: Embree %s: the same answer for %.4f%% of %zu rays; %zu differ, of which the reference "
                      "allows rtk's answer in %zu, Embree's in %zu, both in %zu: agreement %.4f%%\n",
                      s->name, s->nballs ? ", with balls" : "", q ? "occluded1" : "intersect1", same, n, n - agree[q], rtk_ok[q], embree_ok[q],
                      both_ok[q], rate);
        if (rate < 99.99) {
            print_message("%s: agreement with Embree below 99.99%%\n", s->name);
            failures++;
        }
        if (judged[q] > MAX_ADJUDICATIONS) {
            print_message("%s: more disagreements with Embree than can be adjudicated\n", s->name);
            failures++;
        }
    }
    free(embree_hit);
    rtcReleaseScene(scene);
    rtcReleaseDevice(dev);
    return failures;
}
#endif

/* s's scene on dev (flags: the scene's), not yet committed; a moving s
 * with its second time step.  *g: its one geometry, committed.  quads: s's
 * triangles as a quad geometry (quads[4 i ..] = v0 v1 v2 v2, a triangle
 * given as a quad, so the hits are the triangles' with the same ids), or
 * NULL. */
static rtk_scene conformance_scene(rtk_device dev, const scene_data *s, unsigned flags, rtk_geometry *g,
                                   const uint32_t *quads)
{
    rtk_scene scene = test_scene_uncommitted(dev, s->v, s->nv, s->idx, s->nt, flags);
    *g = rtk_scene_get_geometry(scene, 0);
    if (quads) {
        rtk_geometry q;
        assert_int_equal(rtk_scene_detach_geometry(scene, 0), RTK_OK);
        assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_QUAD, &q), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(q, RTK_BUFFER_TYPE_VERTEX, s->v, 0, 12, s->nv), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer(q, RTK_BUFFER_TYPE_INDEX, quads, 0, 16, s->nt), RTK_OK);
        assert_int_equal(rtk_geometry_commit(q), RTK_OK);
        uint32_t id;
        assert_int_equal(rtk_scene_attach_geometry(scene, q, &id), RTK_OK);
        assert_int_equal(id, 0);
        rtk_geometry_release(q);
        *g = q;
    }
    if (s->v1) {
        assert_int_equal(rtk_geometry_set_time_step_count(*g, 2), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(*g, RTK_BUFFER_TYPE_VERTEX, 1, s->v1, 0, 12, s->nv),
                         RTK_OK);
        assert_int_equal(rtk_geometry_commit(*g), RTK_OK);
    }
    return scene;
}

/* Streams (rtk_intersect1M, rtk_occluded1M) and batches (rtk_intersect_batch,
 * rtk_occluded_batch) against the same backend's single-ray calls on the
 * same scene: every ray's record identical to the bit (tfar, Ng, u, v and
 * the ids; occluded: the whole ray).  The records lie STRIDE_PAD bytes
 * apart beyond their size, the gap filled with a pattern that must come
 * back untouched, and every 11th ray is made invalid (a NaN origin, a
 * negative tnear, tnear beyond tfar, in turn), which must come back
 * untouched as from the single call.  Returns the failures. */
#define STRIDE_PAD 12
static int check_streams(rtk_scene scene, const scene_data *s, const rtk_ray *rays, size_t n, const char *backend,
                         const char *label, int batch)
{
    int failures = 0;
    for (int occluded = 0; occluded < 2; occluded++) {
        const size_t size = occluded ? sizeof(rtk_ray) : sizeof(rtk_rayhit), stride = size + STRIDE_PAD;
        unsigned char *one = malloc(n * size), *many = malloc(n * stride), *all = batch ? malloc(n * stride) : NULL;
        assert_true(one && many && (all || !batch));
        for (size_t i = 0; i < n; i++) {
            rtk_rayhit rh = {.ray = rays[i]};
            rh.hit.geomID = rh.hit.primID = rh.hit.instID = RTK_INVALID_GEOMETRY_ID;
            switch (i % 33) {
            case 0: rh.ray.org_y = NAN; break;
            case 11: rh.ray.tnear = -1.0f; break;
            case 22: rh.ray.tfar = 1.0f, rh.ray.tnear = 2.0f; break;
            default: break;
            }
            memcpy(one + i * size, &rh, size);
            memset(many + i * stride, 0xa5, stride);
            memcpy(many + i * stride, &rh, size);
        }
        if (batch)
            memcpy(all, many, n * stride);
        for (size_t i = 0; i < n; i++)
            assert_int_equal(occluded ? rtk_occluded1(scene, (rtk_ray *)(void *)(one + i * size))
                                      : rtk_intersect1(scene, (rtk_rayhit *)(void *)(one + i * size)),
                             RTK_OK);
        assert_int_equal(occluded ? rtk_occluded1M(scene, (rtk_ray *)(void *)many, (uint32_t)n, stride)
                                  : rtk_intersect1M(scene, (rtk_rayhit *)(void *)many, (uint32_t)n, stride),
                         RTK_OK);
        if (batch)
            assert_int_equal(occluded ? rtk_occluded_batch(scene, (rtk_ray *)(void *)all, n, stride, NULL)
                                      : rtk_intersect_batch(scene, (rtk_rayhit *)(void *)all, n, stride, NULL),
                             RTK_OK);
        for (int pass = 0; pass < 1 + batch; pass++) {
            const unsigned char *got = pass ? all : many;
            for (size_t i = 0; i < n; i++) {
                const unsigned char *g = got + i * stride;
                int bad = memcmp(g, one + i * size, size) != 0;
                for (size_t k = size; k < stride; k++)
                    bad |= g[k] != 0xa5;
                if (bad && failures++ < MAX_REPORTS) {
                    char what[96];
                    snprintf(what, sizeof what, "[%s%s] %s%s", backend, label, occluded ? "occluded" : "intersect",
                             pass ? "_batch" : "1M");
                    print_ray(what, s, i, &rays[i]);
                    const rtk_rayhit *a = (const void *)(one + i * size), *b = (const void *)g;
                    print_message("    differs from the single call: tfar %a / %a, geom %u / %u, prim %u / %u, "
                                  "u %a / %a, v %a / %a\n",
                                  a->ray.tfar, b->ray.tfar, occluded ? 0 : a->hit.geomID, occluded ? 0 : b->hit.geomID,
                                  occluded ? 0 : a->hit.primID, occluded ? 0 : b->hit.primID, occluded ? 0 : a->hit.u,
                                  occluded ? 0 : b->hit.u, occluded ? 0 : a->hit.v, occluded ? 0 : b->hit.v);
                }
            }
        }
        free(one);
        free(many);
        free(all);
    }
    return failures;
}

/* Rays [0, n) through the calls of widths[first .. end) (1, 4, 8, 16),
 * intersect and occluded, compared with base; label names the backend and
 * layout in messages.  Returns the failures. */
static int check_calls(rtk_scene scene, const scene_data *s, const rtk_ray *rays, size_t n, int first, int end,
                       answer *const base[2], answer *got, const char *backend, const char *label, size_t *ties)
{
    static const unsigned widths[4] = {1, 4, 8, 16};
    int failures = 0;
    for (int wi = first; wi < end; wi++)
        for (int occluded = 0; occluded < 2; occluded++) {
            char what[96];
            snprintf(what, sizeof what, "[%s%s] %s%u", backend, label, occluded ? "occluded" : "intersect",
                     widths[wi]);
            if (widths[wi] == 1)
                trace1(scene, rays, n, occluded, got);
            else
                failures += trace_packets(scene, rays, n, widths[wi], occluded, got, s, backend);
            failures += compare(s, rays, n, occluded, base[occluded], got, what, ties);
        }
    /* streams on every scene, batches (the same kernels on the device's
     * threads) on a quarter of the rays */
    failures += check_streams(scene, s, rays, n, backend, label, 0);
    failures += check_streams(scene, s, rays, n / 4, backend, label, 1);
    return failures;
}

/* Masks, culling and filters (rtk.h): the geometry's mask is 2 and a
 * filter rejects every fifth triangle (by primID: the same in every
 * backend); the rays take masks 1 (which sees nothing), 2 and all ones and
 * flags none, CULL_BACK and CULL_FRONT in turn.  Every backend and layout,
 * and the triangles given as quads (v3 == v2: the same hits and ids),
 * single rays and packets, against the scalar backend's answers, on a
 * 32nd of the rays (the features' path tests candidates in scalar code,
 * slower per ray).  (Embree has no runtime culling, so it sits out.) */
static int reject_fifth(const rtk_filter_args *a)
{
    return a->hit->primID % 5 != 0;
}

static int check_features(const scene_data *s, const rtk_ray *all, size_t n_all, char names[][32], size_t nb)
{
    const size_t n = (n_all / 32 + 15) / 16 * 16; /* whole packets of 16 (trace_packets) */
    rtk_ray *rays = malloc(n * sizeof *rays);
    answer *base[2] = {malloc(n * sizeof(answer)), malloc(n * sizeof(answer))};
    answer *got = malloc(n * sizeof(answer));
    assert_true(rays && base[0] && base[1] && got);
    static const uint32_t masks[3] = {1u, 2u, ~0u};
    static const uint32_t flags[3] = {0u, RTK_RAY_FLAG_CULL_BACK, RTK_RAY_FLAG_CULL_FRONT};
    for (size_t i = 0; i < n; i++) {
        rays[i] = all[i * 32 % n_all];
        rays[i].mask = masks[i % 3];
        rays[i].flags = flags[(i / 3) % 3];
    }
    uint32_t *quads = malloc((s->nt ? s->nt : 1) * 4 * sizeof *quads);
    assert_non_null(quads);
    for (size_t t = 0; t < s->nt; t++) {
        memcpy(&quads[4 * t], &s->idx[3 * t], 3 * sizeof *quads);
        quads[4 * t + 3] = s->idx[3 * t + 2];
    }
    int failures = 0;
    size_t ties = 0, hits = 0;
    for (size_t bc = 0; bc < 3 * nb; bc++) {
        const size_t b = bc % nb;
        const int compact = bc / nb == 1, as_quads = bc / nb == 2;
        rtk_device dev = test_device(names[b]);
        rtk_geometry g;
        rtk_scene scene = conformance_scene(dev, s, compact ? RTK_SCENE_FLAG_COMPACT : RTK_SCENE_FLAG_NONE, &g,
                                            as_quads ? quads : NULL);
        assert_int_equal(rtk_geometry_set_mask(g, 2u), RTK_OK);
        assert_int_equal(rtk_geometry_set_intersect_filter(g, reject_fifth), RTK_OK);
        assert_int_equal(rtk_geometry_set_occluded_filter(g, reject_fifth), RTK_OK);
        assert_int_equal(rtk_geometry_commit(g), RTK_OK);
        if (rtk_scene_commit(scene) != RTK_OK)
            fail_msg("commit: %s", rtk_device_get_error_message(dev));
        if (bc == 0) {
            trace1(scene, rays, n, 0, base[0]);
            trace1(scene, rays, n, 1, base[1]);
            for (size_t i = 0; i < n; i++) {
                const int hit = base[0][i].prim != RTK_INVALID_GEOMETRY_ID;
                hits += (size_t)hit;
                if ((hit && (rays[i].mask == 1u || base[0][i].prim % 5 == 0)) ||
                    hit != base[1][i].occluded) {
                    if (failures++ < MAX_REPORTS)
                        print_ray("features: a masked-out or filtered hit, or intersect and occluded differ, on", s,
                                  i, &rays[i]);
                }
            }
        }
        failures += check_calls(scene, s, rays, n, bc == 0, 4, base, got, names[b],
                                compact ? " compact features" : as_quads ? " quads features" : " features", &ties);
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
    print_message("%s, with masks, culling and a filter: %zu rays x %zu backends x 3 (default, compact, quads) x 8 "
                  "calls: %zu hits, %zu ties adjudicated, %d failures\n",
                  s->name, n, nb, hits, ties, failures);
    free(quads);
    free(rays);
    free(base[0]);
    free(base[1]);
    free(got);
    return failures;
}

/* User geometry (rtk.h): balls given by callbacks, geometry 1 beside the
 * triangles (geometry 0): a ball per 128 triangles (at least 16, at most
 * 1024), each centred on a triangle with a radius of 0.4% to 1.6% of the
 * scene's diagonal, so closest hits mix balls and triangles and shadow
 * rays end on either; in the moving scene the triangles move and the balls
 * stay.  Every backend, default and compact layouts, single rays and
 * packets (whose callbacks get the packet whole), against the scalar
 * backend's answers, on a 64th of the rays; with Embree 3 present, its
 * user geometry on the same arithmetic (test_sphere_hit) by versus_embree's
 * rules. */
static unsigned ball_packet_calls; /* callback calls with N > 1 */

static void ball_bounds(const rtk_bounds_args *a)
{
    const float *b = ((const float (*)[4])a->geometry_user)[a->prim_id];
    for (int k = 0; k < 3; k++) {
        a->lower[k] = b[k] - b[3];
        a->upper[k] = b[k] + b[3];
    }
}

static void ball_query(const rtk_user_query_args *a, int occluded)
{
    const float *b = ((const float (*)[4])a->geometry_user)[a->prim_id];
    ball_packet_calls += a->N > 1;
    for (uint32_t i = 0; i < a->N; i++) {
        if (!a->valid[i])
            continue;
        const float o[3] = {TEST_LANE(a->rays, a->N, 0, i), TEST_LANE(a->rays, a->N, 1, i),
                            TEST_LANE(a->rays, a->N, 2, i)};
        const float d[3] = {TEST_LANE(a->rays, a->N, 4, i), TEST_LANE(a->rays, a->N, 5, i),
                            TEST_LANE(a->rays, a->N, 6, i)};
        float t;
        if (!test_sphere_hit(b, b[3], o, d, TEST_LANE(a->rays, a->N, 3, i), TEST_LANE(a->rays, a->N, 8, i), &t))
            continue;
        TEST_LANE(a->rays, a->N, 8, i) = occluded ? -INFINITY : t;
        if (occluded)
            continue;
        for (int k = 0; k < 3; k++)
            TEST_LANE(a->rays, a->N, 12 + k, i) = o[k] + t * d[k] - b[k];
        TEST_LANE(a->rays, a->N, 15, i) = TEST_LANE(a->rays, a->N, 16, i) = 0.0f;
    }
}
static void ball_intersect(const rtk_user_query_args *a) { ball_query(a, 0); }
static void ball_occluded(const rtk_user_query_args *a) { ball_query(a, 1); }

static int check_user(scene_data *s, const rtk_ray *all, size_t n_all, char names[][32], size_t nb)
{
    const size_t n = (n_all / 64 + 15) / 16 * 16; /* whole packets of 16 (trace_packets) */
    rtk_ray *rays = malloc(n * sizeof *rays);
    answer *base[2] = {malloc(n * sizeof(answer)), malloc(n * sizeof(answer))};
    answer *got = malloc(n * sizeof(answer));
    size_t nballs = s->nt / 128;
    nballs = nballs < 16 ? 16 : nballs > 1024 ? 1024 : nballs;
    float(*balls)[4] = malloc(nballs * sizeof *balls);
    assert_true(rays && base[0] && base[1] && got && balls);
    for (size_t i = 0; i < n; i++) /* (the features' rays are i * 32) */
        rays[i] = all[(i * 64 + 16) % n_all];
    float lo[3], hi[3];
    const float diag = scene_box(s, lo, hi);
    rng r = {0xba11u ^ (uint64_t)s->nt};
    for (size_t b = 0; b < nballs; b++) {
        const uint32_t t = rng_u32(&r) % (uint32_t)s->nt;
        for (int k = 0; k < 3; k++)
            balls[b][k] = (s->v[3 * (size_t)s->idx[3 * t] + k] + s->v[3 * (size_t)s->idx[3 * t + 1] + k] +
                           s->v[3 * (size_t)s->idx[3 * t + 2] + k]) / 3.0f;
        balls[b][3] = diag * (0.004f + 0.012f * rng_float(&r));
    }
    s->balls = (const float (*)[4])balls;
    s->nballs = nballs;
    int failures = 0;
    size_t ties = 0, on_balls = 0, on_triangles = 0;
    for (size_t bc = 0; bc < 2 * nb; bc++) {
        const size_t b = bc % nb;
        const int compact = bc >= nb;
        rtk_device dev = test_device(names[b]);
        rtk_geometry g, u;
        rtk_scene scene = conformance_scene(dev, s, compact ? RTK_SCENE_FLAG_COMPACT : RTK_SCENE_FLAG_NONE, &g, NULL);
        u = test_user_geometry(dev, (uint32_t)nballs, balls, ball_bounds, ball_intersect, ball_occluded);
        assert_int_equal(rtk_geometry_commit(u), RTK_OK);
        uint32_t id;
        assert_int_equal(rtk_scene_attach_geometry(scene, u, &id), RTK_OK);
        assert_int_equal(id, 1);
        rtk_geometry_release(u);
        if (rtk_scene_commit(scene) != RTK_OK)
            fail_msg("commit: %s", rtk_device_get_error_message(dev));
        if (bc == 0) {
            trace1(scene, rays, n, 0, base[0]);
            trace1(scene, rays, n, 1, base[1]);
            for (size_t i = 0; i < n; i++) {
                const int hit = base[0][i].prim != RTK_INVALID_GEOMETRY_ID;
                on_balls += (size_t)(hit && base[0][i].geom == 1);
                on_triangles += (size_t)(hit && base[0][i].geom == 0);
                if (hit != base[1][i].occluded && failures++ < MAX_REPORTS)
                    print_ray("user geometry: intersect1 and occluded1 differ on", s, i, &rays[i]);
            }
        }
        const unsigned packet_calls = ball_packet_calls;
        failures += check_calls(scene, s, rays, n, bc == 0, 4, base, got, names[b],
                                compact ? " compact user geometry" : " user geometry", &ties);
        if (ball_packet_calls == packet_calls && failures++ < MAX_REPORTS)
            print_message("%s [%s]: no callback call with N > 1 from packet queries\n", s->name, names[b]);
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
    /* both kinds must be hit for the pass to test their mixing */
    if ((!on_balls || !on_triangles) && failures++ < MAX_REPORTS)
        print_message("%s, user geometry: %zu hits on balls, %zu on triangles: the scene does not mix them\n", s->name,
                      on_balls, on_triangles);
    print_message("%s, with %zu balls as user geometry: %zu rays x %zu backends x 2 layouts x 8 calls: %zu hits on "
                  "balls, %zu on triangles, %zu ties adjudicated, %d failures\n",
                  s->name, nballs, n, nb, on_balls, on_triangles, ties, failures);
#ifdef RTK_HAVE_EMBREE
    failures += versus_embree(s, rays, n, base[0], base[1]);
#endif
    s->balls = NULL;
    s->nballs = 0;
    free(balls);
    free(rays);
    free(base[0]);
    free(base[1]);
    free(got);
    return failures;
}

static int check_scene(scene_data *s, char names[][32], size_t nb)
{
    const size_t n = ray_count();
    rtk_ray *rays = malloc(n * sizeof *rays);
    answer *base[2] = {malloc(n * sizeof(answer)), malloc(n * sizeof(answer))};
    answer *got = malloc(n * sizeof(answer));
    assert_true(rays && base[0] && base[1] && got);
    make_rays(s, rays, n, 0x9e3779b9u ^ (uint64_t)s->nt);
    make_spheres(s);

    int failures = 0;
    size_t ties = 0, hits = 0, occl = 0;
    /* every backend with its default layout, then every backend compact,
     * then every backend's Morton tree (low quality, default layout); a
     * moving scene's compact pass (motion blur has no compact layout) is
     * its 4-wide motion layout where the default is the 8-wide one */
    for (size_t bc = 0; bc < 3 * nb; bc++) {
        const size_t b = bc % nb;
        const int compact = bc >= nb && bc < 2 * nb, morton = bc >= 2 * nb;
        rtk_device dev = NULL;
        char config[96];
        snprintf(config, sizeof config, "isa=%s,motion_layout=bvh4.triangle4mb", names[b]);
        if (compact && s->v1 && strcmp(names[b], "scalar")) { /* (every backend but scalar has 8-wide nodes) */
            if (rtk_device_new(config, &dev) != RTK_OK)
                fail_msg("device %s: %s", config, rtk_device_get_error_message(NULL));
        } else {
            dev = test_device(names[b]);
        }
        rtk_geometry g;
        rtk_scene scene =
            conformance_scene(dev, s, compact ? RTK_SCENE_FLAG_COMPACT : RTK_SCENE_FLAG_NONE, &g, NULL);
        assert_int_equal(rtk_scene_set_build_quality(scene, morton ? RTK_BUILD_QUALITY_LOW : RTK_BUILD_QUALITY_MEDIUM),
                         RTK_OK);
        if (rtk_scene_commit(scene) != RTK_OK)
            fail_msg("commit: %s", rtk_device_get_error_message(dev));
        if (bc == 0) { /* the baseline: scalar, default layout, single rays */
            assert_string_equal(names[0], "scalar");
            trace1(scene, rays, n, 0, base[0]);
            trace1(scene, rays, n, 1, base[1]);
            for (size_t i = 0; i < n; i++) {
                hits += base[0][i].prim != RTK_INVALID_GEOMETRY_ID;
                occl += (size_t)base[1][i].occluded;
                /* intersect and occluded must agree with each other */
                if ((base[0][i].prim != RTK_INVALID_GEOMETRY_ID) != base[1][i].occluded && failures++ < MAX_REPORTS)
                    print_ray("intersect1 and occluded1 differ on", s, i, &rays[i]);
            }
        }
        /* a Morton tree differs from the SAH tree in shape only: single
         * rays and the 4- and 8-wide packet kernels (16 is two 8s), on the
         * first quarter of the rays (the kernels are the SAH tree's, which
         * get them all; this keeps CI within its time) */
        failures += check_calls(scene, s, rays, morton ? n / 4 / 48 * 48 : n, bc == 0, morton ? 3 : 4, base, got,
                                names[b], compact ? " compact" : morton ? " morton" : "", &ties);
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
    /* the robust layouts' streams against their single rays (their hits
     * differ from the default's baseline where it leaks), on a quarter */
    for (size_t b = 0; b < nb; b++) {
        rtk_device dev = test_device(names[b]);
        rtk_geometry g;
        rtk_scene scene = conformance_scene(dev, s, RTK_SCENE_FLAG_ROBUST, &g, NULL);
        if (rtk_scene_commit(scene) != RTK_OK)
            fail_msg("commit: %s", rtk_device_get_error_message(dev));
        failures += check_streams(scene, s, rays, n / 4, names[b], " robust", 1);
        rtk_scene_release(scene);
        rtk_device_release(dev);
    }
    print_message("%s: %zu triangles, %zu rays x %zu backends x (2 layouts x 8 calls + Morton x 6 calls on a quarter; "
                  "each also as streams, and on a quarter as batches and robust streams): %zu hits, "
                  "%zu occluded, %zu ties adjudicated, %d failures\n",
                  s->name, s->nt, n, nb, hits, occl, ties, failures);
    failures += check_features(s, rays, n, names, nb);
    failures += check_user(s, rays, n, names, nb);
#ifdef RTK_HAVE_EMBREE
    failures += versus_embree(s, rays, n, base[0], base[1]);
#endif
    free(s->sphere);
    free(rays);
    free(base[0]);
    free(base[1]);
    free(got);
    return failures;
}

/* ---- scenes ---- */

static unsigned part = 1, parts = 1; /* this run's share of the meshes: see main */

/* Backends with scalar first (the baseline). */
static size_t backends(char names[][32])
{
    size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    assert_true(nb >= 1);
    for (size_t i = 0; i < nb; i++)
        if (!strcmp(names[i], "scalar") && i) {
            char t[32];
            memcpy(t, names[0], 32);
            memcpy(names[0], names[i], 32);
            memcpy(names[i], t, 32);
        }
    return nb;
}

static void test_shared_meshes(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = backends(names);
    char *files[64];
    const size_t n = test_mesh_files(files, 64, getenv("RTK_CONFORMANCE_ONLY") /* one mesh, for replays */);
    assert_true(n >= 1);
    int failures = 0;
    for (size_t i = 0; i < n; i++) {
        if (i % parts != part - 1) {
            free(files[i]);
            continue;
        }
        rtk_mesh m;
        char err[1024];
        if (rtk_mesh_load(files[i], &m, err, sizeof err))
            fail_msg("%s", err);
        scene_data s = {.v = m.vertices, .nv = m.vertex_count, .idx = m.indices, .nt = m.triangle_count};
        snprintf(s.name, sizeof s.name, "%s", strrchr(files[i], '/') + 1);
        failures += check_scene(&s, names, nb);
        rtk_mesh_free(&m);
        free(files[i]);
    }
    assert_int_equal(failures, 0);
}

/* A regular grid of quads, two triangles each, on the plane z = 0: every
 * interior edge and vertex is shared, and the camera rays of make_rays aimed
 * at vertices and edge midpoints land exactly on them. */
static void test_grid(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = backends(names);
    enum { G = 256 };
    float *v = malloc((G + 1) * (G + 1) * 3 * sizeof *v);
    uint32_t *idx = malloc(G * G * 6 * sizeof *idx);
    for (int y = 0; y <= G; y++)
        for (int x = 0; x <= G; x++) {
            float *p = v + 3 * (y * (G + 1) + x);
            p[0] = (float)x / G;
            p[1] = (float)y / G;
            p[2] = 0.0f;
        }
    size_t nt = 0;
    for (int y = 0; y < G; y++)
        for (int x = 0; x < G; x++) {
            const uint32_t a = (uint32_t)(y * (G + 1) + x), b = a + 1, c = a + G + 1, d = c + 1;
            const uint32_t t[6] = {a, b, d, a, d, c};
            memcpy(idx + 3 * nt, t, sizeof t);
            nt += 2;
        }
    scene_data s = {.name = "procedural grid", .v = v, .nv = (G + 1) * (G + 1), .idx = idx, .nt = nt};
    assert_int_equal(check_scene(&s, names, nb), 0);
    free(v);
    free(idx);
}

/* A UV sphere (needles and fans of thin triangles at the poles) inside a
 * soup of random overlapping triangles, some far thinner than wide. */
enum { RINGS = 200, SEGS = 400, SOUP = 50000 }; /* the sphere's vertices come first, then the soup's */
static scene_data sphere_and_soup(void)
{
    const size_t nv = (size_t)(RINGS + 1) * SEGS + 3 * SOUP, nt = (size_t)RINGS * SEGS * 2 + SOUP;
    float *v = malloc(nv * 3 * sizeof *v);
    uint32_t *idx = malloc(nt * 3 * sizeof *idx);
    size_t k = 0, t = 0;
    for (int r = 0; r <= RINGS; r++)
        for (int s = 0; s < SEGS; s++) {
            const float th = 3.14159265f * (float)r / RINGS, ph = 6.2831853f * (float)s / SEGS;
            v[3 * k] = sinf(th) * cosf(ph);
            v[3 * k + 1] = cosf(th);
            v[3 * k + 2] = sinf(th) * sinf(ph);
            k++;
        }
    for (int r = 0; r < RINGS; r++)
        for (int s = 0; s < SEGS; s++) {
            const uint32_t a = (uint32_t)(r * SEGS + s), b = (uint32_t)(r * SEGS + (s + 1) % SEGS), c = a + SEGS,
                           d = b + SEGS;
            const uint32_t q[6] = {a, b, d, a, d, c};
            memcpy(idx + 3 * t, q, sizeof q);
            t += 2;
        }
    rng g = {42};
    for (int i = 0; i < SOUP; i++) {
        float c[3], e[3];
        for (int j = 0; j < 3; j++)
            c[j] = 3.0f * rng_float(&g) - 1.5f;
        const float size = (i % 5 == 0 ? 0.3f : 0.03f) * rng_float(&g) + 1e-4f;
        for (int vtx = 0; vtx < 3; vtx++) {
            for (int j = 0; j < 3; j++)
                e[j] = (rng_float(&g) - 0.5f) * size * (i % 7 == 0 && j ? 1e-3f : 1.0f);
            for (int j = 0; j < 3; j++)
                v[3 * k + j] = c[j] + e[j];
            idx[3 * t + vtx] = (uint32_t)k++;
        }
        t++;
    }
    return (scene_data){.name = "procedural sphere and soup", .v = v, .nv = k, .idx = idx, .nt = t};
}

static void test_sphere_and_soup(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = backends(names);
    scene_data s = sphere_and_soup();
    assert_int_equal(check_scene(&s, names, nb), 0);
    free((float *)s.v);
    free((uint32_t *)s.idx);
}

/* The same scene with motion blur: at time step 1 the whole turned about
 * y by 0.3 radians and moved by (0.2, 0.1, 0), and every soup vertex
 * moved on its own by up to 0.05 (the soup's triangles deform). */
static void test_sphere_and_soup_moving(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = backends(names);
    scene_data s = sphere_and_soup();
    float *v1 = malloc(s.nv * 3 * sizeof *v1);
    assert_non_null(v1);
    const float c = cosf(0.3f), sn = sinf(0.3f);
    rng g = {7};
    for (size_t i = 0; i < s.nv; i++) {
        const float *p = s.v + 3 * i;
        const int soup = i >= (size_t)(RINGS + 1) * SEGS;
        v1[3 * i] = c * p[0] + sn * p[2] + 0.2f + (soup ? 0.1f * rng_float(&g) - 0.05f : 0.0f);
        v1[3 * i + 1] = p[1] + 0.1f + (soup ? 0.1f * rng_float(&g) - 0.05f : 0.0f);
        v1[3 * i + 2] = -sn * p[0] + c * p[2] + (soup ? 0.1f * rng_float(&g) - 0.05f : 0.0f);
    }
    s.v1 = v1;
    snprintf(s.name, sizeof s.name, "procedural sphere and soup, moving");
    assert_int_equal(check_scene(&s, names, nb), 0);
    free(v1);
    free((float *)s.v);
    free((uint32_t *)s.idx);
}

/* "test_conformance K/N" runs part K of N, so ctest can spread the suite
 * over cores: the procedural scenes in part 1, the shared meshes dealt out
 * in turn (by sorted name).
 * No argument: everything. */
int main(int argc, char **argv)
{
    if (argc > 1 && (sscanf(argv[1], "%u/%u", &part, &parts) != 2 || part < 1 || part > parts)) {
        fprintf(stderr, "usage: test_conformance [K/N]\n");
        return 2;
    }
    const struct CMUnitTest all[] = {
        cmocka_unit_test(test_grid),
        cmocka_unit_test(test_sphere_and_soup),
        cmocka_unit_test(test_sphere_and_soup_moving),
        cmocka_unit_test(test_shared_meshes),
    };
    if (part == 1)
        return cmocka_run_group_tests(all, NULL, NULL);
    const struct CMUnitTest meshes_only[] = {
        cmocka_unit_test(test_shared_meshes),
    };
    return cmocka_run_group_tests(meshes_only, NULL, NULL);
}
