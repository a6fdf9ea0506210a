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
#include "bvh_stats.h"
#include "png_write.h"
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
    return strstr(file->info.layout, "triangle4i") ? RTK_SCENE_FLAG_COMPACT : 0;
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
 * front-right and a little above, with the 40-degree view (vertical) just
 * wide enough for all eight corners of the box, 5% margin: so the mesh,
 * not the background, fills the picture. */
static camera frame_box(const float lo[3], const float hi[3], int w, int h)
{
    camera c;
    float center[3], extent = 0.0f;
    for (int k = 0; k < 3; k++) {
        center[k] = 0.5f * (lo[k] + hi[k]);
        extent = fmaxf(extent, hi[k] - lo[k]);
    }
    if (!(extent > 0.0f))
        extent = 1.0f;
    const float fov = 40.0f * 3.14159265f / 180.0f;
    const float half_h = tanf(0.5f * fov), half_w = half_h * (float)w / (float)h;
    float view[3] = {0.35f, 0.3f, 1.0f};
    normalize(view);
    float fwd[3] = {-view[0], -view[1], -view[2]}, up[3] = {0, 1, 0}, right[3], vup[3];
    cross(fwd, up, right);
    normalize(right);
    cross(right, fwd, vup);
    /* The distance from the centre at which each corner fits: at depth
     * dist + z a corner at (x, y) across the view must have |x| <= (dist +
     * z) * half_w and |y| <= (dist + z) * half_h. */
    float dist = 0.0f;
    for (int i = 0; i < 8; i++) {
        const float p[3] = {(i & 1 ? hi[0] : lo[0]) - center[0], (i & 2 ? hi[1] : lo[1]) - center[1],
                            (i & 4 ? hi[2] : lo[2]) - center[2]};
        const float x = p[0] * right[0] + p[1] * right[1] + p[2] * right[2];
        const float y = p[0] * vup[0] + p[1] * vup[1] + p[2] * vup[2];
        const float z = p[0] * fwd[0] + p[1] * fwd[1] + p[2] * fwd[2];
        dist = fmaxf(dist, fabsf(x) / (0.95f * half_w) - z);
        dist = fmaxf(dist, fabsf(y) / (0.95f * half_h) - z);
    }
    if (!(dist > 0.0f))
        dist = extent;
    for (int k = 0; k < 3; k++) {
        c.eye[k] = center[k] + view[k] * dist;
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
            "  --load F.rtkb  trace with the BVH dumped by rtktool build --dump (no build)\n"
            "  --config STR   extra device config (e.g. verbose=1)\n");
}

