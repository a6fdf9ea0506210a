/*
 * rtk — ray-tracing kernels for CPUs.  The public C API.
 *
 * Every fallible call returns an rtk_error (RTK_OK == 0 is success) and records
 * a message on its device; releasing NULL is a no-op; the library never exits,
 * aborts or prints unless asked to (verbose=1).
 *
 * Ray semantics (intersect1 / occluded1)
 * --------------------------------------
 * A ray is valid when org and dir are finite, tnear is finite and >= 0, and
 * tfar >= tnear (tfar may be +inf).  A hit at distance t counts when
 * tnear <= t <= tfar (both ends included).  An invalid ray (any NaN, an
 * infinite origin or direction component, tnear < 0, tnear > tfar) is not an
 * error: it hits nothing, and the ray/hit is left untouched.  A zero direction
 * hits nothing.  Direction components of +0.0 and -0.0 are both allowed.
 *
 * intersect1: on a hit, ray.tfar becomes t and the hit record is filled
 * (Ng is the unnormalised geometric normal cross(v1-v0, v2-v0); u and v are the
 * barycentric weights of v1 and v2); on a miss nothing is written, so set
 * hit.geomID = RTK_INVALID_GEOMETRY_ID before the call.  When two triangles are
 * hit at exactly the same t, either may be reported.
 *
 * occluded1: on any hit, ray.tfar becomes -inf; on a miss nothing is written.
 *
 * ray.time is the ray's time, in [0, 1], read only by geometry with motion
 * blur (rtk_geometry_set_time_step_count): such geometry is hit only by
 * rays whose time lies in [0, 1] (a NaN or other time misses it; the rest
 * of the scene is hit as usual).  ray.mask is tested against the
 * geometries' masks (all ones unless set; a ray of mask 0 hits nothing) and
 * ray.flags asks for face culling: see "masks, face culling and filters".
 */
#ifndef RTK_RTK_H
#define RTK_RTK_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define RTK_VERSION_MAJOR 0
#define RTK_VERSION_MINOR 2
#define RTK_VERSION_PATCH 0
/* MAJOR*10000 + MINOR*100 + PATCH, comparable with rtk_version(). */
#define RTK_VERSION (RTK_VERSION_MAJOR * 10000 + RTK_VERSION_MINOR * 100 + RTK_VERSION_PATCH)
#define RTK_VERSION_STRING "0.2.0"

#if defined(_WIN32)
#define RTK_API
#else
#define RTK_API __attribute__((visibility("default")))
#endif

/* The version of the library actually loaded (compare with RTK_VERSION). */
RTK_API int rtk_version(void);
RTK_API const char *rtk_version_string(void);

/* ---- errors ---------------------------------------------------------------
 * One list generates the values, the names and the parser.  Codes are never
 * renumbered; new ones are added at the end. */
#define RTK_ERROR_LIST(X)                                                           \
    X(RTK_OK, 0, "no error")                                                        \
    X(RTK_ERROR_UNKNOWN, 1, "unknown error")                                        \
    X(RTK_ERROR_INVALID_ARGUMENT, 2, "invalid argument")                            \
    X(RTK_ERROR_INVALID_OPERATION, 3, "invalid operation")                          \
    X(RTK_ERROR_OUT_OF_MEMORY, 4, "out of memory")                                  \
    X(RTK_ERROR_INVALID_CONFIG, 5, "invalid configuration string")                  \
    X(RTK_ERROR_NO_BACKEND, 6, "no usable backend")                                 \
    X(RTK_ERROR_UNSUPPORTED_CPU, 7, "the CPU lacks a required instruction set")     \
    X(RTK_ERROR_INVALID_GEOMETRY, 8, "invalid geometry")                            \
    X(RTK_ERROR_CANCELLED, 9, "cancelled by the progress callback")                 \
    X(RTK_ERROR_MEMORY_REFUSED, 10, "memory refused by the memory monitor")         \
    X(RTK_ERROR_UNSUPPORTED, 11, "not supported for this scene or backend")

typedef enum rtk_error {
#define RTK_X_(name, value, text) name = value,
    RTK_ERROR_LIST(RTK_X_)
#undef RTK_X_
} rtk_error;

/* "RTK_ERROR_INVALID_ARGUMENT" etc.; "RTK_ERROR_UNKNOWN" for codes it does not know. */
RTK_API const char *rtk_error_name(rtk_error code);

/* ---- CPU ------------------------------------------------------------------ */
/* Feature bits of rtk_cpu_features().  AVX-class bits are set only when the OS
 * also saves the matching register state (OSXSAVE + XGETBV). */
#define RTK_CPU_FEATURE_LIST(X)       \
    X(SSE, 0, "sse")                  \
    X(SSE2, 1, "sse2")                \
    X(SSE3, 2, "sse3")                \
    X(SSSE3, 3, "ssse3")              \
    X(SSE41, 4, "sse4.1")             \
    X(SSE42, 5, "sse4.2")             \
    X(POPCNT, 6, "popcnt")            \
    X(AVX, 7, "avx")                  \
    X(F16C, 8, "f16c")                \
    X(FMA, 9, "fma")                  \
    X(AVX2, 10, "avx2")               \
    X(BMI1, 11, "bmi1")               \
    X(BMI2, 12, "bmi2")               \
    X(LZCNT, 13, "lzcnt")             \
    X(AVX512F, 14, "avx512f")         \
    X(AVX512DQ, 15, "avx512dq")       \
    X(AVX512CD, 16, "avx512cd")       \
    X(AVX512BW, 17, "avx512bw")       \
    X(AVX512VL, 18, "avx512vl")

enum {
#define RTK_X_(name, bit, text) RTK_CPU_##name = (1ull << (bit)),
    RTK_CPU_FEATURE_LIST(RTK_X_)
#undef RTK_X_
};

/* The features of this CPU usable under this OS. */
RTK_API uint64_t rtk_cpu_features(void);
/* Writes "sse sse2 ... avx2" for the set bits into buf (always NUL-terminated);
 * returns the length the full text needs. */
RTK_API size_t rtk_cpu_features_string(uint64_t features, char *buf, size_t size);

/* ---- handles -------------------------------------------------------------- */
typedef struct rtk_device_s *rtk_device;
typedef struct rtk_scene_s *rtk_scene;
typedef struct rtk_geometry_s *rtk_geometry;

#define RTK_INVALID_GEOMETRY_ID ((uint32_t)-1)

/* ---- device ----------------------------------------------------------------
 * config: NULL or "" for defaults, else comma-separated key=value pairs:
 *   isa=NAME        use exactly this backend (scalar, sse41, avx, avx2)
 *   max_isa=NAME    use the best backend not above this level
 *   threads=N       threads for builds (0 = all cores; see rtk_task_system)
 *   verbose=N       0 silent; 1 one line per backend file and per decision
 *                   on stderr; 2 also scene build statistics
 *   backend_path=D  search only these ':'-separated directories for backends
 *   builder=NAME    build every scene with this builder whatever its quality
 *                   (morton, sah-binned, sah-spatial; Embree's tri_builder)
 *   layout=NAME     build every scene into this layout whatever its flags
 *                   (bvh4.triangle4, bvh8.triangle4 where vectors are 8
 *                   wide, bvh4.triangle4i; Embree's tri_accel)
 *   motion_layout=NAME  the same for motion-blurred triangles (layout=
 *                   applies to static ones only): bvh4.triangle4mb,
 *                   bvh8.triangle4mb where vectors are 8 wide, and their
 *                   .robust ones; Embree's tri_accel_mb
 *                   A builder or layout the active backend lacks fails
 *                   device creation with a message listing what it has.
 * The environment variable RTK_ISA (same values as isa=) narrows the choice
 * further; RTK_BACKEND_PATH (':'-separated) is searched before the directory
 * next to librtk and the compiled-in install directory.
 *
 * On failure *out is NULL and the reason can be read with
 * rtk_device_get_error(NULL) / rtk_device_get_error_message(NULL) on the same
 * thread. */
RTK_API rtk_error rtk_device_new(const char *config, rtk_device *out);
RTK_API void rtk_device_retain(rtk_device device);
RTK_API void rtk_device_release(rtk_device device);

/* The first error since the last call (sticky), then cleared. */
RTK_API rtk_error rtk_device_get_error(rtk_device device);
/* The message of the most recent error ("" when none); valid until the next
 * call on this device from this thread. */
RTK_API const char *rtk_device_get_error_message(rtk_device device);

typedef void (*rtk_error_callback)(void *user, rtk_error code, const char *message);
RTK_API rtk_error rtk_device_set_error_callback(rtk_device device, rtk_error_callback cb, void *user);

/* ---- thread safety ------------------------------------------------------------
 * - Queries (rtk_intersect*, rtk_occluded*, with or without _ctx) on a
 *   committed scene may run from any number of threads at once, also while
 *   other scenes are committed.
 * - A scene must not be committed, have geometry attached or detached, or
 *   have its flags, quality or user data set while any other call uses it
 *   (queries included); different scenes may be committed from different
 *   threads at once (their builds share the device's threads).  Where an
 *   application does it anyway, rtk tells rather than corrupting the
 *   scene: while a commit runs, a second rtk_scene_commit of the scene
 *   from another thread, an attach, a detach, a flag or quality change,
 *   rtk_scene_get_info and every query of the scene fail with
 *   RTK_ERROR_INVALID_OPERATION ("the scene is being committed by
 *   another thread") and leave the running commit unharmed.  A query
 *   that was already running when another thread began the commit is not
 *   seen (rtk would have to count the queries in flight, an atomic
 *   operation on the scene per query): that stays the application's bug.
 *   Threads that want to share one scene's build call
 *   rtk_scene_join_commit instead (below).
 * - A geometry must not be changed (buffers, masks, filters, callbacks,
 *   user data, commit) while a scene that holds it is being committed.
 * - Retain and release may be called from any thread; the last release
 *   must not overlap other calls on the object.
 * - rtk_device_get_error_message is per thread; error callbacks run on the
 *   thread of the failing call; filters and user-geometry callbacks run on
 *   the querying thread.
 *
 * ---- threads ----------------------------------------------------------------
 * Builds run on the device's own pool of worker threads (pthreads), sized by
 * threads= (0: one per CPU the process may run on), created at the first
 * build that can use them and joined by rtk_device_release.  Scenes may be
 * committed from several application threads at once; their builds share
 * the pool.  A build's result (the BVH, byte for byte, and so every hit)
 * does not depend on the thread count or on how the work is scheduled.
 *
 * An application with a task system of its own can hand it to rtk instead,
 * so the two do not compete for the cores.  rtk then runs all its parallel
 * work through parallel_for and starts no threads. */
