/* Scenes: their lifetime, attached geometry and information; the trees
 * they hold. */
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "scene_internal.h"

void blob_release(blob *m)
{
    if (!m || atomic_fetch_sub(&m->refs, 1) != 1)
        return;
    const rtk_memory *mem = m->mem;
    const size_t bytes = m->bytes;
    free(m);
    if (mem)
        mem->account(mem->user, -(int64_t)bytes);
}

void unpin_buffers(blob **pinned, uint32_t count)
{
    for (uint32_t i = 0; i < count; i++)
        blob_release(pinned[i]);
    free(pinned);
}

void accel_ref_release(accel_ref *r)
{
    if (!r || atomic_fetch_sub(&r->refs, 1) != 1)
        return;
    if (r->accel)
        r->layout->release(r->accel);
    unpin_buffers(r->pinned, r->pinned_count);
    for (uint32_t i = 0; i < r->child_count; i++)
        accel_ref_release(r->children[i]);
    free(r->children);
    free(r->user_prims);
    free(r);
}
/* ---- scene ---- */

rtk_error rtk_scene_new(rtk_device device, rtk_scene *out)
{
    CHECK_HANDLE(device, "rtk_scene_new");
    if (!out)
        return rtk_fail(device, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_new: out is NULL");
    *out = NULL;
    rtk_scene s = calloc(1, sizeof *s);
    if (!s)
        return rtk_fail(device, RTK_ERROR_OUT_OF_MEMORY, "rtk_scene_new: out of memory");
    atomic_init(&s->refs, 1);
    atomic_init(&s->committing, COMMIT_IDLE);
    atomic_init(&s->join_end, 0);
    pthread_mutex_init(&s->join_lock, NULL);
    pthread_cond_init(&s->join_cond, NULL);
    s->device = device;
    s->quality = RTK_BUILD_QUALITY_MEDIUM;
    rtk_device_retain(device);
    *out = s;
    return RTK_OK;
}

void rtk_scene_retain(rtk_scene s)
{
    if (s)
        atomic_fetch_add(&s->refs, 1);
}

void scene_drop_accel(rtk_scene s)
{
    accel_ref_release(s->ref);
    s->ref = NULL;
    s->instances = 0;
    s->two_level = 0;
    s->motion_prims = 0;
    s->quads = 0;
    s->user_prims = s->user_skipped = 0;
    for (uint32_t i = 0; i < s->dyn_count; i++)
        accel_ref_release(s->dyn[i].ref);
    free(s->dyn);
    s->dyn = NULL;
    s->dyn_count = 0;
    free(s->built);
    s->built = NULL;
    s->built_count = 0;
    s->refits = 0;
    s->top_refits = 0;
    s->accel = NULL;
    s->intersect1 = NULL;
    s->occluded1 = NULL;
    s->intersect_stream = NULL;
    s->occluded_stream = NULL;
    s->closest_point = NULL;
    s->stream_in_flight = 0;
}

/* Whether `target` is `from` or is placed, through instances attached to
 * it, by `from` (the scenes' current attachments, not their trees).  1 also
 * when out of memory (a caller then refuses). */
int scene_reaches(rtk_scene from, rtk_scene target)
{
    rtk_scene *seen = NULL;
    size_t n = 0, cap = 0, next = 0;
    int found = 0;
    for (rtk_scene at = from; at && !found;) {
        if (at == target) {
            found = 1;
            break;
        }
        for (uint32_t i = 0; i < at->geom_count && !found; i++) {
            const rtk_geometry g = at->geoms[i];
            if (!g || g->type != RTK_GEOMETRY_TYPE_INSTANCE || !g->instanced)
                continue;
            size_t k = 0;
            while (k < n && seen[k] != g->instanced)
                k++;
            if (k < n)
                continue; /* already queued */
            if (n == cap) {
                cap = cap ? 2 * cap : 16;
                rtk_scene *m = realloc(seen, cap * sizeof *m);
                if (!m) {
                    found = 1;
                    break;
                }
                seen = m;
            }
            seen[n++] = g->instanced;
        }
        at = next < n ? seen[next++] : NULL;
    }
    free(seen);
    return found;
}

/* Removes one attachment of g to s from g's owners. */
static void owner_remove(rtk_geometry g, rtk_scene s)
{
    for (uint32_t i = 0; i < g->owner_count; i++)
        if (g->owners[i] == s) {
            g->owners[i] = g->owners[--g->owner_count];
            return;
        }
}

void rtk_scene_release(rtk_scene s)
{
    if (!s || atomic_fetch_sub(&s->refs, 1) != 1)
        return;
    scene_drop_accel(s);
    for (uint32_t i = 0; i < s->geom_count; i++) {
        if (s->geoms[i])
            owner_remove(s->geoms[i], s);
        rtk_geometry_release(s->geoms[i]);
    }
    free(s->geoms);
    pthread_cond_destroy(&s->join_cond);
    pthread_mutex_destroy(&s->join_lock);
    rtk_device dev = s->device;
    free(s);
    rtk_device_release(dev);
}

rtk_error rtk_scene_set_flags(rtk_scene s, unsigned flags)
{
    CHECK_HANDLE(s, "rtk_scene_set_flags");
    if (scene_not_committing(s, "rtk_scene_set_flags"))
        return RTK_ERROR_INVALID_OPERATION;
    if (flags & ~(unsigned)RTK_SCENE_FLAGS_ALL)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_set_flags: unknown flag bits 0x%x",
                        flags & ~(unsigned)RTK_SCENE_FLAGS_ALL);
    s->flags = flags;
    return RTK_OK;
}

