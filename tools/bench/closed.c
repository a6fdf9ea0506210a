/* The closed section: the accuracy harness on closed procedural meshes. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"
#include "closed_mesh.h"

/* ---- closed meshes: the accuracy harness ---- */

/* What one library and mode did with a group of aimed rays. */
typedef struct closed_tally {
    size_t rays, misses, twice, zero_area;
    double *ulps; /* each hit's t error, in ulps of the reference t */
    size_t nulps, cap;
    double point_err; /* the largest |t - t_ref| over the mesh's diagonal */
    double seconds;   /* intersect1 over the timed groups' rays, best of --repeat */
    size_t timed;
} closed_tally;

static void tally_free(closed_tally *t)
{
    free(t->ulps);
    memset(t, 0, sizeof *t);
}

static int tally_ulps(closed_tally *t, double u)
{
    if (t->nulps == t->cap) {
        const size_t cap = t->cap ? 2 * t->cap : 4096;
        double *p = realloc(t->ulps, cap * sizeof *p);
        if (!p)
            return 1;
        t->ulps = p, t->cap = cap;
    }
    t->ulps[t->nulps++] = u;
    return 0;
}

static void tally_sort(closed_tally *t)
{
    if (t->nulps)
        qsort(t->ulps, t->nulps, sizeof *t->ulps, cmp_double);
}

/* The q-quantile of the tally's t errors (sorted by tally_sort); -1 for none. */
static double tally_quantile(const closed_tally *t, double q)
{
    if (!t->nulps)
        return -1.0;
    size_t i = (size_t)(q * (double)(t->nulps - 1) + 0.5);
    return t->ulps[i < t->nulps ? i : t->nulps - 1];
}

/* Where the ray meets the plane of triangle prim, in long double from the
 * float vertices and ray: the reference t. */
static long double plane_t(const rtk_mesh *m, uint32_t prim, const rtk_ray *r)
{
    const uint32_t *x = m->indices + 3 * (size_t)prim;
    long double v[3][3], e1[3], e2[3], n[3];
    for (int j = 0; j < 3; j++)
        for (int k = 0; k < 3; k++)
            v[j][k] = m->vertices[3 * x[j] + k];
    for (int k = 0; k < 3; k++)
        e1[k] = v[1][k] - v[0][k], e2[k] = v[2][k] - v[0][k];
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    const long double o[3] = {r->org_x, r->org_y, r->org_z}, d[3] = {r->dir_x, r->dir_y, r->dir_z};
    long double num = 0, den = 0;
    for (int k = 0; k < 3; k++)
        num += n[k] * (v[0][k] - o[k]), den += n[k] * d[k];
    return num / den;
}

/* Ways a ray is made invalid, to time what a renderer handing over broken
 * rays pays (rtk only: Embree 3 as Debian builds it asserts ray.valid()
 * and aborts the process). */
enum { NINVALID = 4 };

static const char *const invalid_names[NINVALID] = {"NaN origin", "NaN direction", "inf direction", "NaN tnear"};

/* Seconds of intersect1 over the aimed rays, best of `repeat`; with
 * invalid >= 0 each ray broken the way invalid_names[invalid] says. */