typedef void (*rtk_task_fn)(void *data, uint32_t index);
typedef struct rtk_task_system {
    uint32_t struct_size; /* sizeof(rtk_task_system) */
    uint32_t threads;     /* threads the system runs tasks on (>= 1): rtk sizes its work by it */
    void *user;           /* passed back to parallel_for */
    /* Calls fn(data, i) once for every i in [0, count), on any threads and
     * in any order (the caller's thread included), and returns when all
     * calls have returned.  rtk never calls it from inside fn, may call it
     * from several threads at once (one per scene being committed), and
     * never with count 0. */
    void (*parallel_for)(void *user, uint32_t count, rtk_task_fn fn, void *data);
} rtk_task_system;

/* Builds on this device run through *tasks (copied) from now on; NULL goes
 * back to rtk's own threads.  Not while a scene of the device is being
 * committed. */
RTK_API rtk_error rtk_device_set_task_system(rtk_device device, const rtk_task_system *tasks);
/* The number of threads builds on this device may use. */
RTK_API uint32_t rtk_device_get_thread_count(rtk_device device);

/* ---- threads of a batch (added after rtk 0.2.0) ----
 * The batch calls (rtk_intersect_batch, rtk_occluded_batch,
 * rtk_intersect_arrays, rtk_occluded_arrays, rtk_closest_point_batch,
 * rtk_count_intersections, rtk_list_intersections, rtk_occupancy) made
 * from the calling thread run on at most n threads from now on, the
 * calling thread among them: 1 runs them on the calling thread alone; 0,
 * the default, on every thread of the device (rtk_device_get_thread_count),
 * as does a limit above that.  The limit is the calling thread's own, for
 * every device (as OpenMP's omp_set_num_threads): other threads' calls
 * keep theirs, so an application that runs batches from several threads
 * of its own can give each a share of the cores.  It is what Open3D's
 * per-call nthreads means, and rtk's Python module sets it around each
 * call.  No answer depends on it; builds are not limited by it.  Returns
 * the limit it replaces. */
RTK_API uint32_t rtk_set_batch_threads(uint32_t n);

/* ---- memory monitor (added after rtk 0.2.0) ----
 * A device's memory monitor sees the memory rtk takes for the device's
 * scenes (Embree's rtcSetDeviceMemoryMonitorFunction), and may refuse it:
 * monitor(user, bytes, post) is called with bytes > 0 (post 0) before rtk
 * takes that many bytes, and returning 0 refuses them: the call that
 * needed them fails with RTK_ERROR_MEMORY_REFUSED (a commit leaving the
 * scene's previous tree as it was: a device with a monitor builds every
 * tree in fresh memory, never its scene's old tree's); and with bytes < 0
 * (post 1) after rtk has given bytes back (the return value is then
 * ignored).  What it sees is what grows with the scene: geometry buffers
 * rtk allocates (rtk_geometry_set_new_buffer), the trees' node, leaf and
 * attribute arrays, the builders' working arrays (references, codes, node
 * arenas), the motion builder's copies of the time steps, the top level's
 * nodes and objects, and a refit's scratch; not a build's fixed
 * bookkeeping (a few kilobytes) nor the stream calls' lists of pointers.
 * Every byte reported taken is reported given back when freed, so the
 * running sum is what the device holds.  The monitor is called from the
 * threads builds run on, several at once.  Set it before the device's
 * scenes are committed (memory taken before is not reported when freed);
 * NULL removes it. */
typedef int (*rtk_memory_monitor_fn)(void *user, int64_t bytes, int post);
RTK_API rtk_error rtk_device_set_memory_monitor(rtk_device device, rtk_memory_monitor_fn monitor, void *user);

/* Name of the backend this device runs on ("avx2", ...). */
RTK_API const char *rtk_device_get_backend_name(rtk_device device);

typedef enum rtk_backend_status {
    RTK_BACKEND_STATUS_ACTIVE = 0,   /* loaded and used by this device */
    RTK_BACKEND_STATUS_USABLE = 1,   /* loaded fine, not chosen (a better one was, or the config narrowed it out) */
    RTK_BACKEND_STATUS_REJECTED = 2, /* could not be used: see reason */
} rtk_backend_status;

typedef struct rtk_backend_info {
    size_t struct_size;    /* set by the caller to sizeof(rtk_backend_info) */
    const char *path;      /* the file */
    const char *name;      /* backend name, or "" when it could not be read */
    rtk_backend_status status;
    const char *reason;    /* why rejected or not chosen; "" for the active one */
    uint32_t interface_version; /* negotiated; 0 when negotiation did not happen */
    uint64_t cpu_requires; /* RTK_CPU_* bits the backend needs */
} rtk_backend_info;

/* Every backend file the device looked at, in search order. */
RTK_API size_t rtk_device_get_backend_count(rtk_device device);
RTK_API rtk_error rtk_device_get_backend_info(rtk_device device, size_t index, rtk_backend_info *info);
/* The directories searched, ':'-separated. */
RTK_API const char *rtk_device_get_search_path(rtk_device device);

/* ---- scenes ----------------------------------------------------------------*/
typedef enum rtk_scene_flags {
    RTK_SCENE_FLAG_NONE = 0,
    /* Smallest memory: leaves hold vertex indices (layout bvh4.triangle4i,
     * about half the bytes), and traversal reads the vertices from the
     * geometries' vertex buffers, so those must stay valid and unchanged
     * until the scene is committed again or released (buffers rtk
     * allocated are kept alive by the scene until then; shared ones are
     * the application's to keep).  Slower than the default layout. */
    RTK_SCENE_FLAG_COMPACT = 1 << 0,
    /* Watertight: a ray through an edge or vertex shared by triangles of
     * a closed mesh always hits one of them, and exactly one where the
     * mesh crosses the ray once (so a filter collecting every hit counts
     * crossings right: inside/outside parity); the default intersector may
     * let it pass between, or hit two (rays aimed at the edges of real
     * meshes leak there at 0.4-7%, docs/benchmarks/accuracy.md).  A ray exactly
     * through an edge or vertex is decided as if moved by an infinitesimal
     * step in a fixed direction across the ray (a rasteriser's fill rule),
     * so a lone triangle's boundary is half open: such a ray hits it or
     * not by the edge's direction.  The leaves keep the
     * vertices themselves (layouts bvh8/bvh4.triangle4v, the default's
     * memory; with COMPACT bvh4.triangle4i.robust) and the intersector is
     * Woop, Benthin and Wald's (2013), with double precision where a float
     * edge function is exactly zero or underflows; boxes are padded.
     * Tested on closed meshes from 1e-20 to 1e8 in size and up to 1e6 from
     * the origin (tests/test_robust.c).  Costs 2-5% of the default's
     * rate (rtktool trace on the dragon and San Miguel, 1 thread;
     * docs/benchmarks/accuracy.md, "Shared edges").  Moving geometry gets
     * bvh8.triangle4mb.robust (bvh4 on the scalar backend; the vertices
     * interpolated to the ray's time, then the same test), and packets
     * the same test ray by ray within the packet kernels. */
    RTK_SCENE_FLAG_ROBUST = 1 << 1,
    /* Geometry changes often: two levels, a tree per triangle geometry
     * (built with the geometry's own quality: low the Morton builder,
     * medium and high SAH; REFIT built at medium, then refitted when only
     * its vertices moved) and a top level over them (and over the scene's
     * instances), so a commit rebuilds only the trees of the geometries
     * changed since the last one (rtk_scene_info.trees_built, .refits).
     * Tracing is slower than through one tree over everything
     * (docs/benchmarks/two-levels.md measures it beside Embree's
     * two-level mode). */
    RTK_SCENE_FLAG_DYNAMIC = 1 << 2,
} rtk_scene_flags;
#define RTK_SCENE_FLAGS_ALL (RTK_SCENE_FLAG_COMPACT | RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_DYNAMIC)

/* A scene's quality picks the builder (named in rtk_scene_info.builder):
 * low is the Morton builder, the fastest build for a tree somewhat slower
 * to trace (for geometry that changes every frame); medium (the default)
 * the binned SAH builder; high the same with spatial splits.
 *
 * REFIT is a geometry's quality (rtk_geometry_set_build_quality), never a
 * scene's: the geometry deforms, its vertices move while its triangles
 * stay.  When the only changes since a scene's last commit are new vertex
 * positions of REFIT geometries (rtk_geometry_update_buffer, or a new
 * vertex buffer of the same size), rtk_scene_commit keeps the tree and
 * refits it: leaves rewritten, boxes recomputed bottom-up, in a fraction
 * of a build's time.  Such a geometry's zero-area triangles stay in the
 * tree (never hit) for a refit to give them area.  The answers are a
 * rebuild's; the tree's shape, and so its trace speed, stays that of the
 * last build, which suits motion that keeps neighbours together
 * (animation, skinning), not geometry that scatters.  A motion-blurred
 * REFIT geometry refits the same way from its vertices at every time step
 * (the same step count).  Anything else (a
 * vertex that becomes or stops being NaN or infinite, geometry attached,
 * detached, enabled or disabled, other buffers, a geometry's or the
 * scene's quality, the scene's flags) makes the commit build afresh.
 * rtk_scene_info.refits counts the refits since that build. */
