/* The points section: closest points (rtk_closest_point) against Embree's
 * rtcPointQuery, same points, same run. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"
#include "geometry/closest_point.h"

/* Embree's closest point is the application's: rtcPointQuery walks the
 * tree and calls this for each triangle within the query's radius, and it
 * shrinks the radius as it finds nearer ones (Embree's closest_point
 * tutorial does the same).  It measures with rtk's own triangle routine, in
 * double, so the two differ in their walks only, and like rtk it passes
 * over triangles without area. */
typedef struct embree_best {
    const rtk_mesh *m;
    double q[3];
    double d2;
    uint32_t prim;
} embree_best;

static bool embree_point_fn(struct RTCPointQueryFunctionArguments *args)
{
    embree_best *b = args->userPtr;
    const uint32_t *t = &b->m->indices[3 * (size_t)args->primID];
    double v[3][3];
    for (int k = 0; k < 3; k++)
        for (int a = 0; a < 3; a++)
            v[k][a] = b->m->vertices[3 * (size_t)t[k] + a];
    const double e1[3] = {v[1][0] - v[0][0], v[1][1] - v[0][1], v[1][2] - v[0][2]};
    const double e2[3] = {v[2][0] - v[0][0], v[2][1] - v[0][1], v[2][2] - v[0][2]};
    const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
    if (n[0] == 0.0 && n[1] == 0.0 && n[2] == 0.0)
        return false;
    rtk_tri_closest r;
    rtk_closest_point_triangle(&r, b->q, v[0], v[1], v[2]);
    if (!(r.d2 < b->d2))
        return false;
    b->d2 = r.d2;
    b->prim = args->primID;
    args->query->radius = nextafterf((float)sqrt(r.d2), INFINITY);
    return true;
}

enum { POINTS_NEAR, POINTS_BOX, NPOINTSETS };
static const char *const point_set_names[NPOINTSETS] = {"near", "box"};

/* "near": points of random triangles moved off the surface by up to 1%
 * of the box's diagonal in every direction (what a remeshing or
 * registration tool asks); "box": uniform in the mesh's box grown by 10%
 * on each side (what a distance field asks). */
static void make_points(const rtk_mesh *m, int set, size_t n, const float lo[3], const float hi[3], double diag,
                        rtk_point_query *q)
{
    for (size_t i = 0; i < n; i++) {
        double p[3];
        if (set == POINTS_NEAR) {
            const uint32_t *t = &m->indices[3 * ((size_t)(rnd() * (float)m->triangle_count) % m->triangle_count)];
            double u = rnd(), v = rnd();
            if (u + v > 1)
                u = 1 - u, v = 1 - v;
            for (int a = 0; a < 3; a++)
                p[a] = (1 - u - v) * m->vertices[3 * t[0] + a] + u * m->vertices[3 * t[1] + a] +
                       v * m->vertices[3 * t[2] + a] + (rnd() * 2 - 1) * 0.01 * diag;
        } else {
            for (int a = 0; a < 3; a++) {
                const double pad = 0.1 * (hi[a] - lo[a]);
                p[a] = lo[a] - pad + rnd() * (hi[a] - lo[a] + 2 * pad);
            }
        }
        q[i] = (rtk_point_query){.x = p[0], .y = p[1], .z = p[2], .radius = INFINITY};
    }
}

/* Queries through one library, one at a time on this thread; the
 * distances into d, the seconds taken returned. */
static double run_points(scene *sc, const rtk_mesh *m, const rtk_point_query *q, size_t n, double *d, int *fail)
{
    const double t0 = now();
    if (sc->escene) {
        struct RTCPointQueryContext pc;
        for (size_t i = 0; i < n; i++) {
            rtcInitPointQueryContext(&pc);
            embree_best b = {.m = m, .q = {q[i].x, q[i].y, q[i].z}, .d2 = INFINITY, .prim = RTC_INVALID_GEOMETRY_ID};
            struct RTCPointQuery eq = {.x = (float)q[i].x, .y = (float)q[i].y, .z = (float)q[i].z, .time = 0.0f,
                                       .radius = INFINITY};
            rtcPointQuery(sc->escene, &eq, &pc, embree_point_fn, &b);
            d[i] = sqrt(b.d2);
        }
    } else {
        for (size_t i = 0; i < n; i++) {
            rtk_point_hit h;
            if (rtk_closest_point(sc->rscene, &q[i], &h) != RTK_OK) {
                *fail = 1;
                return 0;
            }
            d[i] = h.distance;
        }
    }
    return now() - t0;
}

/* rtk's batch rows on one thread count: rtk_closest_point_batch over the
 * queries q into h, then rtk_closest_point_arrays over the same points as
 * packed doubles (xyz), distances alone into da, each the best of the
 * repeats, and every distance of the arrays checked equal to the batch's. */
