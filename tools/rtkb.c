/* The .rtkb BVH dump: writer and validating reader.  See rtkb.h. */
#define _POSIX_C_SOURCE 200809L
#include "rtkb.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "file_io.h"
#include "le_bytes.h"
#include "rtkm.h"

static const char magic[8] = "RTKBVH";
#define FNV_BASIS 0xcbf29ce484222325ull

enum { A_CHILDREN, A_LOWER, A_UPPER, A_LEAF_FIRST, A_PRIMS, A_COUNT };

/* The arrays' sizes in bytes for these counts; 0 when they overflow. */
static int array_sizes(uint32_t width, uint64_t nodes, uint64_t leaves, uint64_t prims, uint64_t size[A_COUNT])
{
    const uint64_t limit = (uint64_t)1 << 40; /* no count of a sane tree comes near */
    if (nodes >= limit || leaves >= limit || prims >= limit || width > 8)
        return 0;
    size[A_CHILDREN] = nodes * width * 4;
    size[A_LOWER] = size[A_UPPER] = nodes * width * 12;
    size[A_LEAF_FIRST] = (leaves + 1) * 8;
    size[A_PRIMS] = prims * 8;
    return 1;
}

static uint64_t align64(uint64_t x) { return (x + 63) & ~(uint64_t)63; }

static const void *array_data(const rtk_bvh *t, int a)
{
    switch (a) {
    case A_CHILDREN: return t->children;
    case A_LOWER: return t->child_lower;
    case A_UPPER: return t->child_upper;
    case A_LEAF_FIRST: return t->leaf_first;
    default: return t->prims;
    }
}

static uint64_t arrays_checksum(const rtk_bvh *t, const uint64_t size[A_COUNT])
{
    uint64_t h = FNV_BASIS;
    for (int a = 0; a < A_COUNT; a++)
        h = rtkm_checksum(array_data(t, a), (size_t)size[a], h);
    return h;
}

int rtkb_save(const char *path, const rtk_bvh *t, const rtkb_info *info, char *err, size_t err_size)
{
    uint64_t size[A_COUNT], off[A_COUNT];
    if (!array_sizes(t->width, t->node_count, t->leaf_count, t->prim_count, size))
        return file_error(err, err_size, "%s: not written: the tree is too large", path);
    uint64_t at = RTKB_HEADER_SIZE;
    for (int a = 0; a < A_COUNT; a++) {
        off[a] = align64(at);
        at = off[a] + size[a];
    }
    unsigned char h[RTKB_HEADER_SIZE] = {0};
    memcpy(h, magic, sizeof magic);
    le_put32(h + 8, RTKB_VERSION);
    le_put32(h + 12, RTKB_HEADER_SIZE);
    le_put32(h + 16, t->width);
    le_put32(h + 20, t->root);
    le_put64(h + 24, t->node_count);
    le_put64(h + 32, t->leaf_count);
    le_put64(h + 40, t->prim_count);
    for (int a = 0; a < A_COUNT; a++)
        le_put64(h + 48 + 8 * a, off[a]);
    le_put64(h + 88, at);
    memcpy(h + 96, info->layout, strnlen(info->layout, 31));
    memcpy(h + 128, info->builder, strnlen(info->builder, 31));
    le_put32(h + 160, info->quality);
    le_put64(h + 168, info->mesh_triangles);
    le_put64(h + 176, info->mesh_vertices);
    le_put64(h + 184, info->mesh_checksum);
    le_put64(h + 192, info->bytes);
    le_putd(h + 200, info->build_seconds);
    le_putd(h + 208, info->sah_cost);
    le_put64(h + 216, arrays_checksum(t, size));
    le_put64(h + 224, rtkm_checksum(h, 224, FNV_BASIS));

    file_part parts[1 + A_COUNT] = {{h, 0, sizeof h}};
    for (int a = 0; a < A_COUNT; a++)
        parts[1 + a] = (file_part){array_data(t, a), off[a], size[a]};
    return file_write_parts(path, parts, 1 + A_COUNT, err, err_size);
}

