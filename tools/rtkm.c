/* The .rtkm mesh file: writer and validating reader.  See rtkm.h. */
#define _POSIX_C_SOURCE 200809L
#include "rtkm.h"
#include "file_io.h"
#include "le_bytes.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>

static const char magic[8] = "RTKMESH";

uint64_t rtkm_checksum(const void *data, size_t size, uint64_t seed)
{
    const unsigned char *p = data;
    uint64_t h = seed;
    for (; size >= 8; size -= 8, p += 8)
        h = (h ^ le_get64(p)) * 0x100000001b3ull;
    if (size) {
        unsigned char tail[8] = {0};
        memcpy(tail, p, size);
        h = (h ^ le_get64(tail)) * 0x100000001b3ull;
    }
    return h;
}

static uint64_t align64(uint64_t x) { return (x + 63) & ~(uint64_t)63; }

/* The payload checksum: vertices, then indices, seeded with their sizes. */
static uint64_t payload_checksum(const float *v, uint64_t nv, const uint32_t *idx, uint64_t nt)
{
    uint64_t h = rtkm_checksum(NULL, 0, 0xcbf29ce484222325ull ^ (nv * 12) ^ ((nt * 12) << 1));
    h = rtkm_checksum(v, (size_t)nv * 12, h);
    return rtkm_checksum(idx, (size_t)nt * 12, h);
}

uint64_t rtkm_mesh_checksum(const rtk_mesh *mesh)
{
    return payload_checksum(mesh->vertices, mesh->vertex_count, mesh->indices, mesh->triangle_count);
}

int rtkm_save(const char *path, const rtk_mesh *mesh, char *err, size_t err_size)
{
    for (size_t i = 0; i < 3 * mesh->triangle_count; i++)
        if (mesh->indices[i] >= mesh->vertex_count)
            return file_error(err, err_size, "%s: not written: triangle %zu refers to vertex %u of %zu", path, i / 3,
                        mesh->indices[i], mesh->vertex_count);
    const uint64_t nv = mesh->vertex_count, nt = mesh->triangle_count;
    const uint64_t voff = align64(RTKM_HEADER_SIZE), ioff = align64(voff + nv * 12);
    unsigned char h[RTKM_HEADER_SIZE] = {0};
    memcpy(h, magic, sizeof magic);
    le_put32(h + 8, RTKM_VERSION);
    le_put32(h + 12, RTKM_HEADER_SIZE);
    le_put64(h + 16, nv);
    le_put64(h + 24, nt);
    le_put64(h + 32, voff);
    le_put64(h + 40, ioff);
    float lower[3] = {0, 0, 0}, upper[3] = {0, 0, 0};
    if (nv)
        rtk_mesh_bounds(mesh, lower, upper);
    for (int k = 0; k < 3; k++) {
        le_putf(h + 48 + 4 * k, lower[k]);
        le_putf(h + 60 + 4 * k, upper[k]);
    }
    le_put64(h + 72, payload_checksum(mesh->vertices, nv, mesh->indices, nt));
    le_put64(h + 80, rtkm_checksum(h, 80, 0xcbf29ce484222325ull));

    const file_part parts[3] = {{h, 0, sizeof h}, {mesh->vertices, voff, nv * 12}, {mesh->indices, ioff, nt * 12}};
    return file_write_parts(path, parts, 3, err, err_size);
}

