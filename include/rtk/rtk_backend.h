/*
 * rtk backend interface.  Installed so that backends can be built out of tree.
 *
 * A backend is a shared object named librtk_backend_<name>.so that exports two
 * symbols (with <name> its own name, so several backends can be linked
 * statically into one program without clashing):
 *
 *   const rtk_backend_header rtk_backend_<name>_header;      data, read first
 *   int rtk_backend_<name>_negotiate(const rtk_backend_offer *,
 *                                    rtk_backend_answer *);  the entry point
 *
 * The core reads the header without running any backend code, checks the
 * magic, the header size and the CPU requirements against the CPU, and only
 * then calls negotiate.  Negotiation works both ways: the core offers the
 * newest and oldest interface versions it speaks, the backend answers with
 * the version it will use (or a non-zero return to refuse), and the core
 * rejects anything outside its range.
 *
 * Rules: structs carry their own size and only ever grow at the end; readers
 * never read past the size the writer declared; tables end with a zeroed entry;
 * no #if inside these structs.  Code compiled for an ISA must own no
 * constructors and no mutable globals: the header is plain data.
 */
#ifndef RTK_RTK_BACKEND_H
#define RTK_RTK_BACKEND_H

#include <stddef.h>
#include <stdint.h>

#include "rtk.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The interface version this header describes.  Version 2 (rtk 0.2.0)
 * gave every kernel the query argument (rtk_query) and the builders the
 * geometries' attributes (rtk_build_input.attrs): masks and filters.  A
 * version-1 backend's kernels have another signature, so a core of
 * version 2 refuses it. */
#define RTK_BACKEND_INTERFACE_VERSION 2
#define RTK_BACKEND_MAGIC 0x424b5452u /* "RTKB" little-endian */
#define RTK_BACKEND_NAME_MAX 32

/* ---- read before any backend code runs ----------------------------------- */
typedef struct rtk_backend_header {
    uint32_t magic;       /* RTK_BACKEND_MAGIC */
    uint32_t struct_size; /* sizeof(rtk_backend_header) as the backend knows it */
    char name[RTK_BACKEND_NAME_MAX]; /* must match the file name */
    uint32_t level;       /* preference: higher wins among usable backends */
    /* The newest interface version the backend speaks, for the core's
     * message when negotiation fails (0 before rtk 0.2.0: version 1). */
    uint32_t interface_version;
    uint64_t cpu_requires; /* RTK_CPU_* bits, cumulative, OS state included */
} rtk_backend_header;

/* ---- negotiation ---------------------------------------------------------- */
typedef struct rtk_backend_offer {
    uint32_t struct_size;
    uint32_t version_max;  /* newest interface version the core speaks */
    uint32_t version_min;  /* oldest it accepts */
    uint32_t reserved;
    uint64_t cpu_features; /* the features in force */
} rtk_backend_offer;

struct rtk_backend_desc;
typedef struct rtk_backend_answer {
    uint32_t struct_size;
    uint32_t version;                   /* chosen by the backend */
    const struct rtk_backend_desc *desc; /* the backend's tables */
} rtk_backend_answer;

/* Declares a function type and a matching prototype helper, so every
 * implementation can be declared through its typedef and checked. */
#define RTK_BACKEND_FN(ret, name, args) typedef ret(*name##_fn) args

/* Returns 0 and fills answer to accept, non-zero to refuse. */
RTK_BACKEND_FN(int, rtk_backend_negotiate, (const rtk_backend_offer *offer, rtk_backend_answer *answer));

/* ---- what a backend provides ------------------------------------------------*/
typedef struct rtk_accel rtk_accel; /* a built acceleration structure, opaque to the core */

/* One triangle mesh handed to a builder.  Pointers are already offset to the
 * first element; indices have been checked in range by the core. */
typedef struct rtk_build_geometry {
    const void *vertices;
    size_t vertex_stride;
    size_t vertex_count;
    const void *indices;
    size_t index_stride;
    size_t prim_count;
    uint32_t geom_id;
    uint32_t flags; /* RTK_BUILD_GEOMETRY_* (was reserved, 0, before rtk 0.1.0's refit) */
} rtk_build_geometry;

