/*
 * The core's large temporary arrays: a commit's list of the top level's
 * objects (128 bytes each: 128 MB for 10^6 instances).  From 2 MiB on they
 * are mappings of their own on a 2 MiB boundary with transparent huge
 * pages asked for, as the backends' large arrays (backends/common/memory.c):
 * filled once, they fault in a page per 2 MiB instead of one per 4 KiB.
 * Through calloc, that array's page faults took 8% of the samples of a
 * scratch driver's run committing 10^6 instances on the development VM
 * (perf, the instances' creation included).
 */
#define _DEFAULT_SOURCE /* MAP_ANONYMOUS */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "internal.h"

#define BIG_HEAD 64
#define BIG_MAP ((size_t)2 << 20)

void *rtk_big_calloc(size_t count, size_t size)
{
    if (size && count > (SIZE_MAX - 2 * BIG_MAP) / size)
        return NULL;
    const size_t total = (count * size + BIG_HEAD + 4095) & ~(size_t)4095;
    unsigned char *p;
    if (total < BIG_MAP) {
        p = calloc(1, total);
        if (!p)
            return NULL;
    } else {
        unsigned char *m = mmap(NULL, total + BIG_MAP, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (m == MAP_FAILED)
            return NULL;
        const size_t head = (BIG_MAP - (uintptr_t)m % BIG_MAP) % BIG_MAP;
        if (head)
            munmap(m, head);
        munmap(m + head + total, BIG_MAP - head);
        p = m + head;
#ifdef MADV_HUGEPAGE
        madvise(p, total, MADV_HUGEPAGE); /* (a hint: the memory is the same without) */
#endif
    }
    memcpy(p, &total, sizeof total); /* (a new mapping reads as zeros) */
    return p + BIG_HEAD;
}

void rtk_big_free(void *q)
{
    if (!q)
        return;
    unsigned char *p = (unsigned char *)q - BIG_HEAD;
    size_t total;
    memcpy(&total, p, sizeof total);
    if (total < BIG_MAP)
        free(p);
    else
        munmap(p, total);
}
