/* Little-endian field access for rtk's file headers (.rtkm, .rtkb). */
#ifndef RTK_TOOLS_LE_BYTES_H
#define RTK_TOOLS_LE_BYTES_H
#include <stdint.h>
#include <string.h>

static inline void le_put32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (unsigned char)(v >> (8 * i));
}
static inline void le_put64(unsigned char *p, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (unsigned char)(v >> (8 * i));
}
static inline uint32_t le_get32(const unsigned char *p)
{
    uint32_t v = 0;
    for (int i = 3; i >= 0; i--)
        v = v << 8 | p[i];
    return v;
}
static inline uint64_t le_get64(const unsigned char *p)
{
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--)
        v = v << 8 | p[i];
    return v;
}
static inline void le_putf(unsigned char *p, float f)
{
    uint32_t v;
    memcpy(&v, &f, sizeof v);
    le_put32(p, v);
}
static inline float le_getf(const unsigned char *p)
{
    uint32_t v = le_get32(p);
    float f;
    memcpy(&f, &v, sizeof f);
    return f;
}
static inline void le_putd(unsigned char *p, double d)
{
    uint64_t v;
    memcpy(&v, &d, sizeof v);
    le_put64(p, v);
}
static inline double le_getd(const unsigned char *p)
{
    uint64_t v = le_get64(p);
    double d;
    memcpy(&d, &v, sizeof d);
    return d;
}
#endif
