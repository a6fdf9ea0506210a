/* The kernels of backends/common, each named with the backend suffix. */
#ifndef RTK_KERNELS_H
#define RTK_KERNELS_H
#include "backend_common.h"
#include "rtk/rtk_backend.h"

RTK_HIDDEN int RTK_SYM(rtk_build_sah)(const rtk_build_input *in, rtk_build_output *out);
RTK_HIDDEN int RTK_SYM(rtk_build_sah_spatial)(const rtk_build_input *in, rtk_build_output *out);
/* rtk_build_sah for the motion builder's segment trees: an inner node
 * weighed as two blocks of triangles (build_sah.c, leaf_range). */
RTK_HIDDEN int RTK_SYM(rtk_build_sah_motion)(const rtk_build_input *in, rtk_build_output *out);
RTK_HIDDEN int RTK_SYM(rtk_build_morton)(const rtk_build_input *in, rtk_build_output *out);
RTK_HIDDEN void RTK_SYM(rtk_bvh4_release)(rtk_accel *accel);
RTK_HIDDEN int RTK_SYM(rtk_bvh_export)(const rtk_accel *accel, rtk_bvh *tree);
RTK_HIDDEN int RTK_SYM(rtk_bvh_import)(const rtk_build_input *in, const rtk_bvh *tree, rtk_build_output *out);
RTK_HIDDEN int RTK_SYM(rtk_bvh_refit)(rtk_accel *accel, const rtk_build_input *in, rtk_build_output *out);
RTK_HIDDEN void RTK_SYM(rtk_bvh4_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4_intersect4)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4_occluded4)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8_intersect4)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8_occluded4)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8_intersect8)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8_occluded8)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4i_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4i_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4i_intersect4)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4i_occluded4)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4_intersect8)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4_occluded8)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4i_intersect8)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4i_occluded8)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_HIDDEN int RTK_SYM(rtk_build_objects)(const rtk_build_input *in, rtk_build_output *out);
RTK_HIDDEN void RTK_SYM(rtk_objects_release)(rtk_accel *accel);
RTK_HIDDEN int RTK_SYM(rtk_objects_refit)(rtk_accel *accel, const rtk_build_input *in, rtk_build_output *out);
RTK_HIDDEN void RTK_SYM(rtk_objects_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_objects_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_objects_intersect_stream)(const rtk_accel *accel, rtk_rayhit *const *rays, uint32_t count,
                                                      const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_objects_occluded_stream)(const rtk_accel *accel, rtk_ray *const *rays, uint32_t count,
                                                     const rtk_query *q);
#define RTK_OBJECTS_PACKET_DECL_(k)                                                                                    \
    RTK_HIDDEN void RTK_SYM(rtk_objects_intersect##k)(const rtk_accel *accel, const int32_t *active, void *packet,    \
                                                      const rtk_query *q);                                             \
    RTK_HIDDEN void RTK_SYM(rtk_objects_occluded##k)(const rtk_accel *accel, const int32_t *active, void *packet,     \
                                                     const rtk_query *q);
