/* What the core's scene files share: geometries, scenes, the trees they
 * hold, and the functions one of them defines for the others.  Nothing here
 * is exported. */
#ifndef RTK_CORE_SCENE_INTERNAL_H
#define RTK_CORE_SCENE_INTERNAL_H

#include <string.h>

#include "internal.h"

/* Memory rtk allocates for a buffer, reference-counted: a compact scene's
 * BVH reads vertices from it, so the scene holds a reference until its next
 * commit and the memory outlives a buffer replaced or a geometry released
 * in the meantime. */
typedef struct blob {
    atomic_int refs;
    const rtk_memory *mem; /* the device's memory monitor's accounting, or NULL */
    size_t bytes;          /* reported to it */
    _Alignas(16) unsigned char data[];
} blob;

/* A built tree and what it needs to stay valid: a scene holds one, and so
 * does every scene that instances it (committed since), so a tree lives
 * until the last of them lets it go.  Never changed once made, except by a
 * refit (in place, like Embree's: commit the instancing scenes again). */
typedef struct accel_ref {
    atomic_int refs;
    const rtk_layout_entry *layout;
    rtk_accel *accel;
    rtk_intersect1_fn intersect1;
    rtk_occluded1_fn occluded1;
    /* A compact layout reads the vertex buffers: the rtk-allocated ones it
     * uses are held here. */
    blob **pinned;
    uint32_t pinned_count;
    /* A top level (bvh4.object): the trees of its objects. */
    struct accel_ref **children;
    uint32_t child_count;
    uint32_t depth; /* levels of instances below: 0 for a tree of triangles */
    float lower[3], upper[3];
    /* A top level: the user primitives its objects point to, and how many
     * there are in it and in the trees below (which crossings refuse), and
     * of those how many have no point query function (which closest
     * points refuse). */
    struct user_prim *user_prims;
    uint64_t user_deep, user_pointless_deep;
    /* This tree among every tree the process has made, from 1: what the
     * stream kernels' learnt state is kept for (stream.c), where the
     * address of a freed tree may come back for a new one. */
    uint64_t serial;
} accel_ref;

typedef struct buffer {
    const char *data; /* first element */
    size_t stride, count;
    blob *owned;      /* non-NULL when rtk allocated it */
} buffer;

struct rtk_geometry_s {
    atomic_int refs;
    rtk_device device;
    rtk_geometry_type type;
    /* Motion blur: time_steps vertex buffers (1 for every type but meshes
     * with motion), slot 0 in vertex and slots 1 .. time_steps - 1 in
     * steps[0 ..]. */
    unsigned time_steps;
    /* Changed whenever a buffer is set or updated: unique over all
     * geometries, so a scene can tell what changed since its last commit. */
    uint64_t vertex_version, index_version;
    rtk_build_quality quality;
    int enabled;
    int committed;
    void *user;
    /* Read at the scene's commit into its tree (rtk_geometry_attrs). */
    uint32_t mask;
    rtk_filter_fn intersect_filter, occluded_filter;
    /* What only one type has, in the space of the largest (an instance's):
     * read a member only for its type (is_mesh, g->type).  A forest's
     * million instances each saved 72 bytes of mesh buffers and 32 of user
     * callbacks, and 48 more of an inverse no longer kept. */
    union {
        struct { /* triangles and quads (is_mesh) */
            buffer vertex, index;
            buffer *steps;
        };
        struct { /* RTK_GEOMETRY_TYPE_USER */
            uint32_t user_count;
            rtk_bounds_fn bounds;
            rtk_user_query_fn user_intersect, user_occluded;
            rtk_point_query_fn user_point;
        };
        struct { /* RTK_GEOMETRY_TYPE_INSTANCE: the scene placed (retained)
                  * and the transform from its space (row-major 3x4), whose
                  * inverse the geometry's commit checks and the scene's
                  * commit computes (rtk_invert_3x4) */
            rtk_scene instanced;
            float xfm[12];
        };
    };
    /* The scenes the geometry is attached to (not retained; one entry per
     * attachment), so that setting an instance's scene can refuse a cycle
     * of references, which would never be freed: owner_one until a second
     * attachment, then an array of owner_cap. */
    rtk_scene *owners;
    uint32_t owner_count, owner_cap;
    rtk_scene owner_one;
};