typedef enum rtk_build_quality {
    RTK_BUILD_QUALITY_LOW = 0,
    RTK_BUILD_QUALITY_MEDIUM = 1,
    RTK_BUILD_QUALITY_HIGH = 2,
    RTK_BUILD_QUALITY_REFIT = 3,
} rtk_build_quality;

RTK_API rtk_error rtk_scene_new(rtk_device device, rtk_scene *out);
RTK_API void rtk_scene_retain(rtk_scene scene);
RTK_API void rtk_scene_release(rtk_scene scene);
/* Flags this version does not honour yet are accepted, listed in
 * rtk_scene_info.flags_not_honoured, and announced with verbose=1. */
RTK_API rtk_error rtk_scene_set_flags(rtk_scene scene, unsigned flags);
RTK_API rtk_error rtk_scene_set_build_quality(rtk_scene scene, rtk_build_quality quality);
/* The application's pointer, kept with the scene (added in rtk 0.2.0). */
RTK_API rtk_error rtk_scene_set_user_data(rtk_scene scene, void *user);
RTK_API void *rtk_scene_get_user_data(rtk_scene scene);

/* Attaches (and retains) a geometry; its geomID is written to *geom_id. */
RTK_API rtk_error rtk_scene_attach_geometry(rtk_scene scene, rtk_geometry geometry, uint32_t *geom_id);
RTK_API rtk_error rtk_scene_detach_geometry(rtk_scene scene, uint32_t geom_id);
RTK_API rtk_geometry rtk_scene_get_geometry(rtk_scene scene, uint32_t geom_id);

/* ---- the range rtk answers in (added after rtk 0.2.0) ----
 * Every query answers as documented for
 *  - vertex coordinates within +-RTK_COORD_LIMIT (2^36, about 6.9e10);
 *  - triangles whose cross product of edges (v1 - v0) x (v2 - v0) has a
 *    component of at least 2^-80 in magnitude (in double precision): a
 *    triangle of sides about 1e-12 and up, or a needle no thinner than
 *    that per unit of length (only triangles near the origin can be
 *    smaller: at coordinates of 1 two vertices are at least 2^-24 apart);
 *  - any finite ray.
 * Triangles outside the range are left out at commit (never hit) and
 * counted in rtk_scene_info.triangles_out_of_range (and in the device's
 * log at verbose >= 1), as NaN vertices are: before, triangles of edges
 * 1e-19 and smaller or 1e20 and larger were counted in the tree and never
 * hit.  Rays need nothing: one whose direction's largest component is
 * below 2^-8 or above 2^16 is traced with its direction scaled by a power
 * of two (and tnear, tfar and the hit distance by its inverse), and one
 * whose origin lies beyond +-2^36 from where it enters the scene's bounds
 * (the origin moved there along the ray, rounded to float), so a direction
 * of (0, 0, -1e-38) hits a triangle at t = 1e38 and a ray from 1e20 away
 * hits what it points at; a hit farther than FLT_MAX (a direction of
 * 2^-140 toward a triangle 1 away) cannot be reported and is a miss.  Filters and user geometry called for such a ray
 * see it moved and scaled (at its own address), and it is restored before
 * the query returns.  The SAH cost is computed in double and stays finite
 * for any finite scene.  Instances: each scene's own triangles are
 * checked in its own coordinates; a ray is checked in the top level's. */
#define RTK_COORD_LIMIT 68719476736.0f

/* Validates every attached, enabled, committed geometry and builds the BVH.
 * Fails (and names the geometry and triangle) on an index out of range.
 * Triangles with a NaN or infinite vertex are left out of the BVH (they can
 * never be hit) and counted in rtk_scene_info.triangles_skipped; triangles of
 * zero area (collinear or coincident vertices) likewise, counted in
 * rtk_scene_info.triangles_degenerate.
 *
 * A scene of triangles alone (no instances, user geometry or motion blur)
 * committed again, whose tree no other scene holds (no instance of it in a
 * committed scene), builds its new tree in the old one's memory, which then
 * needs no fresh pages: geometry rebuilt every frame pays for its memory
 * once.  So does each rebuilt geometry's tree in a RTK_SCENE_FLAG_DYNAMIC
 * scene that no other scene holds.  A commit that fails after its build has started
 * (out of memory) may leave such a scene without a tree, as if never
 * committed; a failed check of the geometry (an index out of range)
 * leaves the previous tree in place. */
RTK_API rtk_error rtk_scene_commit(rtk_scene scene);

/* Commits the scene with the help of every thread that calls this for it
 * meanwhile (Embree's rtcJoinCommitScene): the first caller starts the
 * commit, whose builds run their parallel work on the threads that have
 * joined (not on the device's pool or task system), and every caller
 * returns when the commit is done, with its result.  A thread arriving
 * after the commit has ended starts a new one.  RTK_ERROR_INVALID_OPERATION
 * while an rtk_scene_commit of the scene runs.  (Added after rtk 0.2.0.) */
RTK_API rtk_error rtk_scene_join_commit(rtk_scene scene);

/* ---- build progress (added after rtk 0.2.0) ----
 * A progress callback sees a scene's commits as they go, and may cancel
 * one (Embree's rtcSetSceneProgressMonitorFunction): progress(user, done)
 * is called with the share of the commit done, from 0 (before anything
 * is built) towards 1, from the threads the build runs on, several at
 * once, at points where the build can still stop; returning 0 cancels
 * the commit, which stops there, frees what it made and fails with
 * RTK_ERROR_CANCELLED, leaving the scene's previous tree as it was (a
 * scene with a progress callback builds its new tree in fresh memory,
 * never in its old tree's, for that).  The one exception: a dynamic
 * scene whose commit had already refitted a geometry's tree (refits work
 * in place) is left without a tree, as after a failed build.  A refit
 * reports once, before it starts.  NULL removes the callback.  The
 * callback must not call rtk on the scene. */
typedef int (*rtk_progress_fn)(void *user, double done);
RTK_API rtk_error rtk_scene_set_progress_monitor(rtk_scene scene, rtk_progress_fn progress, void *user);

typedef struct rtk_scene_info {
    size_t struct_size;          /* set by the caller to sizeof(rtk_scene_info) */
    unsigned flags;              /* as requested */
    unsigned flags_not_honoured; /* requested but not implemented in this version */
    rtk_build_quality quality;
    const char *builder;         /* "morton", "sah-binned", "sah-spatial"; "tree" after rtk_scene_commit_bvh */
    const char *layout;          /* e.g. "bvh8.triangle4", "bvh4.triangle4i" (compact) */
    uint64_t triangles;          /* in the BVH */
    uint64_t triangles_skipped;  /* left out: a NaN or infinite vertex */
    /* Zero area (never hit): left out, except that REFIT geometries keep
     * theirs in the tree (so counted in triangles as well), in case a
     * refit gives them their area back. */
    uint64_t triangles_degenerate;
    uint64_t nodes, leaves;      /* inner nodes; leaf blocks of up to 4 triangles (a leaf holds 1 to 4) */
    uint32_t depth;
    uint64_t bytes;              /* BVH nodes + leaf primitives */
    double bytes_per_triangle;
    double build_seconds;
    double sah_cost;
    float bounds_lower[3], bounds_upper[3];
    /* Rays per packet-kernel call for rtk_intersect4/8/16 (and occluded):
     * N when the backend traces the packet whole, less when it splits it,
     * 1 when it has no packet kernel (the rays as a stream, or ray by
     * ray). */
    uint32_t packet_width[3];
    /* Added after rtk 0.1.0: the threads the last build could run on
     * (rtk_device_get_thread_count when the builder is parallel, else 1). */
    uint32_t build_threads;
    /* Added after rtk 0.1.0: triangle references in the leaves.  Equal to
     * triangles, except after spatial splits (high quality), which put a
     * triangle that crosses a split plane in a leaf on each side, each
     * with the box of its own part: at most 1.2 times triangles. */
    uint64_t references;
    /* Added after rtk 0.1.0: the commits since the tree was built that
     * refitted it (RTK_BUILD_QUALITY_REFIT) instead of building; 0 when
     * the last commit built it.  build_seconds is then the refit's time. */
    uint32_t refits;
    /* Added after rtk 0.1.0: instances in the scene's top level (0: a
     * one-level scene).  A scene with instances reports its top level in
     * layout ("bvh4.object"), builder ("objects"), nodes, leaves, depth,
     * sah_cost and bounds, its own triangles' tree in triangles and
     * triangles_*, and both in bytes. */
    uint64_t instances;
    /* Added after rtk 0.1.0: the trees the last commit built.  A scene
     * flagged RTK_SCENE_FLAG_DYNAMIC has one per triangle geometry, and a
     * commit builds only those of geometries changed since (refits then
     * counts the trees it refitted); any other scene: 1 (one more per time
     * step count of its geometries with motion blur), or 0 after a refit. */
    uint32_t trees_built;
    /* Added after rtk 0.1.0: of triangles, those of geometries with motion
     * blur (more than one time step).  They are built into trees of their
     * own (layout "bvh8.triangle4mb", or "bvh4.triangle4mb" on the scalar
     * backend or with motion_layout=, one tree per time segment),
     * below a top level when the scene has other triangles or instances. */
    uint64_t triangles_motion;
    /* Added in rtk 0.2.0: primitives of user geometry in the top level,
     * and those left out (a box not finite or not ordered). */
    uint64_t user_primitives;
    uint64_t user_primitives_skipped;
    /* Added in rtk 0.2.0: the quads of quad geometries (each two of
     * triangles, those of zero area in triangles_degenerate). */
    uint64_t quads;
    /* Added after rtk 0.2.0: the rays the stream calls (rtk_intersect1M ...)
     * keep in flight per thread, 0 when the scene's layout has no stream
     * kernel and they trace ray by ray. */
    uint32_t stream_in_flight;
    /* Added after rtk 0.2.0: triangles outside the range rtk answers in
     * (see "the range rtk answers in" above rtk_scene_commit): a
     * coordinate beyond +-RTK_COORD_LIMIT, or an area below the range.
     * Left out (never hit); not counted in triangles_skipped or
     * triangles_degenerate.  (REFIT geometries keep their tiny ones in the
     * tree, never hit, and count them in triangles_degenerate, as their
     * zero-area ones: a refit may give them their area back.) */
    uint64_t triangles_out_of_range;
    /* Added after rtk 0.2.0: the commits since a dynamic scene's top level
     * was built that refitted it instead: the same objects (the same trees,
     * instances, masks and transforms) with new boxes, after commits that
     * kept or refitted every tree of its own and built none.  Its SAH cost
     * is then the refit's; once that is more than 1.1 times the build's, the
     * next commit builds the top level afresh.  0 when the last commit
     * built it, or for any other scene.  Only a dynamic scene with a REFIT
     * geometry keeps what a refit needs (8 bytes per top-level item). */
    uint32_t top_level_refits;
} rtk_scene_info;
RTK_API rtk_error rtk_scene_get_info(rtk_scene scene, rtk_scene_info *info);

