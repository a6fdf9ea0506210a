/* libFuzzer target: the device config string parser (core/config.c,
 * compiled into this target: it is not exported).  Any text must parse or
 * fail with a message, never crash, and a parsed config must be freed
 * cleanly. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "core/internal.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char *text = malloc(size + 1);
    if (!text)
        return 0;
    memcpy(text, data, size);
    text[size] = 0;
    rtk_config cfg;
    char msg[256];
    msg[0] = 0;
    const rtk_error e = rtk_config_parse(text, &cfg, msg, sizeof msg);
    if (e == RTK_OK)
        rtk_config_free(&cfg);
    else if (!msg[0])
        abort(); /* a refusal always says why */
    free(text);
    return 0;
}