static const float identity_3x4[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};

/* inv = the inverse of the affine map m (row-major 3x4), in double
 * precision (geometry/affine.h) and rounded; 0 when m is singular or the
 * inverse is not finite (geometry.c). */
int rtk_invert_3x4(const float *m, float *inv);

/* Triangles and quads: a mesh of vertex and index buffers (a quad is two
 * triangles to the builders, rtk.h). */
static inline int is_mesh(const struct rtk_geometry_s *g)
{
    return g->type == RTK_GEOMETRY_TYPE_TRIANGLE || g->type == RTK_GEOMETRY_TYPE_QUAD;
}

/* What a scene's tree was built over, per geometry slot, to tell at the
 * next commit whether a refit serves. */
typedef struct built_geom {
    rtk_geometry g; /* NULL: a free slot or a disabled geometry (never dereferenced) */
    uint64_t vertex_version, index_version;
    size_t prim_count, vertex_count;
    rtk_build_quality quality;
} built_geom;

/* One geometry's own tree in a dynamic scene. */
typedef struct dyn_tree {
    struct accel_ref *ref; /* NULL: none */
    built_geom b;
    rtk_build_output out;
} dyn_tree;

/* rtk_scene_s.committing */
enum { COMMIT_IDLE = 0, COMMIT_RUNNING = 1, COMMIT_JOINED = 2 };

struct rtk_scene_s {
    atomic_int refs;
    /* A commit in progress (COMMIT_*): a second commit, an attach or a
     * query from another thread meanwhile gets an error, not a corrupted
     * scene (commit.c). */
    atomic_int committing;
    rtk_device device;
    void *user; /* rtk_scene_set_user_data */
    unsigned flags;
    rtk_build_quality quality;
    rtk_geometry *geoms; /* by geomID; NULL for free slots */
    uint32_t geom_count;
    /* geoms has room for geom_cap; every slot below geom_free is taken, so
     * that attaching a million instances one by one does not search the
     * table a million times over */
    uint32_t geom_cap, geom_free;

    /* After a successful commit: the tree (ref), and ref->accel and
     * ref->layout at hand. */
    accel_ref *ref;
    rtk_accel *accel;
    const rtk_layout_entry *layout;
    const char *builder; /* the builder's name, or "tree" */
    rtk_intersect1_fn intersect1;
    rtk_occluded1_fn occluded1;
    /* For packets of 4, 8, 16 rays: the widest packet kernel that divides
     * the packet (width 1: none, ray by ray), per query. */
    struct packet_kernel {
        uint32_t width;
        rtk_intersectN_fn fn; /* rtk_occludedN_fn has the same type */
    } packet[2][3];
    /* For streams (stream.c): the layout's stream kernels, NULL when it has
     * none (the core then traces a stream ray by ray). */
    rtk_intersect_stream_fn intersect_stream;
    rtk_occluded_stream_fn occluded_stream;
    uint32_t stream_in_flight; /* rtk_scene_info.stream_in_flight */
    /* For closest points (point_query.c): the layout's kernel, NULL when it
     * has none. */
    rtk_closest_point_kernel_fn closest_point;
    rtk_build_output stats;
    double build_seconds;
    /* With instances: how many, and the build of the scene's own triangles
     * (zero when it has none); stats is then the top level's. */
    uint64_t instances;
    rtk_build_output own_stats;
    int two_level;     /* the tree is a top level (bvh4.object) */
    uint64_t motion_prims; /* triangles with motion blur in the scene's own trees */
    uint64_t quads;        /* of quad geometries, at the last commit (rtk_scene_info.quads) */
    uint64_t user_prims, user_skipped; /* user primitives in the top level, and left out */
    unsigned honoured; /* the flags the scene's trees honour */
    /* RTK_SCENE_FLAG_DYNAMIC: a tree per triangle geometry, by slot, kept
     * from commit to commit while its geometry is unchanged, refitted when
     * only a REFIT geometry's vertices moved; what the last commit did. */
    struct dyn_tree *dyn;
    uint32_t dyn_count;
    uint32_t trees_built, trees_refitted;
    /* A dynamic scene's top level: the commits since its build that
     * refitted it (commit.c, refit_top), and its build's SAH cost (what a
     * refit's is held against). */
    uint32_t top_refits;
    double top_sah_built;
    /* What the tree holds (see built_geom), and the refits since its build. */
    built_geom *built;
    uint32_t built_count;
    unsigned built_flags;
    rtk_build_quality built_quality;
    uint32_t refits;
    /* rtk_scene_join_commit: the threads that join a commit serve the
     * join pool's tasks (the build's) until it ends (join_end), then read
     * its result; join_lock guards the rest. */
    pthread_mutex_t join_lock;
    pthread_cond_t join_cond;
    rtk_pool *join_pool;
    atomic_int join_end;
    unsigned joiners;
    uint64_t join_generation;
    rtk_error join_result;
    rtk_task_system join_tasks;
    /* rtk_scene_set_progress_monitor's, and the commit in progress's
     * (commit.c: commit_progress), NULL when none */
    rtk_progress_fn progress;
    void *progress_user;
    struct commit_progress *commit_progress;
};

