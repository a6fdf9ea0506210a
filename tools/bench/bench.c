/*
 * rtktool bench: rtk beside Embree 3 on the same meshes and the same rays,
 * in one process run.  Compiled into rtktool only when Embree's development
 * package is present (RTK_HAVE_EMBREE).
 *
 * For each mesh:
 *   trace     primary rays (a camera framing the mesh tightly, so most hit),
 *             one cosine-weighted diffuse bounce and one shadow ray per
 *             primary hit; single rays and packets of 4, 8, 16; 1 and 2
 *             threads; Embree at isa=avx2 and at its default, every rtk
 *             backend.  Ratios are to Embree isa=avx2 on the same rays.
 *   render    the paper's Table 2/3: rays per second of the complete
 *             diffuse path tracer of rtktool trace (shading and sampling
 *             included), the same renderer code driving each library.
 *   build     the paper's Table 4: start time, from the first scene call
 *             to a committed scene (API calls, allocation, build), at
 *             every build quality, with what the tree then costs to trace.
 *   refit     a deforming mesh (quality REFIT): the time to refit after
 *             the vertices move, and the trace speed of the refitted tree
 *             beside a tree built afresh over the same shape.
 *   twolevel  instances of the mesh and a dynamic scene of its pieces:
 *             commit times and the path tracer's speed through them.
 *   forest    10^4 and 10^6 instances of the mesh, a bush and a rock over
 *             a ground plane: scene time, memory per instance, the path
 *             tracer's speed.
 *   motion    linear motion blur (the mesh turning and moving, at 2 and 5
 *             time steps): start time, memory, and rays at random times.
 *   accuracy  rays aimed at points on edges shared by two triangles, from
 *             the side both face: in exact arithmetic each hits one of the
 *             two (or something nearer), so a miss, or a hit beyond the
 *             edge, is a ray that leaked through the mesh.  Per
 *             intersector and mode, beside its speed.
 * Output: tables on stdout, DIR/bench.csv, and charts DIR/MESH-SECTION.png
 * drawn by gnuplot (the scripts are kept beside them).  A run replaces the
 * previous run's files only once it is whole (charts.c): one that fails
 * leaves them as they were.
 */
#include "bench.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "bench_internal.h"
#include "file_io.h"
#include "mesh_import.h"

static int parse_list(const char *s, char items[][16], int max)
{
    int n = 0;
    for (const char *p = s; *p && n < max;) {
        const char *end = strchr(p, ',');
        const size_t len = end ? (size_t)(end - p) : strlen(p);
        if (!len || len >= 16)
            return -1;
        memcpy(items[n], p, len);
        items[n++][len] = 0;
        p += len + (end != NULL);
    }
    return n;
}