/* ---- the BVH as data -------------------------------------------------------
 * A layout-neutral copy of a committed scene's BVH: for inspecting the tree
 * (rtktool build), saving it, and committing the same geometry again from
 * the saved tree instead of building one (rtktool build --dump / --load).
 * A scene committed from a tree traces exactly like the scene it came from.
 *
 * Inner node i has `width` child slots; slot c holds the reference
 * children[i * width + c] and the box child_lower/child_upper[(i * width +
 * c) * 3 + axis].  A reference is an inner node's index, RTK_BVH_LEAF_BIT |
 * a leaf's index, or RTK_BVH_EMPTY (an unused slot; its box is ignored).
 * Leaf j holds the triangles prims[leaf_first[j] .. leaf_first[j + 1]).  A
 * tree with no inner node has a leaf (or, for an empty scene, RTK_BVH_EMPTY)
 * as its root. */
#define RTK_BVH_LEAF_BIT 0x80000000u
#define RTK_BVH_EMPTY 0xffffffffu
#define RTK_BVH_MAX_DEPTH 64 /* levels, the leaves' included */

typedef struct rtk_bvh_prim {
    uint32_t geom_id, prim_id;
} rtk_bvh_prim;

typedef struct rtk_bvh {
    size_t struct_size; /* set by the caller to sizeof(rtk_bvh) */
    uint32_t width;     /* child slots per inner node: 4 or 8 */
    uint32_t root;      /* a reference */
    uint64_t node_count, leaf_count, prim_count;
    float *child_lower, *child_upper; /* node_count * width * 3 each */
    uint32_t *children;               /* node_count * width */
    uint64_t *leaf_first;             /* leaf_count + 1, ascending, from 0 to prim_count */
    rtk_bvh_prim *prims;              /* prim_count */
} rtk_bvh;

/* Fills *bvh (struct_size set by the caller) with a copy of the committed
 * scene's tree, in memory rtk_bvh_free releases.  Nodes come in depth-first
 * order (a parent before its children) and leaves in the order of their
 * triangles in memory. */
RTK_API rtk_error rtk_scene_get_bvh(rtk_scene scene, rtk_bvh *bvh);
/* Releases what rtk_scene_get_bvh allocated and zeroes the arrays; only for
 * trees it filled. */
RTK_API void rtk_bvh_free(rtk_bvh *bvh);
/* Checks a tree's structure without any scene: width, counts, every
 * reference in range, every node and leaf referenced exactly once and by a
 * node of smaller index (so no cycles), at most RTK_BVH_MAX_DEPTH levels,
 * leaf ranges ascending and non-empty, every used child box ordered and
 * finite and containing the boxes of the child node's slots.  Returns
 * RTK_OK, or RTK_ERROR_INVALID_ARGUMENT with the first problem in msg. */
RTK_API rtk_error rtk_bvh_check(const rtk_bvh *bvh, char *msg, size_t msg_size);
/* Commits the scene (as rtk_scene_commit does: the same geometry checks and
 * the same layout choice) with `bvh` as its tree instead of building one.
 * Besides rtk_bvh_check, the tree must fit the scene: each triangle it
 * references belongs to an attached, enabled geometry and can be hit
 * (finite, non-zero area); every such triangle is referenced, and lies
 * inside the boxes above its leaf, or (spatial splits) is referenced from
 * several leaves whose boxes together cover it; the width matches the
 * layout's nodes and no
 * leaf holds more triangles than the layout allows (16).  Anything else is
 * RTK_ERROR_INVALID_ARGUMENT naming the problem, and the scene keeps its
 * previous state.  rtk_scene_info.builder is then "tree". */
RTK_API rtk_error rtk_scene_commit_bvh(rtk_scene scene, const rtk_bvh *bvh);

/* ---- geometry --------------------------------------------------------------*/
typedef enum rtk_geometry_type {
    RTK_GEOMETRY_TYPE_TRIANGLE = 0,
    /* Added after rtk 0.1.0: another committed scene, placed by an affine
     * transform (rtk_geometry_set_instanced_scene, _set_transform). */
    RTK_GEOMETRY_TYPE_INSTANCE = 1,
    /* Added in rtk 0.2.0: primitives the application defines by callbacks
     * (see "user geometry" below). */
    RTK_GEOMETRY_TYPE_USER = 2,
    /* Added in rtk 0.2.0: quads, as triangles but four indices per
     * primitive (see "quads" below). */
    RTK_GEOMETRY_TYPE_QUAD = 3,
} rtk_geometry_type;

typedef enum rtk_buffer_type {
    RTK_BUFFER_TYPE_VERTEX = 0, /* float x, y, z per vertex, byte_stride >= 12, multiple of 4 */
    /* uint32 v0, v1, v2 per triangle, byte_stride >= 12, multiple of 4;
     * quads: v0, v1, v2, v3, byte_stride >= 16, at most 2^31 - 1 quads */
    RTK_BUFFER_TYPE_INDEX = 1,
} rtk_buffer_type;

/* ---- quads (added in rtk 0.2.0) ---------------------------------------------
 * A geometry of RTK_GEOMETRY_TYPE_QUAD is a triangle geometry in every
 * respect (buffers, time steps, masks, filters, refit; every call that
 * takes a triangle geometry takes it) except that its index buffer holds
 * quads v0 v1 v2 v3, in order around the quad.  rtk traces quad q as the
 * two triangles (v0, v1, v3) and (v2, v3, v1), as Embree does, so a quad
 * need not be planar, and a triangle can be given as a quad with v3 == v2
 * (its second half has no area and is never hit).  A hit reports
 * primID = q and u, v over the quad: (0, 0) at v0, (1, 0) at v1, (1, 1) at
 * v2, (0, 1) at v3 (Embree's convention); Ng is the normal of the half hit,
 * cross(v1 - v0, v3 - v0) or cross(v3 - v2, v1 - v2), which agree for a
 * planar quad.  Filters see the hit so.  In rtk_scene_info, triangles,
 * triangles_degenerate and bytes_per_triangle count the halves, quads the
 * quads; in a tree rtk_scene_get_bvh exports (and rtk_scene_commit_bvh
 * reads) the halves are prim_id 2q and 2q + 1. */

RTK_API rtk_error rtk_geometry_new(rtk_device device, rtk_geometry_type type, rtk_geometry *out);
RTK_API void rtk_geometry_retain(rtk_geometry geometry);
RTK_API void rtk_geometry_release(rtk_geometry geometry);

/* The application's memory, read at rtk_scene_commit (it must stay valid and
 * unchanged until then; after a commit rtk keeps its own copy of what the BVH
 * needs, so changes show only after the next commit).  Scenes flagged
 * RTK_SCENE_FLAG_COMPACT copy only the indices: their vertex buffers must
 * stay valid and unchanged while the scene uses them. */
RTK_API rtk_error rtk_geometry_set_shared_buffer(rtk_geometry geometry, rtk_buffer_type type, const void *ptr,
                                                 size_t byte_offset, size_t byte_stride, size_t count);
/* Memory owned by rtk (zeroed), returned in *out for the application to fill. */
RTK_API rtk_error rtk_geometry_set_new_buffer(rtk_geometry geometry, rtk_buffer_type type, size_t byte_stride,
                                              size_t count, void **out);
/* Tells rtk the application changed the contents of a buffer in place
 * (a shared buffer, or one from rtk_geometry_set_new_buffer); commit the
 * geometry and the scene to use them.  A geometry of quality
 * RTK_BUILD_QUALITY_REFIT whose vertex buffer changed is refitted. */
RTK_API rtk_error rtk_geometry_update_buffer(rtk_geometry geometry, rtk_buffer_type type);
/* RTK_BUILD_QUALITY_REFIT marks a deforming geometry (see rtk_build_quality);
 * the other qualities (the default is medium) rebuild the scene on any
 * change, with the scene's quality. */
RTK_API rtk_error rtk_geometry_set_build_quality(rtk_geometry geometry, rtk_build_quality quality);
RTK_API rtk_error rtk_geometry_enable(rtk_geometry geometry);
RTK_API rtk_error rtk_geometry_disable(rtk_geometry geometry);
RTK_API rtk_error rtk_geometry_set_user_data(rtk_geometry geometry, void *user);
RTK_API void *rtk_geometry_get_user_data(rtk_geometry geometry);
/* Checks that the buffers are set and consistent (an instance: that it has
 * a scene and an invertible, finite transform); a scene commit uses only
 * committed geometry. */
RTK_API rtk_error rtk_geometry_commit(rtk_geometry geometry);

