/* Committing a scene: checking its geometry, picking a builder and layout,
 * building or refitting its trees (one level, two levels, motion blur),
 * and the tree as data (rtk_scene_commit_bvh, rtk_scene_get_bvh). */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "scene_internal.h"

/* r's tree when it is a tree of triangles (no top level) that nothing but
 * its `own_refs` references of the scene being committed hold (no other
 * scene instances it): a build may take its memory for the scene's next
 * tree (rtk_build_input.recycle); else NULL. */
static rtk_accel *recyclable(const accel_ref *r, int own_refs)
{
    if (!r || !r->accel || r->children || r->user_prims || r->depth || !own_refs ||
        atomic_load(&r->refs) != own_refs)
        return NULL;
    return r->accel;
}

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Index validation: every vertex index of every triangle (quad) in range. */
static rtk_error check_indices(rtk_scene s, uint32_t id, const rtk_geometry g, const char *fn)
{
    const size_t nv = g->vertex.count;
    const int corners = g->type == RTK_GEOMETRY_TYPE_QUAD ? 4 : 3;
    for (size_t t = 0; t < g->index.count; t++) {
        const uint32_t *idx = (const uint32_t *)(g->index.data + t * g->index.stride);
        uint32_t worst = 0;
        for (int c = 0; c < corners; c++)
            worst = idx[c] > worst ? idx[c] : worst;
        if (worst >= nv)
            return rtk_fail(s->device, RTK_ERROR_INVALID_GEOMETRY,
                            "%s: geometry %u, %s %zu: vertex index %u out of range (%zu vertices)", fn, id,
                            corners == 4 ? "quad" : "triangle", t, worst, nv);
    }
    return RTK_OK;
}

/* A quad geometry's quads as the builders' triangles (rtk_backend.h,
 * RTK_GEOMETRY_ATTR_QUAD): 2q = (v0, v1, v3), 2q + 1 = (v2, v3, v1), into
 * tris (6 per quad). */
static void quads_to_triangles(const rtk_geometry g, uint32_t *tris)
{
    for (size_t q = 0; q < g->index.count; q++, tris += 6) {
        const uint32_t *v = (const uint32_t *)(g->index.data + q * g->index.stride);
        tris[0] = v[0], tris[1] = v[1], tris[2] = v[3];
        tris[3] = v[2], tris[4] = v[3], tris[5] = v[1];
    }
}

static const char *flag_names(unsigned flags, char *buf, size_t size)
{
    snprintf(buf, size, "%s%s%s", flags & RTK_SCENE_FLAG_COMPACT ? " compact" : "",
             flags & RTK_SCENE_FLAG_ROBUST ? " robust" : "", flags & RTK_SCENE_FLAG_DYNAMIC ? " dynamic" : "");
    return buf;
}

static const rtk_kernel_entry *find_kernel(const rtk_backend_desc *d, uint32_t layout, uint32_t query)
{
    for (const rtk_kernel_entry *k = d->kernels; k->layout; k++)
        if (k->layout == layout && k->query == query && k->width == 1)
            return k;
    return NULL; /* not reached: the loader checked every layout has both */
}

static const uint32_t packet_widths[3] = {4, 8, 16};

/* The widest packet kernel of at most `n` rays whose width divides n. */
static struct packet_kernel find_packet_kernel(const rtk_backend_desc *d, uint32_t layout, uint32_t query, uint32_t n)
{
    struct packet_kernel best = {.width = 1};
    for (const rtk_kernel_entry *k = d->kernels; k->layout; k++)
        if (k->layout == layout && k->query == query && k->width > best.width && k->width <= n && n % k->width == 0 &&
            (k->width == 4 || k->width == 8 || k->width == 16))
            best = (struct packet_kernel){.width = k->width, .fn = k->fn.intersectN};
    return best;
}

/* A backend's non-zero return as the error it names (else unknown). */
static rtk_error as_error(int rc)
{
    return rc > 0 && rc <= RTK_ERROR_MEMORY_REFUSED ? (rtk_error)rc : RTK_ERROR_UNKNOWN;
}

/* ---- progress (rtk_scene_set_progress_monitor) ----
 * A commit reports its share done by triangles: each build in it covers
 * the slice [base, base + span) of the whole, its builder's own share
 * (rtk_build_input.progress) mapped into that slice.  Calls come from the
 * builders' threads, several at once; once the application's callback
 * returns 0 the commit is cancelled: the builder stops, and the commit
 * fails with RTK_ERROR_CANCELLED, the scene's previous tree kept (a scene
 * with a progress callback builds in fresh memory, never its old tree's,
 * for that). */
typedef struct commit_progress {
    rtk_scene s;
    atomic_int cancelled;
    double base, span;    /* the build in progress's slice */
    uint64_t done, total; /* triangles of the commit's builds */
} commit_progress;

/* The builders' callback (rtk_build_input.progress). */
static int commit_progress_report(void *user, double done)
{
    commit_progress *cp = user;
    if (atomic_load(&cp->cancelled))
        return 0;
    if (!cp->s->progress(cp->s->progress_user, cp->base + cp->span * done)) {
        atomic_store(&cp->cancelled, 1);
        return 0;
    }
    return 1;
}

/* Reports the start of the next build (prims triangles) of the commit, and
 * points it at its slice; an error when the commit is cancelled (then or
 * before).  RTK_OK without a callback. */
static rtk_error progress_next(rtk_scene s, uint64_t prims, const char *fn)
{
    commit_progress *cp = s->commit_progress;
    if (!cp)
        return RTK_OK;
    const double total = cp->total ? (double)cp->total : 1.0;
    cp->base = (double)cp->done / total;
    cp->span = (double)prims / total;
    cp->done += prims;
    if (!commit_progress_report(cp, 0.0))
        return rtk_fail(s->device, RTK_ERROR_CANCELLED, "%s: cancelled by the progress callback", fn);
    return RTK_OK;
}

/* What the build about to start (in) is handed beside its geometry: the
 * device's memory accounting (with a memory monitor) and the commit's
 * progress (with a progress callback); with either it builds in fresh
 * memory (no recycle), so that a refusal or a cancel keeps the old tree. */
static void commit_input(rtk_scene s, rtk_build_input *in)
{
    in->memory = rtk_device_memory(s->device);
    if (in->memory)
        in->recycle = NULL;
    if (!s->commit_progress)
        return;
    in->progress = commit_progress_report;
    in->progress_user = s->commit_progress;
    in->recycle = NULL;
}

static const char *refused_note(rtk_error e)
{
    return e == RTK_ERROR_MEMORY_REFUSED ? " (memory refused by the device's memory monitor)" : "";
}

/* A backend's failure (rc) as the error to report: out of memory after the
 * device's memory monitor refused some (since `refusals`) is the refusal. */
static rtk_error build_error(rtk_scene s, int rc, unsigned refusals)
{
    if (rc == RTK_ERROR_OUT_OF_MEMORY && atomic_load(&s->device->refusals) != refusals)
        return RTK_ERROR_MEMORY_REFUSED;
    return as_error(rc);
}

static uint64_t prims_of(const rtk_build_geometry *geoms, size_t n)
{
    uint64_t p = 0;
    for (size_t k = 0; k < n; k++)
        p += geoms[k].prim_count;
    return p;
}

/* Where a commit's builds run their parallel work: the threads that joined
 * it (rtk_scene_join_commit), else the device's (rtk_device_tasks). */
static const rtk_task_system *commit_tasks(rtk_scene s, rtk_task_system *copy)
{
    if (s->join_pool) {
        *copy = s->join_tasks;
        return copy;
    }
    return rtk_device_tasks(s->device, copy);
}

/* The layout's width-1 kernel for a query the core may not require
 * (closest points), or NULL. */
static const rtk_kernel_entry *find_query_kernel(const rtk_backend_desc *d, uint32_t layout, uint32_t query)
{
    for (const rtk_kernel_entry *k = d->kernels; k->layout; k++)
        if (k->layout == layout && k->query == query && k->width == 1)
            return k;
    return NULL;
}

/* The layout's stream kernel for the query, or NULL. */
static const rtk_kernel_entry *find_stream_kernel(const rtk_backend_desc *d, uint32_t layout, uint32_t query)
{
    for (const rtk_kernel_entry *k = d->kernels; k->layout; k++)
        if (k->layout == layout && k->query == query && k->width == RTK_KERNEL_WIDTH_STREAM)
            return k;
    return NULL;
}