static void bench_usage(FILE *f)
{
    fprintf(f,
            "usage: rtktool bench MESH... [options]\n"
            "  rtk beside Embree 3 (at isa=avx2 and at its default) on the same meshes and rays, in one run:\n"
            "  trace (primary, diffuse, shadow, incoherent and sun rays; single rays and packets; 1 and 2\n"
            "  threads), render (the diffuse path tracer of rtktool trace, as in the Embree paper's Tables 2\n"
            "  and 3), build (start time at every quality, as in its Table 4, against the time to trace the\n"
            "  tree), refit (a deforming mesh: refit time, and the trace speed of the refitted tree), two\n"
            "  levels (instances and a dynamic scene: commit times and trace speed), forest (many instances of\n"
            "  the mesh, a bush and a rock: scene time, memory per instance, trace speed), motion blur (2 and 5\n"
            "  time steps: start time, memory, trace speed at random ray times), accuracy (rays aimed at\n"
            "  shared edges that leak through, beside speed), points (closest points near the surface and\n"
            "  all through the box, against rtcPointQuery) and, once per run, closed (the accuracy\n"
            "  harness: rays aimed at the vertices and edges of closed procedural meshes moved to\n"
            "  10^0..10^8 and sized 1e-8..1e8, needles and zero-area triangles, grazing rays; false misses,\n"
            "  double hits, t error in ulps, each library's default and robust mode; no MESH needed for\n"
            "  --only closed).\n"
            "  Ratios are to Embree isa=avx2.  A MESH named\n"
            "  procedural:N (e.g. procedural:10M) is a bumpy sphere of about N triangles made on the spot.\n"
            "  -o, --output DIR  bench.csv, the charts (PNG, drawn by gnuplot when installed) and their\n"
            "                    gnuplot scripts (default: bench-out)\n"
            "  --threads LIST    thread counts (default: 1,2)\n"
            "  --isa LIST        rtk backends (default: every usable one)\n"
            "  --api LIST        single,packet4,packet8,packet16,stream (default: all)\n"
            "  --rays LIST       the trace section's ray sets: primary,diffuse,shadow,incoherent (bounces from\n"
            "                    random points of the whole mesh),sun (shadow rays along one direction from\n"
            "                    random points of the whole mesh) (default: all)\n"
            "  --only LIST       trace,render,build,refit,twolevel,forest,motion,accuracy,features,closed,\n"
            "                    points\n"
            "                    (default: all)\n"
            "  --size WxH        camera rays for the trace sets (default: 1024x768)\n"
            "  --repeat N        passes per measurement (default: 3); trace: every pass cut into 8 pieces\n"
            "                    traced by each library in turn, the ratio the median over the pieces\n"
            "  --builds N        best of N builds per start time (default: 3)\n"
            "  --forest LIST     the forest's instance counts (default: 10000,1000000; --quick: 1000)\n"
            "  --edge-rays N     rays aimed at edges per mesh (default: 200000)\n"
            "  --render WxHxS    path tracer image and samples per pixel (default: 512x384x1)\n"
            "  --alt DIR         one more library, \"rtk ISA alt\": the last --isa (default avx2) loaded from\n"
            "                    the backends in DIR (another build's lib/rtk), to compare two builds\n"
            "  --robust          trace and render with every library's scene in robust mode (watertight)\n"
            "  --quick           a smoke run: 256x192 rays, 1 pass, 1 build, 1 thread, 20000 edge rays,\n"
            "                    128x96x1 render, closed meshes of a quarter of the triangles, a forest of\n"
            "                    1000 instances\n"
            "examples:\n"
            "  rtktool bench ../shared/meshes/dragon.ply ../shared/meshes/sanmiguel_building.ply -o bench-out\n"
            "  rtktool bench dragon.ply --only trace --isa avx2 --api single,packet8 --threads 1\n"
            "  rtktool bench procedural:100k procedural:1M procedural:16M --only build --isa avx2\n"
            "  rtktool bench --only closed --isa avx2,sse41\n");
}

