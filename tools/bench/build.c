/* The build section: start time at every quality against the time to
 * trace the tree, and a scene built again every frame. */
#include <malloc.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>

#include "bench_internal.h"
#include "progress.h"

/* ---- peak memory of a build ----
 * The growth of the process's resident memory during one commit: freed
 * heap memory is returned to the system first (malloc_trim), the kernel's
 * high-water mark is reset to the resident size (clear_refs 5), and after
 * the commit the high-water mark is read back.  The same measure for both
 * libraries, whatever they allocate with. */

/* A "VmRSS:"-style field of /proc/self/status in kB, or -1. */
static long status_kb(const char *key)
{
    FILE *f = fopen("/proc/self/status", "r");
    if (!f)
        return -1;
    char line[256];
    long v = -1;
    const size_t n = strlen(key);
    while (fgets(line, sizeof line, f))
        if (!strncmp(line, key, n)) {
            v = atol(line + n);
            break;
        }
    fclose(f);
    return v;
}

/* Starts a measurement: the resident size in kB, or -1 when the kernel
 * offers no resettable high-water mark. */
static long peak_begin(void)
{
    malloc_trim(0);
    FILE *f = fopen("/proc/self/clear_refs", "w");
    if (!f)
        return -1;
    const int ok = fputs("5", f) >= 0;
    if (fclose(f) || !ok)
        return -1;
    return status_kb("VmRSS:");
}

/* Seconds of system time the process has used, all its threads: for a
 * build, mostly the kernel giving it fresh pages (zeroing them, and on a
 * VM whose host backs memory at first touch, waiting for the host). */
static double system_seconds(void)
{
    struct rusage u;
    if (getrusage(RUSAGE_SELF, &u))
        return 0.0;
    return (double)u.ru_stime.tv_sec + (double)u.ru_stime.tv_usec * 1e-6;
}

/* Bytes the resident memory grew by at most since peak_begin, or -1. */
static double peak_end(long base_kb)
{
    const long hwm = status_kb("VmHWM:");
    return base_kb < 0 || hwm < 0 ? -1.0 : (double)(hwm - base_kb) * 1024.0;
}

/* A scene over the mesh's moving copy v (refilled from the mesh first) in
 * `mode` at quality q, then `frames` frames of it twisted a little more
 * each and committed again: the best frame's time, from the update calls
 * to the committed scene; -1 (err set) when the scene could not be built. */
double moving_frames(scene *sc, lib *bl, const ctx *c, float *v, int mode, int q, int frames, char *err,
                     size_t err_size)
{
    rtk_mesh moved = *c->m;
    moved.vertices = v;
    memcpy(v, c->padded, (c->m->vertex_count * 3 + 4) * sizeof *v);
    if (scene_build(sc, bl, &moved, v, mode, q, err, err_size))
        return -1;
    double best = 1e30;
    for (int f = 1; f <= frames; f++) {
        twist(c->m, 0.6f * (float)f / (float)frames, v);
        const double t0 = now();
        vertices_commit(sc);
        const double dt = now() - t0;
        best = dt < best ? dt : best;
    }
    return best;
}

/* The same scene built again in each frame (MODE_REBUILD): the best
 * frame's time; -1 with err on a failure. */
static double rebuild_time(lib *bl, const ctx *c, float *v, int q, int frames, char *err, size_t err_size)
{
    scene sc;
    const double best = moving_frames(&sc, bl, c, v, MODE_REBUILD, q, frames, err, err_size);
    if (best < 0)
        return -1;
    int bad = 0;
    if (sc.rscene) {
        rtk_scene_info info = {.struct_size = sizeof info};
        bad = rtk_scene_get_info(sc.rscene, &info) || info.refits != 0 || info.trees_built != 1;
    } else {
        bad = rtcGetDeviceError(bl->edev) != RTC_ERROR_NONE;
    }
    if (bad)
        snprintf(err, err_size, "%.40s: a frame did not build its tree again", bl->name);
    scene_release(&sc);
    return bad ? -1 : best;
}

/* What the build section measured of one library at one quality and
 * thread count. */
typedef struct build_result {
    double best, bytes, peak, trace_rate, rebuild; /* seconds; bytes and peak per triangle */
    double sys; /* seconds of system time (every thread) during the best start build */
    double sah; /* the tree's SAH cost (scene.sah) */
    char builder[32];
} build_result;

/* Quality q on o->threads[ti] threads, every library on a fresh device:
 * the builds in turns (each round builds every library once, so a machine
 * whose speed drifts over the minutes of the section moves every library's
 * best alike; with each library's builds in a block, Embree's own times
 * moved by a quarter between two runs on one VM), then each library's
 * rebuild frames.  res[l] for library l; 0, or 1 with err set. */