static int cmd_trace(int argc, char **argv)
{
    const char *mesh_path = NULL, *out = "trace.png", *isa = NULL, *extra = "", *load = NULL;
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
        else if (!strcmp(a, "--load") && more)
            load = argv[++i];
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

    int rc = 1;
    rtk_scene scene = NULL;
    rtkb_file dump;
    memset(&dump, 0, sizeof dump);
    if (load && rtkb_load(load, &dump, err, sizeof err)) {
        fprintf(stderr, "rtktool: %s\n", err);
        goto done;
    }
    if (load && !dump_fits_mesh(load, &dump, mesh_path, &mesh))
        goto done;
    scene = mesh_scene(dev, &mesh, load ? dump_scene_flags(&dump) : 0, RTK_BUILD_QUALITY_MEDIUM,
                       load ? &dump.tree : NULL);
    if (!scene)
        goto done;
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
    if (load)
        printf("build:      none: the tree of %s, checked and committed in %.3f s\n", load, info.build_seconds);
    else
        printf("build:      %.3f s, %.2f Mtris/s (1 thread)\n", info.build_seconds,
               info.build_seconds > 0 ? (double)mesh.triangle_count / info.build_seconds * 1e-6 : 0.0);
    printf("trace:      %dx%d primary rays, %.1f%% hit, %ld threads, best of %d frames: %.2f Mrays/s\n", w, h,
           100.0 * (double)hits / ((double)w * h), threads, frames, best * 1e-6);
    printf("image:      %s\n", out);
    rc = 0;
done:
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
            "  commits MESH with the dumped tree and checks that it traces like a build.\n"
            "  --quality low|medium|high  build quality (default: medium)\n"
            "  --isa NAME                 backend (scalar, sse41, avx, avx2; default: the best)\n"
            "  --compact                  the compact layout (index leaves, half the memory)\n"
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
            "  rtktool build --load bunny.rtkb bunny.ply --isa sse41\n");
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
        printf("build:     %.3f s, %.2f Mtris/s (1 thread)\n", r->build_seconds,
               r->build_seconds > 0 ? (double)r->mesh_triangles / r->build_seconds * 1e-6 : 0.0);
}

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
    printf("  \"mesh_triangles\": %llu,\n  \"triangles\": %llu,\n  \"nodes\": %llu,\n  \"leaves\": %llu,\n"
           "  \"leaf_blocks\": %llu,\n  \"width\": %u,\n  \"children_per_node\": %.4f,\n  \"depth_max\": %u,\n  \"depth_mean\": %.4f,\n",
           (unsigned long long)r->mesh_triangles, (unsigned long long)s->prims, (unsigned long long)s->nodes,
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
        printf("  \"build_seconds\": %.6f,\n  \"build_mtris_per_second\": %.4f\n}\n", r->build_seconds,
               r->build_seconds > 0 ? (double)r->mesh_triangles / r->build_seconds * 1e-6 : 0.0);
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
    int json = 0, compact = 0;
    long threads = 0, verify = 100000;
    rtk_build_quality quality = RTK_BUILD_QUALITY_MEDIUM;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const int more = i + 1 < argc;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            build_usage(stdout);
            return 0;
        } else if (!strcmp(a, "--quality") && more) {
            const char *q = argv[++i];
            if (!strcmp(q, "low"))
                quality = RTK_BUILD_QUALITY_LOW;
            else if (!strcmp(q, "medium"))
                quality = RTK_BUILD_QUALITY_MEDIUM;
            else if (!strcmp(q, "high"))
                quality = RTK_BUILD_QUALITY_HIGH;
            else {
                fprintf(stderr, "rtktool build: --quality wants low, medium or high (got '%s')\n", q);
                return 2;
            }
        } else if (!strcmp(a, "--isa") && more)
            isa = argv[++i];
        else if (!strcmp(a, "--compact"))
            compact = 1;
        else if (!strcmp(a, "--threads") && more) {
            char *end;
            threads = strtol(argv[++i], &end, 10);
            if (*end || threads < 1 || threads > 1024) {
                fprintf(stderr, "rtktool build: --threads wants 1..1024 (got '%s')\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--json"))
            json = 1;
        else if (!strcmp(a, "--dump") && more)
            dump = argv[++i];
        else if (!strcmp(a, "--load") && more)
            load = argv[++i];
        else if (!strcmp(a, "--png") && more)
            png = argv[++i];
        else if (!strcmp(a, "--verify") && more) {
            char *end;
            verify = strtol(argv[++i], &end, 10);
            if (*end || verify < 0) {
                fprintf(stderr, "rtktool build: --verify wants a ray count (got '%s')\n", argv[i]);
                return 2;
            }
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
        char config[512], threads_kv[32] = "";
        if (threads)
            snprintf(threads_kv, sizeof threads_kv, "threads=%ld,", threads);
        snprintf(config, sizeof config, "%s%s%s%s", threads_kv, isa ? "isa=" : "", isa ? isa : "", extra);
        dev = open_device(config);
        if (!dev)
            goto done;
        const unsigned flags = load ? dump_scene_flags(&file) : compact ? RTK_SCENE_FLAG_COMPACT : 0;
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
    if (!strcmp(argv[1], "build"))
        return cmd_build(argc - 2, argv + 2);
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