int rtkm_load(const char *path, rtk_mesh *mesh, char *err, size_t err_size)
{
    memset(mesh, 0, sizeof *mesh);
    FILE *f = fopen(path, "rb");
    if (!f)
        return file_error(err, err_size, "%s: %s", path, strerror(errno));
    struct stat st;
    unsigned char h[RTKM_HEADER_SIZE];
    int bad = 1;
    const char *why = NULL;
    char whybuf[256];
    if (fstat(fileno(f), &st) != 0) {
        why = strerror(errno);
        goto done;
    }
    if (!S_ISREG(st.st_mode)) {
        why = "not a regular file";
        goto done;
    }
    const uint64_t size = (uint64_t)st.st_size;
    if (size < 16 || fread(h, 1, 16, f) != 16 || memcmp(h, magic, sizeof magic) != 0) {
        why = "not an .rtkm file (bad magic)";
        goto done;
    }
    const uint32_t version = le_get32(h + 8), hsize = le_get32(h + 12);
    if (version != RTKM_VERSION) {
        snprintf(whybuf, sizeof whybuf, ".rtkm version %u; this build reads version %u", version, RTKM_VERSION);
        why = whybuf;
        goto done;
    }
    if (hsize != RTKM_HEADER_SIZE || size < RTKM_HEADER_SIZE || fread(h + 16, 1, hsize - 16, f) != hsize - 16) {
        why = "truncated or malformed header";
        goto done;
    }
    if (le_get64(h + 80) != rtkm_checksum(h, 80, 0xcbf29ce484222325ull)) {
        why = "header checksum mismatch (damaged file)";
        goto done;
    }
    for (unsigned k = 88; k < RTKM_HEADER_SIZE; k++)
        if (h[k]) {
            snprintf(whybuf, sizeof whybuf, "header byte %u is %u where the format has zero (damaged file)", k, h[k]);
            why = whybuf;
            goto done;
        }
    const uint64_t nv = le_get64(h + 16), nt = le_get64(h + 24), voff = le_get64(h + 32), ioff = le_get64(h + 40);
    if (nv > UINT32_MAX || nt > UINT32_MAX || voff % 64 || ioff % 64 || voff < RTKM_HEADER_SIZE ||
        ioff < voff + nv * 12) {
        why = "inconsistent counts or offsets in the header";
        goto done;
    }
    if (size != ioff + nt * 12) {
        snprintf(whybuf, sizeof whybuf, "file is %llu bytes, the header says %llu (truncated or padded)",
                 (unsigned long long)size, (unsigned long long)(ioff + nt * 12));
        why = whybuf;
        goto done;
    }
    mesh->vertices = malloc(nv ? nv * 12 : 1);
    mesh->indices = malloc(nt ? nt * 12 : 1);
    if (!mesh->vertices || !mesh->indices) {
        why = "out of memory";
        goto done;
    }
    /* the whole file is read in order: the zero padding after the header
     * and between the arrays is checked too (the checksums cover only the
     * header's first 80 bytes and the arrays) */
    int pad_ok = 1;
    for (uint64_t at = RTKM_HEADER_SIZE; pad_ok && at < ioff; at++) {
        if (at == voff) {
            if (fread(mesh->vertices, 12, nv, f) != nv)
                break;
            at += nv * 12 - 1;
            continue;
        }
        const int c = fgetc(f);
        pad_ok = c == 0;
    }
    if (!pad_ok) {
        why = "non-zero bytes in the padding between the header and the arrays (damaged file)";
        goto done;
    }
    if (fseeko(f, (off_t)ioff, SEEK_SET) != 0 || fread(mesh->indices, 12, nt, f) != nt) {
        why = "read failed";
        goto done;
    }
    if (le_get64(h + 72) != payload_checksum(mesh->vertices, nv, mesh->indices, nt)) {
        why = "checksum mismatch (damaged file)";
        goto done;
    }
    for (uint64_t i = 0; i < 3 * nt; i++)
        if (mesh->indices[i] >= nv) {
            snprintf(whybuf, sizeof whybuf, "triangle %llu refers to vertex %u of %llu", (unsigned long long)(i / 3),
                     mesh->indices[i], (unsigned long long)nv);
            why = whybuf;
            goto done;
        }
    for (uint64_t t = 0; t < nt; t++) {
        const uint32_t *i = &mesh->indices[3 * t];
        mesh->faces_repeated_vertex += i[0] == i[1] || i[1] == i[2] || i[0] == i[2];
    }
    mesh->vertex_count = (size_t)nv;
    mesh->triangle_count = (size_t)nt;
    mesh->faces_read = (size_t)nt;
    bad = 0;
done:
    fclose(f);
    if (bad) {
        rtk_mesh_free(mesh);
        return file_error(err, err_size, "%s: %s", path, why);
    }
    return 0;
}