static const rtk_layout_io_entry *find_layout_io(const rtk_backend_desc *d, uint32_t layout)
{
    if (!RTK_DESC_HAS(d, layout_io))
        return NULL;
    for (const rtk_layout_io_entry *e = d->layout_io; e->layout; e++)
        if (e->layout == layout)
            return e;
    return NULL;
}

/* What a build, import or refit of the scene's geometries is handed:
 * tasks NULL means the calling thread only. */
static rtk_build_input build_input(rtk_build_quality quality, const rtk_build_geometry *geoms, size_t n,
                                   uint32_t layout, const rtk_task_system *tasks)
{
    return (rtk_build_input){
        .struct_size = sizeof(rtk_build_input),
        .geometry_count = (uint32_t)n,
        .geometries = geoms,
        .quality = (uint32_t)quality,
        .layout = layout,
        .threads = tasks ? tasks->threads : 1,
        .tasks = tasks,
    };
}

static const rtk_layout_refit_entry *find_layout_refit(const rtk_backend_desc *d, uint32_t layout)
{
    if (!RTK_DESC_HAS(d, layout_refit))
        return NULL;
    for (const rtk_layout_refit_entry *e = d->layout_refit; e->layout; e++)
        if (e->layout == layout)
            return e;
    return NULL;
}

/* A compact layout reads vertices from the geometries' buffers: the ones
 * rtk allocated are held (in *pinned, *count) until the next commit.  0
 * when out of memory. */
static int pin_buffers(rtk_scene s, const rtk_layout_entry *layout, const rtk_build_geometry *geoms, size_t n,
                       blob ***pinned, uint32_t *count)
{
    *pinned = NULL;
    *count = 0;
    if (!(layout->scene_flags & RTK_SCENE_FLAG_COMPACT))
        return 1;
    *pinned = calloc(n ? n : 1, sizeof **pinned);
    if (!*pinned)
        return 0;
    for (size_t k = 0; k < n; k++) {
        rtk_geometry g = s->geoms[geoms[k].geom_id];
        if (g->vertex.owned) {
            atomic_fetch_add(&g->vertex.owned->refs, 1);
            (*pinned)[(*count)++] = g->vertex.owned;
        }
    }
    return 1;
}

/* What a tree built now over g holds of it, for a later commit's refit
 * check (the counts only of meshes: the other types have no buffers). */
static built_geom built_now(rtk_geometry g)
{
    const int mesh = is_mesh(g);
    return (built_geom){g, g->vertex_version, g->index_version, mesh ? g->index.count : 0, mesh ? g->vertex.count : 0,
                        g->quality};
}

/* Records what the tree now holds.  Out of memory only costs the next
 * commit its chance of a refit. */
static void remember_built(rtk_scene s)
{
    free(s->built);
    s->built = calloc(s->geom_count ? s->geom_count : 1, sizeof *s->built);
    s->built_count = s->built ? s->geom_count : 0;
    s->built_flags = s->flags;
    s->built_quality = s->quality;
    for (uint32_t i = 0; i < s->built_count; i++) {
        rtk_geometry g = s->geoms[i];
        if (g && g->enabled)
            s->built[i] = built_now(g);
    }
}

/* Whether the next commit may refit (rtk_build_quality): the same
 * geometries, flags and quality as the tree was built with, and new vertex
 * positions in REFIT geometries only (at least one). */
static int refit_serves(rtk_scene s)
{
    if (!s->accel || s->two_level || !s->built || s->flags != s->built_flags || s->quality != s->built_quality)
        return 0;
    const uint32_t slots = s->geom_count > s->built_count ? s->geom_count : s->built_count;
    int moved = 0;
    for (uint32_t i = 0; i < slots; i++) {
        rtk_geometry g = i < s->geom_count ? s->geoms[i] : NULL;
        if (g && !g->enabled)
            g = NULL;
        const built_geom b = i < s->built_count ? s->built[i] : (built_geom){0};
        if (g != b.g)
            return 0;
        if (!g)
            continue;
        if (g->index_version != b.index_version || built_now(g).prim_count != b.prim_count || g->quality != b.quality)
            return 0;
        if (g->vertex_version != b.vertex_version) {
            if (g->quality != RTK_BUILD_QUALITY_REFIT)
                return 0;
            moved = 1;
        }
    }
    return moved;
}

/* The vertex buffers of every time step of geoms[0, n), which have `steps`
 * of them (more than one), as the motion builders and refit take them
 * (rtk_build_input.time_vertices); NULL when out of memory. */
static rtk_build_vertices *time_vertices_of(rtk_scene s, const rtk_build_geometry *geoms, size_t n, unsigned steps)
{
    rtk_build_vertices *tv = calloc(n * steps + 1, sizeof *tv);
    for (size_t k = 0; tv && k < n; k++)
        for (unsigned t = 0; t < steps; t++) {
            const rtk_geometry g = s->geoms[geoms[k].geom_id];
            const buffer *b = t ? &g->steps[t - 1] : &g->vertex;
            tv[k * steps + t] = (rtk_build_vertices){b->data, b->stride};
        }
    return tv;
}

/* What refit_tree did. */
enum { REFIT_NONE, REFIT_DONE, REFIT_DROP };

/* Refits the tree `ref` over geoms[0, n), *stats its build's output (then
 * the refit's).  REFIT_NONE when a build must serve instead (no refit in
 * the backend, or more than the scene's own own_refs references hold it:
 * scenes instancing this one keep it as they saw it, with their boxes of
 * it); REFIT_DROP when the triangles that go in
 * the tree have changed and it may be partly rewritten (never to be traced
 * again); else REFIT_DONE with the result in *err. */
static int refit_tree(rtk_scene s, accel_ref *ref, int own_refs, const rtk_build_geometry *geoms, size_t n,
                      rtk_build_output *stats, double *seconds, const char *fn, rtk_error *err)
{
    rtk_device dev = s->device;
    const rtk_layout_refit_entry *rf = find_layout_refit(dev->backend, ref->layout->id);
    if (!rf || atomic_load(&ref->refs) > own_refs)
        return REFIT_NONE;
    blob **pinned;
    uint32_t pinned_count;
    if (!pin_buffers(s, ref->layout, geoms, n, &pinned, &pinned_count)) {
        *err = rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
        return REFIT_DONE;
    }
    if ((*err = progress_next(s, prims_of(geoms, n), fn))) {
        unpin_buffers(pinned, pinned_count);
        return REFIT_DONE;
    }
    rtk_task_system task_copy;
    rtk_build_input in = build_input(s->quality, geoms, n, ref->layout->id, commit_tasks(s, &task_copy));
    commit_input(s, &in);
    in.progress = NULL; /* (a refit reports once, before it starts: it works in place) */
    /* a motion-blur tree's refit takes every time step's vertices */
    const unsigned steps = n ? s->geoms[geoms[0].geom_id]->time_steps : 1;
    rtk_build_vertices *time_vertices = steps > 1 ? time_vertices_of(s, geoms, n, steps) : NULL;
    if (steps > 1 && !time_vertices) {
        unpin_buffers(pinned, pinned_count);
        *err = rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
        return REFIT_DONE;
    }
    in.time_steps = steps > 1 ? steps : 0;
    in.time_vertices = time_vertices;
    const unsigned refusals = atomic_load(&dev->refusals);
    rtk_build_output out = *stats;
    out.struct_size = sizeof out;
    out.message[0] = '\0';
    const double t0 = now_seconds();
    const int rc = rf->refit(ref->accel, &in, &out);
    const double t1 = now_seconds();
    free(time_vertices);
    if (rc) {
        unpin_buffers(pinned, pinned_count);
        if (rc == RTK_REFIT_NEEDS_BUILD) {
            rtk_log(dev, 1, "scene: no refit (%s): building afresh", out.message);
            return REFIT_DROP;
        }
        const rtk_error e = build_error(s, rc, refusals);
        *err = rtk_fail(dev, e, "%s: refit failed: %s%s", fn, out.message[0] ? out.message : "no reason given",
                        refused_note(e));
        return REFIT_DONE;
    }
    unpin_buffers(ref->pinned, ref->pinned_count);
    ref->pinned = pinned;
    ref->pinned_count = pinned_count;
    memcpy(ref->lower, out.lower, sizeof out.lower);
    memcpy(ref->upper, out.upper, sizeof out.upper);
    *stats = out;
    *seconds = t1 - t0;
    *err = RTK_OK;
    return REFIT_DONE;
}