rtk_error rtk_scene_set_build_quality(rtk_scene s, rtk_build_quality q)
{
    CHECK_HANDLE(s, "rtk_scene_set_build_quality");
    if (scene_not_committing(s, "rtk_scene_set_build_quality"))
        return RTK_ERROR_INVALID_OPERATION;
    if (q == RTK_BUILD_QUALITY_REFIT)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                        "rtk_scene_set_build_quality: REFIT is a geometry's quality (rtk_geometry_set_build_quality)");
    if (q != RTK_BUILD_QUALITY_LOW && q != RTK_BUILD_QUALITY_MEDIUM && q != RTK_BUILD_QUALITY_HIGH)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_set_build_quality: unknown quality %d", (int)q);
    s->quality = q;
    return RTK_OK;
}

rtk_error rtk_scene_set_progress_monitor(rtk_scene s, rtk_progress_fn progress, void *user)
{
    CHECK_HANDLE(s, "rtk_scene_set_progress_monitor");
    if (scene_not_committing(s, "rtk_scene_set_progress_monitor"))
        return RTK_ERROR_INVALID_OPERATION;
    s->progress = progress;
    s->progress_user = progress ? user : NULL;
    return RTK_OK;
}

rtk_error rtk_scene_set_user_data(rtk_scene s, void *user)
{
    CHECK_HANDLE(s, "rtk_scene_set_user_data");
    s->user = user;
    return RTK_OK;
}

void *rtk_scene_get_user_data(rtk_scene s)
{
    if (!s) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_get_user_data: scene is NULL");
        return NULL;
    }
    return s->user;
}

rtk_error rtk_scene_attach_geometry(rtk_scene s, rtk_geometry g, uint32_t *geom_id)
{
    CHECK_HANDLE(s, "rtk_scene_attach_geometry");
    if (scene_not_committing(s, "rtk_scene_attach_geometry"))
        return RTK_ERROR_INVALID_OPERATION;
    if (!g)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_attach_geometry: geometry is NULL");
    if (g->device != s->device)
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                        "rtk_scene_attach_geometry: the geometry belongs to another device");
    if (g->type == RTK_GEOMETRY_TYPE_INSTANCE && g->instanced && scene_reaches(g->instanced, s))
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION,
                        "rtk_scene_attach_geometry: the instance places this scene, or a scene that contains it: a "
                        "cycle");
    if (g->owner_count == g->owner_cap) {
        const uint32_t cap = 2 * g->owner_cap < 4 ? 4 : 2 * g->owner_cap;
        rtk_scene *o = cap > g->owner_cap ? realloc(g->owners == &g->owner_one ? NULL : g->owners, cap * sizeof *o)
                                          : NULL;
        if (o && g->owners == &g->owner_one)
            o[0] = g->owner_one;
        if (!o)
            return rtk_fail(s->device, RTK_ERROR_OUT_OF_MEMORY, "rtk_scene_attach_geometry: out of memory");
        g->owners = o;
        g->owner_cap = cap;
    }
    /* the lowest free geomID, as before: slots below geom_free are taken */
    uint32_t id = s->geom_free;
    while (id < s->geom_count && s->geoms[id])
        id++;
    if (id == s->geom_count) {
        if (s->geom_count == RTK_INVALID_GEOMETRY_ID - 1)
            return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "rtk_scene_attach_geometry: too many geometries");
        if (s->geom_count == s->geom_cap) {
            const uint32_t most = RTK_INVALID_GEOMETRY_ID - 1;
            const uint32_t cap = s->geom_cap < 8 ? 8 : s->geom_cap > most / 2 ? most : 2 * s->geom_cap;
            rtk_geometry *n = realloc(s->geoms, (size_t)cap * sizeof *n);
            if (!n)
                return rtk_fail(s->device, RTK_ERROR_OUT_OF_MEMORY, "rtk_scene_attach_geometry: out of memory");
            s->geoms = n;
            s->geom_cap = cap;
        }
        s->geoms[s->geom_count++] = NULL;
    }
    rtk_geometry_retain(g);
    s->geoms[id] = g;
    s->geom_free = id + 1;
    g->owners[g->owner_count++] = s;
    if (geom_id)
        *geom_id = id;
    return RTK_OK;
}

