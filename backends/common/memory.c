/* The mappings of memory.h's large arrays. */
#define _DEFAULT_SOURCE /* MAP_ANONYMOUS, MAP_NORESERVE */
#include <stdint.h>
#include <sys/mman.h>

#include "memory.h"

void *mem_map(size_t total)
{
    unsigned char *p =
        mmap(NULL, total + RTK_MEM_MAP, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (p == MAP_FAILED)
        return NULL;
    /* (the part before the first 2 MiB boundary and the part after the
     * array given back) */
    const size_t head = (RTK_MEM_MAP - (uintptr_t)p % RTK_MEM_MAP) % RTK_MEM_MAP;
    if (head)
        munmap(p, head);
    munmap(p + head + total, RTK_MEM_MAP - head);
#ifdef MADV_HUGEPAGE
    madvise(p + head, total, MADV_HUGEPAGE); /* (a hint: the memory is the same without) */
#endif
    return p + head;
}

void mem_unmap(void *p, size_t total)
{
    munmap(p, total);
}