static double time_aimed(const render_tracer *tr, const rtk_aimed *a, int invalid, int repeat)
{
    double best = 1e30;
    for (int r = 0; r < repeat; r++) {
        const double t0 = now();
        for (size_t i = 0; i < a->count; i++) {
            _Alignas(16) rtk_rayhit rh = {.ray = a->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
            if (invalid >= 0)
                *(invalid == 0   ? &rh.ray.org_x
                  : invalid == 1 ? &rh.ray.dir_y
                  : invalid == 2 ? &rh.ray.dir_z
                                 : &rh.ray.tnear) = invalid == 2 ? INFINITY : NAN;
            tr->intersect1(tr->scene, &rh);
        }
        best = fmin(best, now() - t0);
    }
    return best;
}

/* The aimed rays through one library's scene of the mesh in one mode:
 * closest hits (a miss, or a first hit beyond the point inside, is a false
 * miss; a hit's t against the reference), then every crossing before the
 * point inside collected by a filter (an even number, more than none, is a
 * double hit); hits on the triangles after the closed surface (zero area)
 * counted in both.  With `timed`, intersect1 over the rays is timed too,
 * and with `invalid` also over the rays made invalid each way (seconds
 * added to invalid[]). */
static int closed_run(lib *l, int mode, const rtk_closed_mesh *cm, const rtk_aimed *a, int timed, int repeat,
                      closed_tally *t, double *invalid, char *err, size_t err_size)
{
    const rtk_mesh *m = &cm->mesh;
    float lo[3], hi[3];
    const double diag = rtk_mesh_bounds(m, lo, hi);
    scene sc;
    if (scene_build(&sc, l, m, m->vertices, mode, 1, err, err_size))
        return 1;
    render_tracer tr = scene_tracer(&sc, 0);
    int bad = 0;
    for (size_t i = 0; i < a->count; i++) {
        _Alignas(16) rtk_rayhit rh = {.ray = a->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        tr.intersect1(tr.scene, &rh);
        const int hit = rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
        t->misses += !hit || rh.ray.tfar > a->t_in[i];
        if (hit && rh.hit.primID >= cm->closed_triangles) {
            t->zero_area++;
        } else if (hit) {
            const long double tr_ = plane_t(m, rh.hit.primID, &a->rays[i]);
            const float tf = fabsf((float)tr_);
            const double ulp = (double)(nextafterf(tf, INFINITY) - tf);
            const double e = (double)fabsl((long double)rh.ray.tfar - tr_);
            bad |= tally_ulps(t, e / ulp);
            t->point_err = fmax(t->point_err, diag > 0 ? e / diag : 0.0);
        }
    }
    if (timed) {
        t->seconds += time_aimed(&tr, a, -1, repeat);
        t->timed += a->count;
        for (int v = 0; invalid && v < NINVALID; v++)
            invalid[v] += time_aimed(&tr, a, v, repeat);
    }
    scene_release(&sc);
    bench_collect = 1;
    bad |= scene_build(&sc, l, m, m->vertices, mode, 1, err, err_size);
    bench_collect = 0;
    if (bad) {
        if (!err[0])
            snprintf(err, err_size, "out of memory");
        return 1;
    }
    tr = scene_tracer(&sc, 0);
    for (size_t i = 0; i < a->count; i++) {
        _Alignas(16) rtk_rayhit rh = {.ray = a->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        bench_seen.n = 0;
        bench_t_limit = a->t_in[i];
        tr.intersect1(tr.scene, &rh);
        unsigned n = 0, flat = 0;
        for (unsigned k = 0; k < bench_seen.n; k++) {
            n += bench_seen.prim[k] < cm->closed_triangles;
            flat += bench_seen.prim[k] >= cm->closed_triangles;
        }
        t->twice += n && n % 2 == 0;
        t->zero_area += flat != 0;
    }
    bench_t_limit = 1.0f + 1e-4f;
    t->rays += a->count;
    scene_release(&sc);
    return 0;
}

/* The closed meshes of the offset and size sweeps: a sphere, a torus and a
 * box of radius `size` around c, checked closed by OpenMesh, and the rays
 * aimed at them.  The mesh lies within its faceting (under 4% of its size)
 * and the rounding of its vertices of the solid's surface: the margin. */
/* Non-zero, with err saying why, unless OpenMesh finds the mesh's closed
 * surface closed. */
static int closed_check(const rtk_closed_mesh *cm, char *err, size_t err_size)
{
    size_t boundary = 0, rejected = 0;
    if (rtk_mesh_is_closed(&cm->mesh, cm->closed_triangles, &boundary, &rejected) == 1)
        return 0;
    snprintf(err, err_size, "the %s is not closed: %zu boundary edges, %zu faces OpenMesh rejected", cm->name,
             boundary, rejected);
    return 1;
}

static int closed_group(const double c[3], double size, int quick, uint64_t seed, rtk_closed_mesh cm[3],
                        rtk_aimed a[3], char *err, size_t err_size)
{
    memset(cm, 0, 3 * sizeof *cm);
    memset(a, 0, 3 * sizeof *a);
    const double mag = fmax(fabs(c[0]), fmax(fabs(c[1]), fabs(c[2]))) + 2.0 * size;
    const double margin = 0.04 * size + mag * 0x1p-23;
    const int f = quick ? 1 : 2; /* --quick: a quarter of the triangles */
    int bad = rtk_closed_sphere(c, size, 24 * f, 12 * f - 1, &cm[0]) ||
              rtk_closed_torus(c, size, 0.4 * size, 24 * f, 12 * f, &cm[1]) || rtk_closed_box(c, size, 4 * f, &cm[2]);
    for (int i = 0; !bad && i < 3; i++) {
        if (closed_check(&cm[i], err, err_size))
            return 1;
        const float out = (float)((i == 1 ? 0.3 : 1.5) * size), in = (float)((i == 1 ? 0.25 : 0.5) * size);
        bad = rtk_closed_aim(&cm[i], margin, out, in, seed + (uint64_t)i, &a[i]);
    }
    if (bad)
        snprintf(err, err_size, "out of memory");
    return bad;
}

static void closed_group_free(rtk_closed_mesh cm[3], rtk_aimed a[3])
{
    for (int i = 0; i < 3; i++)
        rtk_closed_free(&cm[i]), rtk_aimed_free(&a[i]);
}

enum { NOFF = 9, NSIZE = 9, NGRAZE = 7, CLOSED_MODES = 2 };

typedef struct closed_results {
    closed_tally off[NOFF], size[NSIZE], needle, graze[NGRAZE][2]; /* graze: inside faces, on lines */
    double invalid_seconds[NINVALID]; /* the offset sweep's rays at 10^0 made invalid, intersect1 */
} closed_results;

/* Library-and-mode lm's mode: each library's default, then robust. */
static int closed_mode(int lm)
{
    return lm % CLOSED_MODES ? MODE_ROBUST : MODE_DEFAULT;
}

/* Step k of the offset sweep (sizes: of the size sweep): the three closed
 * meshes of radius `size` around c through every library and mode, into
 * each library-and-mode's tally for that step; `timed`: intersect1 timed
 * too, and for rtk the invalid rays. */
static int closed_sweep_step(ctx *c, closed_results *res, int sizes, int k, const double cc[3], double size,
                             uint64_t seed, int timed, size_t *rays, char *err, size_t err_size)
{
    rtk_closed_mesh cm[3];
    rtk_aimed a[3];
    int bad = closed_group(cc, size, c->o->quick, seed, cm, a, err, err_size);
    for (int i = 0; i < 3; i++)
        *rays += a[i].count;
    for (int lm = 0; !bad && lm < c->nlibs * CLOSED_MODES; lm++) {
        lib *l = &c->libs[lm / CLOSED_MODES];
        closed_tally *t = sizes ? &res[lm].size[k] : &res[lm].off[k];
        for (int i = 0; !bad && i < 3; i++)
            bad = closed_run(l, closed_mode(lm), &cm[i], &a[i], timed, timed ? c->o->repeat : 1, t,
                             timed && !l->embree ? res[lm].invalid_seconds : NULL, err, err_size);
    }
    closed_group_free(cm, a);
    return bad;
}

static double per_million(size_t n, size_t of)
{
    return of ? 1e6 * (double)n / (double)of : 0.0;
}

static void closed_print_row(const char *lib_name, int mode, closed_tally *t, int n, int twice)
{
    printf("  %-18s %-7s", lib_name, mode_names[mode]);
    for (int k = 0; k < n; k++)
        printf(" %8.0f", per_million(twice ? t[k].twice : t[k].misses, t[k].rays));
    printf("\n");
}

/* The accuracy harness: closed meshes (OpenMesh checks them closed) and
 * rays aimed exactly at their vertices and edges, through every library in
 * its default and robust modes:
 *   - the meshes moved to 10^k, k = 0 ... 8 (of radius 1, and from 10^7 on
 *     of radius 10^(k-6), so that their vertices keep 2^-4 of the radius
 *     or better apart after rounding): false misses and double hits, and
 *     the failure envelope, the largest offset before the first false miss;
 *   - meshes of radius 1e-8 ... 1e8 near the origin;
 *   - a cylinder of 4096 needle sides and needle caps, with zero-area
 *     triangles on its side lines (collinear) and caps (a repeated vertex),
 *     which must never be hit;
 *   - rays grazing a flat face at 10^-k degrees, k = 0 ... 6;
 *   - the t error of every hit in ulps against the reference (the ray
 *     against the hit triangle's plane in long double), and the hit point's
 *     error over the mesh's diagonal;
 *   - ns per ray (intersect1, 1 thread) over the offset sweep's rays at
 *     10^0, beside the false-miss rate over every aimed ray: the chart. */
int section_closed(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    const int nlm = c->nlibs * CLOSED_MODES;
    closed_results *res = calloc((size_t)nlm, sizeof *res);
    if (!res) {
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    int bad = 0;
    size_t off_rays[NOFF] = {0}, size_rays[NSIZE] = {0}, needle_rays = 0, graze_n[NGRAZE] = {0};
    printf("\nclosed meshes: rays aimed exactly at every vertex and edge of closed meshes (a sphere, a torus and a box "
           "of %s triangles, OpenMesh checking each closed), from outside the solid to a point "
           "inside it (random directions, and along the axes with the other components +0.0 and -0.0): a ray that "
           "reaches its point inside without a hit is a false miss; one that crosses the mesh an even number of "
           "times (every crossing collected by a filter) has hit one crossing twice.  Per million rays.\n",
           o->quick ? "528, 576 and 192" : "2208, 2304 and 768");
    for (int k = 0; !bad && k < NOFF; k++) {
        const double off = pow(10.0, k);
        const double cc[3] = {off, 0.5 * off, -0.25 * off};
        bad = closed_sweep_step(c, res, 0, k, cc, fmax(1.0, off * 1e-6),
                                17u + 3u * (uint64_t)k, k == 0, &off_rays[k], err, err_size);
    }
    for (int k = 0; !bad && k < NSIZE; k++) {
        const double size = pow(10.0, 2 * k - 8);
        const double cc[3] = {0.3 * size, -0.2 * size, 0.1 * size};
        bad = closed_sweep_step(c, res, 1, k, cc, size, 99u + 3u * (uint64_t)k, 0,
                                &size_rays[k], err, err_size);
    }
    if (!bad) {
        const double cc[3] = {0.25, -0.5, 0.125};
        rtk_closed_mesh cyl;
        rtk_aimed a = {0};
        bad = rtk_closed_cylinder(cc, 1.0, 10.0, o->quick ? 1024 : 4096, 1, &cyl) || closed_check(&cyl, err, err_size) ||
              rtk_closed_aim(&cyl, 1e-5, 1.5f, 0.5f, 4242, &a);
        needle_rays = a.count;
        for (int lm = 0; !bad && lm < nlm; lm++)
            bad = closed_run(&c->libs[lm / CLOSED_MODES], closed_mode(lm), &cyl, &a, 0, 1, &res[lm].needle, NULL, err,
                             err_size);
        rtk_aimed_free(&a);
        rtk_closed_free(&cyl);
    }
    if (!bad) {
        const double cc[3] = {0.0, 0.0, -1.0};
        rtk_closed_mesh box;
        bad = rtk_closed_box(cc, 1.0, 16, &box) || closed_check(&box, err, err_size); /* exact vertices: the mesh is the solid */
        for (int k = 0; !bad && k < 2 * NGRAZE; k++) {
            rtk_aimed a;
            bad = rtk_closed_graze(&box, 16, pow(10.0, -(k / 2)), o->quick ? 1000 : 10000, k % 2, 31u + (uint64_t)k, &a);
            graze_n[k / 2] += a.count;
            for (int lm = 0; !bad && lm < nlm; lm++)
                bad = closed_run(&c->libs[lm / CLOSED_MODES], closed_mode(lm), &box, &a, 0, 1,
                                 &res[lm].graze[k / 2][k % 2], NULL, err, err_size);
            rtk_aimed_free(&a);
        }
        rtk_closed_free(&box);
    }
    if (bad) {
        if (!err[0])
            snprintf(err, err_size, "out of memory");
        goto done;
    }
    for (int lm = 0; lm < nlm; lm++) {
        for (int k = 0; k < NOFF; k++)
            tally_sort(&res[lm].off[k]);
        for (int k = 0; k < NGRAZE; k++)
            tally_sort(&res[lm].graze[k][0]), tally_sort(&res[lm].graze[k][1]);
    }

    printf("\n  moved to 10^k (radius max(1, 10^(k-6))); rays per offset:");
    for (int k = 0; k < NOFF; k++)
        printf(" %zu", off_rays[k]);
    printf("\n  false misses       mode   ");
    for (int k = 0; k < NOFF; k++)
        printf("   10^%-3d", k);
    printf(" envelope\n");
    for (int lm = 0; lm < nlm; lm++) {
        closed_tally *t = res[lm].off;
        printf("  %-18s %-7s", c->libs[lm / CLOSED_MODES].name, mode_names[closed_mode(lm)]);
        int env = -1, gap = 0;
        for (int k = 0; k < NOFF; k++) {
            printf(" %8.0f", per_million(t[k].misses, t[k].rays));
            if (!t[k].misses)
                gap |= env < k - 1, env = k;
        }
        if (env < 0)
            printf("     none\n");
        else
            printf("   1e%d%s\n", env, gap ? " (not below)" : "");
    }
    printf("  double hits\n");
    for (int lm = 0; lm < nlm; lm++)
        closed_print_row(c->libs[lm / CLOSED_MODES].name, closed_mode(lm), res[lm].off, NOFF, 1);

    printf("\n  of radius 10^k near the origin; rays per size:");
    for (int k = 0; k < NSIZE; k++)
        printf(" %zu", size_rays[k]);
    printf("\n  false misses       mode   ");
    for (int k = 0; k < NSIZE; k++)
        printf("  10^%-4d", 2 * k - 8);
    printf("\n");
    for (int lm = 0; lm < nlm; lm++)
        closed_print_row(c->libs[lm / CLOSED_MODES].name, closed_mode(lm), res[lm].size, NSIZE, 0);
    printf("  double hits\n");
    for (int lm = 0; lm < nlm; lm++)
        closed_print_row(c->libs[lm / CLOSED_MODES].name, closed_mode(lm), res[lm].size, NSIZE, 1);

    const int sides = o->quick ? 1024 : 4096;
    printf("\n  needles: a cylinder of radius 1 and height 20 with %d sides (side triangles 20 x %.4f, caps fans of "
           "1 x %.4f) and %d zero-area triangles on its side lines and caps; %zu rays\n",
           sides, 6.2832 / sides, 6.2832 / sides, 2 * sides, needle_rays);
    printf("  %-18s %-7s %14s %14s %16s\n", "library", "mode", "false misses", "double hits", "zero-area hits");
    for (int lm = 0; lm < nlm; lm++) {
        const closed_tally *t = &res[lm].needle;
        printf("  %-18s %-7s %14zu %14zu %16zu\n", c->libs[lm / CLOSED_MODES].name,
               mode_names[closed_mode(lm)], t->misses, t->twice, t->zero_area);
    }

    printf("\n  grazing a flat face at 10^-k degrees (%zu rays each, half at points inside its triangles, half on "
           "their edges or at vertices): false misses per million (inside / on edges), and the t error in ulps "
           "(median / max)\n  %-18s %-7s",
           graze_n[0], "library", "mode");
    for (int k = 0; k < NGRAZE; k++) {
        char head[16];
        snprintf(head, sizeof head, "10^-%d deg", k);
        printf(" %18s", head);
    }
    printf("\n");
    for (int lm = 0; lm < nlm; lm++) {
        printf("  %-18s %-7s", c->libs[lm / CLOSED_MODES].name, mode_names[closed_mode(lm)]);
        for (int k = 0; k < NGRAZE; k++) {
            const closed_tally *t = res[lm].graze[k];
            char cell[40];
            snprintf(cell, sizeof cell, "%.0f/%.0f %.1f/%.0f", per_million(t[0].misses, t[0].rays),
                     per_million(t[1].misses, t[1].rays), fmax(tally_quantile(&t[0], 0.5), tally_quantile(&t[1], 0.5)),
                     fmax(tally_quantile(&t[0], 1.0), tally_quantile(&t[1], 1.0)));
            printf(" %18s", cell);
        }
        printf("\n");
    }

    printf("\n  t error of the hits, in ulps of the reference t (median / 99th percentile / max), and the largest hit "
           "point error over the mesh's diagonal, at 10^0 and 10^6; ns per ray (intersect1, 1 thread, the rays at "
           "10^0)\n");
    printf("  %-18s %-7s %22s %10s %22s %10s %8s\n", "library", "mode", "t ulps at 10^0", "point", "t ulps at 10^6",
           "point", "ns/ray");
    FILE *dat = chart_open(c->charts, "closed-accuracy", 0);
    for (int lm = 0; lm < nlm; lm++) {
        closed_results *r = &res[lm];
        const char *name = c->libs[lm / CLOSED_MODES].name, *mode = mode_names[closed_mode(lm)];
        closed_tally *t0 = &r->off[0], *t6 = &r->off[6];
        const double ns = t0->timed ? 1e9 * t0->seconds / (double)t0->timed : 0.0;
        printf("  %-18s %-7s %6.1f / %5.1f / %6.0f %10.1e %6.1f / %5.1f / %6.0f %10.1e %8.1f\n", name, mode,
               tally_quantile(t0, 0.5), tally_quantile(t0, 0.99), tally_quantile(t0, 1.0), t0->point_err,
               tally_quantile(t6, 0.5), tally_quantile(t6, 0.99), tally_quantile(t6, 1.0), t6->point_err,
               ns);
        size_t all = 0, missed = 0, twice = 0, flat = r->needle.zero_area;
        const closed_tally *groups[3] = {r->off, r->size, r->graze[0]};
        const int counts[3] = {NOFF, NSIZE, 2 * NGRAZE};
        for (int g = 0; g < 3; g++)
            for (int k = 0; k < counts[g]; k++)
                all += groups[g][k].rays, missed += groups[g][k].misses, twice += groups[g][k].twice;
        all += r->needle.rays, missed += r->needle.misses, twice += r->needle.twice;
        char variant[48];
        for (int k = 0; k < NOFF; k++) {
            snprintf(variant, sizeof variant, "%s, at 1e%d", mode, k);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->off[k].misses, r->off[k].rays),
                    "false misses per million", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->off[k].twice, r->off[k].rays),
                    "double hits per million", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, tally_quantile(&r->off[k], 0.5),
                    "median t error, ulps", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, tally_quantile(&r->off[k], 1.0),
                    "max t error, ulps", 0);
        }
        for (int k = 0; k < NSIZE; k++) {
            snprintf(variant, sizeof variant, "%s, size 1e%d", mode, 2 * k - 8);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->size[k].misses, r->size[k].rays),
                    "false misses per million", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->size[k].twice, r->size[k].rays),
                    "double hits per million", 0);
        }
        for (int k = 0; k < 2 * NGRAZE; k++) {
            const closed_tally *t = &r->graze[k / 2][k % 2];
            snprintf(variant, sizeof variant, "%s, grazing 1e-%d deg%s", mode, k / 2, k % 2 ? ", edges" : "");
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(t->misses, t->rays),
                    "false misses per million", 0);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, tally_quantile(t, 1.0),
                    "max t error, ulps", 0);
        }
        snprintf(variant, sizeof variant, "%s, needles", mode);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, (double)flat, "zero-area hits", 0);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(r->needle.misses, r->needle.rays),
                "false misses per million", 0);
        snprintf(variant, sizeof variant, "%s, all", mode);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(missed, all),
                "false misses per million", 0);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, per_million(twice, all),
                "double hits per million", 0);
        csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, ns, "ns per ray", 0);
        if (dat) {
            fprintf(dat, "%.2f %.3f %s\n", ns, per_million(missed, all), mode);
            if (lm % CLOSED_MODES == CLOSED_MODES - 1)
                fprintf(dat, "\n\n"); /* one gnuplot index per library */
        }
    }
    printf("\n  invalid rays (the rays at 10^0 with one field broken; rtk answers them as misses without tracing): "
           "ns per ray, intersect1, 1 thread, and against the valid rays\n  %-18s %-7s %8s", "library", "mode",
           "valid");
    for (int v = 0; v < NINVALID; v++)
        printf(" %20s", invalid_names[v]);
    printf("\n");
    for (int lm = 0; lm < nlm; lm++) {
        const closed_tally *t0 = &res[lm].off[0];
        const char *name = c->libs[lm / CLOSED_MODES].name, *mode = mode_names[closed_mode(lm)];
        const double ns = t0->timed ? 1e9 * t0->seconds / (double)t0->timed : 0.0;
        printf("  %-18s %-7s %8.1f", name, mode, ns);
        if (c->libs[lm / CLOSED_MODES].embree) {
            printf("  not measured: Embree 3 (Debian's build) asserts ray.valid() and aborts\n");
            continue;
        }
        for (int v = 0; v < NINVALID; v++) {
            const double bad_ns = t0->timed ? 1e9 * res[lm].invalid_seconds[v] / (double)t0->timed : 0.0;
            char cell[40], variant[48];
            snprintf(cell, sizeof cell, "%.1f (%.2fx)", bad_ns, ns > 0 ? bad_ns / ns : 0.0);
            printf(" %20s", cell);
            snprintf(variant, sizeof variant, "%s, %s", mode, invalid_names[v]);
            csv_row(&c->csv, "closed", name, variant, "aimed", "single", 1, bad_ns, "ns per ray", 0);
        }
        printf("\n");
    }
    if (dat) {
        FILE *gp = chart_open(c->charts, "closed-accuracy", 1);
        if (gp) {
            fprintf(gp,
                    "set terminal pngcairo noenhanced size 900,600 font 'sans,10'\nset output 'closed-accuracy.png'\n"
                    "set title 'closed meshes: speed against accuracy per (library, backend, mode)'\n"
                    "set xlabel 'ns per ray, intersect1, 1 thread (lower is better)'\n"
                    "set ylabel 'false misses per million rays aimed at vertices and edges (lower is better)'\n"
                    "set grid\nset key outside right\nset xrange [0:*]\nset logscale y\nset yrange [0.05:2e5]\n"
                    "set ytics add ('0' 0.1)\nset offsets graph 0.05, graph 0.1, 0, 0\nplot ");
            /* no false miss at all is drawn at 0.1 on the log scale, labelled 0 */
            for (int l = 0; l < c->nlibs; l++)
                fprintf(gp, "%s'closed-accuracy.dat' index %d using 1:($2 > 0 ? $2 : 0.1) with points pt %d ps 1.5 "
                        "lc %d title '%s', '' index %d using 1:($2 > 0 ? $2 : 0.1):3 with labels offset 0.8,0.5 left "
                        "font 'sans,7' tc lt -1 notitle",
                        l ? ", " : "", l, 5 + 2 * (l % 3), l + 1, c->libs[l].name, l);
            fprintf(gp, "\n");
        }
    }
done:
    for (int lm = 0; lm < nlm; lm++) {
        for (int k = 0; k < NOFF; k++)
            tally_free(&res[lm].off[k]);
        for (int k = 0; k < NSIZE; k++)
            tally_free(&res[lm].size[k]);
        for (int k = 0; k < NGRAZE; k++)
            tally_free(&res[lm].graze[k][0]), tally_free(&res[lm].graze[k][1]);
        tally_free(&res[lm].needle);
    }
    free(res);
    return bad;
}