/* ---- motion blur (added after rtk 0.1.0) ------------------------------------
 * A triangle geometry with T > 1 time steps has T vertex buffers, in slots
 * 0 .. T-1: slot k holds the positions at time k / (T - 1), and between
 * two steps every vertex moves on a straight line (linear motion blur, as
 * Embree's rtcSetGeometryTimeStepCount).  A ray at time t sees the
 * triangles at t (rtk_ray.time; times outside [0, 1] miss them).  The
 * index buffer is shared by all steps; every vertex buffer must have as
 * many vertices as slot 0's.  A hit reports u, v and Ng of the triangle at
 * the ray's time.  A triangle with a NaN or infinite vertex at any step is
 * left out (triangles_skipped); one of zero area at some steps stays and
 * is hit where it has area.  Geometry without motion pays nothing for it:
 * a scene holding both builds its static triangles as always, the moving
 * ones into trees of their own (one per time segment), and a top level
 * over them.  Motion-blurred geometry is always rebuilt on a change (a
 * REFIT quality builds as medium); its tree cannot be exported
 * (rtk_scene_get_bvh) or loaded (rtk_scene_commit_bvh). */
#define RTK_MAX_TIME_STEPS 129

/* Sets the number of time steps (1 .. RTK_MAX_TIME_STEPS; 1, the default,
 * is no motion).  Vertex slots at or beyond the new count are released. */
RTK_API rtk_error rtk_geometry_set_time_step_count(rtk_geometry geometry, unsigned count);
/* rtk_geometry_set_shared_buffer and rtk_geometry_set_new_buffer for a
 * slot: a vertex buffer's time step (slot < the time step count), or 0.
 * The calls without _slot are slot 0.  rtk_geometry_update_buffer on the
 * vertex type tells rtk that any of the vertex slots changed. */
RTK_API rtk_error rtk_geometry_set_shared_buffer_slot(rtk_geometry geometry, rtk_buffer_type type, unsigned slot,
                                                      const void *ptr, size_t byte_offset, size_t byte_stride,
                                                      size_t count);
RTK_API rtk_error rtk_geometry_set_new_buffer_slot(rtk_geometry geometry, rtk_buffer_type type, unsigned slot,
                                                   size_t byte_stride, size_t count, void **out);

/* ---- instances (added after rtk 0.1.0) --------------------------------------
 * An instance geometry places a scene of the same device in the scene it is
 * attached to, by an affine transform from the instanced scene's space (its
 * "object space") to the instancing scene's.  A scene holding instances is
 * built as two levels: a top-level tree over its instances (and over one
 * tree of its own triangles, if it has any), each instance's rays traced
 * through the instanced scene's own tree.  Instances of scenes that hold
 * instances work too, up to RTK_MAX_INSTANCE_DEPTH levels.
 *
 * A hit inside an instance reports, as Embree does: instID = the geomID of
 * the instance in the scene traced (the outermost one, when instances are
 * nested), geomID and primID = the triangle's in the innermost scene, Ng in
 * that scene's object space (transform it with the inverse transpose of
 * the instance's transform for a world-space normal), and t along the
 * ray as given (the transform keeps the ray's parametrisation).  Hits in
 * the scene's own triangles report instID = RTK_INVALID_GEOMETRY_ID.
 *
 * The instancing scene uses the instanced scene's tree as it was at the
 * instancing scene's commit (it holds a reference to it, so the instanced
 * scene may be committed again or released meanwhile); commit the
 * instancing scene again to see the instanced scene's changes.  As with
 * any scene, a commit must not overlap another call on the same scene, and
 * the commit of a scene must not overlap the commit of a scene that
 * instances it.  An instance cannot place a scene that contains it, itself
 * or through other instances: rtk_scene_attach_geometry and
 * rtk_geometry_set_instanced_scene refuse such a cycle
 * (RTK_ERROR_INVALID_OPERATION), looking at the scenes' attached
 * geometries, so they must not overlap attaching or detaching in the
 * scenes the instance reaches.  A ray that the transform takes out of the finite floats
 * misses that instance. */
#define RTK_MAX_INSTANCE_DEPTH 8

typedef enum rtk_format {
    RTK_FORMAT_FLOAT3X4_ROW_MAJOR = 1,    /* m[0..3] the first row (x' = m0 x + m1 y + m2 z + m3), ... */
    RTK_FORMAT_FLOAT3X4_COLUMN_MAJOR = 2, /* m[0..2] the first column, ..., m[9..11] the translation */
    RTK_FORMAT_FLOAT4X4_COLUMN_MAJOR = 3, /* the same with a fourth row (ignored; OpenGL's layout) */
} rtk_format;

/* The scene an instance geometry places (retained; NULL lets it go).
 * RTK_ERROR_INVALID_OPERATION on a geometry that is not an instance,
 * RTK_ERROR_INVALID_ARGUMENT for a scene of another device. */
RTK_API rtk_error rtk_geometry_set_instanced_scene(rtk_geometry geometry, rtk_scene scene);
/* The instance's transform from the instanced scene's space to the
 * instancing scene's (default: the identity).  Non-finite values are
 * refused; a singular transform is refused by rtk_geometry_commit. */
RTK_API rtk_error rtk_geometry_set_transform(rtk_geometry geometry, rtk_format format, const float *xfm);

/* ---- rays ------------------------------------------------------------------*/
typedef struct rtk_ray {
    float org_x, org_y, org_z;
    float tnear;
    float dir_x, dir_y, dir_z;
    float time;  /* in [0, 1]: for geometry with motion blur */
    float tfar;
    uint32_t mask;  /* hits only geometry whose mask shares a bit with it: use ~0u for all */
    uint32_t id;    /* the application's */
    uint32_t flags; /* RTK_RAY_FLAG_* (0: none) */
} rtk_ray;

typedef struct rtk_hit {
    float Ng_x, Ng_y, Ng_z;
    float u, v;
    uint32_t primID;
    uint32_t geomID;
    uint32_t instID; /* the instance hit (see rtk_geometry_set_instanced_scene), else RTK_INVALID_GEOMETRY_ID */
} rtk_hit;

typedef struct rtk_rayhit {
    rtk_ray ray;
    rtk_hit hit;
} rtk_rayhit;

/* ---- secondary rays (added in rtk 0.2.0) --------------------------------------
 * Where a ray that leaves a surface should start so that it does not hit
 * that surface again (self-intersection) nor skip geometry just beyond it:
 * the method of Waechter and Binder ("A Fast and Robust Method for
 * Avoiding Self-Intersection", Ray Tracing Gems, 2019).  p is the hit
 * point as computed from the ray (org + t * dir) or from the triangle
 * (barycentrics), n the geometric normal, unit length, pointing to the
 * side the new ray leaves on (flip Ng for rays that go through, as
 * refraction does).  Each coordinate moves along n by 256 ulps of itself
 * times that component of n (integer arithmetic on the float's bits), or,
 * within 1/32 of zero where ulps vanish, by 2^-16 times the component.
 * Start the new ray there with tnear = 0.  tests/test_offset.c measures
 * self-intersections and lost geometry against a fixed epsilon. */
RTK_API void rtk_offset_ray_origin(const float p[3], const float n[3], float out[3]);

/* ---- masks, face culling and filters (added after rtk 0.1.0) ----------------
 * Masks.  Every geometry, triangles and instances alike, has a 32-bit mask
 * (all ones unless set); a ray hits it only when ray.mask & mask != 0.  An
 * instance's mask is tested before the ray enters it, then the masks of
 * the instanced scene's geometries.
 *
 * Face culling, per ray in ray.flags: RTK_RAY_FLAG_CULL_BACK skips the
 * triangles whose geometric normal Ng (rtk_hit's: cross(v1-v0, v2-v0))
 * faces away from the ray, dot(dir, Ng) > 0; RTK_RAY_FLAG_CULL_FRONT those
 * facing it, dot(dir, Ng) < 0.  Inside an instance both are taken in the
 * instanced scene's space (so a mirroring transform swaps the faces, as in
 * Embree).
 *
 * Filters.  A triangle geometry may have an intersection filter, called by
 * rtk_intersect* queries, and an occlusion filter, called by rtk_occluded*:
 * each candidate hit (one that passed the masks and culling, within the
 * ray's [tnear, tfar]) is handed to the filter, which returns non-zero to
 * accept it or 0 to reject it, and the ray goes on as if the triangle were
 * not there (alpha-tested leaves; or every hit along a ray collected by a
 * filter that records each and rejects it).  A closest-hit query calls the
 * filter for candidates closer than the closest hit accepted so far, not
 * in order of distance (single rays take a leaf's triangles nearest first,
 * packets in leaf order), so it may see candidates farther than the hit
 * finally reported; an any-hit query stops at the first accepted.  A filter may be called more
 * than once for the same triangle (spatial splits put a triangle in several
 * leaves), always with a single ray, also during packet queries, on the
 * thread of the query.  It must not change or commit the scene.
 *
 * Scenes pay for these only when they use them: a ray without flags, in a
 * scene without filters whose geometries' masks all share a bit with the
 * ray's (the default masks do, and so does a "visible to every ray" bit set
 * in every mask), runs the kernels' usual path (docs/benchmarks/features.md
 * measures it); otherwise the single-ray kernels take a path of their own
 * that tests each candidate.
 * A geometry's mask, filters and user data (as the filters see it) are
 * read at the scene's commit: set them, commit the geometry, then the
 * scene (which then builds its tree afresh). */
enum {
    RTK_RAY_FLAG_CULL_BACK = 1u << 0,
    RTK_RAY_FLAG_CULL_FRONT = 1u << 1,
};

/* Per query, passed to the filters: the application's pointer.  A
 * renderer that needs more can put this struct first in one of its own. */
typedef struct rtk_query_context {
    void *user;
} rtk_query_context;

typedef struct rtk_filter_args {
    void *geometry_user;              /* the geometry's user data (rtk_geometry_set_user_data) */
    const rtk_query_context *context; /* the query's (rtk_intersect1_ctx, ...), or NULL */
    /* The ray in the geometry's space (inside an instance: the instanced
     * scene's); its tfar is the distance to the closest hit accepted so far
     * (the ray's own tfar before any). */
    const rtk_ray *ray;
    /* The candidate, as the query would report it (instID included), and
     * its distance along the ray. */
    const rtk_hit *hit;
    float t;
} rtk_filter_args;
typedef int (*rtk_filter_fn)(const rtk_filter_args *args);