/* Refits the scene's (one-level) tree.  Returns 0 when a build must serve
 * instead (the tree dropped if it may be partly rewritten, so that if the
 * build fails the scene has none rather than one that no longer fits its
 * vertices), else 1 with the commit's result in *err. */
static int try_refit(rtk_scene s, const rtk_build_geometry *geoms, size_t n, const char *fn, rtk_error *err)
{
    rtk_build_output out = s->stats;
    double seconds = 0.0;
    const int r = refit_tree(s, s->ref, 1, geoms, n, &out, &seconds, fn, err);
    if (r == REFIT_DROP)
        scene_drop_accel(s);
    if (r != REFIT_DONE)
        return 0;
    if (*err)
        return 1;
    s->stats = out;
    s->build_seconds = seconds;
    s->refits++;
    remember_built(s);
    rtk_log(s->device, 2, "scene: refit %u of the %s tree: %llu triangles, SAH %.2f, %.3f s", s->refits, s->builder,
            (unsigned long long)out.prims, out.sah_cost, s->build_seconds);
    return 1;
}

/* A reference to a new tree, with its kernels and box; NULL when out of
 * memory. */
static accel_ref *make_ref(const rtk_backend_desc *bk, const rtk_layout_entry *layout, rtk_accel *accel,
                           const rtk_build_output *out)
{
    static atomic_uint_fast64_t serials;
    accel_ref *r = calloc(1, sizeof *r);
    if (!r)
        return NULL;
    atomic_init(&r->refs, 1);
    r->serial = atomic_fetch_add(&serials, 1) + 1;
    r->layout = layout;
    r->accel = accel;
    r->intersect1 = find_kernel(bk, layout->id, RTK_QUERY_INTERSECT)->fn.intersect1;
    r->occluded1 = find_kernel(bk, layout->id, RTK_QUERY_OCCLUDED)->fn.occluded1;
    memcpy(r->lower, out->lower, sizeof r->lower);
    memcpy(r->upper, out->upper, sizeof r->upper);
    return r;
}

/* The scene's new tree (its old one let go). */
static void install(rtk_scene s, accel_ref *ref, const rtk_build_output *out, const char *builder, double seconds)
{
    const rtk_backend_desc *bk = s->device->backend;
    scene_drop_accel(s);
    s->ref = ref;
    s->accel = ref->accel;
    s->layout = ref->layout;
    s->builder = builder;
    s->stats = *out;
    s->build_seconds = seconds;
    s->intersect1 = ref->intersect1;
    s->occluded1 = ref->occluded1;
    s->honoured = ref->layout->scene_flags;
    for (int w = 0; w < 3; w++) {
        s->packet[0][w] = find_packet_kernel(bk, ref->layout->id, RTK_QUERY_INTERSECT, packet_widths[w]);
        s->packet[1][w] = find_packet_kernel(bk, ref->layout->id, RTK_QUERY_OCCLUDED, packet_widths[w]);
    }
    const rtk_kernel_entry *si = find_stream_kernel(bk, ref->layout->id, RTK_QUERY_INTERSECT);
    const rtk_kernel_entry *so = find_stream_kernel(bk, ref->layout->id, RTK_QUERY_OCCLUDED);
    s->intersect_stream = si ? si->fn.intersect_stream : NULL;
    s->occluded_stream = so ? so->fn.occluded_stream : NULL;
    s->stream_in_flight = si && so ? (si->in_flight ? si->in_flight : 1) : 0;
    const rtk_kernel_entry *cp = find_query_kernel(bk, ref->layout->id, RTK_QUERY_CLOSEST_POINT);
    s->closest_point = cp ? cp->fn.closest_point : NULL;
    remember_built(s);
}

/* From a builder table: the builder named want_builder (else those serving
 * `quality`, or with any_quality all of them) whose layout is want_layout
 * (else honours the most of `flags` and nothing outside them), the first
 * of equals; NULL if none.  Its layout in *layout_out. */
static const rtk_builder_entry *pick_builder(const rtk_backend_desc *bk, const rtk_builder_entry *table,
                                             const char *want_builder, const char *want_layout,
                                             rtk_build_quality quality, int any_quality, unsigned flags,
                                             const rtk_layout_entry **layout_out)
{
    const rtk_builder_entry *builder = NULL;
    int best = -1;
    for (const rtk_builder_entry *b = table; b->name; b++) {
        if (want_builder ? strcmp(b->name, want_builder) : !any_quality && !(b->qualities & (1u << quality)))
            continue;
        const rtk_layout_entry *l = rtk_backend_find_layout(bk, b->layout);
        if (!l || (want_layout ? strcmp(l->name, want_layout) : (l->scene_flags & ~flags) != 0))
            continue;
        const int score = __builtin_popcount(l->scene_flags & flags);
        if (score > best) {
            best = score;
            builder = b;
            *layout_out = l;
        }
    }
    return builder;
}

/* Builds (or, with `tree`, imports) a tree over the triangles of geoms[0, n)
 * with the builder and layout the scene calls for: *ref_out, with the
 * build's output, the builder's name and the time taken.  `recycle`: a tree
 * of the scene's that nothing will read again, whose memory the builder may
 * take (recyclable); *wrote_old is then 1 if it did (after a failure, the
 * caller drops the trees that hold it). */