#define CHECK_HANDLE(h, fn)                                                                \
    do {                                                                                   \
        if (!(h))                                                                          \
            return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, fn ": " #h " is NULL");      \
    } while (0)


/* One user primitive in a top level: the accel its object points to. */
typedef struct user_prim {
    rtk_user_query_fn intersect, occluded;
    rtk_point_query_fn point;
    void *user;
    uint32_t geom_id, prim_id;
} user_prim;

/* A ray's validity (rtk.h), and whether it lies in the range the kernels
 * answer in: what every query checks before a kernel sees the ray. */
/* org and tnear, dir and time: the two runs of four floats rtk_ray starts with */
typedef float ray_floats4 __attribute__((vector_size(16)));
typedef int32_t ray_ints4 __attribute__((vector_size(16)));

/* The window of directions the kernels take as they are (the largest
 * component's magnitude), and the origins (every component's): rays
 * outside go through ray_range.c, which moves and rescales them. */
#define RAY_DIR_MIN 0x1p-8f
#define RAY_DIR_MAX 0x1p16f
#define RAY_ORG_MAX 0x1p36f

enum { RAY_INVALID, RAY_PLAIN, RAY_RANGE };

/* A ray outside that window: ray_check's test in comparisons alone, with
 * no branches, so that a loop over a packet's lanes (query.c,
 * packet_active; ray_arrays.c, trace_group) goes in vectors.  A NaN
 * fails every comparison and so counts as inside: finiteness is asked
 * apart. */
static inline int ray_out_of_window(float ox, float oy, float oz, float dx, float dy, float dz)
{
    const float ax = __builtin_fabsf(dx), ay = __builtin_fabsf(dy), az = __builtin_fabsf(dz);
    return (__builtin_fabsf(ox) > RAY_ORG_MAX) | (__builtin_fabsf(oy) > RAY_ORG_MAX) |
           (__builtin_fabsf(oz) > RAY_ORG_MAX) | (ax > RAY_DIR_MAX) | (ay > RAY_DIR_MAX) | (az > RAY_DIR_MAX) |
           ((ax < RAY_DIR_MIN) & (ay < RAY_DIR_MIN) & (az < RAY_DIR_MIN));
}

/* The lanes of v that are set (all ones), as bits 0..3. */
static inline unsigned ray_lanes(ray_ints4 v)
{
#if defined(__SSE__)
    return (unsigned)__builtin_ia32_movmskps((ray_floats4)v);
#else
    return (v[0] & 1u) | (v[1] & 2u) | (v[2] & 4u) | (v[3] & 8u);
#endif
}