/* RTK_ERROR_INVALID_OPERATION: a filter on an instance (set them on the
 * instanced scene's triangle geometries). */
RTK_API rtk_error rtk_geometry_set_mask(rtk_geometry geometry, uint32_t mask);
RTK_API rtk_error rtk_geometry_set_intersect_filter(rtk_geometry geometry, rtk_filter_fn filter);
RTK_API rtk_error rtk_geometry_set_occluded_filter(rtk_geometry geometry, rtk_filter_fn filter);

/* ---- user geometry (added in rtk 0.2.0) ------------------------------------
 * A geometry of RTK_GEOMETRY_TYPE_USER has a primitive count, a bounds
 * callback and intersect and occluded callbacks.  At the scene's commit rtk
 * asks each primitive's box and builds over the boxes (the scene becomes
 * two levels, as with instances: the primitives and the scene's other trees
 * below one top level); a primitive whose box is not finite and ordered is
 * left out (counted in rtk_scene_info.user_primitives_skipped).  During a
 * query rtk calls the intersect or occluded callback for each primitive
 * whose box the ray enters and whose mask passes (with the ray in the
 * geometry's space), and hits from user geometry, triangles and instances
 * mix: the closest is reported.
 *
 * The callbacks get `N` rays: 1 from rtk_intersect1 / rtk_occluded1 (and
 * from rays a packet query finishes alone), or the packet's width from
 * rtk_intersect4/8/16 on a scene whose top level holds the primitive, with
 * valid[i] != 0 for the lanes to test (the others must not be touched).
 * `rays` is then an rtk_rayhit / rtk_ray for N = 1, else an rtk_rayhitN /
 * rtk_rayN.  On a hit within [tnear, tfar], intersect writes the lane's
 * tfar, u, v and Ng (geomID, primID and instID are rtk's to write), and
 * occluded sets the lane's tfar to -inf.  A lane whose tfar the callback
 * leaves NaN, below tnear or above the old tfar is taken as a miss and
 * restored.  Geometry filters are not called for user geometry (its
 * callbacks decide, with the query's context at hand; rtk_user_offer_hit
 * below asks the query itself).  The callbacks run on the query's thread
 * and must not change or commit the scene. */
typedef struct rtk_bounds_args {
    void *geometry_user;
    uint32_t prim_id;
    float *lower, *upper; /* 3 floats each, for the callback to fill */
} rtk_bounds_args;
typedef void (*rtk_bounds_fn)(const rtk_bounds_args *args);

typedef struct rtk_user_query_args {
    const int *valid;                 /* N lanes */
    void *geometry_user;
    uint32_t geom_id, prim_id;
    const rtk_query_context *context; /* the query's, or NULL */
    void *rays;                       /* see above */
    uint32_t N;
} rtk_user_query_args;
typedef void (*rtk_user_query_fn)(const rtk_user_query_args *args);

/* RTK_ERROR_INVALID_OPERATION on a geometry that is not of the user type.
 * The count and callbacks are read at the geometry's commit (which fails
 * while any is missing) and the boxes at the scene's. */
RTK_API rtk_error rtk_geometry_set_user_primitive_count(rtk_geometry geometry, uint32_t count);
RTK_API rtk_error rtk_geometry_set_bounds_function(rtk_geometry geometry, rtk_bounds_fn bounds);
RTK_API rtk_error rtk_geometry_set_intersect_function(rtk_geometry geometry, rtk_user_query_fn intersect);
RTK_API rtk_error rtk_geometry_set_occluded_function(rtk_geometry geometry, rtk_user_query_fn occluded);

/* Every hit of a user primitive (added after rtk 0.2.0), as Embree's
 * rtcFilterIntersection and rtcFilterOcclusion: an intersect or occluded
 * callback offers each hit it finds for a lane, nearest first, before
 * reporting one.  rtk_user_offer_hit returns 1 when the query takes the
 * hit (the callback then reports it as above: tfar, u, v and Ng, or tfar
 * = -inf) and 0 when it does not (the callback reports nothing for it and
 * offers its next hit beyond, if the primitive has one).  The queries
 * that collect every crossing (rtk_count_intersections,
 * rtk_list_intersections, rtk_occupancy) take none: they collect each hit
 * offered and the walk goes on, which is how they see a primitive that
 * the ray crosses more than once (a sphere: in and out).  Other queries
 * take every hit offered within the lane's [tnear, tfar] (the one a
 * callback that does not offer would report), and a hit outside it is
 * never taken.  User geometry must offer its hits for those queries: a
 * hit a callback reports there without the query having taken it is not
 * counted, and the call fails (RTK_ERROR_UNSUPPORTED, naming the
 * geometry) rather than miss crossings.  `args` must be the callback's
 * own, on its thread, and `lane` one it is to test; otherwise the result
 * is 0 and the thread's error (rtk_device_get_error(NULL)) is
 * RTK_ERROR_INVALID_ARGUMENT. */
typedef struct rtk_user_hit {
    float t;                /* along the lane's ray, as the callback would write to tfar */
    float u, v;             /* as the callback would report them */
    float Ng_x, Ng_y, Ng_z; /* the same */
} rtk_user_hit;
RTK_API int rtk_user_offer_hit(const rtk_user_query_args *args, uint32_t lane, const rtk_user_hit *hit);

/* Closest hit.  RTK_ERROR_INVALID_ARGUMENT for NULL arguments,
 * RTK_ERROR_INVALID_OPERATION for a scene that was never committed.
 * A triangle's hit distance is never less than where the ray enters the
 * triangle's bounding box, less 2^-20 of that distance: a ray grazing a
 * triangle's plane, whose rounded distance can come out far from the
 * triangle, gets that floor instead (and no hit where the floor lies
 * beyond tfar), so that which triangle is nearest never depends on the
 * order in which the boxes were visited. */
RTK_API rtk_error rtk_intersect1(rtk_scene scene, rtk_rayhit *rayhit);
/* Any hit. */
RTK_API rtk_error rtk_occluded1(rtk_scene scene, rtk_ray *ray);
/* The same with a context for the filters (NULL: as without). */
RTK_API rtk_error rtk_intersect1_ctx(rtk_scene scene, rtk_rayhit *rayhit, const rtk_query_context *context);
RTK_API rtk_error rtk_occluded1_ctx(rtk_scene scene, rtk_ray *ray, const rtk_query_context *context);

/* ---- streams (added after rtk 0.2.0) ---------------------------------------
 * `count` single rays in one call: rtk_rayhit (intersect) or rtk_ray
 * (occluded) structs `byte_stride` bytes apart from `rays` (the size of the
 * struct for a plain array; more to step over an application's own fields
 * between them), as Embree 3's rtcIntersect1M / rtcOccluded1M.  Each ray
 * gets exactly what rtk_intersect1 / rtk_occluded1 gives it (t, u, v, Ng
 * and the ids, bit for bit, ties included; filters see the same
 * candidates in the same order), and an invalid ray is left untouched, as
 * there; the rays may be traced in any order, and a filter or user
 * geometry callback is called on the calling thread.
 *
 * What a stream buys: a single ray waits for one cache miss after another
 * (each node of its path depends on the last), while rays of a stream do
 * not depend on each other, so the stream kernels keep several of them in
 * flight on the one thread and switch between them while their memory
 * arrives (docs/benchmarks/streams.md measures it on incoherent rays).  Runs of
 * eight consecutive rays that are coherent (direction signs alike, origins
 * close: camera rays of neighbouring pixels, shadow rays to one light) go
 * through the packet kernels instead, with the same answers (a ray whose
 * hit in a packet could be the other of two triangles tied within rounding
 * is traced alone), so a stream is in rays' order best handed over tile by
 * tile.  Motion-blurred scenes interleave their rays too, each in the
 * tree of its time segment (their coherent runs go one ray after the
 * other: there are no motion packet kernels).  Two-level scenes
 * (instances, RTK_SCENE_FLAG_DYNAMIC) interleave their rays through both
 * levels: the top level walked ray by ray, the object trees below it
 * interleaved (their packets go one ray after the other: interleaving a
 * packet's few rays through two levels measured no faster).
 *
 * The rest (rays that scatter) goes one of several ways: one after the
 * other, interleaved, or for any hits on avx2 walked together by direction
 * octant; which is fastest depends on the scene and the rays, so the kernel
 * times a window of rays each way now and then and keeps the fastest.  What
 * it learnt is kept per thread and scene (closest and any hits apart) from
 * one call to the next, so streams of a tile's rays, a thousand or so, are
 * not each spent measuring; it is only ever a choice of speed.
 *
 * RTK_ERROR_INVALID_ARGUMENT, with nothing written, for a NULL scene, NULL
 * rays with a count above 0, rays not aligned to 4 bytes, a byte_stride
 * below the struct's size or not a multiple of 4, or an array that would
 * run past the end of the address space; RTK_ERROR_INVALID_OPERATION for a
 * scene never committed.  A count of 0 does nothing and succeeds.  The
 * calls run on the calling thread: a renderer with threads of its own
 * calls them from each. */
RTK_API rtk_error rtk_intersect1M(rtk_scene scene, rtk_rayhit *rays, uint32_t count, size_t byte_stride);
RTK_API rtk_error rtk_occluded1M(rtk_scene scene, rtk_ray *rays, uint32_t count, size_t byte_stride);
RTK_API rtk_error rtk_intersect1M_ctx(rtk_scene scene, rtk_rayhit *rays, uint32_t count, size_t byte_stride,
                                      const rtk_query_context *context);
RTK_API rtk_error rtk_occluded1M_ctx(rtk_scene scene, rtk_ray *rays, uint32_t count, size_t byte_stride,
                                     const rtk_query_context *context);

/* The same over the device's threads (rtk_device_get_thread_count: its
 * pool, or the application's task system), for an application that hands
 * over a whole batch at once (millions of rays): the array is cut into
 * pieces of consecutive rays, each piece traced as a stream on one thread,
 * and the call returns when all are done.  Filters and user geometry
 * callbacks then run on those threads, several at once.  The same errors
 * as the stream calls. */
