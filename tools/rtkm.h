/*
 * rtk's own mesh file, .rtkm: what `rtktool convert` writes and every command
 * that takes a mesh reads, with no parsing.  Little-endian, version 1:
 *
 *   offset  size  field
 *        0     8  magic "RTKMESH\0"
 *        8     4  version (1)
 *       12     4  header size in bytes (128)
 *       16     8  vertex count
 *       24     8  triangle count
 *       32     8  byte offset of the vertices (float x, y, z each; 64-aligned)
 *       40     8  byte offset of the indices (uint32 v0, v1, v2 each; 64-aligned)
 *       48    24  bounds: lower x, y, z, upper x, y, z (float; all 0 when empty)
 *       72     8  checksum of the vertex bytes then the index bytes (below)
 *       80     8  checksum of header bytes 0..79
 *       88    40  zero
 *
 * The arrays are raw, so a reader can mmap the file or read each with one
 * read.  The file ends right after the indices.  The checksums are FNV-1a
 * over 8-byte little-endian words (a short tail zero-padded); the payload's
 * starts from the FNV offset basis xor the vertex bytes xor twice the index
 * bytes.  A damaged or truncated file is refused, never traced.
 * Readers refuse other versions by number, so the format can grow.
 */
#ifndef RTK_TOOLS_RTKM_H
#define RTK_TOOLS_RTKM_H

#include <stddef.h>
#include <stdint.h>

#include "mesh_import.h"

#ifdef __cplusplus
extern "C" {
#endif

#define RTKM_VERSION 1u
#define RTKM_HEADER_SIZE 128u

/* Writes mesh to path (replacing it) and returns 0, or non-zero with err
 * saying why.  Indices must be in range. */
int rtkm_save(const char *path, const rtk_mesh *mesh, char *err, size_t err_size);
/* Reads an .rtkm file into *mesh (which rtk_mesh_free releases); returns 0,
 * or non-zero with *mesh empty and err saying why.  rtk_mesh_load calls it
 * for files named *.rtkm. */
int rtkm_load(const char *path, rtk_mesh *mesh, char *err, size_t err_size);
/* The payload checksum of the format for this mesh: a fingerprint of its
 * vertices and indices (an .rtkb file records the one it was built over). */
uint64_t rtkm_mesh_checksum(const rtk_mesh *mesh);
/* The checksum of the format over size bytes, continuing from seed. */
uint64_t rtkm_checksum(const void *data, size_t size, uint64_t seed);

#ifdef __cplusplus
}
#endif
#endif