static inline int ray_check(const rtk_ray *r)
{
    /* 0 * x is 0 for finite x and NaN for NaN or infinity: four lanes at
     * once (org and tnear, dir with time's lane cleared), on every call */
    ray_floats4 o, d;
    memcpy(&o, &r->org_x, sizeof o);
    memcpy(&d, &r->dir_x, sizeof d);
    d = (ray_floats4)((ray_ints4)d & (ray_ints4){-1, -1, -1, 0});
    const ray_ints4 finite = (0.0f * o + 0.0f * d) == 0.0f;
    if (!(ray_lanes(finite) == 15 && r->tnear >= 0.0f && r->tnear <= r->tfar && r->mask != 0))
        return RAY_INVALID;
    /* magnitudes (tnear's and time's lanes cleared), compared four at once:
     * an origin component above RAY_ORG_MAX or a direction component above
     * RAY_DIR_MAX, or all three direction components below RAY_DIR_MIN
     * (the largest one below it).  With scalar maxima here (and a query
     * built per call, query.c) rtk_intersect1 and rtk_occluded1 took 78
     * instructions a call before the kernel; now 61 (callgrind, rtktool
     * bench bunny.ply --only trace --rays primary,shadow --api single). */
    const ray_floats4 ao = (ray_floats4)((ray_ints4)o & (ray_ints4){0x7fffffff, 0x7fffffff, 0x7fffffff, 0});
    const ray_floats4 ad = (ray_floats4)((ray_ints4)d & 0x7fffffff);
    const unsigned big = ray_lanes((ao > RAY_ORG_MAX) | (ad > RAY_DIR_MAX));
    const unsigned tiny = ray_lanes(ad < RAY_DIR_MIN) & 7;
    return (big | (tiny == 7)) ? RAY_RANGE : RAY_PLAIN;
}

/* stream.c: the checks of an array of `count` structs of `size` bytes,
 * `stride` bytes apart, at p (named `what` in the message: "rays",
 * "points"): not NULL, aligned to 4 bytes, the stride no smaller than a
 * struct and a multiple of 4, not running past the address space.  RTK_OK
 * for a count of 0. */
RTK_INTERNAL rtk_error array_check(rtk_scene s, const void *p, size_t count, size_t stride, size_t size,
                                   const char *what, const char *fn);

/* stream.c: rays [0, count) of a checked array (rtk_rayhit, or rtk_ray
 * when occluded, `stride` bytes apart) traced as a stream on this thread:
 * the valid ones through the stream kernel (or ray by ray without one),
 * the invalid ones left as they are. */
RTK_INTERNAL void stream_trace(rtk_scene s, char *rays, size_t count, size_t stride, int occluded, const rtk_query *q);

/* ray_range.c: a ray of class RAY_RANGE traced, in place, with the answer
 * it would get were it inside the window (rtk.h, "the range rtk answers
 * in"); through the scene's single-ray kernels. */
RTK_INTERNAL void range_intersect1(rtk_scene s, rtk_rayhit *rh, const rtk_query *q);
RTK_INTERNAL void range_occluded1(rtk_scene s, rtk_ray *ray, const rtk_query *q);
/* range_intersect1, saying how the traced ray's distances t' map back to
 * the ray's: t = t' / scale + shift (crossings.c maps its filter's) */
RTK_INTERNAL void range_intersect1_map(rtk_scene s, rtk_rayhit *rh, const rtk_query *q, double *shift,
                                       double *scale);
/* either, for an rtk_ray (occluded) or an rtk_rayhit */
RTK_INTERNAL void range_trace1(rtk_scene s, void *ray, int occluded, const rtk_query *q);

/* An error for a call that must not overlap a commit of the scene (fn
 * names it), when one is running; RTK_OK otherwise. */
RTK_INTERNAL rtk_error scene_not_committing(rtk_scene s, const char *fn);

/* point_query.c: what the geometry queries (closest points, crossings)
 * refuse every scene for: NULL, being committed, never committed. */
RTK_INTERNAL rtk_error geometry_query_check(rtk_scene s, const char *fn);
/* point_query.c: what closest points refuse a scene for (rtk.h:
 * rtk_closest_point), those above included; occupancy asks it of scenes
 * with user geometry, whose distances it needs. */
RTK_INTERNAL rtk_error closest_point_check(rtk_scene s, const char *fn);
/* crossings.c: a user geometry's callback reported a hit it had not
 * offered (rtk_user_offer_hit) to query q: when q collects crossings, its
 * call fails, naming the geometry. */
RTK_INTERNAL void crossings_unoffered(const rtk_query *q, uint32_t geom_id);
/* A point within +-2^64 (rtk.h): its float is finite, and squared
 * distances stay far from double's range.  Inline: the batches' ordering
 * (point_order.c) asks for every point. */
