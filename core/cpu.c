/*
 * CPU probe.  AVX-class features count only when the CPU has them and the OS
 * saves the matching register state (OSXSAVE set and XGETBV reporting the XMM
 * and YMM bits, plus opmask/ZMM bits for AVX-512), as dav1d's x86 probe does.
 * This file is compiled for the baseline ISA only.
 */
#include <stdio.h>
#include <string.h>

#include "internal.h"

#if defined(__x86_64__) || defined(__i386__)
#include <cpuid.h>

static uint64_t xgetbv0(void)
{
    uint32_t eax, edx;
    __asm__ volatile("xgetbv" : "=a"(eax), "=d"(edx) : "c"(0));
    return ((uint64_t)edx << 32) | eax;
}

uint64_t rtk_cpu_detect(void)
{
    unsigned a, b, c, d;
    uint64_t f = 0;
    if (!__get_cpuid(0, &a, &b, &c, &d))
        return 0;
    const unsigned max_leaf = a;
    __get_cpuid(1, &a, &b, &c, &d);
    if (d & (1u << 25)) f |= RTK_CPU_SSE;
    if (d & (1u << 26)) f |= RTK_CPU_SSE2;
    if (c & (1u << 0)) f |= RTK_CPU_SSE3;
    if (c & (1u << 9)) f |= RTK_CPU_SSSE3;
    if (c & (1u << 19)) f |= RTK_CPU_SSE41;
    if (c & (1u << 20)) f |= RTK_CPU_SSE42;
    if (c & (1u << 23)) f |= RTK_CPU_POPCNT;

    const int osxsave = (c >> 27) & 1;
    const uint64_t xcr0 = osxsave ? xgetbv0() : 0;
    const int os_ymm = (xcr0 & 0x6) == 0x6;      /* XMM and YMM state */
    const int os_zmm = (xcr0 & 0xe6) == 0xe6;    /* plus opmask, ZMM_Hi256, Hi16_ZMM */
    if (os_ymm) {
        if (c & (1u << 28)) f |= RTK_CPU_AVX;
        if (c & (1u << 29)) f |= RTK_CPU_F16C;
        if (c & (1u << 12)) f |= RTK_CPU_FMA;
    }
    if (max_leaf >= 7) {
        __cpuid_count(7, 0, a, b, c, d);
        if (b & (1u << 3)) f |= RTK_CPU_BMI1;
        if (b & (1u << 8)) f |= RTK_CPU_BMI2;
        if (os_ymm && (b & (1u << 5))) f |= RTK_CPU_AVX2;
        if (os_zmm) {
            if (b & (1u << 16)) f |= RTK_CPU_AVX512F;
            if (b & (1u << 17)) f |= RTK_CPU_AVX512DQ;
            if (b & (1u << 28)) f |= RTK_CPU_AVX512CD;
            if (b & (1u << 30)) f |= RTK_CPU_AVX512BW;
            if (b & (1u << 31)) f |= RTK_CPU_AVX512VL;
        }
    }
    __get_cpuid(0x80000000u, &a, &b, &c, &d);
    if (a >= 0x80000001u) {
        __get_cpuid(0x80000001u, &a, &b, &c, &d);
        if (c & (1u << 5)) f |= RTK_CPU_LZCNT;
    }
    return f;
}
#else
uint64_t rtk_cpu_detect(void)
{
    return 0;
}
#endif

uint64_t rtk_cpu_features(void)
{
    return rtk_cpu_detect();
}

static const struct {
    uint64_t bit;
    const char *name;
} feature_names[] = {
#define RTK_X_(name, bit, text) {RTK_CPU_##name, text},
    RTK_CPU_FEATURE_LIST(RTK_X_)
#undef RTK_X_
};

size_t rtk_cpu_features_string(uint64_t features, char *buf, size_t size)
{
    size_t len = 0;
    uint64_t known = 0;
    if (buf && size)
        buf[0] = '\0';
    for (size_t i = 0; i < sizeof feature_names / sizeof feature_names[0]; i++) {
        known |= feature_names[i].bit;
        if (!(features & feature_names[i].bit))
            continue;
        int n = snprintf(buf && len < size ? buf + len : NULL, buf && len < size ? size - len : 0, "%s%s",
                         len ? " " : "", feature_names[i].name);
        len += (size_t)n;
    }
    if (features & ~known) {
        int n = snprintf(buf && len < size ? buf + len : NULL, buf && len < size ? size - len : 0,
                         "%sunknown(0x%llx)", len ? " " : "", (unsigned long long)(features & ~known));
        len += (size_t)n;
    }
    return len;
}
