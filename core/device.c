/* Version, errors, and the device: config, CPU probe, backend choice. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

int rtk_version(void)
{
    return RTK_VERSION;
}

const char *rtk_version_string(void)
{
    return RTK_VERSION_STRING;
}

const char *rtk_error_name(rtk_error code)
{
    switch (code) {
#define RTK_X_(name, value, text) \
    case name:                    \
        return #name;
        RTK_ERROR_LIST(RTK_X_)
#undef RTK_X_
    }
    return "RTK_ERROR_UNKNOWN";
}

/* Errors of calls that have no device (a failed rtk_device_new, a NULL
 * handle) are kept per thread. */
static _Thread_local rtk_error tls_error;
static _Thread_local char tls_message[RTK_MESSAGE_MAX];
/* What rtk_device_get_error_message returns: a per-thread copy, so another
 * thread's error cannot change it under the caller. */
static _Thread_local char tls_copy[RTK_MESSAGE_MAX];

rtk_error rtk_fail(rtk_device device, rtk_error code, const char *fmt, ...)
{
    char text[RTK_MESSAGE_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    if (!device) {
        if (tls_error == RTK_OK)
            tls_error = code;
        snprintf(tls_message, sizeof tls_message, "%s", text);
        return code;
    }
    pthread_mutex_lock(&device->lock);
    if (device->error == RTK_OK)
        device->error = code;
    snprintf(device->message, sizeof device->message, "%s", text);
    rtk_error_callback cb = device->callback;
    void *user = device->callback_user;
    pthread_mutex_unlock(&device->lock);
    if (device->config.verbose)
        fprintf(stderr, "rtk: error %s: %s\n", rtk_error_name(code), text);
    if (cb)
        cb(user, code, text);
    return code;
}

void rtk_log(rtk_device device, int level, const char *fmt, ...)
{
    if (!device || device->config.verbose < level)
        return;
    va_list ap;
    va_start(ap, fmt);
    fputs("rtk: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
}

static const char *status_word(rtk_backend_status s)
{
    return s == RTK_BACKEND_STATUS_ACTIVE ? "active" : s == RTK_BACKEND_STATUS_USABLE ? "loaded" : "rejected";
}

/* The config's builder= and layout= must name a builder, a layout, and
 * together a builder that produces that layout, in the active backend;
 * else msg lists what the backend has. */
static int check_builder_layout(const rtk_backend_desc *bk, const rtk_config *cfg, char *msg, size_t size)
{
    if (!cfg->builder[0] && !cfg->layout[0])
        return 1;
    int builder_seen = 0, layout_seen = 0;
    for (const rtk_builder_entry *b = bk->builders; b->name; b++) {
        const rtk_layout_entry *l = rtk_backend_find_layout(bk, b->layout);
        const int bm = !cfg->builder[0] || !strcmp(b->name, cfg->builder);
        const int lm = !cfg->layout[0] || (l && !strcmp(l->name, cfg->layout));
        if (bm && lm)
            return 1;
        builder_seen |= bm;
        layout_seen |= lm;
    }
    char list[512] = ""; /* what there is */
    size_t len = 0;
    for (const rtk_builder_entry *b = bk->builders; b->name; b++) {
        const rtk_layout_entry *l = rtk_backend_find_layout(bk, b->layout);
        if (len < sizeof list)
            len += (size_t)snprintf(list + len, sizeof list - len, "%s%s/%s", len ? ", " : "", b->name,
                                    l ? l->name : "?");
    }
    if (!builder_seen)
        snprintf(msg, size, "config builder='%s': backend %s has no such builder (it has, as builder/layout: %s)",
                 cfg->builder, bk->name, list);
    else if (!layout_seen)
        snprintf(msg, size, "config layout='%s': backend %s has no such layout (it has, as builder/layout: %s)",
                 cfg->layout, bk->name, list);
    else
        snprintf(msg, size, "config builder='%s' with layout='%s': backend %s has no such pair (it has, as "
                 "builder/layout: %s)", cfg->builder, cfg->layout, bk->name, list);
    return 0;
}

/* The config's motion_layout= must name a layout of the backend's motion
 * builders; else msg lists those. */
static int check_motion_layout(const rtk_backend_desc *bk, const rtk_config *cfg, char *msg, size_t size)
{
    if (!cfg->motion_layout[0])
        return 1;
    char list[256] = "";
    size_t len = 0;
    for (const rtk_builder_entry *b = RTK_DESC_HAS(bk, motion_builders) ? bk->motion_builders : NULL; b && b->name;
         b++) {
        const rtk_layout_entry *l = rtk_backend_find_layout(bk, b->layout);
        if (l && !strcmp(l->name, cfg->motion_layout))
            return 1;
        if (l && !strstr(list, l->name) && len < sizeof list)
            len += (size_t)snprintf(list + len, sizeof list - len, "%s%s", len ? ", " : "", l->name);
    }
    snprintf(msg, size, "config motion_layout='%s': backend %s has no such motion-blur layout (it has: %s)",
             cfg->motion_layout, bk->name, len ? list : "none");
    return 0;
}

rtk_error rtk_device_new(const char *config, rtk_device *out)
{
    tls_error = RTK_OK;
    tls_message[0] = '\0';
    if (!out)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_new: out is NULL");
    *out = NULL;
    rtk_device d = calloc(1, sizeof *d);
    if (!d)
        return rtk_fail(NULL, RTK_ERROR_OUT_OF_MEMORY, "rtk_device_new: out of memory");
    char msg[4096] = "";
    rtk_error err = rtk_config_parse(config, &d->config, msg, sizeof msg);
    if (err) {
        rtk_config_free(&d->config);
        free(d);
        return rtk_fail(NULL, err, "rtk_device_new: %s", msg);
    }
    atomic_init(&d->refs, 1);
    pthread_mutex_init(&d->lock, NULL);
    d->cpu = rtk_cpu_detect();
    if (d->config.verbose) {
        char feat[512];
        rtk_cpu_features_string(d->cpu, feat, sizeof feat);
        rtk_log(d, 1, "rtk %s, CPU features: %s", RTK_VERSION_STRING, feat);
    }

    err = rtk_backends_load(&d->backends, &d->config, d->cpu, msg, sizeof msg);
    if (d->config.verbose) {
        rtk_log(d, 1, "backend search path: %s", d->backends.search_path ? d->backends.search_path : "");
        for (size_t i = 0; i < d->backends.count; i++) {
            const rtk_backend_entry *e = &d->backends.entries[i];
            rtk_log(d, 1, "backend %s: %s%s%s (interface %u)", e->path, status_word(e->status), e->reason[0] ? ": " : "",
                    e->reason, e->interface_version);
        }
    }
    if (err) {
        rtk_backends_unload(&d->backends);
        rtk_config_free(&d->config);
        pthread_mutex_destroy(&d->lock);
        free(d);
        return rtk_fail(NULL, err, "rtk_device_new: %s", msg);
    }
    d->backend = d->backends.entries[d->backends.active].desc;
    rtk_log(d, 1, "active backend: %s", d->backends.entries[d->backends.active].name);
    if (!check_builder_layout(d->backend, &d->config, msg, sizeof msg) ||
        !check_motion_layout(d->backend, &d->config, msg, sizeof msg)) {
        rtk_backends_unload(&d->backends);
        rtk_config_free(&d->config);
        pthread_mutex_destroy(&d->lock);
        free(d);
        return rtk_fail(NULL, RTK_ERROR_INVALID_CONFIG, "rtk_device_new: %s", msg);
    }
    if (d->config.builder[0] || d->config.layout[0])
        rtk_log(d, 1, "every scene is built%s%s%s%s (device config)", d->config.builder[0] ? " by " : "",
                d->config.builder, d->config.layout[0] ? " into " : "", d->config.layout);
    if (d->config.motion_layout[0])
        rtk_log(d, 1, "every motion-blurred tree is built into %s (device config)", d->config.motion_layout);
    pthread_mutex_init(&d->pool_lock, NULL);
    d->thread_count = d->config.threads ? d->config.threads : rtk_cpu_count();
    rtk_log(d, 1, "builds on %u thread%s%s", d->thread_count, d->thread_count == 1 ? "" : "s",
            d->config.threads ? "" : " (threads=0: one per CPU)");
    *out = d;
    return RTK_OK;
}

void rtk_device_retain(rtk_device device)
{
    if (device)
        atomic_fetch_add(&device->refs, 1);
}

void rtk_device_release(rtk_device device)
{
    if (!device || atomic_fetch_sub(&device->refs, 1) != 1)
        return;
    rtk_pool_free(device->pool);
    pthread_mutex_destroy(&device->pool_lock);
    rtk_backends_unload(&device->backends);
    rtk_config_free(&device->config);
    pthread_mutex_destroy(&device->lock);
    free(device);
}

const rtk_task_system *rtk_device_tasks(rtk_device d, rtk_task_system *copy)
{
    const rtk_task_system *ts = NULL;
    char msg[256] = "";
    pthread_mutex_lock(&d->pool_lock);
    if (!d->user_tasks && !d->pool && d->thread_count > 1) {
        d->pool = rtk_pool_new(d->thread_count, msg, sizeof msg);
        if (d->pool)
            d->tasks = rtk_pool_tasks(d->pool);
        else
            d->thread_count = 1; /* said once, below; builds run on the caller's thread */
    }
    if (d->user_tasks || d->pool) {
        *copy = d->tasks;
        ts = copy;
    }
    pthread_mutex_unlock(&d->pool_lock);
    if (msg[0])
        rtk_log(d, 1, "builds run on the calling thread only: %s", msg);
    return ts;
}

/* The calling thread's limit on a batch's threads (rtk_set_batch_threads;
 * 0: none). */
static _Thread_local uint32_t batch_threads;

uint32_t rtk_set_batch_threads(uint32_t n)
{
    const uint32_t was = batch_threads;
    batch_threads = n;
    return was;
}

/* A batch's pieces, taken in turn by at most as many threads as the limit
 * allows: each runs run_capped once, and the pieces go to whichever asks
 * first, as the pool hands out indices. */
typedef struct capped_for {
    rtk_task_fn fn;
    void *data;
    uint32_t pieces;
    atomic_uint next;
} capped_for;

static void run_capped(void *data, uint32_t index)
{
    (void)index;
    capped_for *c = data;
    for (uint32_t i; (i = atomic_fetch_add_explicit(&c->next, 1, memory_order_relaxed)) < c->pieces;)
        c->fn(c->data, i);
}

void rtk_device_for(rtk_device d, uint32_t pieces, rtk_task_fn fn, void *data)
{
    const uint32_t limit = batch_threads;
    rtk_task_system copy;
    const rtk_task_system *ts = pieces > 1 && limit != 1 ? rtk_device_tasks(d, &copy) : NULL;
    if (ts && limit && limit < ts->threads && limit < pieces) {
        /* limit runners of the pieces, however many threads the pool or
         * the application's task system has: no more run at once */
        capped_for c = {.fn = fn, .data = data, .pieces = pieces};
        atomic_init(&c.next, 0);
        ts->parallel_for(ts->user, limit, run_capped, &c);
    } else if (ts)
        ts->parallel_for(ts->user, pieces, fn, data);
    else
        for (uint32_t i = 0; i < pieces; i++)
            fn(data, i);
}

/* The backends' and buffers' accounting (rtk_memory) of a device: its
 * monitor sees the bytes; a refusal is counted. */
static int device_account(void *user, int64_t bytes)
{
    rtk_device d = user;
    const rtk_memory_monitor_fn fn = d->monitor;
    if (!fn)
        return 1;
    if (bytes < 0) {
        fn(d->monitor_user, bytes, 1);
        return 1;
    }
    if (fn(d->monitor_user, bytes, 0))
        return 1;
    atomic_fetch_add(&d->refusals, 1);
    return 0;
}

const rtk_memory *rtk_device_memory(rtk_device d)
{
    return d->monitor ? &d->memory : NULL;
}

rtk_error rtk_device_set_memory_monitor(rtk_device device, rtk_memory_monitor_fn monitor, void *user)
{
    if (!device)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_set_memory_monitor: device is NULL");
    device->memory = (rtk_memory){.account = device_account, .user = device};
    device->monitor_user = monitor ? user : NULL;
    device->monitor = monitor;
    return RTK_OK;
}

rtk_error rtk_device_set_task_system(rtk_device device, const rtk_task_system *tasks)
{
    if (!device)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_set_task_system: device is NULL");
    if (tasks && (tasks->struct_size < offsetof(rtk_task_system, parallel_for) + sizeof tasks->parallel_for ||
                  !tasks->parallel_for || tasks->threads == 0))
        return rtk_fail(device, RTK_ERROR_INVALID_ARGUMENT,
                        "rtk_device_set_task_system: struct_size not set, parallel_for NULL or threads 0");
    pthread_mutex_lock(&device->pool_lock);
    if (tasks) {
        device->tasks = *tasks;
        device->tasks.struct_size = sizeof device->tasks;
        device->user_tasks = 1;
    } else {
        device->user_tasks = 0;
        device->tasks = device->pool ? rtk_pool_tasks(device->pool) : (rtk_task_system){0};
    }
    pthread_mutex_unlock(&device->pool_lock);
    return RTK_OK;
}

uint32_t rtk_device_get_thread_count(rtk_device device)
{
    if (!device) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_get_thread_count: device is NULL");
        return 0;
    }
    pthread_mutex_lock(&device->pool_lock);
    uint32_t n = device->user_tasks ? device->tasks.threads : device->thread_count;
    pthread_mutex_unlock(&device->pool_lock);
    return n;
}

rtk_error rtk_device_get_error(rtk_device device)
{
    if (!device) {
        rtk_error e = tls_error;
        tls_error = RTK_OK;
        return e;
    }
    pthread_mutex_lock(&device->lock);
    rtk_error e = device->error;
    device->error = RTK_OK;
    pthread_mutex_unlock(&device->lock);
    return e;
}

const char *rtk_device_get_error_message(rtk_device device)
{
    if (!device)
        return tls_message;
    pthread_mutex_lock(&device->lock);
    snprintf(tls_copy, sizeof tls_copy, "%s", device->message);
    pthread_mutex_unlock(&device->lock);
    return tls_copy;
}

rtk_error rtk_device_set_error_callback(rtk_device device, rtk_error_callback cb, void *user)
{
    if (!device)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_set_error_callback: device is NULL");
    pthread_mutex_lock(&device->lock);
    device->callback = cb;
    device->callback_user = user;
    pthread_mutex_unlock(&device->lock);
    return RTK_OK;
}

const char *rtk_device_get_backend_name(rtk_device device)
{
    if (!device) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_get_backend_name: device is NULL");
        return "";
    }
    return device->backends.entries[device->backends.active].name;
}