static inline int xyz_in_range(double x, double y, double z)
{
    return __builtin_fabs(x) <= 0x1p64 && __builtin_fabs(y) <= 0x1p64 && __builtin_fabs(z) <= 0x1p64;
}
static inline int point_in_range(const rtk_point_query *q) { return xyz_in_range(q->x, q->y, q->z); }
/* The double at p, aligned to 4 bytes only (an application's arrays of
 * doubles with a stride that is a multiple of 4, not of 8): one load. */
static inline double load_f64(const char *p)
{
    double d;
    memcpy(&d, p, sizeof d);
    return d;
}
/* The points of a batch: its query records (q), or an application's
 * arrays of three floats or doubles (rtk_point_arrays: p, stride bytes
 * apart, is_double; the call's radius and time) when q is NULL. */
typedef struct point_src {
    const rtk_point_query *q;
    const char *p;
    size_t stride;
    int is_double;
    double radius;
    float time;
} point_src;
static inline void point_src_at(const point_src *s, size_t i, double xyz[3])
{
    if (s->q) {
        xyz[0] = s->q[i].x, xyz[1] = s->q[i].y, xyz[2] = s->q[i].z;
    } else if (s->is_double) {
        const char *p = s->p + i * s->stride;
        xyz[0] = load_f64(p), xyz[1] = load_f64(p + 8), xyz[2] = load_f64(p + 16);
    } else {
        float f[3];
        memcpy(f, s->p + i * s->stride, sizeof f);
        xyz[0] = f[0], xyz[1] = f[1], xyz[2] = f[2];
    }
}
/* Point i as a query: its record, or one made in *tmp from the arrays. */
static inline const rtk_point_query *point_src_query(const point_src *s, size_t i, rtk_point_query *tmp)
{
    if (s->q)
        return &s->q[i];
    double xyz[3];
    point_src_at(s, i, xyz);
    *tmp = (rtk_point_query){.x = xyz[0], .y = xyz[1], .z = xyz[2], .radius = s->radius, .time = s->time};
    return tmp;
}
/* point_query.c: why a query's point and time are not valid (rtk.h:
 * point_in_range, time in [0, 1]), or NULL; for closest points and
 * occupancy */
RTK_INTERNAL const char *point_fault(const rtk_point_query *q);
/* point_query.c: the checks of the point arrays' calls (rtk.h:
 * rtk_point_arrays) but for radius and the scene's own, and their points
 * as a source (src) */
RTK_INTERNAL rtk_error point_arrays_check(rtk_scene s, const rtk_point_arrays *a, size_t count, point_src *src,
                                          const char *fn);
/* point_query.c: one closest-point query, checked valid (rtk.h), through
 * the scene's kernel (s->closest_point, which must be there) */
RTK_INTERNAL void closest_point1(rtk_scene s, const rtk_point_query *q, rtk_point_hit *r);
/* point_order.c: the order to walk `count` points in (along a Morton
 * curve over the box of those in range) into order, a permutation of
 * [0, count); 0, or non-zero (order untouched) when out of memory or count
 * exceeds 2^32 - 1 */
RTK_INTERNAL int point_order(const point_src *src, size_t count, uint32_t *order);

/* scene.c */
RTK_INTERNAL void blob_release(blob *m);
RTK_INTERNAL void unpin_buffers(blob **pinned, uint32_t count);
RTK_INTERNAL void accel_ref_release(accel_ref *r);
/* The scene's tree and what goes with it let go: as never committed. */
RTK_INTERNAL void scene_drop_accel(rtk_scene s);
RTK_INTERNAL int scene_reaches(rtk_scene from, rtk_scene target);

/* geometry.c: a user primitive (the accel of its top-level object) traced
 * through the geometry's callbacks */
RTK_INTERNAL void user_intersect1(const rtk_accel *a, rtk_rayhit *rh, const rtk_query *q);
RTK_INTERNAL void user_occluded1(const rtk_accel *a, rtk_ray *ray, const rtk_query *q);
RTK_INTERNAL int user_point(const rtk_accel *a, const double p[3], double radius, float time, rtk_user_point *out);
RTK_INTERNAL void user_intersect_packet(const rtk_accel *a, const int32_t *active, void *packet, uint32_t width,
                                       const rtk_query *q);
RTK_INTERNAL void user_occluded_packet(const rtk_accel *a, const int32_t *active, void *packet, uint32_t width,
                                      const rtk_query *q);

#endif
