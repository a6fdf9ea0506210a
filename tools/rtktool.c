/*
 * rtktool: how people meet rtk.  `info` shows the CPU and the backends;
 * `convert` turns a mesh into rtk's own .rtkm file; `build` shows, dumps and
 * reloads BVHs; `trace` renders a mesh and measures; `bench` measures rtk
 * beside Embree 3.
 */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <unistd.h>

#include "bench.h"
#include "mesh_import.h"
#include "mesh_tools.h"
#include "bvh_stats.h"
#include "png_io.h"
#include "progress.h"
#include "render.h"
#include "rtkb.h"
#include "rtkm.h"
#include "rtk/rtk.h"

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static const char *status_word(rtk_backend_status s)
{
    return s == RTK_BACKEND_STATUS_ACTIVE ? "active" : s == RTK_BACKEND_STATUS_USABLE ? "usable" : "rejected";
}

static int print_backends(rtk_device dev)
{
    printf("backend search path: %s\n", rtk_device_get_search_path(dev));
    size_t n = rtk_device_get_backend_count(dev);
    for (size_t i = 0; i < n; i++) {
        rtk_backend_info bi = {.struct_size = sizeof bi};
        if (rtk_device_get_backend_info(dev, i, &bi))
            continue;
        printf("  %-8s %-8s %s%s%s\n", bi.name, status_word(bi.status), bi.path, bi.reason[0] ? "\n           " : "",
               bi.reason);
    }
    printf("active backend: %s\n", rtk_device_get_backend_name(dev));
    return 0;
}

static rtk_device open_device(const char *config)
{
    rtk_device dev = NULL;
    rtk_error err = rtk_device_new(config, &dev);
    if (err) {
        fprintf(stderr, "rtktool: %s: %s\n", rtk_error_name(err), rtk_device_get_error_message(NULL));
        return NULL;
    }
    return dev;
}

static void info_usage(FILE *f)
{
    fprintf(f, "usage: rtktool info [--config STR]\n"
               "  Prints rtk's version, the CPU features it detected, every backend file it found with\n"
               "  its status (active, usable, rejected, and why), and the backend a device would use.\n"
               "  --config STR   device config, e.g. isa=sse41 or backend_path=DIR (see README)\n"
               "examples:\n"
               "  rtktool info\n"
               "  RTK_BACKEND_PATH=/opt/rtk/lib/rtk rtktool info --config max_isa=avx\n");
}

static int cmd_info(int argc, char **argv)
{
    const char *config = "";
    for (int i = 0; i < argc; i++) {
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            info_usage(stdout);
            return 0;
        } else if (!strcmp(argv[i], "--config") && i + 1 < argc)
            config = argv[++i];
        else {
            fprintf(stderr, "rtktool info: unknown argument '%s'\n", argv[i]);
            info_usage(stderr);
            return 2;
        }
    }
    char feat[512];
    rtk_cpu_features_string(rtk_cpu_features(), feat, sizeof feat);
    printf("rtk %s\nCPU features: %s\n", rtk_version_string(), feat);
    rtk_device dev = open_device(config);
    if (!dev)
        return 1;
    print_backends(dev);
    rtk_device_release(dev);
    return 0;
}

/* A scene over one mesh (shared buffers), committed by building a BVH or,
 * with `tree`, from that tree.  NULL with the library's message on stderr. */
static rtk_scene mesh_scene(rtk_device dev, const rtk_mesh *mesh, unsigned flags, rtk_build_quality quality,
                            const rtk_bvh *tree)
{
    rtk_scene scene = NULL;
    rtk_geometry geom = NULL;
    if (rtk_scene_new(dev, &scene) || rtk_scene_set_flags(scene, flags) ||
        rtk_scene_set_build_quality(scene, quality) || rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &geom) ||
        rtk_geometry_set_shared_buffer(geom, RTK_BUFFER_TYPE_VERTEX, mesh->vertices, 0, 12, mesh->vertex_count) ||
        rtk_geometry_set_shared_buffer(geom, RTK_BUFFER_TYPE_INDEX, mesh->indices, 0, 12, mesh->triangle_count) ||
        rtk_geometry_commit(geom) || rtk_scene_attach_geometry(scene, geom, NULL) ||
        (tree ? rtk_scene_commit_bvh(scene, tree) : rtk_scene_commit(scene))) {
        fprintf(stderr, "rtktool: %s\n", rtk_device_get_error_message(dev));
        rtk_geometry_release(geom);
        rtk_scene_release(scene);
        return NULL;
    }
    rtk_geometry_release(geom);
    return scene;
}

/* The scene flags that give a dump's layout again: index leaves were a
 * compact scene's. */
static unsigned dump_scene_flags(const rtkb_file *file)
{
    const char *l = file->info.layout;
    return (strstr(l, "triangle4i") ? RTK_SCENE_FLAG_COMPACT : 0) |
           (strstr(l, "robust") || strstr(l, "triangle4v") ? RTK_SCENE_FLAG_ROBUST : 0);
}

/* The device config of build and trace: threads, backend, builder and
 * layout as asked (a loaded dump's layout unless another was asked for,
 * which is an error), then the --config text.  0 after saying why not. */
static int device_config(char *buf, size_t size, const char *cmd, long threads, const char *isa, const char *builder,
                         const char *layout, const rtkb_file *dump, const char *extra)
{
    if (dump && layout && strcmp(layout, dump->info.layout)) {
        fprintf(stderr, "rtktool %s: --layout %s, but the dump holds a %s tree\n", cmd, layout, dump->info.layout);
        return 0;
    }
    if (dump)
        layout = dump->info.layout;
    size_t n = 0;
    buf[0] = '\0';
    if (threads)
        n += (size_t)snprintf(buf, size, "threads=%ld,", threads);
    const char *const keys[] = {"isa", "builder", "layout"}, *const vals[] = {isa, builder, layout};
    for (int k = 0; k < 3; k++)
        if (vals[k] && n < size)
            n += (size_t)snprintf(buf + n, size - n, "%s=%s,", keys[k], vals[k]);
    if (n < size)
        snprintf(buf + n, size - n, "%s", extra);
    return 1;
}

