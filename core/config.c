/* The device configuration string: "key=value,key=value". */
#include <ctype.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

/* One list of known ISA levels; backends outside it are ranked by their header. */
#define RTK_ISA_LIST(X) X(scalar, 0) X(sse41, 10) X(avx, 20) X(avx2, 30) X(avx512, 40)

int rtk_isa_level(const char *name)
{
#define RTK_X_(n, level)      \
    if (!strcmp(name, #n))    \
        return level;
    RTK_ISA_LIST(RTK_X_)
#undef RTK_X_
    return -1;
}

static int valid_backend_name(const char *s, size_t n)
{
    if (n == 0 || n >= RTK_BACKEND_NAME_MAX)
        return 0;
    for (size_t i = 0; i < n; i++)
        if (!(islower((unsigned char)s[i]) || isdigit((unsigned char)s[i]) || s[i] == '_'))
            return 0;
    return 1;
}

static int parse_uint(const char *s, size_t n, unsigned long max, unsigned long *out)
{
    if (n == 0 || n > 10)
        return 0;
    unsigned long v = 0;
    for (size_t i = 0; i < n; i++) {
        if (!isdigit((unsigned char)s[i]))
            return 0;
        v = v * 10 + (unsigned long)(s[i] - '0');
    }
    if (v > max)
        return 0;
    *out = v;
    return 1;
}

/* A builder or layout name: lower-case letters, digits, '.', '-', '_'. */
static int valid_table_name(const char *s, size_t n)
{
    if (n == 0 || n >= RTK_BACKEND_NAME_MAX)
        return 0;
    for (size_t i = 0; i < n; i++)
        if (!(islower((unsigned char)s[i]) || isdigit((unsigned char)s[i]) || strchr(".-_", s[i])))
            return 0;
    return 1;
}

#define KNOWN_KEYS "isa, max_isa, threads, verbose, backend_path, builder, layout, motion_layout"

static rtk_error parse_items(const char *text, rtk_config *cfg, char *msg, size_t msg_size)
{
    const char *p = text;
    while (*p) {
        const char *end = strchr(p, ',');
        if (!end)
            end = p + strlen(p);
        const char *eq = memchr(p, '=', (size_t)(end - p));
        if (end == p) { /* empty item: ",," or a trailing comma */
            p = *end ? end + 1 : end;
            continue;
        }
        if (!eq) {
            snprintf(msg, msg_size, "config item '%.*s' is not key=value (known keys: " KNOWN_KEYS ")",
                     (int)(end - p), p);
            return RTK_ERROR_INVALID_CONFIG;
        }
        const size_t klen = (size_t)(eq - p);
        const char *val = eq + 1;
        const size_t vlen = (size_t)(end - val);
#define KEY(k) (klen == sizeof(k) - 1 && !memcmp(p, k, klen))
        unsigned long v;
        if (KEY("isa") || KEY("max_isa")) {
            if (!valid_backend_name(val, vlen)) {
                snprintf(msg, msg_size, "config %.*s='%.*s': expected a backend name such as scalar, sse41, avx, avx2",
                         (int)klen, p, (int)vlen, val);
                return RTK_ERROR_INVALID_CONFIG;
            }
            char *dst = KEY("isa") ? cfg->isa : cfg->max_isa;
            memcpy(dst, val, vlen);
            dst[vlen] = '\0';
        } else if (KEY("builder") || KEY("layout") || KEY("motion_layout")) {
            if (!valid_table_name(val, vlen)) {
                snprintf(msg, msg_size, "config %.*s='%.*s': expected a name such as %s", (int)klen, p, (int)vlen,
                         val, KEY("builder") ? "morton, sah-binned, sah-spatial"
                              : KEY("layout") ? "bvh4.triangle4, bvh8.triangle4" : "bvh4.triangle4mb, bvh8.triangle4mb");
                return RTK_ERROR_INVALID_CONFIG;
            }
            char *dst = KEY("builder") ? cfg->builder : KEY("layout") ? cfg->layout : cfg->motion_layout;
            memcpy(dst, val, vlen);
            dst[vlen] = '\0';
        } else if (KEY("threads")) {
            if (!parse_uint(val, vlen, 4096, &v)) {
                snprintf(msg, msg_size, "config threads='%.*s': expected a whole number from 0 (all cores) to 4096",
                         (int)vlen, val);
                return RTK_ERROR_INVALID_CONFIG;
            }
            cfg->threads = (unsigned)v;
        } else if (KEY("verbose")) {
            if (!parse_uint(val, vlen, 3, &v)) {
                snprintf(msg, msg_size, "config verbose='%.*s': expected 0, 1, 2 or 3", (int)vlen, val);
                return RTK_ERROR_INVALID_CONFIG;
            }
            cfg->verbose = (int)v;
        } else if (KEY("backend_path")) {
            if (vlen == 0) {
                snprintf(msg, msg_size, "config backend_path is empty: expected ':'-separated directories");
                return RTK_ERROR_INVALID_CONFIG;
            }
            free(cfg->backend_path);
            cfg->backend_path = strndup(val, vlen);
            if (!cfg->backend_path) {
                snprintf(msg, msg_size, "out of memory");
                return RTK_ERROR_OUT_OF_MEMORY;
            }
        } else {
            snprintf(msg, msg_size, "unknown config key '%.*s' (known keys: " KNOWN_KEYS ")", (int)klen, p);
            return RTK_ERROR_INVALID_CONFIG;
        }
#undef KEY
        p = *end ? end + 1 : end;
    }
    return RTK_OK;
}

rtk_error rtk_config_parse(const char *text, rtk_config *cfg, char *msg, size_t msg_size)
{
    memset(cfg, 0, sizeof *cfg);
    if (!text)
        return RTK_OK;
    const rtk_error e = parse_items(text, cfg, msg, msg_size);
    if (e != RTK_OK)
        rtk_config_free(cfg); /* (a backend_path before the bad item; found by fuzz_config) */
    return e;
}

void rtk_config_free(rtk_config *cfg)
{
    free(cfg->backend_path);
    cfg->backend_path = NULL;
}
