/* What the sections of rtktool bench share: the libraries under test and
 * their scenes, the ray sets, tracing them, the output, the settings and
 * the context a section runs in.  Each section is a file of its own
 * (trace.c, render.c, build.c, refit.c, twolevel.c, forest.c, motion.c, accuracy.c,
 * features.c, closed.c, points.c); common.c defines what is declared here, edges.c
 * the rays aimed at shared edges, charts.c the charts' files, bench.c the
 * command line. */
#ifndef RTK_TOOLS_BENCH_INTERNAL_H
#define RTK_TOOLS_BENCH_INTERNAL_H

#include <embree3/rtcore.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "mesh_tools.h"
#include "render.h"
#include "rtk/rtk.h"

double now(void);

typedef struct embree_target {
    RTCScene scene;
    enum RTCIntersectContextFlags flags; /* coherent for camera-ray packets */
} embree_target;

/* MODE_REFIT: a geometry that deforms (quality REFIT): rtk's scene at the
 * given quality, Embree's at low quality and flagged dynamic, the two-level
 * mode in which alone Embree refits. */
enum { MODE_DEFAULT, MODE_COMPACT, MODE_ROBUST, MODE_REFIT, MODE_MASK, MODE_FILTER, MODE_QUAD, MODE_MASKS2, MODE_REBUILD };

extern const char *const mode_names[];

/* MODE_QUAD: the mesh's triangles as quads, each paired with a neighbour
 * across an edge where one is free (the shared edge the diagonal), the
 * rest as quads with v3 == v2 (Embree's way of giving a triangle as a
 * quad): the same triangles, as quad geometry. */
typedef struct quad_list {
    uint32_t *q; /* 4 per quad */
    size_t n;
    size_t paired; /* quads made of two triangles */
} quad_list;

extern quad_list bench_quads; /* of the mesh section_features measures */
/* The accuracy and closed sections' double hits: with bench_collect set,
 * scene_build gives the geometry filters that note each candidate's
 * triangle in bench_seen (those up to t = bench_t_limit) and reject it
 * (common.c). */
typedef struct seen_list {
    uint32_t prim[64];
    unsigned n;
} seen_list;
extern int bench_collect;
extern seen_list bench_seen;
extern float bench_t_limit;

typedef struct lib {
    char name[40];   /* "embree isa=avx2", "embree default", "rtk avx2" */
    char config[320]; /* what lib_open was given besides threads: "isa=avx2", "" */
    int embree;
    RTCDevice edev;
    rtk_device rdev;
    double device_seconds; /* creating the device */
} lib;

typedef struct scene {
    lib *lib;
    RTCScene escene;
    rtk_scene rscene;
    embree_target target[2]; /* incoherent, coherent */
    double seconds;          /* start time: first scene call to committed scene */
    double bytes_per_tri;
    double sah; /* rtk: rtk_scene_info.sah_cost; Embree: -1 (its API reports none) */
    char layout[48];
    char builder[32]; /* rtk: rtk_scene_info.builder; Embree: its builder for the quality */
} scene;

extern long long embree_bytes; /* Embree's memory monitor: allocations minus frees */

enum { SET_PRIMARY, SET_DIFFUSE, SET_SHADOW, SET_INCOHERENT, SET_SUN, NSETS };

extern const char *const set_names[NSETS];
/* the APIs a set is traced through: single rays, packets, streams */
enum { NAPIS = 5 };
extern const int apis[NAPIS];

typedef struct rayset {
    rtk_ray *rays;
    size_t n; /* a multiple of 16 */
    uint32_t (*pair)[2]; /* edge rays: the two triangles of the ray's edge; else NULL */
} rayset;

typedef struct out {
    FILE *csv;
    const char *mesh;
} out;

typedef struct bench_opts {
    const char *outdir;
    int w, h, repeat, builds, edge_rays;
    int threads[4], nthreads;
    char isa[4][16];
    int nisa;
    int api_on[NAPIS];
    int set_on[NSETS]; /* --rays: the trace section's ray sets */
    int do_trace, do_render, do_build, do_refit, do_twolevel, do_motion, do_accuracy, do_features, do_closed, do_points,
        do_forest;
    size_t forest[4]; /* --forest: the forest section's instance counts */
    int nforest;
    int render_w, render_h, render_spp;
    int trace_mode; /* MODE_DEFAULT, or MODE_ROBUST with --robust (trace and render) */
    int quick;      /* --quick: the closed section's meshes coarser and fewer grazing rays */
    const char *alt; /* --alt DIR: one more rtk library, the backends of DIR (backend_path=) */
} bench_opts;

/* Whether --api names api (an entry of apis[]: 1, 4, 8, 16 or RENDER_API_STREAM). */
int api_on(const bench_opts *o, int api);

enum { MAXLIBS = 8 };

/* charts.c: a chart's data (.dat) and gnuplot script (.gp) files.
 *   chart_open: the file NAME.dat (script 0) or NAME.gp (script 1) in the
 *     output directory, open for writing into a temporary file beside it;
 *     NULL (with a warning: the chart is left out) if it cannot be made.
 *     The caller only writes; charts_finish closes.
 *   charts_finish: at the end of the run, when commit, puts every file in
 *     place and draws each chart whose two files are, with gnuplot where
 *     it is installed (keeping the old PNG where it fails); else removes them,
 *     leaving the last run's charts as they were; non-zero if a file could
 *     not be put in place.  Frees cs. */