int cmd_bench(int argc, char **argv)
{
    bench_opts o = {.outdir = "bench-out", .w = 1024, .h = 768, .repeat = 3, .builds = 3, .edge_rays = 200000,
                    .threads = {1, 2}, .nthreads = 2, .api_on = {1, 1, 1, 1, 1}, .set_on = {1, 1, 1, 1, 1},
                    .do_trace = 1, .do_render = 1, .do_build = 1, .do_refit = 1, .do_twolevel = 1, .do_motion = 1,
                    .do_accuracy = 1, .do_features = 1, .do_closed = 1, .do_points = 1, .do_forest = 1,
                    .forest = {10000, 1000000}, .nforest = 2, .render_w = 512, .render_h = 384, .render_spp = 1};
    const char *meshes[64];
    int nmeshes = 0, forest_given = 0;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const int more = i + 1 < argc;
        char items[8][16];
        int n;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            bench_usage(stdout);
            return 0;
        } else if ((!strcmp(a, "-o") || !strcmp(a, "--output")) && more)
            o.outdir = argv[++i];
        else if (!strcmp(a, "--threads") && more) {
            n = parse_list(argv[++i], items, 4);
            o.nthreads = n > 0 ? n : 0;
            for (int k = 0; k < o.nthreads; k++) {
                o.threads[k] = atoi(items[k]);
                if (o.threads[k] < 1 || o.threads[k] > 16)
                    o.nthreads = 0;
            }
            if (!o.nthreads) {
                fprintf(stderr, "rtktool bench: --threads wants a list of 1..16 (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--alt") && more) {
            o.alt = argv[++i];
            if (!o.alt[0] || strlen(o.alt) > 256 || strchr(o.alt, ',')) {
                fprintf(stderr, "rtktool bench: --alt wants a directory (no comma, at most 256 bytes)\n");
                return 2;
            }
        } else if (!strcmp(a, "--isa") && more) {
            o.nisa = parse_list(argv[++i], o.isa, 4);
            if (o.nisa < 1) {
                fprintf(stderr, "rtktool bench: --isa wants a list of backends (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--api") && more) {
            n = parse_list(argv[++i], items, 8);
            memset(o.api_on, 0, sizeof o.api_on);
            for (int k = 0; k < n; k++) {
                int found = 0;
                for (int j = 0; j < NAPIS; j++)
                    if (render_api_parse(items[k]) == apis[j])
                        o.api_on[j] = found = 1;
                if (!found)
                    n = -1;
            }
            if (n < 1) {
                fprintf(stderr, "rtktool bench: --api wants a list of single, packet4, packet8, packet16, stream (got '%s')\n",
                        argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--rays") && more) {
            n = parse_list(argv[++i], items, 8);
            memset(o.set_on, 0, sizeof o.set_on);
            for (int k = 0; k < n; k++) {
                int found = 0;
                for (int j = 0; j < NSETS; j++)
                    if (!strcmp(items[k], set_names[j]))
                        o.set_on[j] = found = 1;
                if (!found)
                    n = -1;
            }
            if (n < 1) {
                fprintf(stderr, "rtktool bench: --rays wants a list of primary, diffuse, shadow, incoherent, sun (got '%s')\n",
                        argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--only") && more) {
            n = parse_list(argv[++i], items, 8);
            o.do_trace = o.do_render = o.do_build = o.do_refit = o.do_twolevel = o.do_motion = o.do_accuracy =
                o.do_features = o.do_closed = o.do_points = o.do_forest = 0;
            for (int k = 0; k < n; k++) {
                int *flag = !strcmp(items[k], "trace")      ? &o.do_trace
                            : !strcmp(items[k], "render")   ? &o.do_render
                            : !strcmp(items[k], "build")    ? &o.do_build
                            : !strcmp(items[k], "refit")    ? &o.do_refit
                            : !strcmp(items[k], "twolevel") ? &o.do_twolevel
                            : !strcmp(items[k], "forest")   ? &o.do_forest
                            : !strcmp(items[k], "motion")   ? &o.do_motion
                            : !strcmp(items[k], "accuracy") ? &o.do_accuracy
                            : !strcmp(items[k], "features") ? &o.do_features
                            : !strcmp(items[k], "closed")   ? &o.do_closed
                            : !strcmp(items[k], "points")   ? &o.do_points
                                                            : NULL;
                if (!flag)
                    n = -1;
                else
                    *flag = 1;
            }
            if (n < 1) {
                fprintf(stderr,
                        "rtktool bench: --only wants a list of trace, render, build, refit, twolevel, forest, motion, "
                        "accuracy, features, closed, points (got '%s')\n",
                        argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--forest") && more) {
            n = parse_list(argv[++i], items, 4);
            o.nforest = n > 0 ? n : 0;
            forest_given = 1;
            for (int k = 0; k < o.nforest; k++) {
                char *end;
                errno = 0;
                const double v = strtod(items[k], &end);
                if (end == items[k] || *end || errno || !(v >= 1 && v <= 1e7) || v != (double)(size_t)v)
                    n = -1;
                else
                    o.forest[k] = (size_t)v;
            }
            if (n < 1) {
                fprintf(stderr, "rtktool bench: --forest wants a list of up to 4 instance counts from 1 to 10^7, "
                                "as 10000 or 1e6 (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--size") && more) {
            char tail;
            if (sscanf(argv[++i], "%dx%d%c", &o.w, &o.h, &tail) != 2 || o.w < 4 || o.h < 4 || o.w > 8192 ||
                o.h > 8192 || o.w % 4 || o.h % 4) {
                fprintf(stderr, "rtktool bench: --size wants WxH, multiples of 4 up to 8192 (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--render") && more) {
            char tail;
            if (sscanf(argv[++i], "%dx%dx%d%c", &o.render_w, &o.render_h, &o.render_spp, &tail) != 3 ||
                o.render_w < 1 || o.render_h < 1 || o.render_spp < 1 || o.render_w > 8192 || o.render_h > 8192 ||
                o.render_spp > 4096) {
                fprintf(stderr, "rtktool bench: --render wants WxHxSPP (got '%s')\n", argv[i]);
                return 2;
            }
        } else if ((!strcmp(a, "--repeat") || !strcmp(a, "--builds") || !strcmp(a, "--edge-rays")) && more) {
            char *end;
            errno = 0;
            const long v = strtol(argv[++i], &end, 10);
            const long hi = !strcmp(a, "--edge-rays") ? 100000000 : 1000;
            if (end == argv[i] || *end || errno || v < (!strcmp(a, "--edge-rays") ? 0 : 1) || v > hi) {
                fprintf(stderr, "rtktool bench: %s wants a whole number up to %ld (got '%s')\n", a, hi, argv[i]);
                return 2;
            }
            *(!strcmp(a, "--repeat") ? &o.repeat : !strcmp(a, "--builds") ? &o.builds : &o.edge_rays) = (int)v;
        } else if (!strcmp(a, "--robust")) {
            o.trace_mode = MODE_ROBUST;
        } else if (!strcmp(a, "--quick")) {
            o.w = 256, o.h = 192, o.repeat = 1, o.builds = 1, o.nthreads = 1, o.threads[0] = 1;
            o.edge_rays = 20000, o.render_w = 128, o.render_h = 96, o.quick = 1;
        } else if (a[0] != '-' && nmeshes < 64)
            meshes[nmeshes++] = a;
        else {
            fprintf(stderr, "rtktool bench: unknown or incomplete argument '%s'\n", a);
            bench_usage(stderr);
            return 2;
        }
    }
    if (o.quick && !forest_given)
        o.forest[0] = 1000, o.nforest = 1;
    const int mesh_sections = o.do_trace || o.do_render || o.do_build || o.do_refit || o.do_twolevel || o.do_forest ||
                              o.do_motion || o.do_accuracy || o.do_features || o.do_points;
    if (!nmeshes && mesh_sections) {
        bench_usage(stderr);
        return 2;
    }
    if (mkdir(o.outdir, 0777) && errno != EEXIST) {
        fprintf(stderr, "rtktool bench: %s: %s\n", o.outdir, strerror(errno));
        return 1;
    }
    /* bench.csv replaces the previous one only once the run is whole: a
     * run that fails (a mesh that does not load, a section's error, a full
     * disk) leaves the last run's rows as they were */
    char csv_path[600], err[1024];
    snprintf(csv_path, sizeof csv_path, "%s/bench.csv", o.outdir);
    file_replace csv_file;
    if (file_replace_open(&csv_file, csv_path, err, sizeof err)) {
        fprintf(stderr, "rtktool bench: %s\n", err);
        return 1;
    }
    FILE *csv = csv_file.f;
    fprintf(csv, "mesh,section,library,variant,set,api,threads,value,unit,ratio_to_embree_avx2\n");

    /* The devices kept open for the whole run build with one thread: they
     * build the trace sets' scenes, whose build time is not measured, and
     * Embree 3 builds with the largest threads= of all its live devices (its
     * TBB limit is process-wide), so a 2-thread device kept open here would
     * make the build section's 1-thread Embree devices build on 2.  Trace
     * threads are the bench's own, whatever the device's threads=. */
    ctx c = {.o = &o, .charts = charts_new(o.outdir)};
    const int kept_threads = 1;
    int rc = 1;
    if (!c.charts) {
        fprintf(stderr, "rtktool bench: out of memory\n");
        goto done;
    }
    if (lib_open(&c.libs[c.nlibs++], "embree isa=avx2", 1, "isa=avx2", kept_threads, err, sizeof err) ||
        lib_open(&c.libs[c.nlibs++], "embree default", 1, "", kept_threads, err, sizeof err)) {
        fprintf(stderr, "rtktool bench: %s\n", err);
        c.nlibs--;
        goto done;
    }
    static const char *const all_isas[] = {"scalar", "sse41", "avx", "avx2"};
    for (int b = 0; b < 4; b++) {
        int wanted = o.nisa == 0;
        for (int k = 0; k < o.nisa; k++)
            wanted |= !strcmp(o.isa[k], all_isas[b]);
        if (!wanted)
            continue;
        char name[40], cfg[32];
        snprintf(name, sizeof name, "rtk %s", all_isas[b]);
        snprintf(cfg, sizeof cfg, "isa=%s", all_isas[b]);
        if (lib_open(&c.libs[c.nlibs], name, 0, cfg, kept_threads, err, sizeof err))
            printf("%s: unavailable (%s)\n", name, err);
        else
            c.nlibs++;
    }
    for (int k = 0; k < o.nisa; k++) {
        int known = 0;
        for (int b = 0; b < 4; b++)
            known |= !strcmp(o.isa[k], all_isas[b]);
        if (!known) {
            fprintf(stderr, "rtktool bench: --isa: no backend '%s' (scalar, sse41, avx, avx2)\n", o.isa[k]);
            goto done;
        }
    }
    if (o.alt) {
        /* the last rtk backend asked for, from the other directory: for
         * comparing two builds of rtk (a change and its parent) in one run */
        const char *isa = o.nisa ? o.isa[o.nisa - 1] : "avx2";
        char name[40], cfg[320];
        snprintf(name, sizeof name, "rtk %s alt", isa);
        snprintf(cfg, sizeof cfg, "isa=%s,backend_path=%s", isa, o.alt);
        if (c.nlibs == MAXLIBS || lib_open(&c.libs[c.nlibs], name, 0, cfg, kept_threads, err, sizeof err)) {
            fprintf(stderr, "rtktool bench: --alt: %s\n", c.nlibs == MAXLIBS ? "too many libraries" : err);
            goto done;
        }
        c.nlibs++;
    }
    char feat[512];
    rtk_cpu_features_string(rtk_cpu_features(), feat, sizeof feat);
    printf("rtk %s beside Embree %d.%d.%d; CPU features: %s; %ld cores online\n", rtk_version_string(),
           RTC_VERSION_MAJOR, RTC_VERSION_MINOR, RTC_VERSION_PATCH, feat, sysconf(_SC_NPROCESSORS_ONLN));
    printf("device creation:");
    for (int l = 0; l < c.nlibs; l++)
        printf(" %s %.1f ms%s", c.libs[l].name, c.libs[l].device_seconds * 1e3, l + 1 < c.nlibs ? "," : "\n");
    for (int mi = 0; mi < nmeshes; mi++) {
        rtk_mesh m;
        size_t want;
        if (rtk_mesh_procedural_name(meshes[mi], &want)) {
            if (rtk_mesh_procedural(want, &m)) {
                fprintf(stderr, "rtktool bench: out of memory for %s\n", meshes[mi]);
                goto done;
            }
        } else if (rtk_mesh_load(meshes[mi], &m, err, sizeof err)) {
            fprintf(stderr, "rtktool: %s\n", err);
            goto done;
        }
        /* Embree reads 16 bytes at the last vertex: a padded copy */
        float *padded = calloc(m.vertex_count * 3 + 4, sizeof(float));
        if (!padded) {
            rtk_mesh_free(&m);
            fprintf(stderr, "rtktool bench: out of memory\n");
            goto done;
        }
        memcpy(padded, m.vertices, m.vertex_count * 3 * sizeof(float));
        c.m = &m;
        c.padded = padded;
        c.csv = (out){csv, meshes[mi]};
        mesh_stem(meshes[mi], c.stem, sizeof c.stem);
        printf("\n== %s: %zu triangles, %zu vertices\n", meshes[mi], m.triangle_count, m.vertex_count);
        printf("memory (BVH and leaves per input triangle; Embree's from its memory monitor):");
        for (int l = 0; l < c.nlibs; l++) {
            scene sc;
            if (scene_build(&sc, &c.libs[l], &m, padded, MODE_DEFAULT, 1, err, sizeof err)) {
                fprintf(stderr, "rtktool bench: %s\n", err);
                free(padded);
                rtk_mesh_free(&m);
                goto done;
            }
            printf(" %s %.1f B%s", c.libs[l].name, sc.bytes_per_tri, l + 1 < c.nlibs ? "," : "\n");
            csv_row(&c.csv, "memory", c.libs[l].name, sc.layout, "", "", 1, sc.bytes_per_tri, "bytes per triangle", 0);
            scene_release(&sc);
        }
        int bad = ((o.do_trace || o.do_build || o.do_refit || o.do_motion || o.do_accuracy || o.do_features) &&
                   make_sets(&c, err, sizeof err)) ||
                  (o.do_trace && section_trace(&c, err, sizeof err)) ||
                  (o.do_render && section_render(&c, err, sizeof err)) ||
                  (o.do_build && section_build(&c, err, sizeof err)) ||
                  (o.do_refit && section_refit(&c, err, sizeof err)) ||
                  (o.do_twolevel && section_twolevel(&c, err, sizeof err)) ||
                  (o.do_forest && section_forest(&c, err, sizeof err)) ||
                  (o.do_motion && section_motion(&c, err, sizeof err)) ||
                  (o.do_accuracy && section_accuracy(&c, err, sizeof err)) ||
                  (o.do_features && section_features(&c, err, sizeof err)) ||
                  (o.do_points && section_points(&c, err, sizeof err));
        free_sets(&c);
        free(padded);
        rtk_mesh_free(&m);
        if (bad) {
            fprintf(stderr, "rtktool bench: %s\n", err);
            goto done;
        }
    }
    if (o.do_closed) {
        c.m = NULL;
        c.csv = (out){csv, "procedural:closed"};
        if (section_closed(&c, err, sizeof err)) {
            fprintf(stderr, "rtktool bench: %s\n", err);
            goto done;
        }
    }
    rc = 0;
done:
    if (rc) {
        file_replace_abort(&csv_file);
        fprintf(stderr, "rtktool bench: %s left as it was, and the charts beside it\n", csv_path);
    } else if (file_replace_commit(&csv_file, ferror(csv) ? EIO : 0, err, sizeof err)) {
        fprintf(stderr, "rtktool bench: %s\n", err);
        rc = 1;
    } else {
        printf("\ncsv: %s\n", csv_path);
    }
    /* the charts like the CSV: in place (and drawn) only after a whole run */
    if (charts_finish(c.charts, rc == 0))
        rc = 1;
    for (int l = 0; l < c.nlibs; l++)
        lib_close(&c.libs[l]);
    return rc;
}