/* A user primitive's answer to rtk_query.user_point: its point nearest to
 * p, the application's u, v and normal there, and its ids. */
typedef struct rtk_user_point {
    double closest[3];
    float u, v;
    float normal[3];
    uint32_t prim_id, geom_id;
} rtk_user_point;

/* The core's: user primitive prim's nearest point to p within radius (in
 * its space) into *out, 1; or 0 (rtk_query.user_point). */
typedef int (*rtk_user_point_fn)(const rtk_accel *prim, const double p[3], double radius, float time,
                                 rtk_user_point *out);

/* What a query carries beside its rays, from the core to the kernels (and
 * from a top level to the trees of its objects).  Never NULL. */
typedef struct rtk_query {
    const rtk_query_context *context; /* the application's (rtk_intersect1_ctx ...), or NULL */
    uint32_t inst_id; /* the outermost instance the ray is inside, else RTK_INVALID_GEOMETRY_ID */
    uint32_t flags;   /* RTK_QUERY_FLAG_* (was reserved: 0 from a core before them) */
    /* Added after rtk 0.2.0 (interface version 2 still), read only when
     * flags has RTK_QUERY_FLAG_FILTER: a filter every candidate hit of
     * the width-1 kernels goes through after its geometry's own (a hit
     * counts only when both accept), with this query's context, in the
     * geometry's space as a geometry filter sees it (instances included).
     * The core's queries for every crossing (rtk_count_intersections ...)
     * collect through it; a backend that honours it says so
     * (RTK_BACKEND_CAP_QUERY_FILTER). */
    rtk_filter_fn filter;
    /* Added after rtk 0.2.0 (interface version 2 still), read only when
     * flags has RTK_QUERY_FLAG_STREAM_STATE, only by the stream kernels:
     * RTK_STREAM_STATE_SIZE bytes, aligned to 8, where a stream kernel
     * keeps what it learnt (how the rays go fastest, traverse_stream.h)
     * for its next call.  The core keeps one per thread and tree, one for
     * closest and one for any hits, zeroed when the thread first streams
     * through that tree; only ever a choice of speed, so a kernel must
     * give every ray the same answer whatever it finds there.  A kernel
     * that does not know the flag passes over it. */
    void *stream_state;
    /* Added after rtk 0.2.0 (interface version 2 still), read only when
     * flags has RTK_QUERY_FLAG_USER_POINT, only by the closest-point
     * kernels: at a user primitive of a top level (an object with
     * intersect_packet, whose accel is the core's), the kernel asks it
     * for its nearest point to p (in the level's space, within radius
     * there) and takes that point into the scene's space and measures it
     * as a triangle's.  A backend that honours it says so
     * (RTK_BACKEND_CAP_USER_POINTS); without it the core refuses closest
     * points on scenes with user geometry. */
    rtk_user_point_fn user_point;
} rtk_query;
#define RTK_QUERY_FLAG_FILTER 1u
#define RTK_QUERY_FLAG_STREAM_STATE 2u
#define RTK_QUERY_FLAG_USER_POINT 4u

#define RTK_STREAM_STATE_SIZE 64

RTK_BACKEND_FN(void, rtk_intersect1, (const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *query));
RTK_BACKEND_FN(void, rtk_occluded1, (const rtk_accel *accel, rtk_ray *ray, const rtk_query *query));

/* One object of a two-level scene (a scene with instances): an accel this
 * backend built before (another scene's, or the scene's own triangles'),
 * placed by an affine map.  Its kernels are called with the ray taken into
 * the object's space: org' = M org + t, dir' = M dir, where world_to_object
 * is the row-major 3x4 [M | t]; t along the ray is the same in both spaces.
 * A hit inside gets hit.instID = inst_id unless that is
 * RTK_INVALID_GEOMETRY_ID (the scene's own triangles); the normal stays in
 * the object's space, as Embree reports it. */