size_t rtk_device_get_backend_count(rtk_device device)
{
    if (!device) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_get_backend_count: device is NULL");
        return 0;
    }
    return device->backends.count;
}

rtk_error rtk_device_get_backend_info(rtk_device device, size_t index, rtk_backend_info *info)
{
    if (!device)
        return rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_get_backend_info: device is NULL");
    if (!info || info->struct_size < offsetof(rtk_backend_info, cpu_requires) + sizeof info->cpu_requires)
        return rtk_fail(device, RTK_ERROR_INVALID_ARGUMENT,
                        "rtk_device_get_backend_info: info is NULL or its struct_size is not set");
    if (index >= device->backends.count)
        return rtk_fail(device, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_get_backend_info: index %zu, only %zu backends",
                        index, device->backends.count);
    const rtk_backend_entry *e = &device->backends.entries[index];
    info->path = e->path;
    info->name = e->name;
    info->status = e->status;
    info->reason = e->reason;
    info->interface_version = e->interface_version;
    info->cpu_requires = e->cpu_requires;
    return RTK_OK;
}

const char *rtk_device_get_search_path(rtk_device device)
{
    if (!device) {
        rtk_fail(NULL, RTK_ERROR_INVALID_ARGUMENT, "rtk_device_get_search_path: device is NULL");
        return "";
    }
    return device->backends.search_path;
}
