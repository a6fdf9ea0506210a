/* The forest section: many instances of a few meshes over a ground plane.
 *
 * Production scenes place a few meshes thousands or millions of times
 * (trees, rocks, bushes).  The forest is the mesh under test, a bush (a UV
 * sphere) and a rock (a bumpy sphere, rtk_mesh_procedural) placed N times
 * at random positions over a square, each turned about the vertical by a
 * random angle and scaled by a random factor from 0.6 to 1.4, standing on
 * a ground plane of two triangles that is a geometry of the top-level scene
 * itself.  The same positions for every library (the generator is seeded
 * per forest).
 *
 * For each library and each N: the time from the first call making the
 * instances to the committed scene (creating N instance geometries
 * included) and the commit's alone, the memory it took per instance (the
 * library's memory monitor, and the process's resident memory), and the
 * diffuse path tracer's rate through it from a camera standing at the
 * forest's edge and looking across it, on 1 and 2 threads (--threads),
 * the libraries taking their passes in turns.
 *
 * The libraries report an instance's geometric normal in the instanced
 * mesh's space (Embree 3 and rtk alike); the path tracer needs it in world
 * space, so each library's tracer is wrapped here by one that turns the
 * normal by the instance's rotation (the same code for both). */
#include <malloc.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bench_internal.h"
#include "closed_mesh.h"

enum { KINDS = 3 }; /* the mesh, a bush, a rock */

/* Where the forest's instances stand: per instance its kind, the cosine and
 * sine of its turn, and its 3x4 row-major transform. */
typedef struct forest {
    size_t n;
    unsigned char *kind;
    float (*cs)[2];
    float (*xfm)[12];
    float half;         /* the forest covers [-half, half] in x and z */
    float lo[3], hi[3]; /* its bounds */
    float ground[4 * 3 + 4]; /* padded: Embree reads 16 bytes at the last vertex */
    uint32_t ground_idx[6];
} forest;

static void forest_free(forest *f)
{
    free(f->kind);
    free(f->cs);
    free(f->xfm);
    memset(f, 0, sizeof *f);
}

/* N instances of the kinds whose bounds are klo/khi: each kind scaled to
 * the footprint `foot` (its larger horizontal extent), its bottom centre
 * put at the instance's place. */
static int forest_make(forest *f, size_t n, const float klo[KINDS][3], const float khi[KINDS][3], float foot)
{
    memset(f, 0, sizeof *f);
    f->n = n;
    f->kind = malloc(n);
    f->cs = malloc(n * sizeof *f->cs);
    f->xfm = malloc(n * sizeof *f->xfm);
    if (!f->kind || !f->cs || !f->xfm) {
        forest_free(f);
        return 1;
    }
    /* one instance per (1.5 foot)^2 of ground, on average */
    f->half = 0.5f * 1.5f * foot * sqrtf((float)n);
    uint64_t s = 0x2545f4914f6cdd1dull ^ (uint64_t)n; /* (its own sequence: rnd_from) */
    float top = 0;
    for (size_t i = 0; i < n; i++) {
        const int k = (int)(i % KINDS);
        const float ext = fmaxf(khi[k][0] - klo[k][0], khi[k][2] - klo[k][2]);
        const float scale = (ext > 0 ? foot / ext : 1.0f) * (0.6f + 0.8f * rnd_from(&s));
        const float a = 6.2831853f * rnd_from(&s), c = cosf(a), sn = sinf(a);
        const float px = f->half * (2.0f * rnd_from(&s) - 1.0f), pz = f->half * (2.0f * rnd_from(&s) - 1.0f);
        /* world = p + scale * R (x - b), b the kind's bottom centre */
        const float b[3] = {0.5f * (klo[k][0] + khi[k][0]), klo[k][1], 0.5f * (klo[k][2] + khi[k][2])};
        const float r[9] = {scale * c, 0, scale * sn, 0, scale, 0, -scale * sn, 0, scale * c};
        float *x = f->xfm[i];
        for (int row = 0; row < 3; row++) {
            x[4 * row + 0] = r[3 * row + 0];
            x[4 * row + 1] = r[3 * row + 1];
            x[4 * row + 2] = r[3 * row + 2];
            x[4 * row + 3] = (row == 0 ? px : row == 2 ? pz : 0.0f) -
                             (r[3 * row] * b[0] + r[3 * row + 1] * b[1] + r[3 * row + 2] * b[2]);
        }
        f->kind[i] = (unsigned char)k;
        f->cs[i][0] = c, f->cs[i][1] = sn;
        top = fmaxf(top, scale * (khi[k][1] - klo[k][1]));
    }
    const float g = f->half + foot;
    const float ground[12] = {-g, 0, -g, g, 0, -g, g, 0, g, -g, 0, g};
    const uint32_t idx[6] = {0, 2, 1, 0, 3, 2}; /* wound to face up */
    memcpy(f->ground, ground, sizeof ground);
    memcpy(f->ground_idx, idx, sizeof idx);
    const float lo[3] = {-g, 0, -g}, hi[3] = {g, top, g};
    memcpy(f->lo, lo, sizeof lo);
    memcpy(f->hi, hi, sizeof hi);
    return 0;
}