/* Whether a dump was built over this mesh (else says so on stderr). */
static int dump_fits_mesh(const char *load, const rtkb_file *file, const char *mesh_path, const rtk_mesh *mesh)
{
    const rtkb_info *i = &file->info;
    const uint64_t sum = rtkm_mesh_checksum(mesh);
    if (i->mesh_triangles == mesh->triangle_count && i->mesh_vertices == mesh->vertex_count && i->mesh_checksum == sum)
        return 1;
    fprintf(stderr,
            "rtktool: %s was built over another mesh (%llu triangles, %llu vertices, checksum %016llx), "
            "not %s (%zu, %zu, %016llx)\n",
            load, (unsigned long long)i->mesh_triangles, (unsigned long long)i->mesh_vertices,
            (unsigned long long)i->mesh_checksum, mesh_path, mesh->triangle_count, mesh->vertex_count,
            (unsigned long long)sum);
    return 0;
}

/* ---- arguments ---- */

/* An integer option's value in lo..hi into *out; else a one-line error
 * naming the command and option, and 0. */
static int int_arg(const char *cmd, const char *opt, const char *s, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    const long v = strtol(s, &end, 10);
    if (end == s || *end || errno || v < lo || v > hi) {
        fprintf(stderr, "rtktool %s: %s wants a whole number %ld..%ld (got '%s')\n", cmd, opt, lo, hi, s);
        return 0;
    }
    *out = v;
    return 1;
}

static int quality_arg(const char *cmd, const char *s, rtk_build_quality *q)
{
    static const char *const names[] = {"low", "medium", "high"};
    static const rtk_build_quality values[] = {RTK_BUILD_QUALITY_LOW, RTK_BUILD_QUALITY_MEDIUM,
                                               RTK_BUILD_QUALITY_HIGH};
    for (int i = 0; i < 3; i++)
        if (!strcmp(s, names[i])) {
            *q = values[i];
            return 1;
        }
    fprintf(stderr, "rtktool %s: --quality wants low, medium or high (got '%s')\n", cmd, s);
    return 0;
}

/* A JSON string member, escaped, on a line of its own. */
static void json_string(const char *key, const char *v, int last)
{
    printf("  \"%s\": \"", key);
    for (const char *p = v; *p; p++) {
        if (*p == '"' || *p == '\\')
            printf("\\%c", *p);
        else if ((unsigned char)*p < 0x20)
            printf("\\u%04x", *p);
        else
            putchar(*p);
    }
    printf("\"%s\n", last ? "" : ",");
}

/* ---- trace ---- */

static void trace_usage(FILE *f)
{
    fprintf(f,
            "usage: rtktool trace MESH [options]\n"
            "  Renders MESH (.rtkm .obj .ply .off .stl .om) to a PNG from a camera that frames it, and prints\n"
            "  the backend, the BVH, the rays traced of each kind and the rays per second.\n"
            "  -o, --output FILE    output PNG (default: trace.png)\n"
            "  --mode MODE          eyelight (default), normals (the geometric normal as a colour),\n"
            "                       ao (ambient occlusion), diffuse (path tracer: grey diffuse surfaces\n"
            "                       under a sky and a sun, next-event shadow rays, Russian roulette)\n"
            "  --size WxH           image size (default: 1024x768)\n"
            "  --spp N              samples per pixel, jittered when more than one (default: 1)\n"
            "  --bounces N          diffuse: surface bounces per path at most (default: 4)\n"
            "  --ao-samples N       ao: rays per hit (default: 8), a tenth of the mesh's size long\n"
            "  --camera E/T[/U[/F]] eye EX,EY,EZ, target TX,TY,TZ, up UX,UY,UZ (default 0,1,0) and vertical\n"
            "                       field of view F in degrees (default 40); trace prints the framing\n"
            "                       camera in this form\n"
            "  --api API            single (intersect1/occluded1, default), packet4, packet8, packet16, stream\n"
            "                       (2x2, 4x2, 4x4 pixels per packet; the paths of a packet stay together;\n"
            "                       stream: the path tracer in wavefront form, each bounce's rays of a\n"
            "                       32x32 tile handed over as one stream)\n"
            "  --isa NAME           backend (scalar, sse41, avx, avx2; default: the best)\n"
            "  --threads N          render threads (default: all cores)\n"
            "  --quality Q          build quality low, medium (default) or high\n"
            "  --builder NAME       build with this builder whatever the quality: morton,\n"
            "                       sah-binned, sah-spatial (default: the quality's)\n"
            "  --layout NAME        build into this layout: bvh4.triangle4, bvh8.triangle4 (sse41, avx, avx2),\n"
            "                       bvh4.triangle4i, or the robust bvh4.triangle4v, bvh8.triangle4v,\n"
            "                       bvh4.triangle4i.robust (default: the backend's fastest)\n"
            "  --frames N           render N times and report the best rate (default: 3)\n"
            "  --seed N             random numbers (default: 1); the image does not depend on\n"
            "                       --threads or --api\n"
            "  --load F.rtkb        trace with the BVH dumped by rtktool build --dump (no build), in\n"
            "                       the dump's layout on any backend that has it\n"
            "  --json               the report as JSON on stdout\n"
            "  --config STR         extra device config (e.g. verbose=1)\n"
            "  A progress bar goes to stderr for renders longer than a second when it is a terminal.\n"
            "examples:\n"
            "  rtktool trace data/bunny.ply -o bunny.png\n"
            "  rtktool trace dragon.ply --mode diffuse --spp 16 --api packet8 -o dragon.png\n"
            "  rtktool trace bunny.ply --mode ao --camera 0.3,0.2,0.4/-0.02,0.1,0/0,1,0/30\n");
}

typedef struct trace_progress {
    progress bar;
    int frame, frames;
} trace_progress;

static void trace_progress_cb(void *user, double done)
{
    trace_progress *p = user;
    progress_update(&p->bar, ((double)p->frame + done) / (double)p->frames);
}