/* A packet of `width` rays (4, 8 or 16) through one object of a top
 * level, as rtk_intersectN_fn with the width given: for the core's user
 * primitives, which take the packet whole. */
RTK_BACKEND_FN(void, rtk_object_packet, (const rtk_accel *object, const int32_t *active, void *packet,
                                         uint32_t width, const rtk_query *query));

typedef struct rtk_build_object {
    const rtk_accel *accel;
    rtk_intersect1_fn intersect1;
    rtk_occluded1_fn occluded1;
    float lower[3], upper[3];  /* the object's box in the scene's space (conservative, from the core) */
    float world_to_object[12]; /* row-major 3x4 [M | t] */
    uint32_t inst_id;
    uint32_t flags;            /* RTK_BUILD_OBJECT_* */
    uint32_t mask;             /* the instance's mask (rtk_geometry_set_mask): a ray enters only if ray.mask & mask */
    uint32_t reserved;
    /* Interface version 2: where not NULL (a user primitive, always
     * RTK_BUILD_OBJECT_IDENTITY), the top level's packet kernels hand it
     * their packets whole, with the lanes that enter its box active;
     * else they trace the object lane by lane with intersect1 / occluded1. */
    rtk_object_packet_fn intersect_packet, occluded_packet;
} rtk_build_object;

/* world_to_object is the identity: the ray goes in unchanged. */
#define RTK_BUILD_OBJECT_IDENTITY 1u

/* The geometry deforms (RTK_BUILD_QUALITY_REFIT): builders keep its
 * zero-area triangles in the tree, as leaf lanes that can never be hit, so
 * that a refit can give them their area back without a build. */
#define RTK_BUILD_GEOMETRY_DEFORMS 1u

typedef struct rtk_build_input {
    uint32_t struct_size;
    uint32_t geometry_count;
    const rtk_build_geometry *geometries;
    uint32_t quality; /* rtk_build_quality */
    uint32_t layout;  /* the layout id to produce */
    uint32_t threads; /* threads the builder may use (>= 1): tasks->threads, or 1 */
    uint32_t reserved;
    /* Added after rtk 0.1.0 (still interface version 1: read only when
     * struct_size covers it).  Where the builder runs its parallel work;
     * NULL or absent: everything on the calling thread.  The builder's
     * output must not depend on it. */
    const rtk_task_system *tasks;
    /* Added after rtk 0.1.0 (the same way): the objects of a two-level
     * scene, for the objects builder (rtk_objects_entry); geometry_count is
     * then 0.  Objects with an empty or non-finite box are left out. */
    uint32_t object_count;
    uint32_t reserved2;
    const rtk_build_object *objects;
    /* Added after rtk 0.1.0 (the same way): motion blur, for the motion
     * builders (rtk_backend_desc.motion_builders) only.  Every geometry has
     * time_steps (>= 2) vertex buffers, the positions at times
     * k / (time_steps - 1) of the ray time range [0, 1]:
     * time_vertices[g * time_steps + k] is geometry g's step k (step 0 is
     * also geometries[g].vertices), all of vertex_count vertices. */
    uint32_t time_steps;
    uint32_t reserved3;
    const struct rtk_build_vertices *time_vertices;
    /* Interface version 2: geometry_count attributes, parallel to
     * geometries; NULL when no geometry has any (every mask all ones, no
     * filter, no quads), and then the kernels test nothing beyond the
     * ray's flags. */
    const struct rtk_geometry_attrs *attrs;
    /* Added after rtk 0.2.0 (interface version 2, read only when struct_size
     * covers it): NULL, or a tree this backend made earlier that nothing
     * will read again (the previous tree of the scene being rebuilt, which
     * the caller releases after this build, whether it succeeds or not).
     * The builder may take its memory for the new tree, which then needs no
     * fresh pages (the system zeroes those at first touch: a sixth of a low
     * quality rebuild of dragon.ply on 2 threads).  It reports that it did
     * in rtk_build_output.recycled. */
    rtk_accel *recycle;
    /* Added after rtk 0.2.0 (interface version 2, read only when struct_size
     * covers it): NULL, or the commit's progress.  The builder calls
     * progress(progress_user, done) with the share of its work done (0 to
     * 1), from any of its threads and several at once, at points where it
     * can still stop without having written into `recycle`; when a call
     * returns 0 the builder stops, frees what it made and returns
     * RTK_ERROR_CANCELLED. */
    int (*progress)(void *user, double done);
    void *progress_user;
    /* Added after rtk 0.2.0 (the same way): NULL, or where the builder
     * reports the memory it takes for the build and the tree (the device's
     * memory monitor).  The tree keeps a copy for its release. */
    const struct rtk_memory *memory;
} rtk_build_input;

