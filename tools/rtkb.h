/*
 * The .rtkb BVH dump: what `rtktool build --dump` writes and `--load`
 * reads.  The tree is rtk's layout-neutral rtk_bvh (rtk.h), so a dump can
 * be inspected without any backend and committed again on any backend
 * whose layout has the same node width.  Little-endian, version 1:
 *
 *   offset  size  field
 *        0     8  magic "RTKBVH\0\0"
 *        8     4  version (1)
 *       12     4  header size in bytes (256)
 *       16     4  node width (4 or 8)
 *       20     4  root reference
 *       24     8  node count
 *       32     8  leaf count
 *       40     8  triangle count (in the leaves)
 *       48     8  byte offset of children   (uint32 x nodes * width)
 *       56     8  byte offset of child_lower (float x nodes * width * 3)
 *       64     8  byte offset of child_upper (float x nodes * width * 3)
 *       72     8  byte offset of leaf_first (uint64 x leaves + 1)
 *       80     8  byte offset of prims       (uint32 geom, prim x triangles)
 *       88     8  file size (the end of prims)
 *       96    32  layout name, NUL-padded      } as the library
 *      128    32  builder name, NUL-padded     } reported them
 *      160     4  build quality (0 low, 1 medium, 2 high)
 *      164     4  zero
 *      168     8  triangles of the mesh built over } the mesh's
 *      176     8  vertices of that mesh            } fingerprint
 *      184     8  rtkm_mesh_checksum of that mesh  }
 *      192     8  memory of the built layout in bytes
 *      200     8  build time in seconds (double)
 *      208     8  SAH cost the library reported (double)
 *      216     8  checksum of the arrays, in the order above (rtkm_checksum)
 *      224     8  checksum of header bytes 0..223
 *      232    24  zero
 *
 * Every array starts on a 64-byte boundary, in the order listed, with zero
 * padding between; the file ends at the last array's end.  The reader
 * checks the header, every offset and count against the file size, both
 * checksums and then the tree itself (rtk_bvh_check), and names the file
 * and the problem when anything is wrong.
 */
#ifndef RTK_TOOLS_RTKB_H
#define RTK_TOOLS_RTKB_H

#include <stddef.h>
#include <stdint.h>

#include "rtk/rtk.h"

#ifdef __cplusplus
extern "C" {
#endif

#define RTKB_VERSION 1u
#define RTKB_HEADER_SIZE 256u

/* What the dump says about its origin. */
typedef struct rtkb_info {
    char layout[32], builder[32];
    uint32_t quality;
    uint64_t mesh_triangles, mesh_vertices, mesh_checksum;
    uint64_t bytes;
    double build_seconds, sah_cost;
} rtkb_info;

/* A dump in memory: the tree's arrays point into data. */
typedef struct rtkb_file {
    rtk_bvh tree;
    rtkb_info info;
    void *data;
} rtkb_file;

/* Writes the tree and info to path (replacing it); 0, or non-zero with err. */
int rtkb_save(const char *path, const rtk_bvh *tree, const rtkb_info *info, char *err, size_t err_size);
/* Reads and checks a dump into *file (which rtkb_free releases); 0, or
 * non-zero with *file empty and err naming the file and the problem. */
int rtkb_load(const char *path, rtkb_file *file, char *err, size_t err_size);
void rtkb_free(rtkb_file *file);

#ifdef __cplusplus
}
#endif
#endif
