/* libFuzzer target: mesh import through OpenMesh (tools/mesh_import.cpp)
 * for every format rtktool reads; the first byte picks the format.  Any
 * bytes must load or fail with a message; a loaded mesh must have every
 * index in range, and a loaded OBJ or STL only finite coordinates.  (The
 * seeds' first byte picks their format: 0 mod 6 OBJ, 3 mod 6 STL, ...) */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const char *const suffixes[] = {".obj", ".ply", ".off", ".stl", ".om", ".rtkm"};
    if (size < 1)
        return 0;
    const char *suffix = suffixes[data[0] % (sizeof suffixes / sizeof *suffixes)];
    char path[256], err[256];
    if (!fuzz_file(data + 1, size - 1, suffix, path, sizeof path))
        return 0;
    rtk_mesh mesh;
    err[0] = 0;
    const int rc = rtk_mesh_load(path, &mesh, err, sizeof err);
    /* OBJ and STL can only say finite numbers (a coordinate OpenMesh
     * cannot read is refused, never dropped or taken as something else) */
    if (rc == 0 && (!strcmp(suffix, ".obj") || !strcmp(suffix, ".stl")))
        for (size_t i = 0; i < 3 * mesh.vertex_count; i++)
            if (!isfinite(mesh.vertices[i]))
                abort();
    fuzz_check_mesh(rc, &mesh, err);
    unlink(path);
    return 0;
}