static rtk_error build_triangles(rtk_scene s, const rtk_build_geometry *in_geoms, size_t n, rtk_build_quality quality,
                                 const rtk_bvh *tree, rtk_accel *recycle, int *wrote_old, const char *fn,
                                 accel_ref **ref_out, rtk_build_output *out_io, const char **builder_name,
                                 double *seconds)
{
    rtk_device dev = s->device;
    const rtk_backend_desc *bk = dev->backend;
    /* The leanest layout that serves: among the builders for this quality
     * (else all of them, saying so), the first whose layout honours the most
     * of the scene's flags and nothing the scene did not ask for (a compact
     * layout is slower; a robust one costs time too).  The device config's
     * builder= and layout= override the quality and the flags (the device
     * checked that the backend has them). */
    const char *want_builder = dev->config.builder[0] ? dev->config.builder : NULL;
    const char *want_layout = dev->config.layout[0] ? dev->config.layout : NULL;
    const rtk_builder_entry *builder = NULL;
    const rtk_layout_entry *layout = NULL;
    /* geometries with motion blur come in groups of one time step count */
    const unsigned steps = n ? s->geoms[in_geoms[0].geom_id]->time_steps : 1;
    if (steps > 1) {
        /* the motion builder of the quality (or the one named builder=),
         * into the layout motion_layout= names (layout= names layouts of
         * static triangles) */
        const char *want_mb = dev->config.motion_layout[0] ? dev->config.motion_layout : NULL;
        if (!RTK_DESC_HAS(bk, motion_builders) || !bk->motion_builders[0].name)
            return rtk_fail(dev, RTK_ERROR_INVALID_OPERATION,
                            "%s: backend %s cannot trace motion blur (it predates it)", fn, bk->name);
        /* as for static triangles, by the flags (robust: the watertight
         * test): the named builder or those of the quality, else any */
        for (int any = 0; any < 2 && !builder; any++)
            builder = pick_builder(bk, bk->motion_builders, any ? NULL : want_builder, want_mb, quality, any, s->flags,
                                   &layout);
        if (!builder) {
            builder = bk->motion_builders;
            layout = rtk_backend_find_layout(bk, builder->layout);
        }
    }
    for (int any_quality = want_builder != NULL; steps == 1 && any_quality < 2 && !builder; any_quality++) {
        builder = pick_builder(bk, bk->builders, want_builder, want_layout, quality, any_quality, s->flags, &layout);
        if (builder && any_quality && !want_builder)
            rtk_log(dev, 1, "scene: no builder for quality %d in backend %s; using %s", (int)quality, bk->name,
                    builder->name);
    }
    if (!builder) {
        return rtk_fail(dev, RTK_ERROR_UNKNOWN, "%s: backend %s has no builder for a scene with flags 0x%x", fn,
                        bk->name, s->flags);
    }
    unsigned not_honoured = s->flags & ~layout->scene_flags;
    if (not_honoured) {
        char names[64];
        rtk_log(dev, 1, "scene: flags%s requested but not honoured by this version; the scene is built as default",
                flag_names(not_honoured, names, sizeof names));
    }

    rtk_error perr = progress_next(s, prims_of(in_geoms, n), fn);
    if (perr)
        return perr;
    rtk_task_system task_copy;
    rtk_build_input in = build_input(quality, in_geoms, n, layout->id, tree ? NULL : commit_tasks(s, &task_copy));
    in.recycle = tree ? NULL : recycle;
    commit_input(s, &in);
    const unsigned refusals = atomic_load(&dev->refusals);
    /* masks, filters and quads: passed only when some geometry has one, so
     * a scene without any builds a tree whose kernels test nothing more */
    rtk_geometry_attrs *attrs = NULL;
    for (size_t k = 0; k < n; k++) {
        const rtk_geometry g = s->geoms[in_geoms[k].geom_id];
        if (g->mask != ~0u || g->intersect_filter || g->occluded_filter || g->type == RTK_GEOMETRY_TYPE_QUAD) {
            attrs = calloc(n, sizeof *attrs);
            if (!attrs)
                return rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
            for (size_t j = 0; j < n; j++) {
                const rtk_geometry h = s->geoms[in_geoms[j].geom_id];
                attrs[j] = (rtk_geometry_attrs){
                    .mask = h->mask,
                    .flags = h->type == RTK_GEOMETRY_TYPE_QUAD ? RTK_GEOMETRY_ATTR_QUAD : 0u,
                    .intersect_filter = h->intersect_filter,
                    .occluded_filter = h->occluded_filter,
                    .user = h->user};
            }
            in.attrs = attrs;
            break;
        }
    }
    rtk_build_vertices *time_vertices = NULL;
    if (steps > 1) {
        time_vertices = time_vertices_of(s, in_geoms, n, steps);
        if (!time_vertices) {
            free(attrs);
            return rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
        }
        in.time_steps = steps;
        in.time_vertices = time_vertices;
    }
    rtk_build_output out = {.struct_size = sizeof out};
    double t0 = now_seconds();
    int rc;
    if (tree) {
        /* Everything the backend will trust is checked here first. */
        const rtk_layout_io_entry *io = find_layout_io(bk, layout->id);
        char why[256];
        uint64_t non_finite = 0, degenerate = 0, out_of_range = 0, in_tree = 0;
        rtk_error err = RTK_OK;
        if (!io)
            err = rtk_fail(dev, RTK_ERROR_INVALID_OPERATION, "%s: backend %s cannot import a tree into layout %s", fn,
                           bk->name, layout->name);
        else if ((err = rtk_bvh_check(tree, why, sizeof why)) ||
                 (err = rtk_bvh_check_fit(tree, in_geoms, (uint32_t)n, &non_finite, &degenerate, &out_of_range,
                                          &in_tree, why, sizeof why)))
            rtk_fail(dev, err, "%s: %s", fn, why);
        if (err) {
            free(attrs);
            return err;
        }
        rc = io->import_tree(&in, tree, &out);
        /* the tree may hold a triangle more than once (spatial splits) */
        out.refs = tree->prim_count;
        out.prims = in_tree;
        out.prims_skipped = non_finite;
        out.prims_degenerate = degenerate;
        out.prims_out_of_range = out_of_range;
    } else {
        rc = builder->build(&in, &out);
    }
    double t1 = now_seconds();
    free(time_vertices);
    free(attrs);
    *wrote_old = out.recycled != 0;
    if (rc != 0 && out.recycled)
        rtk_log(dev, 1, "scene: the failed build took the memory of the scene's previous tree; the scene has none now");
    if (rc != 0) {
        const rtk_error e = build_error(s, rc, refusals);
        return rtk_fail(dev, e, "%s: %s failed: %s%s", fn, tree ? "import" : "build",
                        out.message[0] ? out.message : "no reason given", refused_note(e));
    }

    /* (the application keeps its shared buffers alive itself) */
    blob **pinned;
    uint32_t pinned_count;
    if (!pin_buffers(s, layout, in_geoms, n, &pinned, &pinned_count)) {
        layout->release(out.accel);
        return rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
    }
    accel_ref *ref = make_ref(bk, layout, out.accel, &out);
    if (!ref) {
        unpin_buffers(pinned, pinned_count);
        layout->release(out.accel);
        return rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
    }
    ref->pinned = pinned;
    ref->pinned_count = pinned_count;
    *ref_out = ref;
    *out_io = out;
    *builder_name = tree ? "tree" : builder->name;
    *seconds = t1 - t0;
    if (out.prims_skipped)
        rtk_log(dev, 1, "scene: %llu triangles with NaN or infinite vertices left out (never hit)",
                (unsigned long long)out.prims_skipped);
    if (out.prims_degenerate)
        rtk_log(dev, 1, "scene: %llu zero-area triangles left out (never hit)",
                (unsigned long long)out.prims_degenerate);
    if (out.prims_out_of_range)
        rtk_log(dev, 1, "scene: %llu triangles outside rtk's range (a coordinate beyond +-2^36, or too small an "
                "area) left out (never hit)", (unsigned long long)out.prims_out_of_range);
    rtk_log(dev, 2, "scene: %s/%s on %s: %llu triangles, %llu nodes, %llu leaves, depth %u, %.1f bytes/triangle, "
            "SAH %.2f, %.3f s on %u thread%s",
            *builder_name, layout->name, bk->name, (unsigned long long)out.prims, (unsigned long long)out.nodes,
            (unsigned long long)out.leaves, out.depth, out.prims ? (double)out.bytes / (double)out.prims : 0.0,
            out.sah_cost, *seconds, out.threads ? out.threads : 1, out.threads > 1 ? "s" : "");
    return RTK_OK;

}

static const rtk_objects_entry *find_objects(const rtk_backend_desc *d)
{
    if (!RTK_DESC_HAS(d, objects) || !d->objects[0].layout)
        return NULL;
    return d->objects;
}

/* The box of lower/upper mapped by the row-major 3x4 m, rounded outwards
 * and padded for the rounding of rays taken into the object's space; an
 * inverted box for an empty one. */
static void world_box(const float *m, const float lower[3], const float upper[3], float lo[3], float hi[3])
{
    if (!(lower[0] <= upper[0] && lower[1] <= upper[1] && lower[2] <= upper[2])) {
        for (int k = 0; k < 3; k++) {
            lo[k] = INFINITY;
            hi[k] = -INFINITY;
        }
        return;
    }
    double dlo[3] = {INFINITY, INFINITY, INFINITY}, dhi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int c = 0; c < 8; c++) {
        const double p[3] = {c & 1 ? upper[0] : lower[0], c & 2 ? upper[1] : lower[1], c & 4 ? upper[2] : lower[2]};
        for (int k = 0; k < 3; k++) {
            const double v = (double)m[4 * k] * p[0] + (double)m[4 * k + 1] * p[1] + (double)m[4 * k + 2] * p[2] +
                             (double)m[4 * k + 3];
            dlo[k] = v < dlo[k] ? v : dlo[k];
            dhi[k] = v > dhi[k] ? v : dhi[k];
        }
    }
    for (int k = 0; k < 3; k++) {
        const double mag = fmax(fmax(fabs(dlo[k]), fabs(dhi[k])), dhi[k] - dlo[k]);
        const double pad = mag * 0x1p-18 + 1e-30;
        lo[k] = (float)(dlo[k] - pad);
        hi[k] = (float)(dhi[k] + pad);
        if ((double)lo[k] > dlo[k] - pad)
            lo[k] = nextafterf(lo[k], -INFINITY);
        if ((double)hi[k] < dhi[k] + pad)
            hi[k] = nextafterf(hi[k], INFINITY);
    }
}

static void release_refs(accel_ref **refs, uint32_t n)
{
    for (uint32_t i = 0; i < n; i++)
        accel_ref_release(refs[i]);
}

/* A refitted top level is built afresh once its SAH cost
 * (rtk_build_output.sah_cost) is this much above its build's. */