/* The process's resident memory, in bytes (0 if unknown). */
static double resident_bytes(void)
{
    FILE *fp = fopen("/proc/self/statm", "r");
    long pages = 0, resident = 0;
    if (!fp)
        return 0;
    if (fscanf(fp, "%ld %ld", &pages, &resident) != 2)
        resident = 0;
    fclose(fp);
    return (double)resident * (double)sysconf(_SC_PAGESIZE);
}

static int64_t rtk_bytes; /* rtk's memory monitor over the forest's device */

static int rtk_monitor(void *user, int64_t bytes, int post)
{
    (void)user;
    (void)post;
    __atomic_add_fetch(&rtk_bytes, bytes, __ATOMIC_RELAXED);
    return 1;
}

typedef struct forest_scene {
    scene sc;
    double make_ms, commit_ms; /* first call to committed; the commit alone */
    double monitor_bytes, resident;
} forest_scene;

/* The forest over the kinds' scenes: instances 0 .. n - 1 (geomID = the
 * instance's index), the ground plane geomID n. */
static int forest_scene_build(forest_scene *fs, lib *l, const forest *f, scene *kinds, char *err, size_t err_size)
{
    memset(fs, 0, sizeof *fs);
    scene *sc = &fs->sc;
    sc->lib = l;
    malloc_trim(0);
    const double res0 = resident_bytes();
    const long long eb0 = embree_bytes;
    const int64_t rb0 = rtk_bytes;
    const double t0 = now();
    double t1;
    if (l->embree) {
        RTCScene s = rtcNewScene(l->edev);
        for (size_t i = 0; i < f->n; i++)
            attach_instance(l, s, NULL, &kinds[f->kind[i]], f->xfm[i]);
        RTCGeometry g = rtcNewGeometry(l->edev, RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, f->ground, 0, 12, 4);
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, f->ground_idx, 0, 12, 2);
        rtcCommitGeometry(g);
        rtcAttachGeometry(s, g);
        rtcReleaseGeometry(g);
        t1 = now();
        if (embree_commit(sc, s, t0, "the forest", err, err_size))
            return 1;
        fs->monitor_bytes = (double)(embree_bytes - eb0);
    } else {
        rtk_scene s = NULL;
        int bad = rtk_scene_new(l->rdev, &s) != RTK_OK;
        for (size_t i = 0; i < f->n && !bad; i++)
            bad = attach_instance(l, NULL, s, &kinds[f->kind[i]], f->xfm[i]);
        rtk_geometry g = NULL;
        bad = bad || rtk_geometry_new(l->rdev, RTK_GEOMETRY_TYPE_TRIANGLE, &g) ||
              rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, f->ground, 0, 12, 4) ||
              rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_INDEX, f->ground_idx, 0, 12, 2) ||
              rtk_geometry_commit(g) || rtk_scene_attach_geometry(s, g, NULL);
        rtk_geometry_release(g);
        t1 = now();
        if (rtk_commit(sc, s, bad, t0, err, err_size))
            return 1;
        fs->monitor_bytes = (double)(rtk_bytes - rb0);
    }
    fs->make_ms = sc->seconds * 1e3;
    fs->commit_ms = (t0 + sc->seconds - t1) * 1e3;
    fs->resident = resident_bytes() - res0;
    return 0;
}

