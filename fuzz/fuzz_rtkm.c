/* libFuzzer target: the .rtkm reader (tools/rtkm.c).  Any bytes must load
 * or fail with a message; a loaded mesh must have every index in range. */
#include <stdlib.h>

#include "fuzz_common.h"
#include "rtkm.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[256], err[256];
    if (!fuzz_file(data, size, ".rtkm", path, sizeof path))
        return 0;
    rtk_mesh mesh;
    err[0] = 0;
    fuzz_check_mesh(rtkm_load(path, &mesh, err, sizeof err), &mesh, err);
    unlink(path);
    return 0;
}