/* Memory accounting (rtk_build_input.memory): account(user, bytes) with
 * bytes > 0 before taking that many bytes (0 refuses them: the allocation
 * fails), with bytes < 0 after giving them back.  Any thread. */
typedef struct rtk_memory {
    int (*account)(void *user, int64_t bytes);
    void *user;
} rtk_memory;

/* What a triangle geometry asks of the kernels beyond its triangles
 * (rtk.h: masks, filters), one per rtk_build_input.geometries entry.  The
 * builder copies them into the accel (an accel lives on in the scenes that
 * instance it): they are the accel's until it is released. */
typedef struct rtk_geometry_attrs {
    uint32_t mask;
    uint32_t flags; /* RTK_GEOMETRY_ATTR_* */
    rtk_filter_fn intersect_filter; /* NULL: none */
    rtk_filter_fn occluded_filter;
    void *user;                     /* rtk_geometry_set_user_data's, for the filters */
} rtk_geometry_attrs;

/* The geometry's triangles are the halves of quads (rtk.h: quads): its
 * triangle 2q is (v0, v1, v3) of quad q, 2q + 1 is (v2, v3, v1).  The
 * kernels report a hit on either as primID q with u, v over the quad
 * (for the second half, 1 - u and 1 - v), to the filters as well. */
#define RTK_GEOMETRY_ATTR_QUAD 1u

/* One vertex buffer of a time step: already offset to the first vertex. */
typedef struct rtk_build_vertices {
    const void *vertices;
    size_t stride;
} rtk_build_vertices;

typedef struct rtk_build_output {
    uint32_t struct_size;
    uint32_t depth;
    rtk_accel *accel;
    uint64_t prims;         /* primitives in the structure */
    uint64_t prims_skipped; /* left out: a NaN or infinite vertex */
    uint64_t prims_degenerate; /* left out: zero area */
    uint64_t nodes, leaves;
    uint64_t bytes;
    double sah_cost;
    float lower[3], upper[3];
    char message[160]; /* why a build failed */
    /* Added after rtk 0.1.0 (written only when struct_size covers it): the
     * threads the build ran its parallel work on (in->threads, or 1 for a
     * builder that ignores in->tasks). */
    uint32_t threads;
    /* Added after rtk 0.1.0 (the same way): triangle references in the
     * leaves, more than prims where spatial splits put a triangle in
     * several leaves; 0 from an older backend means prims. */
    uint64_t refs;
    /* Added after rtk 0.2.0 (the same way): 1 when the builder wrote into
     * in->recycle's memory; after a failed build that tree is then gone. */
    uint32_t recycled;
    uint32_t reserved;
    /* Added after rtk 0.2.0 (the same way): left out for lying outside
     * rtk's range (rtk.h): a coordinate beyond +-2^36, or area too small
     * (a deforming geometry's tiny triangles are kept, never hit, and
     * counted in prims_degenerate instead); not counted in prims_skipped
     * or prims_degenerate. */
    uint64_t prims_out_of_range;
} rtk_build_output;

