/*
 * Memory the backend takes for builds and trees, reported to the core's
 * memory monitor (rtk_backend.h: rtk_memory, the device's
 * rtk_device_set_memory_monitor): an allocation is reported before it is
 * made, and fails when the monitor refuses it; its release is reported
 * after.  A NULL rtk_memory (no monitor) reports nothing.
 *
 * What goes through here is what grows with the scene: the reservations
 * of build_common.c (the builders' working arrays, the trees' node and
 * leaf arrays), the trees' heap arrays (their geometries' attributes, the
 * motion builder's time-step vertices and segments, the top level's nodes
 * and objects) and the refit's scratch; a build's fixed bookkeeping
 * (per-chunk counters, task structs) does not.
 */
#ifndef RTK_MEMORY_H
#define RTK_MEMORY_H

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "rtk/rtk_backend.h"

/* Reports `bytes` about to be taken: 0 when the monitor refuses them. */
static inline int mem_take(const rtk_memory *m, size_t bytes)
{
    return !m || !m->account || !bytes || m->account(m->user, (int64_t)bytes);
}

/* Reports `bytes` given back. */
static inline void mem_give(const rtk_memory *m, size_t bytes)
{
    if (m && m->account && bytes)
        m->account(m->user, -(int64_t)bytes);
}

/* Heap memory of `size` bytes, 64-byte aligned (zeroed with `zero`), its
 * size kept in a header for mem_free; NULL when refused or out of memory. */
#define RTK_MEM_HEAD 64
static inline void *mem_alloc(const rtk_memory *m, size_t size, int zero)
{
    if (size > SIZE_MAX - 2 * RTK_MEM_HEAD)
        return NULL;
    const size_t total = (size + RTK_MEM_HEAD + 63) & ~(size_t)63;
    if (!mem_take(m, total))
        return NULL;
    unsigned char *p = aligned_alloc(64, total);
    if (!p) {
        mem_give(m, total);
        return NULL;
    }
    if (zero)
        memset(p + RTK_MEM_HEAD, 0, size);
    memcpy(p, &total, sizeof total);
    return p + RTK_MEM_HEAD;
}

static inline void mem_free(const rtk_memory *m, void *q)
{
    if (!q)
        return;
    unsigned char *p = (unsigned char *)q - RTK_MEM_HEAD;
    size_t total;
    memcpy(&total, p, sizeof total);
    free(p);
    mem_give(m, total);
}

/* mem_alloc's array grown (or shrunk) to `size` bytes, the contents kept;
 * NULL (q untouched) when refused or out of memory. */
static inline void *mem_realloc(const rtk_memory *m, void *q, size_t size)
{
    if (!q)
        return mem_alloc(m, size, 0);
    size_t old;
    memcpy(&old, (unsigned char *)q - RTK_MEM_HEAD, sizeof old);
    void *n = mem_alloc(m, size, 0);
    if (!n)
        return NULL;
    const size_t keep = old - RTK_MEM_HEAD < size ? old - RTK_MEM_HEAD : size;
    memcpy(n, q, keep);
    mem_free(m, q);
    return n;
}

#endif