/* The wrapped tracer: the library's, with an instance's normal turned into
 * world space. */
typedef struct forest_tracer {
    render_tracer inner;
    const forest *f;
} forest_tracer;

/* rh's normal, of an instance's hit, turned into world space. */
static void forest_turn(const forest *f, rtk_rayhit *rh)
{
    const unsigned inst = rh->hit.instID;
    if (rh->hit.geomID != RTK_INVALID_GEOMETRY_ID && inst < f->n) {
        const float c = f->cs[inst][0], s = f->cs[inst][1], x = rh->hit.Ng_x, z = rh->hit.Ng_z;
        rh->hit.Ng_x = c * x + s * z;
        rh->hit.Ng_z = -s * x + c * z;
    }
}

static void forest_intersect1(void *scene, rtk_rayhit *rh)
{
    const forest_tracer *ft = scene;
    ft->inner.intersect1(ft->inner.scene, rh);
    forest_turn(ft->f, rh);
}

static void forest_intersect1M(void *scene, rtk_rayhit *rh, unsigned n, size_t stride)
{
    const forest_tracer *ft = scene;
    ft->inner.intersect1M(ft->inner.scene, rh, n, stride);
    for (unsigned i = 0; i < n; i++)
        forest_turn(ft->f, (rtk_rayhit *)(void *)((char *)rh + i * stride));
}

static void forest_occluded1M(void *scene, rtk_ray *rays, unsigned n, size_t stride)
{
    const forest_tracer *ft = scene;
    ft->inner.occluded1M(ft->inner.scene, rays, n, stride);
}

static void forest_occluded1(void *scene, rtk_ray *ray)
{
    const forest_tracer *ft = scene;
    ft->inner.occluded1(ft->inner.scene, ray);
}

/* The path tracer's APIs here: single rays and streams (each bounce's
 * rays of a tile), each where --api names it. */
#define FOREST_APIS 2
static const int forest_apis[FOREST_APIS] = {1, RENDER_API_STREAM};

/* One pass of the path tracer through the forest on `threads` threads
 * with API `api`: its rate (Mrays/s) or -1, and the share of camera rays
 * that hit something. */
static double forest_rate(const bench_opts *o, scene *sc, const forest *f, int threads, int api, float *rgb,
                          double *hit_share, char *err, size_t err_size)
{
    render_settings rs;
    diffuse_settings(&rs, o, f->lo, f->hi, threads);
    rs.api = api;
    /* at the forest's south edge, at three times the tallest instance's
     * height, looking across to its middle */
    const float eye[3] = {0.1f * f->half, 3.0f * f->hi[1], f->half}, at[3] = {0, 0, 0}, up[3] = {0, 1, 0};
    if (render_camera_look(&rs.camera, eye, at, up, 50.0f, rs.width, rs.height, err, err_size))
        return -1;
    forest_tracer ft = {scene_tracer(sc, 0), f};
    const render_tracer t = {.scene = &ft,
                             .intersect1 = forest_intersect1,
                             .occluded1 = forest_occluded1,
                             .intersect1M = forest_intersect1M,
                             .occluded1M = forest_occluded1M};
    return diffuse_pass(&t, &rs, rgb, hit_share, err, err_size);
}