RTK_BACKEND_FN(int, rtk_build, (const rtk_build_input *in, rtk_build_output *out));
RTK_BACKEND_FN(void, rtk_accel_release, (rtk_accel *accel));
/* Packet kernels of width N (4, 8 or 16): `packet` is an rtk_rayhitN
 * (intersect) or rtk_rayN (occluded), aligned to 4*N bytes; `active` holds N
 * int32 lanes, -1 where the lane is active and its ray valid (the core has
 * checked validity, as for the single-ray kernels), 0 elsewhere, aligned like
 * the packet.  At least one lane is active.  Inactive lanes must not be
 * written. */
RTK_BACKEND_FN(void, rtk_intersectN, (const rtk_accel *accel, const int32_t *active, void *packet,
                                       const rtk_query *query));
RTK_BACKEND_FN(void, rtk_occludedN, (const rtk_accel *accel, const int32_t *active, void *packet,
                                      const rtk_query *query));

/* Streams (added after rtk 0.2.0; interface version 2 still: a core that
 * knows them looks for kernel entries of width RTK_KERNEL_WIDTH_STREAM, an
 * older one passes over them, and a layout without them gets its streams
 * traced ray by ray through the width-1 kernel).  `count` single rays, each
 * an rtk_rayhit (intersect) or rtk_ray (occluded) the core has checked
 * valid (as for rtk_intersect1_fn); each must get exactly the answer the
 * layout's width-1 kernel gives it, whatever order they are traced in. */
RTK_BACKEND_FN(void, rtk_intersect_stream, (const rtk_accel *accel, rtk_rayhit *const *rays, uint32_t count,
                                             const rtk_query *query));
RTK_BACKEND_FN(void, rtk_occluded_stream, (const rtk_accel *accel, rtk_ray *const *rays, uint32_t count,
                                            const rtk_query *query));
#define RTK_KERNEL_WIDTH_STREAM 0xffffffffu

/* Closest points (added after rtk 0.2.0; interface version 2 still: a core
 * that knows them looks for kernel entries of query
 * RTK_QUERY_CLOSEST_POINT, width 1, an older one passes over them, and a
 * scene whose layout has none answers RTK_ERROR_UNSUPPORTED).  The core
 * fills the state: the query point and time (checked as rtk.h says),
 * best2 the squared radius, the result's ids RTK_INVALID_GEOMETRY_ID,
 * reserved 0.  The kernel looks for the triangle nearest to the point, in
 * the same space (through the objects of a top level, in the space of the
 * accel it is handed), and wherever it finds one nearer than sqrt(best2)
 * it lowers best2 to its squared distance and writes the result: the
 * point, u, v, the unit normal, primID, geomID and instID (the outermost
 * instance entered, or query->inst_id); distance is left for the core to
 * set.  Of triangles at exactly the same distance it keeps the least
 * instID, then geomID, then primID (rtk.h, rtk_point_hit), whatever order
 * it meets them in. */
typedef struct rtk_point_state {
    double p[3];
    double best2;
    float time;
    uint32_t reserved; /* the kernel's own between its calls for one query (the core sets it 0) */
    rtk_point_hit *result;
} rtk_point_state;
RTK_BACKEND_FN(void, rtk_closest_point_kernel, (const rtk_accel *accel, rtk_point_state *state,
                                                const rtk_query *query));

enum rtk_query_kind {
    RTK_QUERY_NONE = 0, /* ends a table */
    RTK_QUERY_INTERSECT = 1,
    RTK_QUERY_OCCLUDED = 2,
    RTK_QUERY_CLOSEST_POINT = 3, /* width 1: fn.closest_point */
};