static int build_turns(ctx *c, int q, int ti, float *moving, unsigned char *hits, build_result *res, char *err,
                       size_t err_size)
{
    const bench_opts *o = c->o;
    lib bl[MAXLIBS];
    int opened = 0, rc = 0;
    for (; opened < c->nlibs; opened++)
        if (lib_open(&bl[opened], c->libs[opened].name, c->libs[opened].embree, c->libs[opened].config,
                     o->threads[ti], err, err_size)) {
            rc = 1;
            break;
        }
    for (int l = 0; l < c->nlibs; l++)
        res[l] = (build_result){.best = 1e30, .peak = -1.0, .sah = -1.0};
    for (int b = 0; !rc && b < o->builds; b++)
        for (int l = 0; !rc && l < c->nlibs; l++) {
            scene sc;
            const long base = b == 0 ? peak_begin() : -1;
            const double sys0 = system_seconds();
            if (scene_build(&sc, &bl[l], c->m, c->padded, MODE_DEFAULT, q, err, err_size)) {
                rc = 1;
                break;
            }
            const double sys = system_seconds() - sys0;
            if (b == 0)
                res[l].peak = peak_end(base) / (double)c->m->triangle_count;
            if (sc.seconds < res[l].best) {
                res[l].best = sc.seconds;
                res[l].sys = sys;
            }
            res[l].bytes = sc.bytes_per_tri;
            res[l].sah = sc.sah;
            memcpy(res[l].builder, sc.builder, sizeof res[l].builder);
            if (b == o->builds - 1 && ti == 0) {
                const render_tracer t = scene_tracer(&sc, 0);
                res[l].trace_rate = trace_set(&t, &c->sets[SET_DIFFUSE], 1, 0, 1, o->repeat, hits);
            }
            scene_release(&sc);
        }
    for (int l = 0; !rc && l < c->nlibs; l++) {
        res[l].rebuild = rebuild_time(&bl[l], c, moving, q, o->builds + 1, err, err_size);
        rc = res[l].rebuild < 0;
    }
    for (int l = 0; l < opened; l++)
        lib_close(&bl[l]);
    return rc;
}

/* The results of quality q on o->threads[ti] threads, one per library. */
static build_result *build_row(const ctx *c, build_result *res, int q, int ti)
{
    return &res[((size_t)q * (size_t)c->o->nthreads + (size_t)ti) * (size_t)c->nlibs];
}

