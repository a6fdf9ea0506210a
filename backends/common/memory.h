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

#include "backend_common.h"
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

/* Arrays of RTK_MEM_MAP bytes or more are mappings of their own that start
 * on a 2 MiB boundary and ask for transparent huge pages, as the trees'
 * node and leaf arrays do (build_common.c, build_reserve_huge): written
 * once by a build, they fault in a page per 2 MiB instead of one per
 * 4 KiB.  For the top level of 10^6 instances (its references, objects,
 * transforms and nodes, about 140 MB), page-fault handling was the largest
 * item of perf's profile of a scratch driver committing it (a quarter of
 * the run's samples, the instances' creation included; on this VM each
 * fault also costs the hypervisor an entry and an exit).  Mapped so, that
 * commit took 1,272-1,284 ms against 1,503-1,534
 * (docs/benchmarks/two-levels.md). */
#define RTK_MEM_MAP ((size_t)2 << 20)

/* A mapping of `total` bytes (a multiple of 4 KiB) on a 2 MiB boundary,
 * huge pages asked for; NULL when out of memory (build_common.c). */
#define mem_map RTK_SYM(rtk_mem_map)
#define mem_unmap RTK_SYM(rtk_mem_unmap)
void *mem_map(size_t total);
void mem_unmap(void *p, size_t total);

/* Memory of `size` bytes, 64-byte aligned (zeroed with `zero`), its size
 * kept in a header for mem_free (bit 0 set: a mapping, mem_map); NULL when
 * refused or out of memory. */
#define RTK_MEM_HEAD 64
static inline void *mem_alloc(const rtk_memory *m, size_t size, int zero)
{
    if (size > SIZE_MAX - 2 * RTK_MEM_MAP)
        return NULL;
    const size_t total = (size + RTK_MEM_HEAD + 63) & ~(size_t)63;
    if (!mem_take(m, total))
        return NULL;
    const int mapped = total >= RTK_MEM_MAP;
    unsigned char *p = mapped ? mem_map((total + 4095) & ~(size_t)4095) : aligned_alloc(64, total);
    if (!p) {
        mem_give(m, total);
        return NULL;
    }
    if (zero && !mapped) /* (a new mapping reads as zeros) */
        memset(p + RTK_MEM_HEAD, 0, size);
    const size_t head = total | (size_t)mapped;
    memcpy(p, &head, sizeof head);
    return p + RTK_MEM_HEAD;
}

/* The bytes mem_alloc took for q (its header without the mapping bit). */
static inline size_t mem_size(const void *q)
{
    size_t head;
    memcpy(&head, (const unsigned char *)q - RTK_MEM_HEAD, sizeof head);
    return head & ~(size_t)1;
}

static inline void mem_free(const rtk_memory *m, void *q)
{
    if (!q)
        return;
    unsigned char *p = (unsigned char *)q - RTK_MEM_HEAD;
    size_t head;
    memcpy(&head, p, sizeof head);
    const size_t total = head & ~(size_t)1;
    if (head & 1)
        mem_unmap(p, (total + 4095) & ~(size_t)4095);
    else
        free(p);
    mem_give(m, total);
}

/* mem_alloc's array grown (or shrunk) to `size` bytes, the contents kept;
 * NULL (q untouched) when refused or out of memory. */
static inline void *mem_realloc(const rtk_memory *m, void *q, size_t size)
{
    if (!q)
        return mem_alloc(m, size, 0);
    const size_t old = mem_size(q);
    void *n = mem_alloc(m, size, 0);
    if (!n)
        return NULL;
    const size_t keep = old - RTK_MEM_HEAD < size ? old - RTK_MEM_HEAD : size;
    memcpy(n, q, keep);
    mem_free(m, q);
    return n;
}

#endif