/* Layout ids are global so the core can name and choose them. */
#define RTK_LAYOUT_LIST(X)                                                                                             \
    X(RTK_LAYOUT_BVH4_TRIANGLE4, 1, "bvh4.triangle4")                                                                  \
    X(RTK_LAYOUT_BVH8_TRIANGLE4, 2, "bvh8.triangle4")                                                                  \
    X(RTK_LAYOUT_BVH4_TRIANGLE4I, 3, "bvh4.triangle4i")                                                                \
    X(RTK_LAYOUT_BVH4_OBJECT, 4, "bvh4.object")                                                                       \
    X(RTK_LAYOUT_BVH4_TRIANGLE4MB, 5, "bvh4.triangle4mb")                                                              \
    X(RTK_LAYOUT_BVH4_TRIANGLE4V, 6, "bvh4.triangle4v")                                                                \
    X(RTK_LAYOUT_BVH8_TRIANGLE4V, 7, "bvh8.triangle4v")                                                                \
    X(RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, 8, "bvh4.triangle4i.robust")                                                  \
    X(RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST, 9, "bvh4.triangle4mb.robust")                                                \
    X(RTK_LAYOUT_BVH8_TRIANGLE4MB, 10, "bvh8.triangle4mb")                                                             \
    X(RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST, 11, "bvh8.triangle4mb.robust")
enum rtk_layout_id {
    RTK_LAYOUT_NONE = 0,
#define RTK_X_(id, value, text) id = value,
    RTK_LAYOUT_LIST(RTK_X_)
#undef RTK_X_
};

typedef struct rtk_builder_entry {
    const char *name;       /* NULL ends the table */
    uint32_t qualities;     /* bit (1 << rtk_build_quality) for each quality it serves */
    uint32_t layout;        /* the layout it produces */
    rtk_build_fn build;
} rtk_builder_entry;

typedef struct rtk_layout_entry {
    uint32_t id;            /* 0 ends the table */
    uint32_t scene_flags;   /* scene flags this layout honours */
    const char *name;
    rtk_accel_release_fn release;
} rtk_layout_entry;

typedef struct rtk_kernel_entry {
    uint32_t layout;        /* 0 ends the table */
    uint32_t query;         /* enum rtk_query_kind */
    uint32_t width;         /* rays per call: 1 (required), or 4, 8, 16 (optional packet kernels), or
                             * RTK_KERNEL_WIDTH_STREAM (optional stream kernels) */
    uint32_t in_flight;     /* a stream kernel's rays in flight per thread (0 elsewhere; was reserved) */
    union {
        rtk_intersect1_fn intersect1; /* width 1 */
        rtk_occluded1_fn occluded1;
        rtk_intersectN_fn intersectN; /* width 4, 8, 16 */
        rtk_occludedN_fn occludedN;
        rtk_intersect_stream_fn intersect_stream; /* width RTK_KERNEL_WIDTH_STREAM */
        rtk_occluded_stream_fn occluded_stream;
        rtk_closest_point_kernel_fn closest_point; /* query RTK_QUERY_CLOSEST_POINT */
        void (*any)(void);
    } fn;
} rtk_kernel_entry;

/* Converting a layout to and from the layout-neutral rtk_bvh (rtk.h).
 *
 * export: the core sizes the arrays from the accel's rtk_build_output:
 * nodes * 8 slots (enough for any node width), leaves + 1 leaf_first
 * entries and 4 * leaves prims (`leaves` counts blocks, so that is enough);
 * the function sets width, root and the three counts and fills the arrays.
 *
 * import: builds the layout in->layout over in->geometries from `tree`,
 * which the core has checked (rtk_bvh_check, and every referenced triangle
 * exists, can be hit and lies inside its boxes); the function checks what
 * is the layout's own (the width, triangles per leaf, sizes) and fills
 * `out` as a builder does.  A tree exported from an accel imports to the
 * same bytes. */
RTK_BACKEND_FN(int, rtk_accel_export, (const rtk_accel *accel, rtk_bvh *tree));
RTK_BACKEND_FN(int, rtk_accel_import, (const rtk_build_input *in, const rtk_bvh *tree, rtk_build_output *out));

typedef struct rtk_layout_io_entry {
    uint32_t layout;        /* 0 ends the table */
    uint32_t reserved;
    rtk_accel_export_fn export_tree;
    rtk_accel_import_fn import_tree;
} rtk_layout_io_entry;