int section_forest(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    /* the kinds: the mesh, a bush, a rock */
    rtk_closed_mesh bush;
    rtk_mesh rock;
    const double centre[3] = {0, 0, 0};
    if (rtk_closed_sphere(centre, 1.0, 24, 12, &bush)) {
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    if (rtk_mesh_procedural(20000, &rock)) {
        rtk_closed_free(&bush);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    const rtk_mesh *kmesh[KINDS] = {c->m, &bush.mesh, &rock};
    float klo[KINDS][3], khi[KINDS][3], *kpad[KINDS] = {0};
    int rc = 0;
    for (int k = 0; k < KINDS; k++) {
        rtk_mesh_bounds(kmesh[k], klo[k], khi[k]);
        if (k == 0)
            continue;
        /* Embree reads 16 bytes at the last vertex: padded copies */
        kpad[k] = calloc(kmesh[k]->vertex_count * 3 + 4, sizeof(float));
        if (!kpad[k])
            rc = 1;
        else
            memcpy(kpad[k], kmesh[k]->vertices, kmesh[k]->vertex_count * 3 * sizeof(float));
    }
    const float foot = fmaxf(khi[0][0] - klo[0][0], khi[0][2] - klo[0][2]);
    float *rgb = malloc((size_t)o->render_w * (size_t)o->render_h * 3 * sizeof *rgb);
    if (rc || !rgb) {
        snprintf(err, err_size, "out of memory");
        rc = 1;
    }
    for (int fi = 0; fi < o->nforest && !rc; fi++) {
        forest f;
        if (forest_make(&f, o->forest[fi], (const float(*)[3])klo, (const float(*)[3])khi, foot)) {
            snprintf(err, err_size, "out of memory for a forest of %zu instances", o->forest[fi]);
            rc = 1;
            break;
        }
        printf("\nforest, %zu instances of the mesh, a bush (%zu triangles) and a rock (%zu), each turned and "
               "scaled at random over a ground plane (the ground a geometry of the top level): the time from "
               "the first call to the committed scene and the commit's alone (builds on 1 thread, best of %d), "
               "memory per instance (the library's memory monitor; resident memory), and the path tracer's rate "
               "through it from its edge (%dx%d, %d spp, Mrays/s, single rays and streams, the best of %d passes "
               "taken by the libraries in turns)\n",
               f.n, bush.mesh.triangle_count, rock.triangle_count, o->builds, o->render_w, o->render_h,
               o->render_spp, o->repeat);
        printf("  %-20s %10s %10s %8s %10s %10s", "library", "scene ms", "commit ms", "ratio", "B/inst", "RSS B/inst");
        for (int ti = 0; ti < o->nthreads; ti++)
            for (int a = 0; a < FOREST_APIS; a++)
                if (api_on(o, forest_apis[a]))
                    printf(" %2dt %-7s %7s", o->threads[ti], render_api_name(forest_apis[a]), "ratio");
        printf(" %6s\n", "hits");
        /* Each library's forest first (its last build kept), then the path
         * tracer's passes taken in turns, the best of each kept: a slow
         * spell of the machine falls on all libraries alike. */
        scene kinds[MAXLIBS][KINDS];
        forest_scene best[MAXLIBS];
        double rate[MAXLIBS][4][FOREST_APIS], hits[MAXLIBS];
        memset(kinds, 0, sizeof kinds);
        memset(best, 0, sizeof best);
        memset(rate, 0, sizeof rate);
        memset(hits, 0, sizeof hits);
        for (int l = 0; l < c->nlibs && !rc; l++) {
            lib *lb = &c->libs[l];
            if (!lb->embree)
                rtk_device_set_memory_monitor(lb->rdev, rtk_monitor, NULL);
            for (int k = 0; k < KINDS && !rc; k++)
                rc = scene_build(&kinds[l][k], lb, kmesh[k], k ? kpad[k] : c->padded, MODE_DEFAULT, 1, err,
                                 err_size);
            best[l].make_ms = 1e30;
            for (int b = 0; b < o->builds && !rc; b++) {
                forest_scene fs;
                rc = forest_scene_build(&fs, lb, &f, kinds[l], err, err_size);
                if (rc)
                    break;
                if (fs.make_ms < best[l].make_ms)
                    best[l].make_ms = fs.make_ms;
                if (b == 0 || fs.commit_ms < best[l].commit_ms)
                    best[l].commit_ms = fs.commit_ms;
                if (b == 0)
                    best[l].monitor_bytes = fs.monitor_bytes, best[l].resident = fs.resident;
                if (b == o->builds - 1)
                    best[l].sc = fs.sc;
                else
                    scene_release(&fs.sc);
            }
        }
        for (int r = 0; r < o->repeat && !rc; r++)
            for (int ti = 0; ti < o->nthreads && !rc; ti++)
                for (int a = 0; a < FOREST_APIS && !rc; a++)
                    for (int l = 0; l < c->nlibs && !rc && api_on(o, forest_apis[a]); l++) {
                        const double v = forest_rate(o, &best[l].sc, &f, o->threads[ti], forest_apis[a], rgb,
                                                     &hits[l], err, err_size);
                        rc = v < 0;
                        rate[l][ti][a] = v > rate[l][ti][a] ? v : rate[l][ti][a];
                    }
        for (int l = 0; l < c->nlibs; l++) {
            lib *lb = &c->libs[l];
            if (best[l].sc.lib)
                scene_release(&best[l].sc);
            for (int k = 0; k < KINDS; k++)
                if (kinds[l][k].lib)
                    scene_release(&kinds[l][k]);
            if (!lb->embree)
                rtk_device_set_memory_monitor(lb->rdev, NULL, NULL);
        }
        for (int l = 0; l < c->nlibs && !rc; l++) {
            lib *lb = &c->libs[l];
            const forest_scene *bl = &best[l];
            printf("  %-20s %10.1f %10.1f %7.2fx %10.0f %10.0f", lb->name, bl->make_ms, bl->commit_ms,
                   ratio(best[0].make_ms, bl->make_ms), bl->monitor_bytes / (double)f.n, bl->resident / (double)f.n);
            for (int ti = 0; ti < o->nthreads; ti++)
                for (int a = 0; a < FOREST_APIS; a++)
                    if (api_on(o, forest_apis[a]))
                        printf(" %11.2f %7.2fx", rate[l][ti][a], ratio(rate[l][ti][a], rate[0][ti][a]));
            printf(" %5.1f%%\n", 100.0 * hits[l]);
            char variant[48];
            snprintf(variant, sizeof variant, "forest %zu", f.n);
            csv_row(&c->csv, "twolevel", lb->name, variant, "scene", "", 1, bl->make_ms, "ms",
                    ratio(best[0].make_ms, bl->make_ms));
            csv_row(&c->csv, "twolevel", lb->name, variant, "commit", "", 1, bl->commit_ms, "ms", 0);
            csv_row(&c->csv, "twolevel", lb->name, variant, "memory monitor", "", 1,
                    bl->monitor_bytes / (double)f.n, "bytes per instance", 0);
            csv_row(&c->csv, "twolevel", lb->name, variant, "resident memory", "", 1, bl->resident / (double)f.n,
                    "bytes per instance", 0);
            for (int ti = 0; ti < o->nthreads; ti++)
                for (int a = 0; a < FOREST_APIS; a++)
                    if (api_on(o, forest_apis[a]))
                        csv_row(&c->csv, "twolevel", lb->name, variant, "diffuse path tracer",
                                render_api_name(forest_apis[a]), o->threads[ti], rate[l][ti][a], "Mrays/s",
                                ratio(rate[l][ti][a], rate[0][ti][a]));
        }
        forest_free(&f);
    }
    free(rgb);
    for (int k = 0; k < KINDS; k++)
        free(kpad[k]);
    rtk_mesh_free(&rock);
    rtk_closed_free(&bush);
    return rc;
}
