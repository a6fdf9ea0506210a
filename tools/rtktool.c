/*
 * rtktool: how people meet rtk.  `info` shows the CPU and the backends;
 * `convert` turns a mesh into rtk's own .rtkm file; `trace` renders a mesh
 * and measures build and trace speed.
 */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <unistd.h>

#include "mesh_import.h"
#include "mesh_tools.h"
#include "png_write.h"
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

static int cmd_info(int argc, char **argv)
{
    const char *config = "";
    for (int i = 0; i < argc; i++) {
        if (!strcmp(argv[i], "--config") && i + 1 < argc)
            config = argv[++i];
        else {
            fprintf(stderr, "rtktool info: unknown argument '%s'\n", argv[i]);
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

/* ---- trace ---- */

typedef struct camera {
    float eye[3], du[3], dv[3], corner[3]; /* ray dir = corner + x * du + y * dv */
} camera;

static void normalize(float v[3])
{
    float l = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if (l > 0.0f)
        for (int k = 0; k < 3; k++)
            v[k] /= l;
}

static void cross(const float a[3], const float b[3], float c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

/* A camera that frames the bounding box: looking at its centre from the
 * front-right and a little above, at a distance where the bounding sphere
 * fills the 40-degree view. */
static camera frame_box(const float lo[3], const float hi[3], int w, int h)
{
    camera c;
    float center[3], radius = 0.0f;
    for (int k = 0; k < 3; k++) {
        center[k] = 0.5f * (lo[k] + hi[k]);
        float e = 0.5f * (hi[k] - lo[k]);
        radius += e * e;
    }
    radius = sqrtf(radius);
    if (!(radius > 0.0f))
        radius = 1.0f;
    const float fov = 40.0f * 3.14159265f / 180.0f;
    const float dist = 1.1f * radius / tanf(0.5f * fov);
    float view[3] = {0.35f, 0.3f, 1.0f};
    normalize(view);
    for (int k = 0; k < 3; k++)
        c.eye[k] = center[k] + view[k] * dist;
    float fwd[3] = {-view[0], -view[1], -view[2]}, up[3] = {0, 1, 0}, right[3], vup[3];
    cross(fwd, up, right);
    normalize(right);
    cross(right, fwd, vup);
    const float half_h = tanf(0.5f * fov), half_w = half_h * (float)w / (float)h;
    for (int k = 0; k < 3; k++) {
        c.du[k] = right[k] * (2.0f * half_w / (float)w);
        c.dv[k] = -vup[k] * (2.0f * half_h / (float)h);
        c.corner[k] = fwd[k] - right[k] * half_w + vup[k] * half_h;
    }
    return c;
}

typedef struct trace_job {
    rtk_scene scene;
    const camera *cam;
    int w, h;
    unsigned char *rgb;
    int row_begin, row_end;
    uint64_t rays, hits;
} trace_job;

static void *trace_rows(void *arg)
{
    trace_job *j = arg;
    for (int y = j->row_begin; y < j->row_end; y++) {
        for (int x = 0; x < j->w; x++) {
            rtk_rayhit rh;
            memset(&rh, 0, sizeof rh);
            float d[3];
            for (int k = 0; k < 3; k++)
                d[k] = j->cam->corner[k] + ((float)x + 0.5f) * j->cam->du[k] + ((float)y + 0.5f) * j->cam->dv[k];
            rh.ray.org_x = j->cam->eye[0];
            rh.ray.org_y = j->cam->eye[1];
            rh.ray.org_z = j->cam->eye[2];
            rh.ray.dir_x = d[0];
            rh.ray.dir_y = d[1];
            rh.ray.dir_z = d[2];
            rh.ray.tnear = 0.0f;
            rh.ray.tfar = INFINITY;
            rh.ray.mask = 0xffffffffu;
            rh.hit.geomID = RTK_INVALID_GEOMETRY_ID;
            rtk_intersect1(j->scene, &rh);
            j->rays++;
            unsigned char *px = &j->rgb[3 * ((size_t)y * (size_t)j->w + (size_t)x)];
            if (rh.hit.geomID == RTK_INVALID_GEOMETRY_ID) {
                px[0] = 24;
                px[1] = 26;
                px[2] = 32;
                continue;
            }
            j->hits++;
            /* Eye light: brightness by the cosine between normal and view. */
            float n[3] = {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
            normalize(n);
            normalize(d);
            float c = fabsf(n[0] * d[0] + n[1] * d[1] + n[2] * d[2]);
            float v = 0.1f + 0.9f * c;
            px[0] = (unsigned char)(255.0f * v * 0.95f);
            px[1] = (unsigned char)(255.0f * v * 0.85f);
            px[2] = (unsigned char)(255.0f * v * 0.70f);
        }
    }
    return NULL;
}

static void trace_usage(FILE *f)
{
    fprintf(f,
            "usage: rtktool trace MESH [options]\n"
            "  Renders MESH (.rtkm .obj .ply .off .stl .om) with eye-light shading from a camera\n"
            "  that frames it, and prints the backend, build time and rays per second.\n"
            "  -o FILE        output PNG (default: trace.png)\n"
            "  --size WxH     image size (default: 1024x768)\n"
            "  --isa NAME     backend (scalar, sse41, avx, avx2; default: the best)\n"
            "  --threads N    render threads (default: all cores)\n"
            "  --frames N     render N times and report the best rate (default: 3)\n"
            "  --config STR   extra device config (e.g. verbose=1)\n");
}

static int cmd_trace(int argc, char **argv)
{
    const char *mesh_path = NULL, *out = "trace.png", *isa = NULL, *extra = "";
    int w = 1024, h = 768, frames = 3;
    long threads = sysconf(_SC_NPROCESSORS_ONLN);
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const int more = i + 1 < argc;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            trace_usage(stdout);
            return 0;
        } else if (!strcmp(a, "-o") && more)
            out = argv[++i];
        else if (!strcmp(a, "--size") && more) {
            if (sscanf(argv[++i], "%dx%d", &w, &h) != 2 || w < 1 || h < 1 || w > 16384 || h > 16384) {
                fprintf(stderr, "rtktool trace: --size wants WxH, each 1..16384\n");
                return 2;
            }
        } else if (!strcmp(a, "--isa") && more)
            isa = argv[++i];
        else if (!strcmp(a, "--threads") && more)
            threads = strtol(argv[++i], NULL, 10);
        else if (!strcmp(a, "--frames") && more)
            frames = atoi(argv[++i]);
        else if (!strcmp(a, "--config") && more)
            extra = argv[++i];
        else if (a[0] != '-' && !mesh_path)
            mesh_path = a;
        else {
            fprintf(stderr, "rtktool trace: unknown or incomplete argument '%s'\n", a);
            trace_usage(stderr);
            return 2;
        }
    }
    if (!mesh_path) {
        trace_usage(stderr);
        return 2;
    }
    if (threads < 1 || threads > 256 || frames < 1) {
        fprintf(stderr, "rtktool trace: --threads wants 1..256 and --frames at least 1\n");
        return 2;
    }

    char config[512];
    snprintf(config, sizeof config, "%s%s%s%s", isa ? "isa=" : "", isa ? isa : "", isa && extra[0] ? "," : "", extra);
    rtk_device dev = open_device(config);
    if (!dev)
        return 1;

    char err[1024];
    rtk_mesh mesh;
    double t0 = now();
    if (rtk_mesh_load(mesh_path, &mesh, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        rtk_device_release(dev);
        return 1;
    }
    double t_load = now() - t0;

    rtk_scene scene = NULL;
    rtk_geometry geom = NULL;
    int rc = 1;
    if (rtk_scene_new(dev, &scene) || rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &geom) ||
        rtk_geometry_set_shared_buffer(geom, RTK_BUFFER_TYPE_VERTEX, mesh.vertices, 0, 12, mesh.vertex_count) ||
        rtk_geometry_set_shared_buffer(geom, RTK_BUFFER_TYPE_INDEX, mesh.indices, 0, 12, mesh.triangle_count) ||
        rtk_geometry_commit(geom) || rtk_scene_attach_geometry(scene, geom, NULL) || rtk_scene_commit(scene)) {
        fprintf(stderr, "rtktool: %s\n", rtk_device_get_error_message(dev));
        goto done;
    }
    rtk_scene_info info = {.struct_size = sizeof info};
    rtk_scene_get_info(scene, &info);

    unsigned char *rgb = calloc((size_t)w * (size_t)h, 3);
    if (!rgb) {
        fprintf(stderr, "rtktool: out of memory for a %dx%d image\n", w, h);
        goto done;
    }
    camera cam = frame_box(info.bounds_lower, info.bounds_upper, w, h);
    trace_job jobs[256];
    pthread_t tid[256];
    double best = 0.0;
    uint64_t hits = 0;
    for (int f = 0; f < frames; f++) {
        double s = now();
        for (long t = 0; t < threads; t++) {
            jobs[t] = (trace_job){.scene = scene, .cam = &cam, .w = w, .h = h, .rgb = rgb,
                                  .row_begin = (int)(h * t / threads), .row_end = (int)(h * (t + 1) / threads)};
            pthread_create(&tid[t], NULL, trace_rows, &jobs[t]);
        }
        hits = 0;
        for (long t = 0; t < threads; t++) {
            pthread_join(tid[t], NULL);
            hits += jobs[t].hits;
        }
        double rate = (double)w * h / (now() - s);
        if (rate > best)
            best = rate;
    }
    if (rtk_png_write_rgb(out, rgb, w, h, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        free(rgb);
        goto done;
    }
    free(rgb);

    printf("mesh:       %s: %zu vertices, %zu triangles (loaded in %.2f s)\n", mesh_path, mesh.vertex_count,
           mesh.triangle_count, t_load);
    printf("backend:    %s\n", rtk_device_get_backend_name(dev));
    printf("bvh:        %s, %s builder, %llu nodes, %llu leaves, depth %u, SAH %.2f, %.1f bytes/triangle\n",
           info.layout, info.builder, (unsigned long long)info.nodes, (unsigned long long)info.leaves, info.depth,
           info.sah_cost, info.bytes_per_triangle);
    if (info.triangles_skipped || info.triangles_degenerate)
        printf("            left out: %llu triangles with non-finite vertices, %llu of zero area\n",
               (unsigned long long)info.triangles_skipped, (unsigned long long)info.triangles_degenerate);
    printf("build:      %.3f s, %.2f Mtris/s (1 thread)\n", info.build_seconds,
           info.build_seconds > 0 ? (double)mesh.triangle_count / info.build_seconds * 1e-6 : 0.0);
    printf("trace:      %dx%d primary rays, %.1f%% hit, %ld threads, best of %d frames: %.2f Mrays/s\n", w, h,
           100.0 * (double)hits / ((double)w * h), threads, frames, best * 1e-6);
    printf("image:      %s\n", out);
    rc = 0;
done:
    rtk_geometry_release(geom);
    rtk_scene_release(scene);
    rtk_device_release(dev);
    rtk_mesh_free(&mesh);
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
               "                     infinite vertex (without it they are counted and kept)\n");
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

static void usage(FILE *f)
{
    fprintf(f, "usage: rtktool COMMAND [options]\n"
               "  info                 CPU features, backends found and rejected, the active one\n"
               "  convert IN OUT.rtkm  import a mesh into rtk's mesh file (rtktool convert --help)\n"
               "  trace MESH [opts]    render MESH to a PNG and measure (rtktool trace --help)\n"
               "  help                 this text\n");
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    if (!strcmp(argv[1], "info"))
        return cmd_info(argc - 2, argv + 2);
    if (!strcmp(argv[1], "convert"))
        return cmd_convert(argc - 2, argv + 2);
    if (!strcmp(argv[1], "trace"))
        return cmd_trace(argc - 2, argv + 2);
    if (!strcmp(argv[1], "help") || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
        usage(stdout);
        return 0;
    }
    fprintf(stderr, "rtktool: unknown command '%s'\n", argv[1]);
    usage(stderr);
    return 2;
}