RTK_API rtk_error rtk_intersect_batch(rtk_scene scene, rtk_rayhit *rays, size_t count, size_t byte_stride,
                                      const rtk_query_context *context);
RTK_API rtk_error rtk_occluded_batch(rtk_scene scene, rtk_ray *rays, size_t count, size_t byte_stride,
                                     const rtk_query_context *context);

/* ---- ray arrays (added after rtk 0.2.0) ------------------------------------
 * Batches in the form array libraries hold rays and want answers (numpy,
 * Open3D's RaycastingScene): each ray six numbers, origin then direction,
 * in float or double, and each answer in an array of its own, over the
 * device's threads.  rtk builds the rtk_rayhit records itself, a piece at a
 * time, traces them and writes the answers out, so the caller neither
 * builds records nor reads them back.  Each group of eight consecutive
 * rays (or 4x2 neighbours, with row_length) that share their origin (bit
 * for bit) and their directions' signs (camera rays) goes through the packet kernels
 * (rtk_intersect8), the rest as a stream (rtk_intersect_batch): every ray
 * gets rtk_intersect1's answer for the ray rounded to float, except, as
 * with packets, which of two triangles hit at exactly the same t.
 *
 * All rays share tnear and tfar (tnear <= tfar, not NaN), time 0, mask
 * 0xFFFFFFFF, and no filter context.  A ray that rtk_ray's rules make
 * invalid (NaN, infinite, a zero direction) misses.  Answer arrays left
 * NULL are not written. */
typedef struct rtk_ray_arrays {
    const void *rays;    /* count rays of 6 numbers: org x, y, z, dir x, y, z */
    int rays_double;     /* non-zero: the numbers are double (else float) */
    size_t ray_stride;   /* bytes from one ray to the next: 0 for packed (6 numbers); a multiple of 4 */
    float tnear, tfar;
    /* rtk_intersect_arrays */
    float *t_hit;        /* the first hit's t (in direction lengths), +inf for a miss */
    uint32_t *geom_ids;  /* the hit's geomID, primID and instID, RTK_INVALID_GEOMETRY_ID for a miss */
    uint32_t *prim_ids;
    uint32_t *inst_ids;
    float *uvs;          /* u, v per ray: the hit's, 0 for a miss */
    float *normals;      /* x, y, z per ray: the hit's Ng made unit length, 0 for a miss */
    /* rtk_occluded_arrays */
    uint8_t *occluded;   /* 1 when something lies along the ray within [tnear, tfar], else 0 */
    /* 0, or the rays are an image's pixels row by row, this many a row (a
     * camera's rays as Open3D's create_rays_pinhole makes them): the
     * packets then take 4x2 blocks of pixels instead of eight along a row
     * (camera rays through the bunny and the dragon 7-11% faster).  Only
     * the speed depends on it: every ray's answer is the same. */
    size_t row_length;
} rtk_ray_arrays;

/* RTK_ERROR_INVALID_ARGUMENT, with nothing written, for a NULL scene or
 * arrays, NULL rays with a count above 0, rays not aligned to 4 bytes
 * (float) or 8 (double), a stride below a ray's six numbers or not a
 * multiple of 4, tnear negative or NaN, tfar NaN or below tnear, and
 * (rtk_occluded_arrays) occluded NULL; RTK_ERROR_INVALID_OPERATION for a
 * scene never committed or being committed. */
RTK_API rtk_error rtk_intersect_arrays(rtk_scene scene, const rtk_ray_arrays *arrays, size_t count);
RTK_API rtk_error rtk_occluded_arrays(rtk_scene scene, const rtk_ray_arrays *arrays, size_t count);

/* ---- closest points (added after rtk 0.2.0) --------------------------------
 * The point of the scene's surface nearest to a query point, within a
 * radius: for the geometry tools that ask for distances rather than hits.
 * The traversal visits the boxes nearest to the point first and leaves out
 * every box farther than the best triangle so far, so a query costs a few
 * dozen box and triangle steps wherever the point lies.  Far from the
 * surface it also tests each leaf's box oriented along its triangles: a
 * tree makes those at its first closest-point query (64 bytes per leaf of
 * up to four triangles, about 16 per triangle, through the device's memory
 * monitor; a tree only traced never does, and a refit drops them).
 *
 * The surface is the scene's triangles as rays see them: triangle and quad
 * meshes, through instances (instances of instances too: the distance is
 * measured in the scene's space whatever the instance's scale or shear),
 * at the query's time for motion blur, and without the triangles rays
 * never hit either (those left out at the commit: zero area, NaN or
 * infinite vertices, outside rtk's range; rtk_scene_info counts them).
 * Masks and filters play no part.  User geometry answers through its
 * point query function (rtk_geometry_set_point_query_function); a scene
 * with user geometry that has none is refused (RTK_ERROR_UNSUPPORTED).
 *
 * Precision: the query point is a double and the answer is computed in
 * double from the scene's float vertices, so it loses nothing of either;
 * distance is the distance from the query point to the point x, y, z
 * reported.  The default layouts keep a vertex and two edges per triangle
 * (v1 = v0 + (v1 - v0)), which can move a vertex by half an ulp of an
 * edge; robust scenes (RTK_SCENE_FLAG_ROBUST) and compact ones keep or
 * read the vertices themselves.
 *
 * Ties: of triangles at exactly the same distance (a point nearest to a
 * vertex they share, say), the one with the least instID is reported,
 * then the least geomID, then the least primID (a scene's own geometry,
 * instID RTK_INVALID_GEOMETRY_ID, counts as the greatest instID; of a
 * quad's two halves, the first).  So every backend, thread count, batch
 * and single call gives the same answer for a scene of the same layout.
 * (Only the same ids reached through two paths of nested instances, with
 * one outermost instance, are told apart by the order of the walk.)  */
typedef struct rtk_point_query {
    double x, y, z;  /* the query point: finite, each coordinate within +-2^64 */
    double radius;   /* only surface within this distance counts: >= 0, INFINITY for all of it */
    float time;      /* motion blur: the time in [0, 1] the scene is taken at */
    uint32_t reserved; /* 0 */
} rtk_point_query;

typedef struct rtk_point_hit {
    double x, y, z;  /* the nearest point of the surface */
    double distance; /* from the query point to it; INFINITY when no surface lies within the radius */
    float u, v;      /* its barycentric coordinates on the triangle (over the quad for quads), as a hit's */
    float n_x, n_y, n_z; /* the triangle's unit normal in the scene's space, oriented as a hit's Ng (0 when it has no area) */
    uint32_t primID, geomID, instID; /* as a hit's; RTK_INVALID_GEOMETRY_ID when no surface lies within the radius */
} rtk_point_hit;

/* Closest points on user geometry (added after rtk 0.2.0), as Embree's
 * rtcSetGeometryPointQueryFunction: for each user primitive whose box lies
 * within the best distance found so far (in the geometry's space, through
 * any instances), rtk calls the geometry's point query function with the
 * query point and that distance (radius: a bound from above, +inf at
 * first, in the geometry's space).  The function returns 1 and fills
 * closest (the primitive's point nearest to p, or any point of it within
 * radius nearer than the others it could give), u, v (the application's
 * parameters of that point) and normal (the surface's unit normal there,
 * or 0, 0, 0), or returns 0 when the primitive has no point within
 * radius.  rtk takes the point into the scene's space, measures its
 * distance itself and keeps the nearest of every candidate, user or
 * triangle (a closest point that is NaN or infinite is left out); the
 * result's primID, geomID and instID are rtk's, as for hits, and its
 * normal is the function's taken into the scene's space.  Through an
 * instance the function works in the geometry's space: the answer is
 * exact through similarities (rotations, uniform scales, moves); through
 * a shear or an uneven scale the point nearest in the geometry's space
 * may not be the nearest in the scene's (as with Embree's).  The function
 * runs on the query's thread (a batch's threads) and must not change or
 * commit the scene. */
typedef struct rtk_point_query_args {
    void *geometry_user;
    uint32_t geom_id, prim_id;
    double p[3];       /* the query point, in the geometry's space */
    double radius;     /* only points within this of p are wanted; INFINITY at first */
    float time;        /* the query's */
    uint32_t reserved; /* 0 */
    /* the function's answer where it returns 1: */
    double closest[3];
    float u, v;
    float normal[3];
} rtk_point_query_args;
typedef int (*rtk_point_query_fn)(rtk_point_query_args *args);

/* RTK_ERROR_INVALID_OPERATION on a geometry that is not of the user type;
 * NULL removes the function (the geometry's scenes then refuse closest
 * points).  Read at the geometry's commit. */
RTK_API rtk_error rtk_geometry_set_point_query_function(rtk_geometry geometry, rtk_point_query_fn fn);

/* One query, on the calling thread.  RTK_ERROR_INVALID_ARGUMENT for a NULL
 * argument, a point not finite or beyond +-2^64, a radius negative or NaN,
 * a time outside [0, 1] or reserved not 0 (nothing written);
 * RTK_ERROR_INVALID_OPERATION for a scene never committed or being
 * committed; RTK_ERROR_UNSUPPORTED for a scene with user geometry that has
 * no point query function, or a backend without closest-point kernels
 * (or, for user geometry, one that predates them). */
RTK_API rtk_error rtk_closest_point(rtk_scene scene, const rtk_point_query *query, rtk_point_hit *result);

/* `count` queries over the device's threads (its pool, or the
 * application's task system), results[i] for queries[i].  The errors of
 * rtk_closest_point for the call as a whole (then nothing is written);
 * a query that is not valid gets distance NaN and the invalid ids
 * (RTK_INVALID_GEOMETRY_ID) and the others their answers, and the call
 * succeeds. */
RTK_API rtk_error rtk_closest_point_batch(rtk_scene scene, const rtk_point_query *queries,
                                          rtk_point_hit *results, size_t count);