int section_build(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    static const char *const qn[3] = {"low", "medium", "high"};
    const int frames = o->builds + 1;
    printf("\nbuild (Table 4 of the Embree paper): start time from the first scene call to a committed scene (API "
           "calls, allocation, build), best of %d, the libraries' builds in turns, at each quality; rebuild: a "
           "scene built again after its "
           "vertices move (the mesh twisted a little more in each of %d frames; Embree's flagged dynamic), best of "
           "the frames, from the update calls to the committed scene; sys: the system time of the best start build (all "
           "threads; mostly the kernel giving the build fresh pages); scaling: the library's own speed-up over its "
           "%d-thread times, start / rebuild; bytes per triangle of the tree and at the peak of the first build "
           "(the growth of resident memory during it, a fresh device each time); SAH: the tree's SAH cost in rtk's "
           "model (rtk_scene_info.sah_cost: a traversal step 1, a block of four triangles 1, relative to the root; "
           "Embree's API reports none); then the diffuse rays of the trace section through that tree, single rays, "
           "1 thread\n",
           o->builds, frames, o->threads[0]);
    printf("  %-20s %-8s %-14s %7s %9s %8s %7s %10s %8s %13s %9s %7s %7s %7s  %s\n", "library", "quality",
           "builder", "threads", "start ms", "ratio", "sys ms", "rebuild ms", "ratio", "scaling", "Mtris/s", "B/tri",
           "peak", "SAH", "diffuse Mrays/s");
    const rayset diff = c->sets[SET_DIFFUSE];
    unsigned char *hits = malloc(diff.n + 1);
    float *moving = calloc(c->m->vertex_count * 3 + 4, sizeof *moving);
    /* row (q * nthreads + ti) of nlibs results: quality q on threads[ti], a result per library */
    build_result *res = calloc((size_t)3 * (size_t)o->nthreads * (size_t)c->nlibs, sizeof *res);
    if (!hits || !moving || !res) {
        free(hits);
        free(moving);
        free(res);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    progress bar;
    progress_begin(&bar, "rtktool bench: build");
    for (int q = 0; q < 3; q++)
        for (int ti = 0; ti < o->nthreads; ti++) {
            if (build_turns(c, q, ti, moving, hits, build_row(c, res, q, ti), err, err_size)) {
                progress_end(&bar);
                free(hits);
                free(moving);
                free(res);
                return 1;
            }
            progress_update(&bar, (double)(q * o->nthreads + ti + 1) / (3 * o->nthreads));
        }
    progress_end(&bar);
    char chart[200];
    snprintf(chart, sizeof chart, "%s-build", c->stem);
    FILE *dat = chart_open(c->charts, chart, 0);
    for (int l = 0; l < c->nlibs; l++) {
        for (int q = 0; q < 3; q++) {
            for (int ti = 0; ti < o->nthreads; ti++) {
                const build_result *ref = build_row(c, res, q, ti), *r = &ref[l], *first = &build_row(c, res, q, 0)[l];
                const double best = r->best, rebuild = r->rebuild, trace_rate = r->trace_rate;
                char scaling[32] = "-";
                if (ti > 0)
                    snprintf(scaling, sizeof scaling, "%.2fx/%.2fx", ratio(first->best, best),
                             ratio(first->rebuild, rebuild));
                printf("  %-20s %-8s %-14s %7d %9.1f %7.2fx %7.1f %10.1f %7.2fx %13s %9.2f %7.1f %7.1f", c->libs[l].name,
                       qn[q], r->builder, o->threads[ti], best * 1e3, ratio(ref->best, best), r->sys * 1e3,
                       rebuild * 1e3, ratio(ref->rebuild, rebuild), scaling,
                       (double)c->m->triangle_count / best * 1e-6, r->bytes, r->peak);
                if (r->sah >= 0)
                    printf(" %7.3f", r->sah);
                else
                    printf(" %7s", "-");
                if (ti == 0)
                    printf("  %.2f", trace_rate);
                printf("\n");
                char variant[48]; /* quality:builder */
                snprintf(variant, sizeof variant, "%s:%s", qn[q], r->builder);
                csv_row(&c->csv, "build", c->libs[l].name, variant, "start", "", o->threads[ti], best * 1e3, "ms",
                        ratio(ref->best, best));
                csv_row(&c->csv, "build", c->libs[l].name, variant, "rebuild", "", o->threads[ti], rebuild * 1e3,
                        "ms", ratio(ref->rebuild, rebuild));
                csv_row(&c->csv, "build", c->libs[l].name, variant, "start system time", "", o->threads[ti],
                        r->sys * 1e3, "ms", 0);
                if (ti > 0) {
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "start scaling", "", o->threads[ti],
                            ratio(first->best, best), "x", 0);
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "rebuild scaling", "", o->threads[ti],
                            ratio(first->rebuild, rebuild), "x", 0);
                }
                if (r->peak >= 0)
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "peak memory", "", o->threads[ti], r->peak,
                            "bytes per triangle", 0);
                if (r->sah >= 0)
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "sah cost", "", o->threads[ti], r->sah,
                            "relative to the root", 0);
                if (ti == 0) {
                    csv_row(&c->csv, "build", c->libs[l].name, variant, "diffuse", "single", 1, trace_rate, "Mrays/s",
                            0);
                    if (dat)
                        fprintf(dat, "%.3f %.4f %s%s", best * 1e3,
                                trace_rate > 0 ? (double)diff.n / trace_rate * 1e-3 : 0.0, variant,
                                q == 2 ? "\n\n\n" : "\n");
                }
            }
        }
    }
    free(res);
    if (dat) {
        FILE *gp = chart_open(c->charts, chart, 1);
        if (gp) {
            fprintf(gp,
                    "set terminal pngcairo noenhanced size 900,600 font 'sans,10'\nset output '%s-build.png'\n"
                    "set title '%s: start time against the time to trace %zu diffuse rays, per builder, 1 thread'\n"
                    "set xlabel 'start time, ms (lower is better)'\nset ylabel 'trace time, ms (lower is better)'\n"
                    "set grid\nset key outside right\nset offsets graph 0.05, graph 0.1, graph 0.1, graph 0.1\n"
                    "set xrange [0:*]\nset yrange [0:*]\nplot ",
                    c->stem, base_name(c->csv.mesh), diff.n);
            for (int l = 0; l < c->nlibs; l++) {
                fprintf(gp, "%s'%s-build.dat' index %d using 1:2 with linespoints pt 7 ps 1.2 lw 1.5 lc %d title '%s'",
                        l ? ", " : "", c->stem, l, l + 1, c->libs[l].name);
                if (!c->libs[l].embree || l == 0) /* Embree's other ISA has the same builders */
                    fprintf(gp, ", '' index %d using 1:2:3 with labels offset 0.8,0.5 left font 'sans,7' tc lt -1 "
                            "notitle", l);
            }
            fprintf(gp, "\n");
        }
    }
    free(hits);
    free(moving);
    return 0;
}
