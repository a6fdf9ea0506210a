/* rtk_offset_ray_origin: where a secondary ray starts (rtk.h). */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "internal.h"

/* Waechter and Binder (Ray Tracing Gems, 2019, chapter 6): constants as
 * there.  Coordinates farther than ORIGIN from zero move by a whole number
 * of ulps (INT_SCALE * n: up to 256), which scales with the coordinate as
 * the rounding error of computing it does; nearer zero, where an ulp is
 * tiny, by FLOAT_SCALE * n. */
#define ORIGIN (1.0f / 32.0f)
#define FLOAT_SCALE (1.0f / 65536.0f)
#define INT_SCALE 256.0f

void rtk_offset_ray_origin(const float p[3], const float n[3], float out[3])
{
    for (int k = 0; k < 3; k++) {
        /* (n should be unit length; anything else is clamped, NaN is 0) */
        const float of = INT_SCALE * n[k];
        const int32_t of_i = of >= 2147483520.0f    ? INT32_MAX
                             : of <= -2147483520.0f ? -INT32_MAX
                             : of == of             ? (int32_t)of
                                                    : 0;
        int32_t bits;
        memcpy(&bits, &p[k], sizeof bits);
        /* away from zero along n: more ulps where p and n agree in sign,
         * fewer where they differ (the bits' magnitude is the float's) */
        const int64_t moved = (int64_t)bits + (p[k] < 0.0f ? -(int64_t)of_i : (int64_t)of_i);
        const int32_t moved_i = (int32_t)(moved > INT32_MAX ? INT32_MAX : moved < INT32_MIN ? INT32_MIN : moved);
        float q;
        memcpy(&q, &moved_i, sizeof q);
        /* a coordinate near the float range that would step off it (or a
         * NaN or infinite one) is left where it is */
        out[k] = fabsf(p[k]) < ORIGIN ? p[k] + FLOAT_SCALE * n[k] : isfinite(q) ? q : p[k];
    }
}
