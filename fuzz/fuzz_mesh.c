/* libFuzzer target: mesh import through OpenMesh (tools/mesh_import.cpp)
 * for every format rtktool reads; the first byte picks the format.  Any
 * bytes must load or fail with a message; a loaded mesh must have every
 * index in range. */
#include <stdlib.h>

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
    fuzz_check_mesh(rtk_mesh_load(path, &mesh, err, sizeof err), &mesh, err);
    unlink(path);
    return 0;
}
