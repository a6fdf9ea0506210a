/* Prints what a device found: the active backend, then every backend file
 * with its status and reason; or the error of rtk_device_new.  Built by
 * tests/packages_test.sh against an installed or unpacked rtk. */
#include <stdio.h>

#include <rtk/rtk.h>

int main(void)
{
    rtk_device dev = NULL;
    if (rtk_device_new(NULL, &dev) != RTK_OK) {
        printf("error: %s\n", rtk_device_get_error_message(NULL));
        return 2;
    }
    printf("active: %s\n", rtk_device_get_backend_name(dev));
    printf("searched: %s\n", rtk_device_get_search_path(dev));
    const size_t n = rtk_device_get_backend_count(dev);
    for (size_t i = 0; i < n; i++) {
        rtk_backend_info bi = {.struct_size = sizeof bi};
        rtk_device_get_backend_info(dev, i, &bi);
        static const char *status[] = {"active", "usable", "rejected"};
        printf("backend %s: %s%s%s\n", bi.name, status[bi.status], bi.reason[0] ? ": " : "", bi.reason);
    }
    rtk_device_release(dev);
    return 0;
}
