/* What rtk's libFuzzer targets share: the input as a file (the readers take
 * paths), in a memory-backed file whose name ends as the reader wants. */
#ifndef RTK_FUZZ_COMMON_H
#define RTK_FUZZ_COMMON_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "mesh_import.h"

/* Writes data to a file in /dev/shm (or TMPDIR) named with `suffix`, and
 * returns its path in buf; NULL if it cannot. */
static inline const char *fuzz_file(const uint8_t *data, size_t size, const char *suffix, char *buf, size_t buf_size)
{
    const char *dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : (getenv("TMPDIR") ? getenv("TMPDIR") : "/tmp");
    snprintf(buf, buf_size, "%s/rtk-fuzz-%ld%s", dir, (long)getpid(), suffix);
    FILE *f = fopen(buf, "wb");
    if (!f)
        return NULL;
    const size_t n = size ? fwrite(data, 1, size, f) : 0;
    if (fclose(f) != 0 || n != size)
        return NULL;
    return buf;
}

/* What a mesh reader (rtk_mesh_load, rtkm_load) must give for any bytes:
 * a mesh whose every index is in range (freed here), or an error that says
 * why; abort() otherwise, for libFuzzer to report. */
static inline void fuzz_check_mesh(int rc, rtk_mesh *mesh, const char *err)
{
    if (rc == 0) {
        for (size_t i = 0; i < 3 * mesh->triangle_count; i++)
            if (mesh->indices[i] >= mesh->vertex_count)
                abort();
        rtk_mesh_free(mesh);
    } else if (!err[0]) {
        abort();
    }
}

#endif
