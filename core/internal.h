/* Internal declarations of librtk (the core).  Nothing here is exported. */
#ifndef RTK_CORE_INTERNAL_H
#define RTK_CORE_INTERNAL_H

#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "rtk/rtk.h"
#include "rtk/rtk_backend.h"

#define RTK_INTERNAL __attribute__((visibility("hidden")))
/* Error messages, with room for one line per backend file the device looked at. */
#define RTK_MESSAGE_MAX 4096

/* ---- config ---- */
typedef struct rtk_config {
    char isa[RTK_BACKEND_NAME_MAX];     /* "" = any */
    char max_isa[RTK_BACKEND_NAME_MAX]; /* "" = no ceiling */
    unsigned threads;                   /* 0 = all cores */
    int verbose;
    char *backend_path; /* NULL = default search order; else ':'-separated dirs (owned) */
    char builder[RTK_BACKEND_NAME_MAX]; /* "" = the scene's quality picks it */
    char layout[RTK_BACKEND_NAME_MAX];  /* "" = the scene's flags pick it */
    char motion_layout[RTK_BACKEND_NAME_MAX]; /* the same for motion-blurred triangles */
} rtk_config;

/* Parses "key=value,..." into cfg; on failure returns RTK_ERROR_INVALID_CONFIG
 * and writes the reason into msg. */
RTK_INTERNAL rtk_error rtk_config_parse(const char *text, rtk_config *cfg, char *msg, size_t msg_size);
RTK_INTERNAL void rtk_config_free(rtk_config *cfg);
/* The level of a known ISA name (scalar 0, sse41 10, avx 20, avx2 30, avx512 40), or -1. */
RTK_INTERNAL int rtk_isa_level(const char *name);

/* ---- cpu ---- */
RTK_INTERNAL uint64_t rtk_cpu_detect(void);

/* ---- backends ---- */
typedef struct rtk_backend_entry {
    char *path;
    char name[RTK_BACKEND_NAME_MAX];
    rtk_backend_status status;
    char reason[512];
    uint32_t interface_version;
    uint32_t level;
    uint32_t header_version; /* the header's interface_version: the newest the backend speaks (0: unknown) */
    uint64_t cpu_requires;
    void *handle;                /* dlopen handle, kept only for the active backend */
    const rtk_backend_desc *desc;
} rtk_backend_entry;

typedef struct rtk_backend_registry {
    rtk_backend_entry *entries;
    size_t count;
    char *search_path; /* ':'-joined, for messages */
    int active;        /* index into entries, -1 when none */
} rtk_backend_registry;

/* Discovers, checks and loads backends, then picks one as the config asks.
 * On failure returns an error and writes a message that names the
 * directories searched and every rejection. */
RTK_INTERNAL rtk_error rtk_backends_load(rtk_backend_registry *reg, const rtk_config *cfg, uint64_t cpu,
                                         char *msg, size_t msg_size);
RTK_INTERNAL void rtk_backends_unload(rtk_backend_registry *reg);
/* Whether a backend's descriptor has the table `field` (one added after
 * rtk 0.1.0): its struct_size covers it and it is not NULL. */
#define RTK_DESC_HAS(d, field)                                                                                         \
    ((d)->struct_size >= offsetof(rtk_backend_desc, field) + sizeof(d)->field && (d)->field)
/* The layout entry with this id in a backend's table, or NULL. */
RTK_INTERNAL const rtk_layout_entry *rtk_backend_find_layout(const rtk_backend_desc *d, uint32_t id);

/* ---- pool.c: the device's worker threads ---- */
typedef struct rtk_pool rtk_pool;
/* The CPUs this process may run on (at least 1). */
RTK_INTERNAL unsigned rtk_cpu_count(void);
/* A pool running tasks on `threads` threads: the caller's and threads - 1
 * workers.  NULL with the reason in msg. */
RTK_INTERNAL rtk_pool *rtk_pool_new(unsigned threads, char *msg, size_t msg_size);
/* Joins the workers; no parallel_for may be running. */
RTK_INTERNAL void rtk_pool_free(rtk_pool *pool);
RTK_INTERNAL rtk_task_system rtk_pool_tasks(rtk_pool *pool);
/* A pool with no workers of its own, whose jobs application threads run
 * by joining it: rtk_pool_serve runs them on the calling thread until the
 * pool is freed or *until is set (and rtk_pool_wake called). */