int rtkb_load(const char *path, rtkb_file *file, char *err, size_t err_size)
{
    memset(file, 0, sizeof *file);
    FILE *f = fopen(path, "rb");
    if (!f)
        return file_error(err, err_size, "%s: %s", path, strerror(errno));
    char why[320] = "";
    unsigned char *data = NULL;
    struct stat st;
    if (fstat(fileno(f), &st) != 0) {
        snprintf(why, sizeof why, "%s", strerror(errno));
        goto done;
    }
    if (!S_ISREG(st.st_mode)) {
        snprintf(why, sizeof why, "not a regular file");
        goto done;
    }
    const uint64_t fsize = (uint64_t)st.st_size;
    unsigned char h[RTKB_HEADER_SIZE];
    if (fsize < 16 || fread(h, 1, 16, f) != 16 || memcmp(h, magic, sizeof magic) != 0) {
        snprintf(why, sizeof why, "not an .rtkb file (bad magic)");
        goto done;
    }
    if (le_get32(h + 8) != RTKB_VERSION) {
        snprintf(why, sizeof why, ".rtkb version %u; this build reads version %u", le_get32(h + 8), RTKB_VERSION);
        goto done;
    }
    if (le_get32(h + 12) != RTKB_HEADER_SIZE || fsize < RTKB_HEADER_SIZE ||
        fread(h + 16, 1, RTKB_HEADER_SIZE - 16, f) != RTKB_HEADER_SIZE - 16) {
        snprintf(why, sizeof why, "truncated or malformed header");
        goto done;
    }
    if (le_get64(h + 224) != rtkm_checksum(h, 224, FNV_BASIS)) {
        snprintf(why, sizeof why, "header checksum mismatch (damaged file)");
        goto done;
    }
    rtk_bvh *t = &file->tree;
    *t = (rtk_bvh){.struct_size = sizeof *t, .width = le_get32(h + 16), .root = le_get32(h + 20),
                   .node_count = le_get64(h + 24), .leaf_count = le_get64(h + 32), .prim_count = le_get64(h + 40)};
    uint64_t size[A_COUNT], off[A_COUNT];
    if ((t->width != 4 && t->width != 8) ||
        !array_sizes(t->width, t->node_count, t->leaf_count, t->prim_count, size)) {
        snprintf(why, sizeof why, "width %u, %llu nodes, %llu leaves, %llu triangles: not a tree rtk writes",
                 t->width, (unsigned long long)t->node_count, (unsigned long long)t->leaf_count,
                 (unsigned long long)t->prim_count);
        goto done;
    }
    uint64_t end = RTKB_HEADER_SIZE;
    for (int a = 0; a < A_COUNT; a++) {
        off[a] = le_get64(h + 48 + 8 * a);
        if (off[a] % 64 || off[a] < end || off[a] > ((uint64_t)1 << 48)) {
            snprintf(why, sizeof why, "array %d at offset %llu: not 64-aligned or overlapping the one before", a,
                     (unsigned long long)off[a]);
            goto done;
        }
        end = off[a] + size[a];
    }
    if (le_get64(h + 88) != end || fsize != end) {
        snprintf(why, sizeof why, "file is %llu bytes, the header says %llu and its counts %llu (truncated or padded)",
                 (unsigned long long)fsize, (unsigned long long)le_get64(h + 88), (unsigned long long)end);
        goto done;
    }
    data = aligned_alloc(64, align64(fsize));
    if (!data) {
        snprintf(why, sizeof why, "out of memory for %llu bytes", (unsigned long long)fsize);
        goto done;
    }
    memcpy(data, h, RTKB_HEADER_SIZE);
    if (fread(data + RTKB_HEADER_SIZE, 1, fsize - RTKB_HEADER_SIZE, f) != fsize - RTKB_HEADER_SIZE) {
        snprintf(why, sizeof why, "read failed");
        goto done;
    }
    /* Padding is zero, so every byte of a dump is accounted for. */
    for (uint64_t at = 232, a = 0; a <= A_COUNT; a++) {
        const uint64_t to = a < A_COUNT ? off[a] : fsize;
        for (; at < to; at++)
            if (data[at]) {
                snprintf(why, sizeof why, "non-zero padding at byte %llu (damaged file)", (unsigned long long)at);
                goto done;
            }
        at = a < A_COUNT ? off[a] + size[a] : fsize;
    }
    t->children = (uint32_t *)(data + off[A_CHILDREN]);
    t->child_lower = (float *)(data + off[A_LOWER]);
    t->child_upper = (float *)(data + off[A_UPPER]);
    t->leaf_first = (uint64_t *)(data + off[A_LEAF_FIRST]);
    t->prims = (rtk_bvh_prim *)(data + off[A_PRIMS]);
    if (le_get64(h + 216) != arrays_checksum(t, size)) {
        snprintf(why, sizeof why, "checksum mismatch (damaged file)");
        goto done;
    }
    char msg[256];
    if (rtk_bvh_check(t, msg, sizeof msg) != RTK_OK) {
        snprintf(why, sizeof why, "not a valid tree: %s", msg);
        goto done;
    }
    rtkb_info *info = &file->info;
    memcpy(info->layout, h + 96, 31);
    memcpy(info->builder, h + 128, 31);
    info->quality = le_get32(h + 160);
    info->mesh_triangles = le_get64(h + 168);
    info->mesh_vertices = le_get64(h + 176);
    info->mesh_checksum = le_get64(h + 184);
    info->bytes = le_get64(h + 192);
    info->build_seconds = le_getd(h + 200);
    info->sah_cost = le_getd(h + 208);
    file->data = data;
    data = NULL;
done:
    fclose(f);
    free(data);
    if (why[0]) {
        memset(file, 0, sizeof *file);
        return file_error(err, err_size, "%s: %s", path, why);
    }
    return 0;
}

void rtkb_free(rtkb_file *file)
{
    free(file->data);
    memset(file, 0, sizeof *file);
}
