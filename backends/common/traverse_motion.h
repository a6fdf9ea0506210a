/* Traversal of bvhN.triangle4mb and bvhN.triangle4mb.robust (motion
 * blur, build_motion.c), included by traverse_bvh4mb.c, traverse_bvh4mbr.c
 * (N = 4) and traverse_bvh8mb.c, traverse_bvh8mbr.c (N = 8, defining
 * RTK_BVHN first): the single-ray template with planes and vertices
 * interpolated to the ray's time, through the tree of the time segment the
 * time falls in.  A ray whose time is outside [0, 1] (or NaN) hits nothing
 * here: the motion is defined over that range only.  Streams interleave
 * their rays as in the static layouts (traverse_stream.h, each ray in its
 * segment's tree).  No packet kernels: the core traces a packet's rays as
 * a stream. */
#ifndef RTK_BVHN
#define RTK_BVHN 4
#endif
#define RTK_MOTION 1
#include "traverse_bvhn.h"

/* The segment of the ray's time and the time within it into p; the
 * segment's tree, or NULL when the time is outside [0, 1]. */
static inline const rtk_accel *segment_at(const rtk_accel *accel, float time, ray_pre *p)
{
    if (!(time >= 0.0f && time <= 1.0f))
        return NULL;
    const uint32_t n = accel->segment_count;
    const float ts = time * (float)n;
    uint32_t s = (uint32_t)ts;
    s = s < n ? s : n - 1;
    const float f = ts - (float)s; /* exact: ts and s are within a factor of two or s is 0 */
    p->ftime = vn_set1(f);
    p->f4 = vf4_set1(f);
    p->one_f4 = vf4_set1(1.0f - f);
    const rtk_accel *seg = &accel->segments[s];
    return seg->root == RTK_BVH4_EMPTY ? NULL : seg;
}

void BVHN_INTERSECT1(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q)
{
    ray_pre p;
    ray_mem pm;
    ray_pre_init(&p, &pm, &rayhit->ray, accel);
    const rtk_accel *seg = segment_at(accel, rayhit->ray.time, &p);
    if (!seg)
        return;
    feat_ctx fc; /* (the attributes are the top accel's: the segments share them) */
    const feat_ctx *f = feat_init(&fc, &rayhit->ray, accel, q);
    closest_hit best = CLOSEST_HIT_NONE;
    float tfar = rayhit->ray.tfar;
    closest_from(seg, seg->root, &p, rayhit->ray.tnear, &tfar, &best, f);
    closest_hit_write(seg, accel, &best, &p, tfar, rayhit);
}

void BVHN_OCCLUDED1(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q)
{
    ray_pre p;
    ray_mem pm;
    ray_pre_init(&p, &pm, ray, accel);
    const rtk_accel *seg = segment_at(accel, ray->time, &p);
    feat_ctx fc;
    if (seg && any_from(seg, seg->root, &p, ray->tnear, ray->tfar, feat_init(&fc, ray, accel, q)))
        ray->tfar = -INFINITY;
}

#include "traverse_stream.h"