rtk_error rtk_scene_detach_geometry(rtk_scene s, uint32_t id)
{
    CHECK_HANDLE(s, "rtk_scene_detach_geometry");
    if (scene_not_committing(s, "rtk_scene_detach_geometry"))
        return RTK_ERROR_INVALID_OPERATION;
    if (id >= s->geom_count || !s->geoms[id])
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_detach_geometry: no geometry %u", id);
    owner_remove(s->geoms[id], s);
    rtk_geometry_release(s->geoms[id]);
    s->geoms[id] = NULL;
    if (id < s->geom_free)
        s->geom_free = id;
    return RTK_OK;
}

rtk_geometry rtk_scene_get_geometry(rtk_scene s, uint32_t id)
{
    if (!s) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_get_geometry: s is NULL");
        return NULL;
    }
    if (id >= s->geom_count || !s->geoms[id]) {
        rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT, "rtk_scene_get_geometry: no geometry %u", id);
        return NULL;
    }
    return s->geoms[id];
}

rtk_error rtk_scene_get_info(rtk_scene s, rtk_scene_info *info)
{
    CHECK_HANDLE(s, "rtk_scene_get_info");
    if (scene_not_committing(s, "rtk_scene_get_info"))
        return RTK_ERROR_INVALID_OPERATION;
    /* Callers built against the 0.1.0 struct (without packet_width) are served too. */
    if (!info || info->struct_size < offsetof(rtk_scene_info, packet_width))
        return rtk_fail(s->device, RTK_ERROR_INVALID_ARGUMENT,
                        "rtk_scene_get_info: info is NULL or its struct_size is not set");
    if (!s->accel)
        return rtk_fail(s->device, RTK_ERROR_INVALID_OPERATION, "rtk_scene_get_info: the scene was never committed");
    const rtk_build_output *o = &s->stats;
    size_t keep = info->struct_size;
    memset(info, 0, keep < sizeof *info ? keep : sizeof *info);
    info->struct_size = keep;
    info->flags = s->flags;
    info->flags_not_honoured = s->flags & ~s->honoured;
    info->quality = s->quality;
    info->builder = s->builder;
    info->layout = s->layout->name;
    /* with instances: the triangles and bytes of the scene's own tree too */
    const rtk_build_output *tris = s->two_level ? &s->own_stats : o;
    info->triangles = tris->prims;
    info->triangles_skipped = tris->prims_skipped;
    info->triangles_degenerate = tris->prims_degenerate;
    info->nodes = o->nodes;
    info->leaves = o->leaves;
    info->depth = o->depth;
    info->bytes = o->bytes + (s->two_level ? s->own_stats.bytes : 0);
    info->bytes_per_triangle = tris->prims ? (double)info->bytes / (double)tris->prims : 0.0;
    info->build_seconds = s->build_seconds;
    info->sah_cost = o->sah_cost;
    memcpy(info->bounds_lower, o->lower, sizeof o->lower);
    memcpy(info->bounds_upper, o->upper, sizeof o->upper);
    if (keep >= offsetof(rtk_scene_info, packet_width) + sizeof info->packet_width)
        for (int w = 0; w < 3; w++)
            info->packet_width[w] = s->packet[0][w].width;
    if (keep >= offsetof(rtk_scene_info, build_threads) + sizeof info->build_threads)
        info->build_threads = o->threads ? o->threads : 1;
    if (keep >= offsetof(rtk_scene_info, references) + sizeof info->references)
        info->references = tris->refs ? tris->refs : tris->prims;
    if (keep >= offsetof(rtk_scene_info, refits) + sizeof info->refits)
        info->refits = s->dyn ? s->trees_refitted : s->refits;
    if (keep >= offsetof(rtk_scene_info, instances) + sizeof info->instances)
        info->instances = s->instances;
    if (keep >= offsetof(rtk_scene_info, trees_built) + sizeof info->trees_built)
        info->trees_built = s->dyn || !s->refits ? s->trees_built : 0;
    if (keep >= offsetof(rtk_scene_info, triangles_motion) + sizeof info->triangles_motion)
        info->triangles_motion = s->motion_prims;
    if (keep >= offsetof(rtk_scene_info, user_primitives_skipped) + sizeof info->user_primitives_skipped) {
        info->user_primitives = s->user_prims;
        info->user_primitives_skipped = s->user_skipped;
    }
    if (keep >= offsetof(rtk_scene_info, quads) + sizeof info->quads)
        info->quads = s->quads;
    if (keep >= offsetof(rtk_scene_info, stream_in_flight) + sizeof info->stream_in_flight)
        info->stream_in_flight = s->stream_in_flight;
    if (keep >= offsetof(rtk_scene_info, triangles_out_of_range) + sizeof info->triangles_out_of_range)
        info->triangles_out_of_range = tris->prims_out_of_range;
    if (keep >= offsetof(rtk_scene_info, top_level_refits) + sizeof info->top_level_refits)
        info->top_level_refits = s->two_level ? s->top_refits : 0;
    return RTK_OK;
}
