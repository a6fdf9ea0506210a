/* One rtk device for a fuzz target's whole run, on the backends of the
 * build tree (RTK_FUZZ_BACKENDS, set by CMake) unless RTK_BACKEND_PATH
 * says otherwise. */
#ifndef RTK_FUZZ_DEVICE_H
#define RTK_FUZZ_DEVICE_H

#include <stdio.h>
#include <stdlib.h>

#include "rtk/rtk.h"

static rtk_device fuzz_device(const char *config)
{
    static rtk_device dev;
    if (!dev) {
        setenv("RTK_BACKEND_PATH", RTK_FUZZ_BACKENDS, 0);
        if (rtk_device_new(config, &dev) != RTK_OK) {
            fprintf(stderr, "fuzz: no device: %s\n", rtk_device_get_error_message(NULL));
            abort();
        }
    }
    return dev;
}

#endif