/* Refitting: after the vertex positions of the geometries an accel was
 * built over have changed (the same geometries, triangles and flags, as
 * the core checks), the accel keeps its tree and takes the new positions:
 * leaf data rewritten, every box recomputed bottom-up.  Only geometries
 * flagged RTK_BUILD_GEOMETRY_DEFORMS may have moved; the others are as
 * they were at the build.  `in` describes the geometries as for the build
 * (vertex buffers may have moved in memory), `out` holds the accel's
 * rtk_build_output on entry and is updated (bounds, SAH cost, counts of
 * left-out triangles, threads).
 *
 * Returns 0 on success; RTK_REFIT_NEEDS_BUILD when the triangles that go
 * in the tree are no longer the ones it holds (a vertex became or stopped
 * being NaN or infinite): the accel may then be partly rewritten, and the
 * core must build afresh or drop it.  Any other non-zero value is an
 * rtk_error, with the accel untouched.
 *
 * Added after rtk 0.2.0: the top level (the objects entry's layout) may
 * have a refit entry too.  `in` then holds the objects (object_count,
 * objects) as for its build, with new boxes: the same trees (refitted in
 * place, so their nodes are where they were), kernels, masks, ids, flags
 * and transforms, which the function checks.  It refits only a top level
 * built with quality RTK_BUILD_QUALITY_REFIT (which keeps what a refit
 * needs), and returns RTK_REFIT_NEEDS_BUILD with the accel untouched when
 * it was not or the objects differ. */
#define RTK_REFIT_NEEDS_BUILD (-1)
RTK_BACKEND_FN(int, rtk_accel_refit, (rtk_accel *accel, const rtk_build_input *in, rtk_build_output *out));

typedef struct rtk_layout_refit_entry {
    uint32_t layout;        /* 0 ends the table */
    uint32_t reserved;
    rtk_accel_refit_fn refit;
} rtk_layout_refit_entry;

/* The top level of two-level scenes: a builder over rtk_build_input.objects
 * producing `layout` (which has its width-1 kernels in the kernel table;
 * the core traces packets through it ray by ray).  Not in the builders
 * table: a triangle scene never gets this layout.  With quality
 * RTK_BUILD_QUALITY_REFIT the tree keeps what its refit needs (see
 * rtk_accel_refit); every other quality builds the same tree. */
typedef struct rtk_objects_entry {
    uint32_t layout;
    uint32_t reserved;
    rtk_build_fn build;
} rtk_objects_entry;

typedef struct rtk_backend_desc {
    uint32_t struct_size;
    uint32_t reserved;
    const char *name;
    const rtk_builder_entry *builders;
    const rtk_layout_entry *layouts;
    const rtk_kernel_entry *kernels;
    /* Added after rtk 0.1.0 (still interface version 1: read only when
     * struct_size covers it; NULL or absent = no tree export or import). */
    const rtk_layout_io_entry *layout_io;
    /* Added after rtk 0.1.0 (the same way; NULL or absent = no refit, the
     * core rebuilds instead). */
    const rtk_layout_refit_entry *layout_refit;
    /* Added after rtk 0.1.0 (the same way; NULL or absent = no instances:
     * the core refuses to commit a scene that has some). */
    const rtk_objects_entry *objects;
    /* Added after rtk 0.1.0 (the same way; NULL or absent = no motion
     * blur: the core refuses to commit a scene with geometry of several
     * time steps).  Builders over rtk_build_input.time_steps > 1, whose
     * layouts read rtk_ray.time; never used for a scene without motion. */
    const rtk_builder_entry *motion_builders;
    /* Added after rtk 0.2.0 (the same way; absent = 0): RTK_BACKEND_CAP_*. */
    uint64_t caps;
} rtk_backend_desc;
/* The width-1 kernels honour rtk_query.filter (RTK_QUERY_FLAG_FILTER). */
#define RTK_BACKEND_CAP_QUERY_FILTER 1u
/* The closest-point kernel honours rtk_query.user_point. */
#define RTK_BACKEND_CAP_USER_POINTS 2u

#define RTK_BACKEND_EXPORT __attribute__((visibility("default")))

#ifdef __cplusplus
}
#endif
#endif