RTK_OBJECTS_PACKET_DECL_(4)
RTK_OBJECTS_PACKET_DECL_(8)
RTK_OBJECTS_PACKET_DECL_(16)
#undef RTK_OBJECTS_PACKET_DECL_
RTK_HIDDEN int RTK_SYM(rtk_build_motion)(const rtk_build_input *in, rtk_build_output *out);
RTK_HIDDEN void RTK_SYM(rtk_motion_release)(rtk_accel *accel);
RTK_HIDDEN int RTK_SYM(rtk_motion_refit)(rtk_accel *accel, const rtk_build_input *in, rtk_build_output *out);
RTK_HIDDEN void RTK_SYM(rtk_bvh4mb_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4mb_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4v_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4v_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8v_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8v_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4ir_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4ir_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
#define RTK_PACKET_DECL_(tag, k)                                                                                      \
    RTK_HIDDEN void RTK_SYM(rtk_bvh##tag##_intersect##k)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q); \
    RTK_HIDDEN void RTK_SYM(rtk_bvh##tag##_occluded##k)(const rtk_accel *accel, const int32_t *active, void *packet, const rtk_query *q);
RTK_PACKET_DECL_(4v, 4)
RTK_PACKET_DECL_(4v, 8)
RTK_PACKET_DECL_(8v, 4)
RTK_PACKET_DECL_(8v, 8)
RTK_PACKET_DECL_(4ir, 4)
RTK_PACKET_DECL_(4ir, 8)
#undef RTK_PACKET_DECL_
/* the closest hits of a stream's coherent groups (traverse_packet.h:
 * PK_INTERSECT_EXACT) */
#define RTK_EXACT_DECL_(tag, k)                                                                                        \
    RTK_HIDDEN unsigned RTK_SYM(rtk_bvh##tag##_intersect##k##_exact)(const rtk_accel *accel, const int32_t *active,    \
                                                                     void *packet, const rtk_query *q);
RTK_EXACT_DECL_(4, 4)
RTK_EXACT_DECL_(4, 8)
RTK_EXACT_DECL_(8, 4)
RTK_EXACT_DECL_(8, 8)
RTK_EXACT_DECL_(4i, 4)
RTK_EXACT_DECL_(4i, 8)
RTK_EXACT_DECL_(4v, 4)
RTK_EXACT_DECL_(4v, 8)
RTK_EXACT_DECL_(8v, 4)
RTK_EXACT_DECL_(8v, 8)
RTK_EXACT_DECL_(4ir, 4)
RTK_EXACT_DECL_(4ir, 8)
#undef RTK_EXACT_DECL_
/* streams (traverse_stream.h), RTK_STREAM_K rays in flight per thread
 * (backend_config.h may set it) */
#ifndef RTK_STREAM_K
#define RTK_STREAM_K 8
#endif
#define RTK_STREAM_DECL_(tag)                                                                                          \
    RTK_HIDDEN void RTK_SYM(rtk_bvh##tag##_intersect_stream)(const rtk_accel *accel, rtk_rayhit *const *rays,          \
                                                              uint32_t count, const rtk_query *q);                     \
    RTK_HIDDEN void RTK_SYM(rtk_bvh##tag##_occluded_stream)(const rtk_accel *accel, rtk_ray *const *rays,              \
                                                             uint32_t count, const rtk_query *q);
RTK_STREAM_DECL_(4)
RTK_STREAM_DECL_(8)
RTK_STREAM_DECL_(4i)
RTK_STREAM_DECL_(4v)
RTK_STREAM_DECL_(8v)
RTK_STREAM_DECL_(4ir)
RTK_STREAM_DECL_(4mb)
RTK_STREAM_DECL_(4mbr)
RTK_STREAM_DECL_(8mb)
RTK_STREAM_DECL_(8mbr)
#undef RTK_STREAM_DECL_
/* the merged two-level traversals (traverse_objects.h): a top level
 * (bvh4.object) whose objects are mostly trees of the layout named */
#define RTK_OBJECTS_MERGED_DECL_(tag)                                                                                  \
    RTK_HIDDEN void RTK_SYM(rtk_bvh##tag##_objects_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit,             \
                                                                const rtk_query *q);                                   \
    RTK_HIDDEN void RTK_SYM(rtk_bvh##tag##_objects_occluded1)(const rtk_accel *accel, rtk_ray *ray,                    \
                                                               const rtk_query *q);                                   \
    RTK_HIDDEN void RTK_SYM(rtk_bvh##tag##_objects_intersect_stream)(const rtk_accel *accel, rtk_rayhit *const *rays,  \
                                                                      uint32_t count, const rtk_query *q);             \
    RTK_HIDDEN void RTK_SYM(rtk_bvh##tag##_objects_occluded_stream)(const rtk_accel *accel, rtk_ray *const *rays,      \
                                                                     uint32_t count, const rtk_query *q);
RTK_OBJECTS_MERGED_DECL_(4)
RTK_OBJECTS_MERGED_DECL_(8)
RTK_OBJECTS_MERGED_DECL_(4i)
RTK_OBJECTS_MERGED_DECL_(4v)
RTK_OBJECTS_MERGED_DECL_(8v)
RTK_OBJECTS_MERGED_DECL_(4ir)
#undef RTK_OBJECTS_MERGED_DECL_
RTK_HIDDEN void RTK_SYM(rtk_bvh4mbr_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh4mbr_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8mb_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8mb_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8mbr_intersect1)(const rtk_accel *accel, rtk_rayhit *rayhit, const rtk_query *q);
RTK_HIDDEN void RTK_SYM(rtk_bvh8mbr_occluded1)(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q);
/* closest points, every layout (point_query.c) */
RTK_HIDDEN void RTK_SYM(rtk_closest_point)(const rtk_accel *accel, rtk_point_state *state, const rtk_query *q);
#endif