typedef struct charts charts;
charts *charts_new(const char *outdir);
FILE *chart_open(charts *cs, const char *name, int script);
int charts_finish(charts *cs, int commit);

typedef struct ctx {
    const bench_opts *o;
    const rtk_mesh *m;
    const float *padded;
    lib libs[MAXLIBS];
    int nlibs;
    out csv;
    char stem[128];
    rayset sets[NSETS]; /* the mesh's ray sets, shared by the sections */
    charts *charts;     /* the run's charts, put in place at its end */
} ctx;

/* common.c */
double now(void);
int lib_open(lib *l, const char *name, int embree, const char *config, int threads, char *err,
             size_t err_size);
void lib_close(lib *l);
int embree_commit(scene *sc, RTCScene s, double t0, const char *what, char *err, size_t err_size);
int rtk_commit(scene *sc, rtk_scene s, int bad, double t0, char *err, size_t err_size);
int embree_mesh_commit(scene *sc, RTCScene s, RTCGeometry g, const rtk_mesh *m, int quads, double t0,
                       long long bytes0, const char *what, char *err, size_t err_size);
int rtk_mesh_commit(scene *sc, rtk_scene s, rtk_geometry g, const rtk_mesh *m, int quads, int bad, double t0,
                    char *err, size_t err_size);
int scene_build(scene *sc, lib *l, const rtk_mesh *m, const float *padded, int mode, int quality, char *err,
                size_t err_size);
void scene_release(scene *sc);
render_tracer scene_tracer(scene *sc, int coherent);
float rnd(void);
/* rnd's generator over the caller's own state (a sequence that does not
 * depend on what other sections drew) */
float rnd_from(uint64_t *state);
void make_primary(const rtk_mesh *m, int w, int h, rayset *set);
void tri_normal(const rtk_mesh *m, uint32_t t, double n[3]);
double trace_pass(const render_tracer *t, const rayset *set, int api, int occluded, int threads,
                  unsigned char *hits);
double trace_set(const render_tracer *t, const rayset *set, int api, int occluded, int threads, int repeat,
                 unsigned char *hits);
void csv_row(const out *o, const char *section, const char *library, const char *variant, const char *set,
             const char *api, int threads, double value, const char *unit, double ratio);
const char *base_name(const char *path);
void mesh_stem(const char *path, char *stem, size_t size);
int make_sets(ctx *c, char *err, size_t err_size);
void free_sets(ctx *c);
double ratio(double v, double ref);
void print_row_label(const char *label);
void print_cell(double v, double ref, int is_ref);
void print_header(const ctx *c);
void twist(const rtk_mesh *m, float t, float *dst);
/* An instance of child's scene placed by xfm (row-major 3x4), attached to
 * Embree's scene es or rtk's rs, whichever library l is; non-zero when one
 * of rtk's calls failed (its device says why). */
int attach_instance(const lib *l, RTCScene es, rtk_scene rs, const scene *child, const float xfm[12]);
/* The path tracer of the two-level and forest sections: diffuse, the
 * bench's --render size and samples, single rays, on `threads` threads,
 * the framing camera of lo/hi; and one pass of it through t: its rate in
 * Mrays/s (-1 with a message when it cannot render), with the share of
 * camera rays that hit in *hit_share (unless NULL). */
void diffuse_settings(render_settings *rs, const bench_opts *o, const float lo[3], const float hi[3], int threads);
double diffuse_pass(const render_tracer *t, const render_settings *rs, float *rgb, double *hit_share, char *err,
                    size_t err_size);
void vertices_commit(scene *sc);
int cmp_double(const void *x, const void *y);

/* edges.c */
int quads_make(const rtk_mesh *m, quad_list *out);
size_t make_edge_rays(const rtk_mesh *m, size_t want, rayset *set);
size_t count_leaks(const render_tracer *t, const rayset *set);
size_t count_double_hits(const render_tracer *t, const rayset *set);

/* trace.c */
int section_trace(ctx *c, char *err, size_t err_size);

/* render.c */
int section_render(ctx *c, char *err, size_t err_size);

/* build.c */
double moving_frames(scene *sc, lib *bl, const ctx *c, float *v, int mode, int q, int frames, char *err,
                     size_t err_size);
int section_build(ctx *c, char *err, size_t err_size);

/* refit.c */
int section_refit(ctx *c, char *err, size_t err_size);

/* twolevel.c */
int section_twolevel(ctx *c, char *err, size_t err_size);

/* forest.c: many instances of a few meshes */
int section_forest(ctx *c, char *err, size_t err_size);

/* motion.c */
int section_motion(ctx *c, char *err, size_t err_size);

/* accuracy.c */
int section_accuracy(ctx *c, char *err, size_t err_size);

/* closed.c */
int section_closed(ctx *c, char *err, size_t err_size);

/* features.c */
int section_features(ctx *c, char *err, size_t err_size);
/* points.c: closest points against Embree's rtcPointQuery */
int section_points(ctx *c, char *err, size_t err_size);

#endif