#define TOP_REFIT_SAH_GROWTH 1.1

/* Refits the scene's top level (rtk_objects_refit) over `in`'s objects,
 * which must be the ones it was built over, with new boxes, and whose trees
 * children[0, nchildren) must be the ones it holds.  1 when done: its stats
 * and time set (the time own_seconds and the refit's); 0 when the top level
 * must be built instead (the scene's is shared, over other trees, not
 * built for refitting, or its SAH cost grew past TOP_REFIT_SAH_GROWTH of
 * its build's: the boxes it has then are the refit's, which hold). */
static int refit_top(rtk_scene s, const rtk_layout_entry *layout, const rtk_build_input *in, accel_ref *const *children,
                     uint32_t nchildren, double own_seconds)
{
    rtk_device dev = s->device;
    accel_ref *top = s->ref;
    const rtk_layout_refit_entry *rf = find_layout_refit(dev->backend, layout->id);
    if (!rf || !top || !s->two_level || top->layout != layout || atomic_load(&top->refs) != 1 ||
        top->child_count != nchildren || (nchildren && memcmp(top->children, children, nchildren * sizeof *children)))
        return 0;
    rtk_build_output out = s->stats;
    out.struct_size = sizeof out;
    out.message[0] = '\0';
    const double t0 = now_seconds();
    const int rc = rf->refit(top->accel, in, &out);
    const double t1 = now_seconds();
    if (rc) {
        rtk_log(dev, 2, "scene: the top level is built, not refitted: %s",
                out.message[0] ? out.message : "no reason given");
        return 0;
    }
    if (out.sah_cost > s->top_sah_built * TOP_REFIT_SAH_GROWTH) {
        rtk_log(dev, 2, "scene: the refitted top level's SAH cost grew from %.2f to %.2f: built afresh",
                s->top_sah_built, out.sah_cost);
        return 0;
    }
    memcpy(top->lower, out.lower, sizeof out.lower);
    memcpy(top->upper, out.upper, sizeof out.upper);
    s->stats = out;
    s->build_seconds = own_seconds + (t1 - t0);
    s->top_refits++;
    rtk_log(dev, 2, "scene: top level refitted (%u since its build): SAH %.2f (%.2f at its build), %.6f s",
            s->top_refits, out.sah_cost, s->top_sah_built, t1 - t0);
    return 1;
}

/* The top level of a scene with ni instances, or a dynamic one: over the
 * instanced scenes' trees and own[0, own_count) (trees of the scene's own
 * triangles: one, or one per geometry in a dynamic scene; the references
 * are taken over here whatever happens), own_total their builds' output
 * summed.  for_refit: a dynamic scene with deforming geometry, whose top
 * level is built so that it can be refitted, and refitted (refit_top) when
 * may_refit (no tree of its own was built). */
static rtk_error commit_objects(rtk_scene s, accel_ref **own, uint32_t own_count, const rtk_build_output *own_total,
                                double own_seconds, uint32_t ni, int for_refit, int may_refit, const char *fn)
{
    rtk_device dev = s->device;
    const rtk_backend_desc *bk = dev->backend;
    const rtk_objects_entry *oe = find_objects(bk);
    const rtk_layout_entry *layout = oe ? rtk_backend_find_layout(bk, oe->layout) : NULL;
    if (!layout || !oe->build) {
        release_refs(own, own_count);
        return rtk_fail(dev, RTK_ERROR_INVALID_OPERATION, "%s: backend %s cannot trace instances (it predates them)",
                        fn, bk->name);
    }
    /* user primitives: every one whose box the bounds callback gives finite
     * and ordered */
    uint64_t nu = 0;
    for (uint32_t i = 0; i < s->geom_count; i++) {
        rtk_geometry g = s->geoms[i];
        if (g && g->enabled && g->type == RTK_GEOMETRY_TYPE_USER)
            nu += g->user_count;
    }
    if (nu > UINT32_MAX - (uint64_t)ni - own_count) {
        release_refs(own, own_count);
        return rtk_fail(dev, RTK_ERROR_INVALID_ARGUMENT, "%s: more than 2^32 objects in the top level", fn);
    }
    const uint32_t count = ni + own_count + (uint32_t)nu;
    rtk_build_object *objs = rtk_big_calloc(count ? count : 1, sizeof *objs);
    accel_ref **children = calloc(count ? count : 1, sizeof *children);
    user_prim *prims = calloc(nu ? nu : 1, sizeof *prims);
    if (!objs || !children || !prims) {
        rtk_big_free(objs);
        free(children);
        free(prims);
        release_refs(own, own_count);
        return rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
    }
    uint32_t k = 0, depth = 0;
    for (uint32_t o = 0; o < own_count; o++) {
        const accel_ref *t = own[o];
        objs[k] = (rtk_build_object){.accel = t->accel, .intersect1 = t->intersect1, .occluded1 = t->occluded1,
                                     .inst_id = RTK_INVALID_GEOMETRY_ID, .flags = RTK_BUILD_OBJECT_IDENTITY,
                                     .mask = ~0u};
        memcpy(objs[k].world_to_object, identity_3x4, sizeof identity_3x4);
        memcpy(objs[k].lower, t->lower, sizeof t->lower);
        memcpy(objs[k].upper, t->upper, sizeof t->upper);
        children[k++] = own[o];
    }
    for (uint32_t i = 0; i < s->geom_count; i++) {
        rtk_geometry g = s->geoms[i];
        if (!g || !g->enabled || g->type != RTK_GEOMETRY_TYPE_INSTANCE)
            continue;
        accel_ref *c = g->instanced->ref;
        atomic_fetch_add(&c->refs, 1);
        objs[k] = (rtk_build_object){.accel = c->accel, .intersect1 = c->intersect1, .occluded1 = c->occluded1,
                                     .inst_id = i, .mask = g->mask};
        rtk_invert_3x4(g->xfm, objs[k].world_to_object); /* (rtk_geometry_commit checked it) */
        world_box(g->xfm, c->lower, c->upper, objs[k].lower, objs[k].upper);
        children[k++] = c;
        depth = c->depth + 1 > depth ? c->depth + 1 : depth;
    }
    const uint32_t nchildren = k;
    uint64_t used = 0, skipped = 0, pointless = 0;
    for (uint32_t i = 0; i < s->geom_count; i++) {
        rtk_geometry g = s->geoms[i];
        if (!g || !g->enabled || g->type != RTK_GEOMETRY_TYPE_USER)
            continue;
        for (uint32_t p = 0; p < g->user_count; p++) {
            float lo[3] = {NAN, NAN, NAN}, hi[3] = {NAN, NAN, NAN};
            g->bounds(&(rtk_bounds_args){.geometry_user = g->user, .prim_id = p, .lower = lo, .upper = hi});
            int ok = 1;
            for (int a = 0; a < 3; a++)
                ok &= isfinite(lo[a]) && isfinite(hi[a]) && lo[a] <= hi[a];
            if (!ok) {
                skipped++;
                continue;
            }
            user_prim *u = &prims[used++];
            *u = (user_prim){.intersect = g->user_intersect, .occluded = g->user_occluded, .point = g->user_point,
                             .user = g->user, .geom_id = i, .prim_id = p};
            pointless += !g->user_point;
            objs[k] = (rtk_build_object){.accel = (const rtk_accel *)(const void *)u,
                                         .intersect1 = user_intersect1, .occluded1 = user_occluded1,
                                         .inst_id = RTK_INVALID_GEOMETRY_ID, .flags = RTK_BUILD_OBJECT_IDENTITY,
                                         .mask = g->mask, .intersect_packet = user_intersect_packet,
                                         .occluded_packet = user_occluded_packet};
            memcpy(objs[k].world_to_object, identity_3x4, sizeof identity_3x4);
            memcpy(objs[k].lower, lo, sizeof lo);
            memcpy(objs[k].upper, hi, sizeof hi);
            k++;
        }
    }
    rtk_build_input in = build_input(for_refit ? RTK_BUILD_QUALITY_REFIT : s->quality, NULL, 0, layout->id, NULL);
    in.object_count = k;
    in.objects = objs;
    commit_input(s, &in);
    in.progress = NULL; /* (the top level is one step, reported here) */
    const unsigned refusals = atomic_load(&dev->refusals);
    rtk_build_output out = {.struct_size = sizeof out};
    const double t0 = now_seconds();
    const rtk_error cancelled = progress_next(s, 0, fn); /* (the top level's one step) */
    if (!cancelled && may_refit && !used && refit_top(s, layout, &in, children, nchildren, own_seconds)) {
        /* (the top level holds the same trees already) */
        rtk_big_free(objs);
        release_refs(children, nchildren);
        free(children);
        free(prims);
        s->own_stats = *own_total;
        return RTK_OK;
    }
    const int rc = cancelled ? (int)cancelled : oe->build(&in, &out);
    const double t1 = now_seconds();
    rtk_big_free(objs);
    accel_ref *top = rc ? NULL : make_ref(bk, layout, out.accel, &out);
    if (!top) {
        if (!rc)
            layout->release(out.accel);
        release_refs(children, nchildren);
        free(children);
        free(prims);
        if (cancelled)
            return cancelled;
        return rc ? rtk_fail(dev, build_error(s, rc, refusals), "%s: the top level's build failed: %s%s", fn,
                             out.message[0] ? out.message : "no reason given",
                             refused_note(build_error(s, rc, refusals)))
                  : rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
    }
    top->children = children;
    top->child_count = nchildren;
    top->depth = depth;
    top->user_prims = prims;
    top->user_deep = used;
    top->user_pointless_deep = pointless;
    for (uint32_t c = 0; c < nchildren; c++) {
        top->user_deep += children[c]->user_deep;
        top->user_pointless_deep += children[c]->user_pointless_deep;
    }
    install(s, top, &out, "objects", own_seconds + (t1 - t0));
    s->top_refits = 0;
    s->top_sah_built = out.sah_cost;
    if (!used) /* the objects' packet kernels serve user primitives' callbacks; other top levels go ray by ray */
        for (int w = 0; w < 3; w++)
            s->packet[0][w] = s->packet[1][w] = (struct packet_kernel){.width = 1};
    s->user_prims = used;
    s->user_skipped = skipped;
    s->instances = ni;
    s->two_level = 1;
    s->own_stats = *own_total;
    /* the flags every tree of the scene's own triangles honours (a backend
     * older than robust motion blur has a moving geometry's tree honour
     * none); with no triangles of its own, a
     * compact or robust request is served (the instanced scenes' own
     * flags apply to their triangles) */
    s->honoured = s->flags & (RTK_SCENE_FLAG_COMPACT | RTK_SCENE_FLAG_ROBUST);
    for (unsigned i = 0; i < own_count; i++)
        s->honoured = (i ? s->honoured : ~0u) & own[i]->layout->scene_flags;
    rtk_log(dev, 2, "scene: two levels on %s: %u instances and %u trees of the scene's own triangles, %llu top-level "
            "nodes, depth %u, %.3f s", bk->name, ni, own_count, (unsigned long long)out.nodes, out.depth,
            s->build_seconds);
    return RTK_OK;
}