/* ---- every crossing, inside and outside (added after rtk 0.2.0) ------------
 * For geometry tools: how many times and where each ray crosses the
 * surface, and whether points lie inside closed meshes.  Each ray is
 * traced once, every candidate hit within [tnear, tfar] collected (the
 * geometries' masks and filters apply as for rtk_intersect1: a candidate
 * counts when they accept it), sorted by t, a triangle met twice at the
 * same t kept once.
 *
 * Exactly once per crossing needs RTK_SCENE_FLAG_ROBUST: its watertight
 * test gives a ray through an edge or vertex shared by the triangles of a
 * closed mesh exactly one of them where the surface crosses the ray once
 * (tests/test_points.c counts rays through vertices and edges); the
 * default intersector may count such a ray twice or not at all.  User
 * geometry's crossings are the hits its callbacks offer
 * (rtk_user_offer_hit; a callback that reports a hit without offering it
 * fails the call, RTK_ERROR_UNSUPPORTED), and rtk_occupancy needs its
 * point query functions too (rtk_closest_point's refusals).  A backend
 * whose kernels predate the query filters the collection goes through is
 * refused (RTK_ERROR_UNSUPPORTED).
 * Over the device's threads; invalid rays (rtk_ray's rules) cross nothing.
 * Rays with a byte stride as the stream calls take them. */
typedef struct rtk_crossing {
    float t;             /* along the ray */
    float u, v;          /* as a hit's */
    float Ng_x, Ng_y, Ng_z; /* as a hit's: unnormalised, in the instanced scene's space */
    uint32_t primID, geomID, instID;
} rtk_crossing;

/* counts[i]: the crossings of ray i. */
RTK_API rtk_error rtk_count_intersections(rtk_scene scene, const rtk_ray *rays, size_t count, size_t byte_stride,
                                          uint32_t *counts);
/* Ray i's crossings, sorted by t, into crossings[offsets[i] ..
 * offsets[i + 1]): offsets (count + 1 entries, non-decreasing) from the
 * prefix sums of rtk_count_intersections on the same rays.  A ray with
 * more crossings than its room gets what fits and the call
 * RTK_ERROR_INVALID_ARGUMENT, naming it. */
RTK_API rtk_error rtk_list_intersections(rtk_scene scene, const rtk_ray *rays, size_t count, size_t byte_stride,
                                         const uint64_t *offsets, rtk_crossing *crossings);
/* inside[i] = 1 when point i (x, y, z and time of rtk_point_query; radius
 * ignored) lies inside the surface or on it, 0 outside,
 * RTK_OCCUPANCY_INVALID for a point not finite, beyond +-2^64 or at a
 * time outside [0, 1].  The rule: the parity of the crossings of a ray
 * from the point in a fixed direction; a point on the surface is inside.
 * A double point is answered as a double: where the surface passes
 * between it and its float (it lies within float's rounding of the
 * surface), the parity is taken from a point further from the surface on
 * its side, reached by steps its distance from the surface shows to be
 * clear (a point within 2^-44 of its coordinates' magnitude from the
 * surface counts as on it).  Exact for closed meshes (every edge shared
 * by two triangles) in robust scenes, points at edges and vertices
 * included, and double points wherever the mesh lies (tests/test_crossings.c:
 * points 1e-4 off unit meshes 10^5 from the origin, where float's grid
 * is 2^-7); for open meshes the answer is that ray's parity, which
 * another direction may contradict.  Through an instance, the surface is
 * where the instance's float transform puts it (a few ulps of float from
 * where double would); user geometry's, where its callbacks' hits and
 * point query function put it. */
#define RTK_OCCUPANCY_INVALID 255u
RTK_API rtk_error rtk_occupancy(rtk_scene scene, const rtk_point_query *points, size_t count, uint8_t *inside);

/* Closest points and occupancy over an application's arrays (added after
 * rtk 0.2.0), as numpy's and Open3D's users hold them: points as rows of
 * three floats or doubles, each answer into an array of its own (those
 * left NULL are not written), with no query and result records built and
 * copied (64 + 40 bytes a point: a 256^3 grid's 1.7 GB).  Point i gets
 * the answer rtk_closest_point_batch (rtk_occupancy) gives the query
 * {x, y, z, radius, time} of its numbers (a float point taken as the
 * double it is), over the device's threads, on every backend and thread
 * count: distances and nearest points in the points' type (a float point's
 * the float nearest to the double answer), everything else as in
 * rtk_point_hit.  A point not finite or beyond +-2^64 gets distance NaN,
 * a nearest point of NaNs, the invalid ids and (occupancy)
 * RTK_OCCUPANCY_INVALID; the call succeeds. */
typedef struct rtk_point_arrays {
    const void *points;  /* count points of 3 numbers: x, y, z */
    int points_double;   /* non-zero: the numbers are double (else float) */
    size_t point_stride; /* bytes from one point to the next: 0 for packed (3 numbers); a multiple of 4 */
    double radius;       /* rtk_closest_point_arrays: only surface within this distance counts (>= 0;
                          * INFINITY for all of it, the usual setting: 0 finds only points on the surface) */
    float time;          /* every point's, for motion blur: in [0, 1] */
    /* rtk_closest_point_arrays, in the points' type (float or double): */
    void *distances;     /* INFINITY where no surface lies within radius */
    void *closest;       /* x, y, z per point: the surface's point nearest to it (NaN where none) */
    /* and as rtk_point_hit's: */
    uint32_t *geom_ids;  /* RTK_INVALID_GEOMETRY_ID where none */
    uint32_t *prim_ids;
    uint32_t *inst_ids;
    float *uvs;          /* u, v per point */
    float *normals;      /* x, y, z per point: the triangle's unit normal */
    /* rtk_occupancy_arrays: */
    uint8_t *inside;     /* 1 inside the surface or on it, 0 outside, RTK_OCCUPANCY_INVALID */
} rtk_point_arrays;

/* RTK_ERROR_INVALID_ARGUMENT, with nothing written, for a NULL scene or
 * arrays, NULL points with a count above 0, points not aligned to 4 bytes
 * (float) or 8 (double), a stride below a point's three numbers or not a
 * multiple of 4, a time outside [0, 1], (rtk_closest_point_arrays) a
 * radius negative or NaN and (rtk_occupancy_arrays) inside NULL; and the
 * scene's refusals of rtk_closest_point_batch and rtk_occupancy. */
RTK_API rtk_error rtk_closest_point_arrays(rtk_scene scene, const rtk_point_arrays *arrays, size_t count);
RTK_API rtk_error rtk_occupancy_arrays(rtk_scene scene, const rtk_point_arrays *arrays, size_t count);

/* ---- ray packets -----------------------------------------------------------
 * Packets of 4, 8 or 16 rays as structures of arrays: the fields of rtk_ray
 * and rtk_hit, in the same order, one array of N per field.  A packet must be
 * aligned to 4*N bytes (the types carry that alignment, so declared variables
 * and memory from aligned_alloc are fine); a misaligned packet is
 * RTK_ERROR_INVALID_ARGUMENT.
 *
 * valid[i] != 0 makes lane i active (valid == NULL: all lanes).  Each active
 * lane gets the answer rtk_intersect1 / rtk_occluded1 gives for that ray
 * (when two triangles are hit at exactly the same t, either may be reported);
 * inactive lanes and invalid rays are left untouched.
 *
 * Packet traversal pays off for coherent rays (camera rays through
 * neighbouring pixels): the packet visits each node once for all its rays
 * (testing the node against the frustum of the whole packet first when its
 * rays share their direction signs), and switches to single-ray traversal
 * for the few rays still active once it has spread out (the hybrid scheme
 * of Embree).  Every width works on every
 * backend: a packet wider than the backend's packet kernels is traced as
 * several narrower packets, and where there is no packet kernel (the
 * scalar backend; motion blur on every backend) the packet's rays go
 * through the layout's stream kernel as a stream of their own (scattered
 * rays interleaved, see rtk_intersect1M), or one by one where it has none;
 * rtk_scene_info.packet_width says which (1 for both). */
#define RTK_PACKET_TYPES_(N)                                                                                           \
    typedef struct __attribute__((aligned(4 * N))) rtk_ray##N {                                                        \
        float org_x[N], org_y[N], org_z[N];                                                                            \
        float tnear[N];                                                                                                \
        float dir_x[N], dir_y[N], dir_z[N];                                                                            \
        float time[N];                                                                                                 \
        float tfar[N];                                                                                                 \
        uint32_t mask[N];                                                                                              \
        uint32_t id[N];                                                                                                \
        uint32_t flags[N];                                                                                             \
    } rtk_ray##N;                                                                                                      \
    typedef struct __attribute__((aligned(4 * N))) rtk_hit##N {                                                        \
        float Ng_x[N], Ng_y[N], Ng_z[N];                                                                               \
        float u[N], v[N];                                                                                              \
        uint32_t primID[N];                                                                                            \
        uint32_t geomID[N];                                                                                            \
        uint32_t instID[N];                                                                                            \
    } rtk_hit##N;                                                                                                      \
    typedef struct rtk_rayhit##N {                                                                                     \
        rtk_ray##N ray;                                                                                                \
        rtk_hit##N hit;                                                                                                \
    } rtk_rayhit##N;                                                                                                   \
    RTK_API rtk_error rtk_intersect##N(rtk_scene scene, const int *valid, rtk_rayhit##N *rayhit);                     \
    RTK_API rtk_error rtk_occluded##N(rtk_scene scene, const int *valid, rtk_ray##N *ray);                            \
    RTK_API rtk_error rtk_intersect##N##_ctx(rtk_scene scene, const int *valid, rtk_rayhit##N *rayhit,                \
                                             const rtk_query_context *context);                                        \
    RTK_API rtk_error rtk_occluded##N##_ctx(rtk_scene scene, const int *valid, rtk_ray##N *ray,                       \
                                            const rtk_query_context *context);
RTK_PACKET_TYPES_(4)
RTK_PACKET_TYPES_(8)
RTK_PACKET_TYPES_(16)

#ifdef __cplusplus
}
#endif
#endif