static int batch_rows(ctx *c, lib *bl, scene *bs, int set, int threads, double ref_rate, const rtk_point_query *q,
                      const double *xyz, size_t n, rtk_point_hit *h, double *da, char *err, size_t err_size)
{
    const int repeat = c->o->repeat;
    double bb = INFINITY;
    for (int r = 0; r < repeat; r++) {
        const double t0 = now();
        if (rtk_closest_point_batch(bs->rscene, q, h, n) != RTK_OK) {
            snprintf(err, err_size, "%s: rtk_closest_point_batch: %s", bl->name, rtk_device_get_error_message(bl->rdev));
            return 1;
        }
        const double s = now() - t0;
        bb = s < bb ? s : bb;
    }
    const rtk_point_arrays a = {.points = xyz, .points_double = 1, .radius = INFINITY, .distances = da};
    double ba = INFINITY;
    for (int r = 0; r < repeat; r++) {
        const double t0 = now();
        if (rtk_closest_point_arrays(bs->rscene, &a, n) != RTK_OK) {
            snprintf(err, err_size, "%s: rtk_closest_point_arrays: %s", bl->name, rtk_device_get_error_message(bl->rdev));
            return 1;
        }
        const double s = now() - t0;
        ba = s < ba ? s : ba;
    }
    size_t differ = 0;
    for (size_t i = 0; i < n; i++)
        differ += memcmp(&da[i], &h[i].distance, sizeof da[i]) != 0;
    if (differ) {
        snprintf(err, err_size, "%s: rtk_closest_point_arrays: %zu of %zu distances differ from "
                 "rtk_closest_point_batch's", bl->name, differ, n);
        return 1;
    }
    const double secs[2] = {bb, ba};
    const char *const kind[2] = {"batch", "arrays"};
    for (int k = 0; k < 2; k++) {
        const double rate = (double)n / secs[k];
        printf("  %-20s %-5s %8d %10.3f %7.2fx %10.0f  (%s)\n", bl->name, point_set_names[set], threads, rate * 1e-6,
               ratio(rate, ref_rate), secs[k] / (double)n * 1e9, kind[k]);
        csv_row(&c->csv, "points", bl->name, "default", point_set_names[set], kind[k], threads, rate * 1e-6,
                "Mpoints/s", ratio(rate, ref_rate));
    }
    return 0;
}

int section_points(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    const size_t n = 100000;
    printf("\npoints: closest points to %zu points per set, one query at a time on 1 thread (rtk: rtk_closest_point; "
           "Embree: rtcPointQuery with a callback measuring each triangle with rtk's routine, in double); "
           "batch: rtk_closest_point_batch over the device's threads (arrays: rtk_closest_point_arrays on the same "
           "points as packed doubles, distances alone, as a distance query asks); best of %d; agreement: distances "
           "equal to 1e-6 of the box's diagonal\n",
           n, o->repeat);
    printf("  %-20s %-5s %8s %10s %8s %10s %7s %9s\n", "library", "set", "threads", "Mpoints/s", "ratio", "ns/point",
           "agree", "max diff");
    rtk_point_query *q = malloc(n * sizeof *q);
    rtk_point_hit *h = malloc(n * sizeof *h);
    double *d = malloc(n * sizeof *d), *dref = malloc(n * sizeof *dref);
    double *xyz = malloc(3 * n * sizeof *xyz), *da = malloc(n * sizeof *da);
    if (!q || !h || !d || !dref || !xyz || !da) {
        free(q);
        free(h);
        free(d);
        free(dref);
        free(xyz);
        free(da);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    float lo[3], hi[3];
    const double diag = rtk_mesh_bounds(c->m, lo, hi);
    int rc = 0;
    for (int set = 0; set < NPOINTSETS && !rc; set++) {
        make_points(c->m, set, n, lo, hi, diag, q);
        for (size_t i = 0; i < n; i++)
            xyz[3 * i] = q[i].x, xyz[3 * i + 1] = q[i].y, xyz[3 * i + 2] = q[i].z;
        double ref_rate = 0;
        for (int l = 0; l < c->nlibs && !rc; l++) {
            scene sc;
            rc = scene_build(&sc, &c->libs[l], c->m, c->padded, MODE_DEFAULT, 1, err, err_size);
            if (rc)
                break;
            double best = INFINITY;
            int fail = 0;
            for (int r = 0; r < o->repeat && !fail; r++) {
                const double s = run_points(&sc, c->m, q, n, d, &fail);
                best = s < best ? s : best;
            }
            if (fail) {
                snprintf(err, err_size, "%s: rtk_closest_point: %s", c->libs[l].name,
                         rtk_device_get_error_message(c->libs[l].rdev));
                scene_release(&sc);
                rc = 1;
                break;
            }
            if (l == 0)
                memcpy(dref, d, n * sizeof *d);
            size_t agree = 0;
            double maxdiff = 0;
            for (size_t i = 0; i < n; i++) {
                const double diff = fabs(d[i] - dref[i]);
                agree += diff <= 1e-6 * diag;
                maxdiff = diff > maxdiff ? diff : maxdiff;
            }
            const double rate = (double)n / best;
            if (l == 0)
                ref_rate = rate;
            printf("  %-20s %-5s %8d %10.3f %7.2fx %10.0f %6.2f%% %9.2g\n", c->libs[l].name, point_set_names[set], 1,
                   rate * 1e-6, ratio(rate, ref_rate), best / (double)n * 1e9, 100.0 * (double)agree / (double)n,
                   maxdiff);
            csv_row(&c->csv, "points", c->libs[l].name, "default", point_set_names[set], "single", 1, rate * 1e-6,
                    "Mpoints/s", ratio(rate, ref_rate));
            /* rtk's batch over each thread count asked for */
            if (sc.rscene)
                for (int ti = 0; ti < o->nthreads && !rc; ti++) {
                    lib bl;
                    rc = lib_open(&bl, c->libs[l].name, 0, c->libs[l].config, o->threads[ti], err, err_size);
                    if (rc)
                        break;
                    scene bs;
                    rc = scene_build(&bs, &bl, c->m, c->padded, MODE_DEFAULT, 1, err, err_size);
                    if (!rc) {
                        rc = batch_rows(c, &bl, &bs, set, o->threads[ti], ref_rate, q, xyz, n, h, da, err, err_size);
                        scene_release(&bs);
                    }
                    lib_close(&bl);
                }
            scene_release(&sc);
        }
    }
    free(q);
    free(h);
    free(d);
    free(dref);
    free(xyz);
    free(da);
    return rc;
}