/* Adds a tree's build to the sum of a scene's own trees. */
static void add_output(rtk_build_output *total, uint64_t *motion, const rtk_build_output *o, const accel_ref *tree)
{
    total->prims += o->prims;
    total->prims_skipped += o->prims_skipped;
    total->prims_degenerate += o->prims_degenerate;
    total->prims_out_of_range += o->prims_out_of_range;
    total->refs += o->refs ? o->refs : o->prims;
    total->bytes += o->bytes;
    switch (tree->layout->id) {
    case RTK_LAYOUT_BVH4_TRIANGLE4MB:
    case RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST:
    case RTK_LAYOUT_BVH8_TRIANGLE4MB:
    case RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST: *motion += o->prims; break;
    default: break;
    }
}

/* How a dynamic scene builds a geometry's own tree: its quality (low: the
 * Morton builder, for geometry that changes every frame; medium, high:
 * SAH), a deforming (REFIT) geometry's first build at medium. */
static rtk_build_quality tree_quality(rtk_geometry g)
{
    return g->quality == RTK_BUILD_QUALITY_REFIT ? RTK_BUILD_QUALITY_MEDIUM : g->quality;
}

/* A dynamic scene (RTK_SCENE_FLAG_DYNAMIC): a tree per triangle geometry
 * of geoms[0, n) (kept while its geometry is unchanged, refitted when only
 * a REFIT geometry's vertices moved, else built with tree_quality) and a
 * top level over them and the ni instances. */
static rtk_error commit_dynamic(rtk_scene s, const rtk_build_geometry *geoms, size_t n, uint32_t ni, const char *fn)
{
    rtk_device dev = s->device;
    dyn_tree *nd = calloc(s->geom_count ? s->geom_count : 1, sizeof *nd);
    accel_ref **own = calloc(n ? n : 1, sizeof *own);
    if (!nd || !own) {
        free(nd);
        free(own);
        return rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
    }
    /* the scene's old top level holds each old tree once more; scenes that
     * instance this one hold its top level, and so them */
    const int own_refs = s->ref && atomic_load(&s->ref->refs) == 1 ? 2 : 0;
    rtk_build_output total = {.struct_size = sizeof total};
    uint64_t motion = 0;
    double seconds = 0.0;
    uint32_t built = 0, refitted = 0;
    int touched = 0; /* an old tree refitted, rewritten in place or recycled */
    int deforming = 0; /* a REFIT geometry: the top level is built for refitting */
    for (size_t k = 0; k < n; k++)
        deforming |= s->geoms[geoms[k].geom_id]->quality == RTK_BUILD_QUALITY_REFIT;
    rtk_error err = RTK_OK;
    for (size_t k = 0; k < n && !err; k++) {
        const uint32_t i = geoms[k].geom_id;
        const rtk_geometry g = s->geoms[i];
        const built_geom now = built_now(g);
        const dyn_tree *old = i < s->dyn_count && s->dyn[i].ref && s->dyn[i].b.g == g ? &s->dyn[i] : NULL;
        const int same_tris = old && old->b.index_version == now.index_version &&
                              old->b.prim_count == now.prim_count && old->b.quality == now.quality;
        if (same_tris && old->b.vertex_version == now.vertex_version && old->b.vertex_count == now.vertex_count) {
            atomic_fetch_add(&old->ref->refs, 1);
            nd[i] = (dyn_tree){old->ref, now, old->out};
            if (s->commit_progress) /* (kept: its triangles are done) */
                s->commit_progress->done += geoms[k].prim_count;
        } else if (same_tris && g->quality == RTK_BUILD_QUALITY_REFIT && g->vertex.count >= old->b.vertex_count) {
            rtk_build_output out = old->out;
            double t = 0.0;
            const int r = refit_tree(s, old->ref, own_refs, &geoms[k], 1, &out, &t, fn, &err);
            /* (refit_tree fails before it writes, or writes and drops) */
            touched |= r == REFIT_DROP || (r == REFIT_DONE && !err);
            if (r == REFIT_DONE && !err) {
                atomic_fetch_add(&old->ref->refs, 1);
                nd[i] = (dyn_tree){old->ref, now, out};
                refitted++;
                seconds += t;
            }
        }
        if (!nd[i].ref && !err) {
            /* (indices were checked in range when the tree is not kept;
             * an old tree only this scene holds may give its memory) */
            const char *name;
            double t = 0.0;
            int wrote_old = 0;
            err = build_triangles(s, &geoms[k], 1, tree_quality(g), NULL, recyclable(old ? old->ref : NULL, own_refs),
                                  &wrote_old, fn, &nd[i].ref, &nd[i].out, &name, &t);
            touched |= wrote_old;
            nd[i].b = now;
            built++;
            seconds += t;
        }
        if (nd[i].ref) {
            own[k] = nd[i].ref;
            atomic_fetch_add(&nd[i].ref->refs, 1); /* one for the top level's children */
            add_output(&total, &motion, &nd[i].out, nd[i].ref);
        }
    }
    if (!err)
        err = commit_objects(s, own, (uint32_t)n, &total, seconds, ni, deforming, !built, fn);
    else
        release_refs(own, (uint32_t)n);
    free(own);
    if (err) {
        for (uint32_t i = 0; i < s->geom_count; i++)
            accel_ref_release(nd[i].ref);
        free(nd);
        if (touched) /* its old top level's boxes may no longer hold */
            scene_drop_accel(s);
        return err;
    }
    /* (the old trees, when the old top level was refitted and kept) */
    for (uint32_t i = 0; i < s->dyn_count; i++)
        accel_ref_release(s->dyn[i].ref);
    free(s->dyn);
    s->dyn = nd;
    s->dyn_count = s->geom_count;
    s->motion_prims = motion;
    s->trees_built = built;
    s->trees_refitted = refitted;
    s->honoured |= RTK_SCENE_FLAG_DYNAMIC;
    return RTK_OK;
}