/* Triangles per second of a build, in millions (0 for a build too quick to time). */
static double build_mtris(uint64_t triangles, double seconds)
{
    return seconds > 0 ? (double)triangles / seconds * 1e-6 : 0.0;
}

/* The "build:" line of trace and build: time, rate and threads. */
static void print_build_line(const char *label, double seconds, uint64_t triangles, unsigned threads)
{
    printf("%s%.3f s, %.2f Mtris/s (%u thread%s)\n", label, seconds, build_mtris(triangles, seconds), threads,
           threads == 1 ? "" : "s");
}

static int cmd_trace(int argc, char **argv)
{
    const char *mesh_path = NULL, *out = "trace.png", *isa = NULL, *extra = "", *load = NULL, *camera = NULL;
    const char *builder = NULL, *layout = NULL;
    int w = 1024, h = 768, json = 0, api = 1;
    long frames = 3, spp = 1, bounces = 4, ao_samples = 8, seed = 1;
    long threads = sysconf(_SC_NPROCESSORS_ONLN);
    render_mode mode = RENDER_EYELIGHT;
    rtk_build_quality quality = RTK_BUILD_QUALITY_MEDIUM;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const int more = i + 1 < argc;
        int ok = 1;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            trace_usage(stdout);
            return 0;
        } else if ((!strcmp(a, "-o") || !strcmp(a, "--output")) && more)
            out = argv[++i];
        else if (!strcmp(a, "--size") && more) {
            char tail;
            if (sscanf(argv[++i], "%dx%d%c", &w, &h, &tail) != 2 || w < 1 || h < 1 || w > 16384 || h > 16384) {
                fprintf(stderr, "rtktool trace: --size wants WxH, each 1..16384 (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--mode") && more) {
            if (render_mode_parse(argv[++i], &mode)) {
                fprintf(stderr, "rtktool trace: --mode wants eyelight, normals, ao or diffuse (got '%s')\n",
                        argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--api") && more) {
            const char *v = argv[++i];
            api = render_api_parse(v);
            if (!api) {
                fprintf(stderr, "rtktool trace: --api wants single, packet4, packet8, packet16 or stream (got '%s')\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--spp") && more)
            ok = int_arg("trace", a, argv[++i], 1, 1 << 16, &spp);
        else if (!strcmp(a, "--bounces") && more)
            ok = int_arg("trace", a, argv[++i], 0, 1000, &bounces);
        else if (!strcmp(a, "--ao-samples") && more)
            ok = int_arg("trace", a, argv[++i], 1, 1 << 16, &ao_samples);
        else if (!strcmp(a, "--seed") && more)
            ok = int_arg("trace", a, argv[++i], 0, 0xffffffffl, &seed);
        else if (!strcmp(a, "--camera") && more)
            camera = argv[++i];
        else if (!strcmp(a, "--isa") && more)
            isa = argv[++i];
        else if (!strcmp(a, "--builder") && more)
            builder = argv[++i];
        else if (!strcmp(a, "--layout") && more)
            layout = argv[++i];
        else if (!strcmp(a, "--threads") && more)
            ok = int_arg("trace", a, argv[++i], 1, 1024, &threads);
        else if (!strcmp(a, "--quality") && more)
            ok = quality_arg("trace", argv[++i], &quality);
        else if (!strcmp(a, "--frames") && more)
            ok = int_arg("trace", a, argv[++i], 1, 1000, &frames);
        else if (!strcmp(a, "--load") && more)
            load = argv[++i];
        else if (!strcmp(a, "--json"))
            json = 1;
        else if (!strcmp(a, "--config") && more)
            extra = argv[++i];
        else if (a[0] != '-' && !mesh_path)
            mesh_path = a;
        else {
            fprintf(stderr, "rtktool trace: unknown or incomplete argument '%s'\n", a);
            trace_usage(stderr);
            return 2;
        }
        if (!ok)
            return 2;
    }
    if (!mesh_path) {
        trace_usage(stderr);
        return 2;
    }
    if (threads < 1)
        threads = 1;

    char config[512], err[1024];
    render_camera given;
    if (camera && render_camera_parse(&given, camera, w, h, err, sizeof err)) {
        fprintf(stderr, "rtktool trace: %s\n", err);
        return 2;
    }
    int rc = 1;
    rtk_device dev = NULL;
    rtk_scene scene = NULL;
    float *rgb = NULL;
    unsigned char *rgb8 = NULL;
    rtk_mesh mesh;
    memset(&mesh, 0, sizeof mesh);
    rtkb_file dump;
    memset(&dump, 0, sizeof dump);
    if (load && rtkb_load(load, &dump, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        goto done;
    }
    if (!device_config(config, sizeof config, "trace", 0, isa, builder, layout, load ? &dump : NULL, extra)) {
        rc = 2;
        goto done;
    }
    dev = open_device(config);
    if (!dev)
        goto done;

    double t0 = now();
    if (rtk_mesh_load(mesh_path, &mesh, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        goto done;
    }
    double t_load = now() - t0;

    if (load && !dump_fits_mesh(load, &dump, mesh_path, &mesh))
        goto done;
    scene = mesh_scene(dev, &mesh, load ? dump_scene_flags(&dump) : 0, quality, load ? &dump.tree : NULL);
    if (!scene)
        goto done;
    rtk_scene_info info = {.struct_size = sizeof info};
    rtk_scene_get_info(scene, &info);

    render_settings rs;
    render_defaults(&rs, info.bounds_lower, info.bounds_upper, w, h);
    if (camera)
        rs.camera = given;
    rs.mode = mode;
    rs.api = api;
    rs.spp = (int)spp;
    rs.threads = (int)threads;
    rs.max_bounces = (int)bounces;
    rs.ao_samples = (int)ao_samples;
    rs.seed = (uint32_t)seed;
    trace_progress prog = {.frames = (int)frames};
    progress_begin(&prog.bar, "rtktool trace");
    rs.progress = trace_progress_cb;
    rs.progress_user = &prog;

    rgb = malloc((size_t)w * (size_t)h * 3 * sizeof *rgb);
    rgb8 = malloc((size_t)w * (size_t)h * 3);
    if (!rgb || !rgb8) {
        fprintf(stderr, "rtktool: out of memory for a %dx%d image\n", w, h);
        goto done;
    }
    const render_tracer tracer = render_tracer_rtk(scene);
    render_stats st, best = {0};
    for (prog.frame = 0; prog.frame < frames; prog.frame++) {
        if (render_image(&tracer, &rs, rgb, &st, err, sizeof err)) {
            progress_end(&prog.bar);
            fprintf(stderr, "rtktool trace: %s\n", err);
            goto done;
        }
        if (!prog.frame || st.seconds < best.seconds)
            best = st;
    }
    progress_end(&prog.bar);
    render_to_rgb8(&rs, rgb, rgb8);
    if (rtk_png_write_rgb(out, rgb8, w, h, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        goto done;
    }

    const uint64_t rays = render_stats_rays(&best);
    const double mrays = best.seconds > 0 ? (double)rays / best.seconds * 1e-6 : 0.0;
    const double hit = best.primary ? 100.0 * (double)best.primary_hits / (double)best.primary : 0.0;
    const unsigned pw = api == 1 || api == RENDER_API_STREAM ? 1 : info.packet_width[api == 4 ? 0 : api == 8 ? 1 : 2];
    char packets[128] = "";
    if (api == RENDER_API_STREAM && info.stream_in_flight)
        snprintf(packets, sizeof packets, " (each bounce's rays of a 32x32 tile one stream, %u rays in flight)",
                 info.stream_in_flight);
    else if (api == RENDER_API_STREAM)
        snprintf(packets, sizeof packets, " (each bounce's rays of a 32x32 tile one stream, traced ray by ray)");
    else if (api > 1)
        snprintf(packets, sizeof packets, " (the backend traces %s)",
                 pw == (unsigned)api ? "them whole" : pw > 1 ? "them split in narrower packets" : "them ray by ray");
    char cam_spec[256];
    const render_camera *c = &rs.camera;
    snprintf(cam_spec, sizeof cam_spec, "%g,%g,%g/%g,%g,%g/%g,%g,%g/%g", c->eye[0], c->eye[1], c->eye[2],
             c->target[0], c->target[1], c->target[2], c->up[0], c->up[1], c->up[2], c->fov);
    if (json) {
        printf("{\n");
        json_string("mesh", mesh_path, 0);
        printf("  \"triangles\": %zu,\n", mesh.triangle_count);
        json_string("backend", rtk_device_get_backend_name(dev), 0);
        json_string("layout", info.layout, 0);
        printf("  \"bytes_per_triangle\": %.2f,\n  \"build_seconds\": %.6f,\n  \"built\": %s,\n",
               info.bytes_per_triangle, info.build_seconds, load ? "false" : "true");
        json_string("mode", render_mode_name(mode), 0);
        json_string("api", render_api_name(api), 0);
        printf("  \"packet_width\": %u,\n  \"width\": %d,\n  \"height\": %d,\n  \"spp\": %ld,\n  \"threads\": %ld,\n",
               pw, w, h, spp, threads);
        json_string("camera", cam_spec, 0);
        printf("  \"rays\": {\"primary\": %llu, \"bounce\": %llu, \"shadow\": %llu, \"ao\": %llu, \"total\": %llu},\n"
               "  \"primary_hit_percent\": %.3f,\n  \"frames\": %ld,\n  \"seconds\": %.6f,\n  \"mrays_per_s\": %.4f,\n",
               (unsigned long long)best.primary, (unsigned long long)best.bounce, (unsigned long long)best.shadow,
               (unsigned long long)best.ao, (unsigned long long)rays, hit, frames, best.seconds, mrays);
        json_string("image", out, 1);
        printf("}\n");
        rc = 0;
        goto done;
    }
    printf("mesh:       %s: %zu vertices, %zu triangles (loaded in %.2f s)\n", mesh_path, mesh.vertex_count,
           mesh.triangle_count, t_load);
    printf("backend:    %s\n", rtk_device_get_backend_name(dev));
    printf("bvh:        %s, %s builder, %llu nodes, %llu leaves, depth %u, SAH %.2f, %.1f bytes/triangle\n",
           info.layout, info.builder, (unsigned long long)info.nodes, (unsigned long long)info.leaves, info.depth,
           info.sah_cost, info.bytes_per_triangle);
    if (info.triangles_skipped || info.triangles_degenerate || info.triangles_out_of_range)
        printf("            left out: %llu triangles with non-finite vertices, %llu of zero area, %llu outside "
               "rtk's range (rtk.h)\n",
               (unsigned long long)info.triangles_skipped, (unsigned long long)info.triangles_degenerate,
               (unsigned long long)info.triangles_out_of_range);
    if (load)
        printf("build:      none: the tree of %s, checked and committed in %.3f s\n", load, info.build_seconds);
    else
        print_build_line("build:      ", info.build_seconds, mesh.triangle_count, info.build_threads);
    printf("camera:     --camera %s\n", cam_spec);
    printf("render:     %s, %dx%d, %ld spp", render_mode_name(mode), w, h, spp);
    if (mode == RENDER_DIFFUSE)
        printf(", up to %ld bounces (Russian roulette from bounce %d)", bounces, rs.rr_depth);
    if (mode == RENDER_AO)
        printf(", %ld rays of length %g per hit", ao_samples, rs.ao_distance);
    printf(", %s API%s, %ld thread%s\n", render_api_name(api), packets, threads, threads > 1 ? "s" : "");
    printf("rays:       %llu primary (%.1f%% hit)", (unsigned long long)best.primary, hit);
    if (best.bounce || mode == RENDER_DIFFUSE)
        printf(", %llu bounce", (unsigned long long)best.bounce);
    if (best.shadow || mode == RENDER_DIFFUSE)
        printf(", %llu shadow", (unsigned long long)best.shadow);
    if (best.ao || mode == RENDER_AO)
        printf(", %llu ao", (unsigned long long)best.ao);
    printf(": %llu per frame\n", (unsigned long long)rays);
    printf("trace:      best of %ld frame%s %.3f s: %.2f Mrays/s\n", frames, frames > 1 ? "s:" : ":", best.seconds,
           mrays);
    printf("image:      %s\n", out);
    rc = 0;
done:
    free(rgb);
    free(rgb8);
    rtk_scene_release(scene);
    rtk_device_release(dev);
    rtk_mesh_free(&mesh);
    rtkb_free(&dump);
    return rc;
}

static void convert_usage(FILE *f)
{
    fprintf(f, "usage: rtktool convert IN OUT.rtkm [options]\n"
               "  Reads IN (.obj .ply .off .stl .om .rtkm, through OpenMesh) as triangles: polygons\n"
               "  split into fans, every face kept, no vertex duplicated; writes rtk's mesh file,\n"
               "  which every rtktool command reads without parsing (tools/rtkm.h).\n"
               "  --merge-vertices   merge vertices at the same position (reports how many)\n"
               "  --drop-degenerate  drop the triangles rtk never hits: zero area, or a NaN or\n"
               "                     infinite vertex (without it they are counted and kept)\n"
               "examples:\n"
               "  rtktool convert bunny.ply bunny.rtkm\n"
               "  rtktool convert scan.stl scan.rtkm --merge-vertices --drop-degenerate\n");
}

static int ends_with(const char *s, const char *suffix)
{
    const size_t n = strlen(s), m = strlen(suffix);
    return n >= m && !strcasecmp(s + n - m, suffix);
}

static int cmd_convert(int argc, char **argv)
{
    const char *in = NULL, *out = NULL;
    int merge = 0, drop = 0;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            convert_usage(stdout);
            return 0;
        } else if (!strcmp(a, "--merge-vertices"))
            merge = 1;
        else if (!strcmp(a, "--drop-degenerate"))
            drop = 1;
        else if (a[0] != '-' && !in)
            in = a;
        else if (a[0] != '-' && !out)
            out = a;
        else {
            fprintf(stderr, "rtktool convert: unknown argument '%s'\n", a);
            convert_usage(stderr);
            return 2;
        }
    }
    if (!in || !out) {
        convert_usage(stderr);
        return 2;
    }
    if (!ends_with(out, ".rtkm")) {
        fprintf(stderr, "rtktool convert: the output name must end in .rtkm (got '%s')\n", out);
        return 2;
    }
    char err[1024];
    rtk_mesh mesh;
    double t0 = now();
    if (rtk_mesh_load(in, &mesh, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        return 1;
    }
    printf("read:     %s: %zu faces (%zu polygons triangulated, %zu repeating a vertex), %zu vertices, "
           "%zu triangles, %.2f s\n",
           in, mesh.faces_read, mesh.polygons_triangulated, mesh.faces_repeated_vertex, mesh.vertex_count,
           mesh.triangle_count, now() - t0);
    printf("          %zu vertices duplicated to keep every face\n", mesh.vertices_duplicated);
    if (merge) {
        const size_t merged = rtk_mesh_merge_vertices(&mesh);
        if (merged == (size_t)-1) {
            fprintf(stderr, "rtktool: out of memory merging vertices\n");
            rtk_mesh_free(&mesh);
            return 1;
        }
        printf("merged:   %zu vertices at positions already seen\n", merged);
    }
    size_t degenerate, non_finite;
    if (drop) {
        rtk_mesh_drop_unhittable(&mesh, &degenerate, &non_finite);
        printf("dropped:  %zu triangles of zero area, %zu with a NaN or infinite vertex\n", degenerate, non_finite);
    } else {
        rtk_mesh_count_unhittable(&mesh, &degenerate, &non_finite);
        if (degenerate || non_finite)
            printf("kept:     %zu triangles of zero area, %zu with a NaN or infinite vertex (never hit; "
                   "--drop-degenerate drops them)\n",
                   degenerate, non_finite);
    }
    t0 = now();
    if (rtkm_save(out, &mesh, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        rtk_mesh_free(&mesh);
        return 1;
    }
    float lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    if (mesh.vertex_count)
        rtk_mesh_bounds(&mesh, lo, hi);
    printf("wrote:    %s: %zu vertices, %zu triangles, bounds [%g %g %g]..[%g %g %g], %.2f s\n", out,
           mesh.vertex_count, mesh.triangle_count, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2], now() - t0);
    rtk_mesh_free(&mesh);
    return 0;
}

/* ---- build ---- */

static void build_usage(FILE *f)
{
    fprintf(f,
            "usage: rtktool build MESH [options]\n"
            "       rtktool build --load FILE.rtkb [MESH] [options]\n"
            "  Builds a BVH over MESH and prints what it is made of: nodes and leaves,\n"
            "  depth, triangles per leaf, SAH cost, memory, build time.\n"
            "  With --load, reads a dump instead: checks every offset, count and reference\n"
            "  in it and prints the same statistics (no backend needed); given MESH too,\n"
            "  commits MESH with the dumped tree (in the dump's layout, on the best backend\n"
            "  that has it) and checks that it traces like a build.\n"
            "  --quality low|medium|high  build quality (default: medium)\n"
            "  --isa NAME                 backend (scalar, sse41, avx, avx2; default: the best)\n"
            "  --compact                  a compact scene: index leaves, half the memory\n"
            "  --robust                   a robust scene: the watertight intersector\n"
            "  --builder NAME             this builder whatever the quality: morton (low),\n"
            "                             sah-binned (medium), sah-spatial (high)\n"
            "  --layout NAME              this layout: bvh4.triangle4, bvh8.triangle4 (sse41, avx, avx2),\n"
            "                             bvh4.triangle4i, bvh4.triangle4v, bvh8.triangle4v,\n"
            "                             bvh4.triangle4i.robust (default: the backend's fastest, or\n"
            "                             bvh4.triangle4i with --compact, bvh8/bvh4.triangle4v\n"
            "                             with --robust, bvh4.triangle4i.robust with both)\n"
            "  --threads N                threads the device may use (default: all cores)\n"
            "  --json                     the statistics as one JSON object on stdout\n"
            "  --dump FILE.rtkb           write the tree to FILE.rtkb (tools/rtkb.h)\n"
            "  --load FILE.rtkb           read a dump (see above)\n"
            "  --png FILE                 draw the boxes of the first 8 levels, a panel per level\n"
            "  --verify N                 with --load and MESH: rays to compare (default: 100000)\n"
            "  --config STR               extra device config (e.g. verbose=1)\n"
            "examples:\n"
            "  rtktool build dragon.ply --json\n"
            "  rtktool build bunny.ply --isa sse41 --dump bunny.rtkb --png bunny-boxes.png\n"
            "  rtktool build --load bunny.rtkb\n"
            "  rtktool build --load bunny.rtkb bunny.ply\n"
            "  rtktool build dragon.ply --builder morton --layout bvh4.triangle4 --threads 1\n");
}

static const char *quality_name(unsigned q)
{
    return q == RTK_BUILD_QUALITY_LOW ? "low" : q == RTK_BUILD_QUALITY_HIGH ? "high" : "medium";
}

/* What is printed: the tree's statistics and what the library said. */
typedef struct build_report {
    const char *mesh, *backend, *layout, *builder;
    unsigned quality;
    uint64_t mesh_triangles;
    uint64_t bytes;       /* 0: not known (a dump read alone records the original's) */
    double build_seconds; /* < 0: not built here */
    unsigned build_threads;
    double sah_reported;
    bvh_stats st;
} build_report;

static void print_report(const build_report *r)
{
    const bvh_stats *s = &r->st;
    if (r->mesh)
        printf("mesh:      %s (%llu triangles)\n", r->mesh, (unsigned long long)r->mesh_triangles);
    else
        printf("mesh:      not loaded (the dump was built over %llu triangles)\n",
               (unsigned long long)r->mesh_triangles);
    printf("backend:   %s\n", r->backend);
    printf("bvh:       %s, %s builder, quality %s, %u-wide nodes\n", r->layout, r->builder, quality_name(r->quality),
           s->width);
    printf("nodes:     %llu inner, %llu leaves (%llu blocks of 4 triangles), %.2f children per node\n",
           (unsigned long long)s->nodes, (unsigned long long)s->leaves, (unsigned long long)s->leaf_blocks,
           s->nodes ? (double)s->slots_used / (double)s->nodes : 0.0);
    printf("depth:     max %u, mean %.2f (levels, the leaves' included)\n", s->depth_max, s->depth_mean);
    if (s->refs != s->prims)
        printf("triangles: %llu in leaves as %llu references (spatial splits); references per leaf:\n",
               (unsigned long long)s->prims, (unsigned long long)s->refs);
    else
        printf("triangles: %llu in leaves; per leaf:\n", (unsigned long long)s->prims);
    uint64_t most = 1;
    for (int b = 0; b < BVH_STATS_LEAF_BINS; b++)
        most = s->leaf_prims[b] > most ? s->leaf_prims[b] : most;
    for (int b = 0; b < BVH_STATS_LEAF_BINS; b++) {
        if (!s->leaf_prims[b])
            continue;
        char bar[41];
        const int n = (int)(40.0 * (double)s->leaf_prims[b] / (double)most + 0.5);
        memset(bar, '#', (size_t)n);
        bar[n] = '\0';
        printf("  %s%2d %9llu %5.1f%% %s\n", b == 16 ? ">" : " ", b == 16 ? 16 : b + 1,
               (unsigned long long)s->leaf_prims[b], 100.0 * (double)s->leaf_prims[b] / (double)(s->leaves ? s->leaves : 1),
               bar);
    }
    printf("SAH cost:  %.3f (traversal step 1, block of 4 triangles 1, relative to the root)\n", s->sah);
    if (r->bytes)
        printf("memory:    %.2f MiB, %.1f bytes/triangle\n", (double)r->bytes / 1048576.0,
               s->prims ? (double)r->bytes / (double)s->prims : 0.0);
    if (r->build_seconds >= 0.0)
        print_build_line("build:     ", r->build_seconds, r->mesh_triangles, r->build_threads);
}

static void print_json(const build_report *r)
{
    const bvh_stats *s = &r->st;
    printf("{\n");
    if (r->mesh)
        json_string("mesh", r->mesh, 0);
    else
        printf("  \"mesh\": null,\n");
    json_string("backend", r->backend, 0);
    json_string("layout", r->layout, 0);
    json_string("builder", r->builder, 0);
    json_string("quality", quality_name(r->quality), 0);
    printf("  \"mesh_triangles\": %llu,\n  \"triangles\": %llu,\n  \"references\": %llu,\n  \"nodes\": %llu,\n  \"leaves\": %llu,\n"
           "  \"leaf_blocks\": %llu,\n  \"width\": %u,\n  \"children_per_node\": %.4f,\n  \"depth_max\": %u,\n  \"depth_mean\": %.4f,\n",
           (unsigned long long)r->mesh_triangles, (unsigned long long)s->prims, (unsigned long long)s->refs,
           (unsigned long long)s->nodes,
           (unsigned long long)s->leaves, (unsigned long long)s->leaf_blocks, s->width,
           s->nodes ? (double)s->slots_used / (double)s->nodes : 0.0, s->depth_max, s->depth_mean);
    printf("  \"triangles_per_leaf\": {");
    for (int b = 0, first = 1; b < BVH_STATS_LEAF_BINS; b++)
        if (s->leaf_prims[b]) {
            printf("%s\"%s%d\": %llu", first ? "" : ", ", b == 16 ? ">" : "", b == 16 ? 16 : b + 1,
                   (unsigned long long)s->leaf_prims[b]);
            first = 0;
        }
    printf("},\n  \"sah_cost\": %.6f,\n", s->sah);
    if (r->bytes)
        printf("  \"bytes\": %llu,\n  \"bytes_per_triangle\": %.3f,\n", (unsigned long long)r->bytes,
               s->prims ? (double)r->bytes / (double)s->prims : 0.0);
    else
        printf("  \"bytes\": null,\n  \"bytes_per_triangle\": null,\n");
    if (r->build_seconds >= 0.0)
        printf("  \"build_seconds\": %.6f,\n  \"build_threads\": %u,\n  \"build_mtris_per_second\": %.4f\n}\n",
               r->build_seconds, r->build_threads,
               build_mtris(r->mesh_triangles, r->build_seconds));
    else
        printf("  \"build_seconds\": null,\n  \"build_mtris_per_second\": null\n}\n");
}

/* Random rays through both scenes: how many answers agree exactly (t, hit
 * or miss, triangle) and how many only in t (a tie between two triangles
 * the two trees settled differently). */
static void compare_scenes(rtk_scene a, rtk_scene b, const float lo[3], const float hi[3], long n, long *same,
                           long *tie)
{
    uint64_t state = 0x9e3779b97f4a7c15ull;
    *same = *tie = 0;
    for (long i = 0; i < n; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            state = state * 6364136223846793005ull + 1442695040888963407ull;
            const float r1 = (float)(state >> 40) / 16777216.0f;
            state = state * 6364136223846793005ull + 1442695040888963407ull;
            const float r2 = (float)(state >> 40) / 16777216.0f;
            const float e = hi[k] - lo[k];
            o[k] = lo[k] - 0.5f * e + 2.0f * e * r1;
            d[k] = lo[k] + e * r2 - o[k]; /* aimed into the box */
        }
        rtk_rayhit x;
        memset(&x, 0, sizeof x);
        x.ray = (rtk_ray){.org_x = o[0], .org_y = o[1], .org_z = o[2], .dir_x = d[0], .dir_y = d[1], .dir_z = d[2],
                          .tfar = INFINITY, .mask = 0xffffffffu};
        x.hit.geomID = x.hit.primID = RTK_INVALID_GEOMETRY_ID;
        rtk_rayhit y = x;
        rtk_intersect1(a, &x);
        rtk_intersect1(b, &y);
        if (!memcmp(&x, &y, sizeof x))
            (*same)++;
        else if (x.ray.tfar == y.ray.tfar && (x.hit.geomID == RTK_INVALID_GEOMETRY_ID) ==
                                                 (y.hit.geomID == RTK_INVALID_GEOMETRY_ID))
            (*tie)++;
    }
}

static int cmd_build(int argc, char **argv)
{
    const char *mesh_path = NULL, *isa = NULL, *extra = "", *dump = NULL, *load = NULL, *png = NULL;
    const char *builder = NULL, *layout = NULL;
    int json = 0, compact = 0, robust = 0;
    long threads = 0, verify = 100000;
    rtk_build_quality quality = RTK_BUILD_QUALITY_MEDIUM;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const int more = i + 1 < argc;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            build_usage(stdout);
            return 0;
        } else if (!strcmp(a, "--quality") && more) {
            if (!quality_arg("build", argv[++i], &quality))
                return 2;
        } else if (!strcmp(a, "--isa") && more)
            isa = argv[++i];
        else if (!strcmp(a, "--compact"))
            compact = 1;
        else if (!strcmp(a, "--robust"))
            robust = 1;
        else if (!strcmp(a, "--builder") && more)
            builder = argv[++i];
        else if (!strcmp(a, "--layout") && more)
            layout = argv[++i];
        else if (!strcmp(a, "--threads") && more) {
            if (!int_arg("build", a, argv[++i], 1, 1024, &threads))
                return 2;
        } else if (!strcmp(a, "--json"))
            json = 1;
        else if (!strcmp(a, "--dump") && more)
            dump = argv[++i];
        else if (!strcmp(a, "--load") && more)
            load = argv[++i];
        else if (!strcmp(a, "--png") && more)
            png = argv[++i];
        else if (!strcmp(a, "--verify") && more) {
            if (!int_arg("build", a, argv[++i], 0, 1L << 40, &verify))
                return 2;
        } else if (!strcmp(a, "--config") && more)
            extra = argv[++i];
        else if (a[0] != '-' && !mesh_path)
            mesh_path = a;
        else {
            fprintf(stderr, "rtktool build: unknown or incomplete argument '%s'\n", a);
            build_usage(stderr);
            return 2;
        }
    }
    if (!mesh_path && !load) {
        build_usage(stderr);
        return 2;
    }
    if (dump && load) {
        fprintf(stderr, "rtktool build: --dump and --load do not go together\n");
        return 2;
    }
    if (dump && !ends_with(dump, ".rtkb")) {
        fprintf(stderr, "rtktool build: the dump's name must end in .rtkb (got '%s')\n", dump);
        return 2;
    }

    char err[1024];
    rtkb_file file;
    memset(&file, 0, sizeof file);
    if (load && rtkb_load(load, &file, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        return 1;
    }
    build_report rep = {.quality = quality, .build_seconds = -1.0};
    rtk_mesh mesh;
    memset(&mesh, 0, sizeof mesh);
    rtk_device dev = NULL;
    rtk_scene scene = NULL, fresh = NULL;
    rtk_bvh tree = {.struct_size = sizeof tree};
    int owned_tree = 0, rc = 1;

    if (load && !mesh_path) { /* offline: the file alone */
        rep.backend = "none (the file alone)";
        rep.layout = file.info.layout;
        rep.builder = file.info.builder;
        rep.quality = file.info.quality;
        rep.mesh_triangles = file.info.mesh_triangles;
        rep.bytes = file.info.bytes;
        tree = file.tree;
    } else {
        if (rtk_mesh_load(mesh_path, &mesh, err, sizeof err)) {
            fprintf(stderr, "rtktool: %s\n", err);
            goto done;
        }
        if (load && !dump_fits_mesh(load, &file, mesh_path, &mesh))
            goto done;
        char config[512];
        if (!device_config(config, sizeof config, "build", threads, isa, builder, layout, load ? &file : NULL,
                           extra)) {
            rc = 2;
            goto done;
        }
        dev = open_device(config);
        if (!dev)
            goto done;
        const unsigned flags = load ? dump_scene_flags(&file)
                                    : (compact ? RTK_SCENE_FLAG_COMPACT : 0) | (robust ? RTK_SCENE_FLAG_ROBUST : 0);
        scene = mesh_scene(dev, &mesh, flags, quality, load ? &file.tree : NULL);
        if (!scene)
            goto done;
        rtk_scene_info info = {.struct_size = sizeof info};
        rtk_scene_get_info(scene, &info);
        /* A dump committed is the tree already read (an export gives it back
         * unchanged, as test_bvh checks); a build's tree is exported. */
        if (load) {
            tree = file.tree;
        } else if (rtk_scene_get_bvh(scene, &tree)) {
            fprintf(stderr, "rtktool: %s\n", rtk_device_get_error_message(dev));
            goto done;
        } else {
            owned_tree = 1;
        }
        rep.mesh = mesh_path;
        rep.backend = rtk_device_get_backend_name(dev);
        rep.layout = info.layout;
        rep.builder = load ? file.info.builder : info.builder;
        rep.quality = load ? file.info.quality : (unsigned)info.quality;
        rep.mesh_triangles = mesh.triangle_count;
        rep.bytes = info.bytes;
        rep.build_seconds = load ? -1.0 : info.build_seconds;
        rep.build_threads = info.build_threads;
        rep.sah_reported = info.sah_cost;
        if (load && verify > 0) { /* the dump against a fresh build */
            fresh = mesh_scene(dev, &mesh, flags, (rtk_build_quality)file.info.quality, NULL);
            if (!fresh)
                goto done;
            long same, tie;
            compare_scenes(scene, fresh, info.bounds_lower, info.bounds_upper, verify, &same, &tie);
            fprintf(json ? stderr : stdout,
                    "verify:    %ld random rays against a fresh build: %ld identical, %ld ties settled differently, "
                    "%ld different\n",
                    verify, same, tie, verify - same - tie);
            if (same + tie != verify) {
                fprintf(stderr, "rtktool: the loaded tree traces differently from a fresh build\n");
                goto done;
            }
        }
    }
    if (bvh_stats_compute(&tree, &rep.st)) {
        fprintf(stderr, "rtktool: out of memory for the statistics\n");
        goto done;
    }
    if (json)
        print_json(&rep);
    else
        print_report(&rep);
    if (load && !json)
        printf("dump:      %s: checked (offsets, counts, checksums, every reference and box); written from %s, "
               "built in %.3f s\n",
               load, file.info.layout, file.info.build_seconds);
    if (dump) {
        rtkb_info bi = {.quality = rep.quality,
                        .mesh_triangles = mesh.triangle_count,
                        .mesh_vertices = mesh.vertex_count,
                        .mesh_checksum = rtkm_mesh_checksum(&mesh),
                        .bytes = rep.bytes,
                        .build_seconds = rep.build_seconds,
                        .sah_cost = rep.sah_reported};
        snprintf(bi.layout, sizeof bi.layout, "%s", rep.layout);
        snprintf(bi.builder, sizeof bi.builder, "%s", rep.builder);
        if (rtkb_save(dump, &tree, &bi, err, sizeof err)) {
            fprintf(stderr, "rtktool: %s\n", err);
            goto done;
        }
        fprintf(json ? stderr : stdout, "dump:      %s\n", dump);
    }
    if (png) {
        if (bvh_picture(&tree, &rep.st, 8, 320, png, err, sizeof err)) {
            fprintf(stderr, "rtktool: %s\n", err);
            goto done;
        }
        fprintf(json ? stderr : stdout,
                "picture:   %s: panel n shows the boxes of the children of the nodes at depth n\n", png);
    }
    rc = 0;
done:
    if (owned_tree)
        rtk_bvh_free(&tree);
    rtk_scene_release(fresh);
    rtk_scene_release(scene);
    rtk_device_release(dev);
    rtk_mesh_free(&mesh);
    rtkb_free(&file);
    return rc;
}

static void usage(FILE *f)
{
    fprintf(f, "usage: rtktool COMMAND [options]\n"
               "  info                 CPU features, backends found and rejected, the active one\n"
               "  convert IN OUT.rtkm  import a mesh into rtk's mesh file (rtktool convert --help)\n"
               "  build MESH [opts]    build a BVH and show its statistics; dump and inspect trees\n"
               "                       (rtktool build --help)\n"
               "  trace MESH [opts]    render MESH to a PNG and measure (rtktool trace --help)\n"
               "  bench MESH... [opts] rtk beside Embree 3: trace, render, build and accuracy, with a\n"
               "                       table, a CSV and charts (rtktool bench --help)\n"
               "  help                 this text\n");
}

int main(int argc, char **argv)
{
    /* A write past a file size limit (ulimit -f) fails with EFBIG rather
     * than killing rtktool, so it can say so and remove its temporary
     * file (file_replace: the file it replaces is left as it was). */
    signal(SIGXFSZ, SIG_IGN);
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    if (!strcmp(argv[1], "info"))
        return cmd_info(argc - 2, argv + 2);
    if (!strcmp(argv[1], "convert"))
        return cmd_convert(argc - 2, argv + 2);
    if (!strcmp(argv[1], "build"))
        return cmd_build(argc - 2, argv + 2);
    if (!strcmp(argv[1], "trace"))
        return cmd_trace(argc - 2, argv + 2);
    if (!strcmp(argv[1], "bench")) {
#ifdef RTK_HAVE_EMBREE
        return cmd_bench(argc - 2, argv + 2);
#else
        fprintf(stderr, "rtktool bench: unavailable: this rtktool was built without Embree 3 (install "
                        "libembree-dev and build again)\n");
        return 1;
#endif
    }
    if (!strcmp(argv[1], "help") || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
        usage(stdout);
        return 0;
    }
    fprintf(stderr, "rtktool: unknown command '%s'\n", argv[1]);
    usage(stderr);
    return 2;
}