RTK_INTERNAL rtk_pool *rtk_pool_new_joinable(char *msg, size_t msg_size);
RTK_INTERNAL void rtk_pool_serve(rtk_pool *pool, atomic_int *until);
RTK_INTERNAL void rtk_pool_wake(rtk_pool *pool);

/* ---- device ---- */
struct rtk_device_s {
    atomic_int refs;
    rtk_config config;
    uint64_t cpu;
    rtk_backend_registry backends;
    const rtk_backend_desc *backend; /* the active backend's tables */

    pthread_mutex_t lock; /* guards the error state */
    rtk_error error;      /* sticky: first since the last get */
    char message[RTK_MESSAGE_MAX]; /* of the most recent error */
    rtk_error_callback callback;
    void *callback_user;

    pthread_mutex_t pool_lock; /* guards pool, tasks, user_tasks and thread_count */
    unsigned thread_count;     /* threads= resolved (0: the CPU count) */
    rtk_pool *pool;            /* created by the first build that uses more than one thread */
    rtk_task_system tasks;     /* the application's (user_tasks), else the pool's once it exists */
    int user_tasks;

    /* rtk_device_set_memory_monitor's, NULL when none; memory is what the
     * backends and the geometry buffers report through (user: the device),
     * refusals counts the monitor's refusals (so a failed build can tell a
     * refusal from the system's out of memory) */
    rtk_memory_monitor_fn monitor;
    void *monitor_user;
    rtk_memory memory;
    atomic_uint refusals;
};

/* The task system a build on this device runs on: the application's, or
 * the device's pool (started now if it is not yet), or NULL for the
 * calling thread only (threads=1, or the pool could not start: logged). */
RTK_INTERNAL const rtk_task_system *rtk_device_tasks(rtk_device device, rtk_task_system *copy);
/* fn(data, i) for every i < pieces: over the device's task system when
 * there are several pieces and it has one, else one after the other on
 * the calling thread.  What every batch query splits its array with. */
RTK_INTERNAL void rtk_device_for(rtk_device device, uint32_t pieces, rtk_task_fn fn, void *data);

/* The device's memory accounting for builds and buffers (rtk_memory), or
 * NULL when it has no memory monitor. */
RTK_INTERNAL const rtk_memory *rtk_device_memory(rtk_device device);

/* Records an error on the device (NULL: on this thread), calls the callback,
 * and returns code, so callers can write `return rtk_fail(dev, code, ...)`. */
RTK_INTERNAL rtk_error rtk_fail(rtk_device device, rtk_error code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* A line on stderr when verbose >= level. */
RTK_INTERNAL void rtk_log(rtk_device device, int level, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

/* ---- big_array.c ---- */
/* calloc for large temporary arrays (huge pages from 2 MiB on), freed with
 * rtk_big_free. */
RTK_INTERNAL void *rtk_big_calloc(size_t count, size_t size);
RTK_INTERNAL void rtk_big_free(void *p);

/* ---- bvh.c ---- */
/* The tree (already through rtk_bvh_check) against the geometries it would
 * be built over: see rtk_scene_commit_bvh.  RTK_ERROR_INVALID_ARGUMENT with
 * the first problem in msg.  A tree may hold a triangle that cannot be hit
 * only where a build would (build_hittable): a deforming geometry's
 * zero-area or tiny triangle.  On success the triangles are counted as a
 * build counts them (rtk_triangle_classify): left out for a non-finite
 * vertex, of zero area (in the tree or not), outside rtk's range, and
 * distinct ones in the tree. */
RTK_INTERNAL rtk_error rtk_bvh_check_fit(const rtk_bvh *t, const rtk_build_geometry *geoms, uint32_t geom_count,
                                         uint64_t *non_finite, uint64_t *degenerate, uint64_t *out_of_range,
                                         uint64_t *in_tree, char *msg, size_t size);
/* Allocates the arrays of a tree of these sizes (leaves + 1 leaf_first). */
RTK_INTERNAL rtk_error rtk_bvh_alloc(rtk_bvh *t, uint32_t width, uint64_t nodes, uint64_t leaves, uint64_t prims);

#endif