/* The most trees of a scene's own triangles: one without motion blur and
 * one per time step count (2 .. RTK_MAX_TIME_STEPS). */
#define MAX_OWN_TREES RTK_MAX_TIME_STEPS

static int cmp_u64(const void *a, const void *b)
{
    const uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return x < y ? -1 : x > y;
}

/* Orders geoms[0, n) (in id order) as the trees take them: without motion
 * blur first, then by time step count, ids ascending within each.  0 when
 * out of memory. */
static int group_by_time_steps(rtk_scene s, rtk_build_geometry *geoms, size_t n)
{
    uint64_t *key = malloc((n ? n : 1) * sizeof *key);
    rtk_build_geometry *copy = malloc((n ? n : 1) * sizeof *copy);
    if (!key || !copy) {
        free(key);
        free(copy);
        return 0;
    }
    for (size_t k = 0; k < n; k++)
        key[k] = (uint64_t)s->geoms[geoms[k].geom_id]->time_steps << 32 | k;
    qsort(key, n, sizeof *key, cmp_u64);
    memcpy(copy, geoms, n * sizeof *copy);
    for (size_t k = 0; k < n; k++)
        geoms[k] = copy[(uint32_t)key[k]];
    free(key);
    free(copy);
    return 1;
}

/* rtk_scene_commit (tree == NULL) and rtk_scene_commit_bvh: fn names the
 * entry point in messages. */
static rtk_error commit(rtk_scene s, const rtk_bvh *tree, const char *fn)
{
    rtk_device dev = s->device;

    /* A refit keeps the indices, checked at the last commit: in range still
     * unless the vertex buffer shrank. */
    const int refit = !tree && refit_serves(s);
    size_t n = 0;
    uint32_t ni = 0, nug = 0; /* instances, user geometries */
    uint64_t quads = 0;       /* in quad geometries */
    for (uint32_t i = 0; i < s->geom_count; i++) {
        rtk_geometry g = s->geoms[i];
        if (!g)
            continue;
        if (!g->committed)
            return rtk_fail(dev, RTK_ERROR_INVALID_OPERATION,
                            "%s: geometry %u is attached but not committed", fn, i);
        if (!g->enabled)
            continue;
        if (g->type == RTK_GEOMETRY_TYPE_INSTANCE) {
            const accel_ref *c = g->instanced->ref;
            if (!c)
                return rtk_fail(dev, RTK_ERROR_INVALID_OPERATION,
                                "%s: geometry %u instances a scene that was never committed", fn, i);
            if (c->depth + 1 > RTK_MAX_INSTANCE_DEPTH)
                return rtk_fail(dev, RTK_ERROR_INVALID_OPERATION,
                                "%s: geometry %u nests instances deeper than RTK_MAX_INSTANCE_DEPTH (%d)", fn, i,
                                RTK_MAX_INSTANCE_DEPTH);
            ni++;
            continue;
        }
        if (g->type == RTK_GEOMETRY_TYPE_USER) {
            nug++;
            continue;
        }
        /* indices unchanged since the tree that is kept (a refit's, or a
         * dynamic scene's geometry's) are in range still, unless the
         * vertex buffer shrank */
        const int kept = refit ? g->vertex.count >= s->built[i].vertex_count
                               : (s->flags & RTK_SCENE_FLAG_DYNAMIC) && i < s->dyn_count && s->dyn[i].ref &&
                                     s->dyn[i].b.g == g && s->dyn[i].b.index_version == g->index_version &&
                                     g->vertex.count >= s->dyn[i].b.vertex_count;
        rtk_error err = kept ? RTK_OK : check_indices(s, i, g, fn);
        if (err)
            return err;
        if (tree && g->time_steps > 1)
            return rtk_fail(dev, RTK_ERROR_INVALID_OPERATION,
                            "%s: geometry %u has motion blur: a loaded tree holds no motion", fn, i);
        n++;
        quads += g->type == RTK_GEOMETRY_TYPE_QUAD ? g->index.count : 0;
    }
    if ((ni || nug) && tree)
        return rtk_fail(dev, RTK_ERROR_INVALID_OPERATION,
                        "%s: a scene with instances or user geometry cannot take a loaded tree", fn);
    /* Quads go to the builders as their triangles, written for this commit
     * after the geometries (one allocation, freed with them: the layouts
     * keep no pointer to the indices). */
    const size_t head = ((n ? n : 1) * sizeof(rtk_build_geometry) + 15) & ~(size_t)15;
    rtk_build_geometry *in_geoms =
        quads > (SIZE_MAX - head) / 24 ? NULL : calloc(1, head + (size_t)quads * 6 * sizeof(uint32_t));
    if (!in_geoms)
        return rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
    uint32_t *quad_tris = (uint32_t *)((char *)in_geoms + head);
    n = 0;
    for (uint32_t i = 0; i < s->geom_count; i++) {
        rtk_geometry g = s->geoms[i];
        if (!g || !g->enabled || !is_mesh(g))
            continue;
        in_geoms[n++] = (rtk_build_geometry){
            .vertices = g->vertex.data,
            .vertex_stride = g->vertex.stride,
            .vertex_count = g->vertex.count,
            .indices = g->index.data,
            .index_stride = g->index.stride,
            .prim_count = g->index.count,
            .geom_id = i,
            .flags = g->quality == RTK_BUILD_QUALITY_REFIT ? RTK_BUILD_GEOMETRY_DEFORMS : 0,
        };
        if (g->type == RTK_GEOMETRY_TYPE_QUAD) {
            quads_to_triangles(g, quad_tris);
            in_geoms[n - 1].indices = quad_tris;
            in_geoms[n - 1].index_stride = 3 * sizeof(uint32_t);
            in_geoms[n - 1].prim_count = 2 * g->index.count;
            quad_tris += 6 * g->index.count;
        }
    }
    rtk_error err;
    if (refit && try_refit(s, in_geoms, n, fn, &err)) {
        free(in_geoms);
        return err;
    }
    /* (try_refit reported through s->commit_progress, set by the caller) */
    if ((s->flags & RTK_SCENE_FLAG_DYNAMIC) && !tree) {
        err = commit_dynamic(s, in_geoms, n, ni, fn);
        free(in_geoms);
        if (!err)
            s->quads = quads;
        return err;
    }
    /* The scene's own triangles: those without motion blur in one tree,
     * those with it in one per time step count.  A single tree with no
     * instances is the whole scene; else each is an object of the top
     * level. */
    if (!group_by_time_steps(s, in_geoms, n)) {
        free(in_geoms);
        return rtk_fail(dev, RTK_ERROR_OUT_OF_MEMORY, "%s: out of memory", fn);
    }
    accel_ref *own[MAX_OWN_TREES];
    rtk_build_output own_out[MAX_OWN_TREES], total = {.struct_size = sizeof total};
    const char *own_builder[MAX_OWN_TREES];
    uint32_t own_count = 0;
    uint64_t motion = 0;
    double seconds = 0.0;
    err = RTK_OK;
    for (size_t k = 0; (k < n || (!n && !ni && !nug && !own_count)) && !err; own_count++) {
        size_t end = k;
        while (end < n && s->geoms[in_geoms[end].geom_id]->time_steps == s->geoms[in_geoms[k].geom_id]->time_steps)
            end++;
        double t = 0.0;
        own_out[own_count] = (rtk_build_output){.struct_size = sizeof own_out[0]};
        /* a scene of one tree rebuilt as one tree: the old one's memory
         * may serve the new one (recyclable) */
        rtk_accel *recycle = !own_count && end == n && !ni && !nug ? recyclable(s->ref, 1) : NULL;
        int wrote_old = 0;
        err = build_triangles(s, in_geoms + k, end - k, s->quality, tree, recycle, &wrote_old, fn, &own[own_count],
                              &own_out[own_count], &own_builder[own_count], &t);
        if (err && wrote_old) /* the failed build wrote into the scene's tree */
            scene_drop_accel(s);
        if (err)
            break;
        add_output(&total, &motion, &own_out[own_count], own[own_count]);
        seconds += t;
        k = end;
    }
    free(in_geoms);
    if (err) {
        release_refs(own, own_count);
        return err;
    }
    if (ni || nug || own_count > 1) {
        err = commit_objects(s, own, own_count, &total, seconds, ni, 0, 0, fn);
    } else {
        install(s, own[0], &own_out[0], own_builder[0], seconds);
        s->own_stats = total;
    }
    if (!err) {
        s->motion_prims = motion;
        s->trees_built = own_count;
        s->quads = quads;
    }
    return err;
}

/* ---- one commit at a time ----
 * rtk.h forbids committing a scene from two threads at once, or while
 * another thread uses it, but an application that does must get an error,
 * not a heap corrupted by two builds writing one scene (rtk_scene_commit
 * from two threads crashed in the builder's node placement).  A commit
 * takes the scene's committing flag (compare and swap); a second commit
 * meanwhile, and an attach, a detach, a flag or quality change or a
 * query, fails with RTK_ERROR_INVALID_OPERATION and leaves the running
 * commit alone.  (A query already running when another thread starts a
 * commit is not seen: that would take an atomic operation on the scene
 * by every query.) */
rtk_error scene_not_committing(rtk_scene s, const char *fn)
{
    if (__builtin_expect(atomic_load_explicit(&s->committing, memory_order_relaxed) == COMMIT_IDLE, 1))
        return RTK_OK;
    return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION,
                    "%s: the scene is being committed by another thread (a scene must not be used while it is "
                    "committed; to commit it from several threads, use rtk_scene_join_commit)", fn);
}

/* commit() with the scene's progress callback, if any, wired in. */
static rtk_error commit_reporting(rtk_scene s, const rtk_bvh *tree, const char *fn)
{
    if (!s->progress)
        return commit(s, tree, fn);
    commit_progress cp = {.s = s};
    atomic_init(&cp.cancelled, 0);
    for (uint32_t i = 0; i < s->geom_count; i++) {
        const rtk_geometry g = s->geoms[i];
        if (g && g->enabled && is_mesh(g))
            cp.total += g->index.count * (g->type == RTK_GEOMETRY_TYPE_QUAD ? 2u : 1u);
    }
    s->commit_progress = &cp;
    const rtk_error err = commit(s, tree, fn);
    s->commit_progress = NULL;
    return err;
}

static rtk_error commit_alone(rtk_scene s, const rtk_bvh *tree, const char *fn)
{
    int idle = COMMIT_IDLE;
    if (!atomic_compare_exchange_strong(&s->committing, &idle, COMMIT_RUNNING))
        return scene_not_committing(s, fn);
    const rtk_error err = commit_reporting(s, tree, fn);
    atomic_store(&s->committing, COMMIT_IDLE);
    return err;
}

rtk_error rtk_scene_commit(rtk_scene s)
{
    CHECK_HANDLE(s, "rtk_scene_commit");
    return commit_alone(s, NULL, "rtk_scene_commit");
}

rtk_error rtk_scene_commit_bvh(rtk_scene s, const rtk_bvh *bvh)
{
    CHECK_HANDLE(s, "rtk_scene_commit_bvh");
    if (!bvh)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_commit_bvh: bvh is NULL");
    return commit_alone(s, bvh, "rtk_scene_commit_bvh");
}

/* The first thread to call it (no commit running) commits the scene, its
 * builds' parallel work going to a pool of its own that the threads
 * calling it meanwhile join: they run the build's tasks until the commit
 * ends, and return its result.  A thread that arrives while the commit is
 * ending waits for it to end and then starts a new one. */
rtk_error rtk_scene_join_commit(rtk_scene s)
{
    static const char fn[] = "rtk_scene_join_commit";
    CHECK_HANDLE(s, "rtk_scene_join_commit");
    pthread_mutex_lock(&s->join_lock);
    for (;;) {
        const int state = atomic_load(&s->committing);
        if (state == COMMIT_JOINED && !atomic_load(&s->join_end)) { /* join it */
            rtk_pool *pool = s->join_pool;
            const uint64_t gen = s->join_generation;
            s->joiners++;
            pthread_mutex_unlock(&s->join_lock);
            rtk_pool_serve(pool, &s->join_end);
            pthread_mutex_lock(&s->join_lock);
            while (s->join_generation == gen)
                pthread_cond_wait(&s->join_cond, &s->join_lock);
            const rtk_error err = s->join_result;
            if (--s->joiners == 0)
                pthread_cond_broadcast(&s->join_cond);
            pthread_mutex_unlock(&s->join_lock);
            return err;
        }
        if (state == COMMIT_JOINED) { /* ending: wait, then start anew */
            pthread_cond_wait(&s->join_cond, &s->join_lock);
            continue;
        }
        int idle = COMMIT_IDLE;
        if (!atomic_compare_exchange_strong(&s->committing, &idle, COMMIT_JOINED)) {
            pthread_mutex_unlock(&s->join_lock);
            return scene_not_committing(s, fn); /* an rtk_scene_commit is running */
        }
        break;
    }
    char msg[256] = "";
    rtk_pool *pool = rtk_pool_new_joinable(msg, sizeof msg);
    if (!pool) {
        atomic_store(&s->committing, COMMIT_IDLE);
        pthread_cond_broadcast(&s->join_cond);
        pthread_mutex_unlock(&s->join_lock);
        return rtk_fail(s->device, RTK_ERROR_OUT_OF_MEMORY, "%s: %s", fn, msg);
    }
    s->join_tasks = rtk_pool_tasks(pool);
    /* the builders size their work by the threads that may run it: as
     * many as the device would use (the result is the same on any number) */
    const uint32_t threads = rtk_device_get_thread_count(s->device);
    s->join_tasks.threads = threads > 1 ? threads : 2;
    atomic_store(&s->join_end, 0);
    s->join_pool = pool;
    pthread_mutex_unlock(&s->join_lock);

    const rtk_error err = commit_reporting(s, NULL, fn);

    pthread_mutex_lock(&s->join_lock);
    atomic_store(&s->join_end, 1);
    s->join_result = err;
    s->join_generation++;
    rtk_pool_wake(pool);
    pthread_cond_broadcast(&s->join_cond);
    while (s->joiners > 0) /* (they hold the pool until they leave it) */
        pthread_cond_wait(&s->join_cond, &s->join_lock);
    s->join_pool = NULL;
    atomic_store(&s->committing, COMMIT_IDLE);
    pthread_cond_broadcast(&s->join_cond);
    pthread_mutex_unlock(&s->join_lock);
    rtk_pool_free(pool);
    return err;
}

rtk_error rtk_scene_get_bvh(rtk_scene s, rtk_bvh *bvh)
{
    CHECK_HANDLE(s, "rtk_scene_get_bvh");
    if (scene_not_committing(s, "rtk_scene_get_bvh"))
        return RTK_ERROR_INVALID_OPERATION;
    if (!bvh || bvh->struct_size < sizeof *bvh)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                        "rtk_scene_get_bvh: bvh is NULL or its struct_size is not set");
    if (!s->accel)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "rtk_scene_get_bvh: the scene was never committed");
    const rtk_layout_io_entry *io = find_layout_io(s->device->backend, s->layout->id);
    if (!io)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "rtk_scene_get_bvh: backend %s cannot export layout %s",
                        s->device->backend->name, s->layout->name);
    /* Sizes from the build's counts: leaves counts blocks of up to four
     * triangles, at least one per leaf. */
    const rtk_build_output *o = &s->stats;
    rtk_bvh t;
    if (rtk_bvh_alloc(&t, 8, o->nodes, o->leaves, 4 * o->leaves))
        return rtk_fail(s->device, RTK_ERROR_OUT_OF_MEMORY, "rtk_scene_get_bvh: out of memory");
    int rc = io->export_tree(s->accel, &t);
    if (rc) {
        rtk_bvh_free(&t);
        return rtk_fail(s->device, as_error(rc),
                        "rtk_scene_get_bvh: the export failed");
    }
    *bvh = t;
    return RTK_OK;
}
