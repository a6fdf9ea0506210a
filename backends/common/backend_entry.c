/*
 * The backend entry point and its tables, compiled once per backend.
 *
 * Hand-tuned overrides: a backend's backend_config.h may define
 * RTK_OVERRIDE_BVH4_INTERSECT1 / RTK_OVERRIDE_BVH4_OCCLUDED1 /
 * RTK_OVERRIDE_BUILD_SAH to the name of its own function (listed in that
 * backend's RTK_BACKEND_<NAME>_SOURCES in CMake); the table then points there
 * instead of at the common kernel.  Every override is tested against the
 * scalar backend like everything else.
 */
#include <stddef.h>

#include "backend_common.h"
#include "bvh4_triangle4.h"
#include "kernels.h"
#include "simd/simd.h"

#ifndef RTK_BACKEND_LEVEL
#error "RTK_BACKEND_LEVEL is set by rtk_add_backend() in CMake"
#endif
#ifndef RTK_BACKEND_CPU_REQUIRES
#error "RTK_BACKEND_CPU_REQUIRES is set by rtk_add_backend() in CMake"
#endif

#ifdef RTK_OVERRIDE_BVH4_INTERSECT1
#define BVH4_INTERSECT1 RTK_OVERRIDE_BVH4_INTERSECT1
#else
#define BVH4_INTERSECT1 RTK_SYM(rtk_bvh4_intersect1)
#endif
#ifdef RTK_OVERRIDE_BVH4_OCCLUDED1
#define BVH4_OCCLUDED1 RTK_OVERRIDE_BVH4_OCCLUDED1
#else
#define BVH4_OCCLUDED1 RTK_SYM(rtk_bvh4_occluded1)
#endif
#ifdef RTK_OVERRIDE_BUILD_SAH
#define BUILD_SAH RTK_OVERRIDE_BUILD_SAH
#else
#define BUILD_SAH RTK_SYM(rtk_build_sah)
#endif

#define SAH_QUALITIES (1u << RTK_BUILD_QUALITY_MEDIUM)
#define SPATIAL_QUALITIES (1u << RTK_BUILD_QUALITY_HIGH)
#define MORTON_QUALITIES (1u << RTK_BUILD_QUALITY_LOW)

/* The core takes the first builder that serves a scene's quality, and that
 * builder's layout: with 8-wide vectors (sse41, avx, avx2) that is bvh8.triangle4.
 * Measured on dragon (bench_vs_embree, 1 thread, avx2): primary rays 4.25 ->
 * 5.37 Mrays/s against bvh4, random and shadow rays within 2%, memory 66.6 ->
 * 70.2 bytes/triangle (Embree's default is about 70).  On sse41 (8 lanes
 * as two SSE halves, vfloat8_sse41.h) since 8-wide nodes measured faster
 * there too: rtktool bench dragon.ply sanmiguel_building.ply --only trace
 * --isa scalar,sse41 --threads 1, two rounds against bvh4.triangle4, diffuse
 * single rays on dragon 3.36-3.45 -> 3.58-4.10 Mrays/s, San Miguel
 * 15.4-16.5 -> 17.9-18.7, packets of 8 (no longer two of 4) camera rays
 * 9.0-9.3 -> 11.7-12.1 and 23.1-23.9 -> 29.2-29.3, packets of 4 within 5%
 * either way.  Low quality is the
 * Morton builder, medium the binned SAH builder and high the same with
 * spatial splits; rtk_scene_info names the builder used. */
static const rtk_builder_entry builders[] = {
#ifdef RTK_SIMD_HAS_8
    {.name = "morton", .qualities = MORTON_QUALITIES, .layout = RTK_LAYOUT_BVH8_TRIANGLE4, .build = RTK_SYM(rtk_build_morton)},
    {.name = "sah-binned", .qualities = SAH_QUALITIES, .layout = RTK_LAYOUT_BVH8_TRIANGLE4, .build = BUILD_SAH},
    {.name = "sah-spatial", .qualities = SPATIAL_QUALITIES, .layout = RTK_LAYOUT_BVH8_TRIANGLE4, .build = RTK_SYM(rtk_build_sah_spatial)},
#endif
    {.name = "morton", .qualities = MORTON_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4, .build = RTK_SYM(rtk_build_morton)},
    {.name = "sah-binned", .qualities = SAH_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4, .build = BUILD_SAH},
    {.name = "sah-spatial", .qualities = SPATIAL_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4, .build = RTK_SYM(rtk_build_sah_spatial)},
    /* compact scenes: 4-wide nodes (half the bytes of 8-wide ones per
     * child slot filled) and index leaves, on every backend */
    {.name = "morton", .qualities = MORTON_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .build = RTK_SYM(rtk_build_morton)},
    {.name = "sah-binned", .qualities = SAH_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .build = BUILD_SAH},
    {.name = "sah-spatial", .qualities = SPATIAL_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .build = RTK_SYM(rtk_build_sah_spatial)},
    /* robust scenes: vertex leaves (the watertight test needs the
     * vertices themselves), 8-wide nodes where vectors are 8 wide; robust
     * and compact: index leaves */
#ifdef RTK_SIMD_HAS_8
    {.name = "morton", .qualities = MORTON_QUALITIES, .layout = RTK_LAYOUT_BVH8_TRIANGLE4V, .build = RTK_SYM(rtk_build_morton)},
    {.name = "sah-binned", .qualities = SAH_QUALITIES, .layout = RTK_LAYOUT_BVH8_TRIANGLE4V, .build = BUILD_SAH},
    {.name = "sah-spatial", .qualities = SPATIAL_QUALITIES, .layout = RTK_LAYOUT_BVH8_TRIANGLE4V, .build = RTK_SYM(rtk_build_sah_spatial)},
#endif
    {.name = "morton", .qualities = MORTON_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4V, .build = RTK_SYM(rtk_build_morton)},
    {.name = "sah-binned", .qualities = SAH_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4V, .build = BUILD_SAH},
    {.name = "sah-spatial", .qualities = SPATIAL_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4V, .build = RTK_SYM(rtk_build_sah_spatial)},
    {.name = "morton", .qualities = MORTON_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, .build = RTK_SYM(rtk_build_morton)},
    {.name = "sah-binned", .qualities = SAH_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, .build = BUILD_SAH},
    {.name = "sah-spatial", .qualities = SPATIAL_QUALITIES, .layout = RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, .build = RTK_SYM(rtk_build_sah_spatial)},
    {0},
};

static const rtk_layout_entry layouts[] = {
#ifdef RTK_SIMD_HAS_8
    {.id = RTK_LAYOUT_BVH8_TRIANGLE4, .scene_flags = 0, .name = "bvh8.triangle4", .release = RTK_SYM(rtk_bvh4_release)},
#endif
    {.id = RTK_LAYOUT_BVH4_TRIANGLE4, .scene_flags = 0, .name = "bvh4.triangle4", .release = RTK_SYM(rtk_bvh4_release)},
    {.id = RTK_LAYOUT_BVH4_TRIANGLE4I, .scene_flags = RTK_SCENE_FLAG_COMPACT, .name = "bvh4.triangle4i",
     .release = RTK_SYM(rtk_bvh4_release)},
#ifdef RTK_SIMD_HAS_8
    {.id = RTK_LAYOUT_BVH8_TRIANGLE4V, .scene_flags = RTK_SCENE_FLAG_ROBUST, .name = "bvh8.triangle4v",
     .release = RTK_SYM(rtk_bvh4_release)},
#endif
    {.id = RTK_LAYOUT_BVH4_TRIANGLE4V, .scene_flags = RTK_SCENE_FLAG_ROBUST, .name = "bvh4.triangle4v",
     .release = RTK_SYM(rtk_bvh4_release)},
    {.id = RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, .scene_flags = RTK_SCENE_FLAG_ROBUST | RTK_SCENE_FLAG_COMPACT,
     .name = "bvh4.triangle4i.robust", .release = RTK_SYM(rtk_bvh4_release)},
    /* the top level of scenes with instances (objects.c): built by the
     * objects entry below, never by a triangle builder */
    {.id = RTK_LAYOUT_BVH4_OBJECT, .scene_flags = 0, .name = "bvh4.object", .release = RTK_SYM(rtk_objects_release)},
    /* motion blur (build_motion.c): built by the motion builders below */
#ifdef RTK_SIMD_HAS_8
    {.id = RTK_LAYOUT_BVH8_TRIANGLE4MB, .scene_flags = 0, .name = "bvh8.triangle4mb",
     .release = RTK_SYM(rtk_motion_release)},
    {.id = RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST, .scene_flags = RTK_SCENE_FLAG_ROBUST, .name = "bvh8.triangle4mb.robust",
     .release = RTK_SYM(rtk_motion_release)},
#endif
    {.id = RTK_LAYOUT_BVH4_TRIANGLE4MB, .scene_flags = 0, .name = "bvh4.triangle4mb",
     .release = RTK_SYM(rtk_motion_release)},
    {.id = RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST, .scene_flags = RTK_SCENE_FLAG_ROBUST, .name = "bvh4.triangle4mb.robust",
     .release = RTK_SYM(rtk_motion_release)},
    {0},
};

static const rtk_kernel_entry kernels[] = {
#ifdef RTK_SIMD_HAS_8
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4, .query = RTK_QUERY_INTERSECT, .width = 1,
     .fn.intersect1 = RTK_SYM(rtk_bvh8_intersect1)},
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4, .query = RTK_QUERY_OCCLUDED, .width = 1,
     .fn.occluded1 = RTK_SYM(rtk_bvh8_occluded1)},
    /* packets: the core splits 16 into 8s, and uses the 4-wide kernel for 4 */
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4, .query = RTK_QUERY_INTERSECT, .width = 4,
     .fn.intersectN = RTK_SYM(rtk_bvh8_intersect4)},
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4, .query = RTK_QUERY_OCCLUDED, .width = 4,
     .fn.occludedN = RTK_SYM(rtk_bvh8_occluded4)},
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4, .query = RTK_QUERY_INTERSECT, .width = 8,
     .fn.intersectN = RTK_SYM(rtk_bvh8_intersect8)},
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4, .query = RTK_QUERY_OCCLUDED, .width = 8,
     .fn.occludedN = RTK_SYM(rtk_bvh8_occluded8)},
#endif
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4, .query = RTK_QUERY_INTERSECT, .width = 1, .fn.intersect1 = BVH4_INTERSECT1},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4, .query = RTK_QUERY_OCCLUDED, .width = 1, .fn.occluded1 = BVH4_OCCLUDED1},
#ifdef __SSE4_1__
    /* Not in the scalar backend, where the core goes ray by ray: there the
     * packet kernel is no faster (bench_vs_embree primary8: dragon 2.56
     * against 2.41 Mrays/s ray by ray, San Miguel 5.36 against 5.45). */
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4, .query = RTK_QUERY_INTERSECT, .width = 4,
     .fn.intersectN = RTK_SYM(rtk_bvh4_intersect4)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4, .query = RTK_QUERY_OCCLUDED, .width = 4,
     .fn.occludedN = RTK_SYM(rtk_bvh4_occluded4)},
#endif
#ifdef RTK_SIMD_HAS_8
    /* 8-ray packets over 4-wide nodes where vectors are 8 wide */
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4, .query = RTK_QUERY_INTERSECT, .width = 8,
     .fn.intersectN = RTK_SYM(rtk_bvh4_intersect8)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4, .query = RTK_QUERY_OCCLUDED, .width = 8,
     .fn.occludedN = RTK_SYM(rtk_bvh4_occluded8)},
#endif
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .query = RTK_QUERY_INTERSECT, .width = 1,
     .fn.intersect1 = RTK_SYM(rtk_bvh4i_intersect1)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .query = RTK_QUERY_OCCLUDED, .width = 1,
     .fn.occluded1 = RTK_SYM(rtk_bvh4i_occluded1)},
#ifdef __SSE4_1__
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .query = RTK_QUERY_INTERSECT, .width = 4,
     .fn.intersectN = RTK_SYM(rtk_bvh4i_intersect4)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .query = RTK_QUERY_OCCLUDED, .width = 4,
     .fn.occludedN = RTK_SYM(rtk_bvh4i_occluded4)},
#endif
#ifdef RTK_SIMD_HAS_8
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .query = RTK_QUERY_INTERSECT, .width = 8,
     .fn.intersectN = RTK_SYM(rtk_bvh4i_intersect8)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4I, .query = RTK_QUERY_OCCLUDED, .width = 8,
     .fn.occludedN = RTK_SYM(rtk_bvh4i_occluded8)},
#endif
    /* robust layouts: the same kernels with the watertight test (packet
     * kernels as for the default layouts) */
#define KERNEL1(id, tag)                                                                                               \
    {.layout = id, .query = RTK_QUERY_INTERSECT, .width = 1, .fn.intersect1 = RTK_SYM(rtk_bvh##tag##_intersect1)},    \
        {.layout = id, .query = RTK_QUERY_OCCLUDED, .width = 1, .fn.occluded1 = RTK_SYM(rtk_bvh##tag##_occluded1)}
#define KERNELN(id, tag, k)                                                                                            \
    {.layout = id, .query = RTK_QUERY_INTERSECT, .width = k, .fn.intersectN = RTK_SYM(rtk_bvh##tag##_intersect##k)},  \
        {.layout = id, .query = RTK_QUERY_OCCLUDED, .width = k, .fn.occludedN = RTK_SYM(rtk_bvh##tag##_occluded##k)}
#ifdef RTK_SIMD_HAS_8
    KERNEL1(RTK_LAYOUT_BVH8_TRIANGLE4V, 8v),
    KERNELN(RTK_LAYOUT_BVH8_TRIANGLE4V, 8v, 4),
    KERNELN(RTK_LAYOUT_BVH8_TRIANGLE4V, 8v, 8),
#endif
    KERNEL1(RTK_LAYOUT_BVH4_TRIANGLE4V, 4v),
    KERNEL1(RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, 4ir),
#ifdef __SSE4_1__
    KERNELN(RTK_LAYOUT_BVH4_TRIANGLE4V, 4v, 4),
    KERNELN(RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, 4ir, 4),
#endif
#ifdef RTK_SIMD_HAS_8
    KERNELN(RTK_LAYOUT_BVH4_TRIANGLE4V, 4v, 8),
    KERNELN(RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, 4ir, 8),
#endif
    /* streams: many single rays in flight (traverse_stream.h) */
#define KERNELM(id, tag)                                                                                               \
    {.layout = id, .query = RTK_QUERY_INTERSECT, .width = RTK_KERNEL_WIDTH_STREAM, .in_flight = RTK_STREAM_K,        \
     .fn.intersect_stream = RTK_SYM(rtk_bvh##tag##_intersect_stream)},                                                 \
        {.layout = id, .query = RTK_QUERY_OCCLUDED, .width = RTK_KERNEL_WIDTH_STREAM, .in_flight = RTK_STREAM_K,      \
         .fn.occluded_stream = RTK_SYM(rtk_bvh##tag##_occluded_stream)}
#ifdef RTK_SIMD_HAS_8
    KERNELM(RTK_LAYOUT_BVH8_TRIANGLE4, 8),
    KERNELM(RTK_LAYOUT_BVH8_TRIANGLE4V, 8v),
#endif
    KERNELM(RTK_LAYOUT_BVH4_TRIANGLE4, 4),
    KERNELM(RTK_LAYOUT_BVH4_TRIANGLE4I, 4i),
    KERNELM(RTK_LAYOUT_BVH4_TRIANGLE4V, 4v),
    KERNELM(RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST, 4ir),
    /* motion blur: each ray in its time segment's tree (traverse_motion.h) */
#ifdef RTK_SIMD_HAS_8
    KERNELM(RTK_LAYOUT_BVH8_TRIANGLE4MB, 8mb),
    KERNELM(RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST, 8mbr),
#endif
    KERNELM(RTK_LAYOUT_BVH4_TRIANGLE4MB, 4mb),
    KERNELM(RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST, 4mbr),
#undef KERNEL1
#undef KERNELN
#undef KERNELM
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_INTERSECT, .width = 1,
     .fn.intersect1 = RTK_SYM(rtk_objects_intersect1)},
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_OCCLUDED, .width = 1,
     .fn.occluded1 = RTK_SYM(rtk_objects_occluded1)},
    /* streams through both levels (traverse_objects_stream.h); the core
     * hands them packets too (core/query.c), whose few rays they trace one
     * after the other (objs_slots) */
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_INTERSECT, .width = RTK_KERNEL_WIDTH_STREAM,
     .in_flight = RTK_STREAM_K, .fn.intersect_stream = RTK_SYM(rtk_objects_intersect_stream)},
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_OCCLUDED, .width = RTK_KERNEL_WIDTH_STREAM,
     .in_flight = RTK_STREAM_K, .fn.occluded_stream = RTK_SYM(rtk_objects_occluded_stream)},
    /* whole packets through the top level, for user primitives' callbacks
     * (the core uses them only in scenes that have some) */
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_INTERSECT, .width = 4,
     .fn.intersectN = RTK_SYM(rtk_objects_intersect4)},
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_OCCLUDED, .width = 4,
     .fn.occludedN = RTK_SYM(rtk_objects_occluded4)},
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_INTERSECT, .width = 8,
     .fn.intersectN = RTK_SYM(rtk_objects_intersect8)},
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_OCCLUDED, .width = 8,
     .fn.occludedN = RTK_SYM(rtk_objects_occluded8)},
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_INTERSECT, .width = 16,
     .fn.intersectN = RTK_SYM(rtk_objects_intersect16)},
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .query = RTK_QUERY_OCCLUDED, .width = 16,
     .fn.occludedN = RTK_SYM(rtk_objects_occluded16)},
#ifdef RTK_SIMD_HAS_8
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4MB, .query = RTK_QUERY_INTERSECT, .width = 1,
     .fn.intersect1 = RTK_SYM(rtk_bvh8mb_intersect1)},
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4MB, .query = RTK_QUERY_OCCLUDED, .width = 1,
     .fn.occluded1 = RTK_SYM(rtk_bvh8mb_occluded1)},
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST, .query = RTK_QUERY_INTERSECT, .width = 1,
     .fn.intersect1 = RTK_SYM(rtk_bvh8mbr_intersect1)},
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST, .query = RTK_QUERY_OCCLUDED, .width = 1,
     .fn.occluded1 = RTK_SYM(rtk_bvh8mbr_occluded1)},
#endif
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4MB, .query = RTK_QUERY_INTERSECT, .width = 1,
     .fn.intersect1 = RTK_SYM(rtk_bvh4mb_intersect1)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4MB, .query = RTK_QUERY_OCCLUDED, .width = 1,
     .fn.occluded1 = RTK_SYM(rtk_bvh4mb_occluded1)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST, .query = RTK_QUERY_INTERSECT, .width = 1,
     .fn.intersect1 = RTK_SYM(rtk_bvh4mbr_intersect1)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST, .query = RTK_QUERY_OCCLUDED, .width = 1,
     .fn.occluded1 = RTK_SYM(rtk_bvh4mbr_occluded1)},
    /* closest points: one kernel walks every layout (point_query.c) */
#define CLOSEST(id) {.layout = id, .query = RTK_QUERY_CLOSEST_POINT, .width = 1, .fn.closest_point = RTK_SYM(rtk_closest_point)}
#ifdef RTK_SIMD_HAS_8
    CLOSEST(RTK_LAYOUT_BVH8_TRIANGLE4),
    CLOSEST(RTK_LAYOUT_BVH8_TRIANGLE4V),
    CLOSEST(RTK_LAYOUT_BVH8_TRIANGLE4MB),
    CLOSEST(RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST),
#endif
    CLOSEST(RTK_LAYOUT_BVH4_TRIANGLE4),
    CLOSEST(RTK_LAYOUT_BVH4_TRIANGLE4I),
    CLOSEST(RTK_LAYOUT_BVH4_TRIANGLE4V),
    CLOSEST(RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST),
    CLOSEST(RTK_LAYOUT_BVH4_OBJECT),
    CLOSEST(RTK_LAYOUT_BVH4_TRIANGLE4MB),
    CLOSEST(RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST),
#undef CLOSEST
    {0},
};

/* Every layout converts to and from rtk_bvh the same way. */
#define LAYOUT_IO(id) {.layout = id, .export_tree = RTK_SYM(rtk_bvh_export), .import_tree = RTK_SYM(rtk_bvh_import)}
static const rtk_layout_io_entry layout_io[] = {
#ifdef RTK_SIMD_HAS_8
    LAYOUT_IO(RTK_LAYOUT_BVH8_TRIANGLE4),
#endif
    LAYOUT_IO(RTK_LAYOUT_BVH4_TRIANGLE4),
    LAYOUT_IO(RTK_LAYOUT_BVH4_TRIANGLE4I),
#ifdef RTK_SIMD_HAS_8
    LAYOUT_IO(RTK_LAYOUT_BVH8_TRIANGLE4V),
#endif
    LAYOUT_IO(RTK_LAYOUT_BVH4_TRIANGLE4V),
    LAYOUT_IO(RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST),
    {0},
};

/* Every static layout refits the same way (refit.c). */
#define LAYOUT_REFIT(id) {.layout = id, .refit = RTK_SYM(rtk_bvh_refit)}
static const rtk_layout_refit_entry layout_refit[] = {
#ifdef RTK_SIMD_HAS_8
    LAYOUT_REFIT(RTK_LAYOUT_BVH8_TRIANGLE4),
#endif
    LAYOUT_REFIT(RTK_LAYOUT_BVH4_TRIANGLE4),
    LAYOUT_REFIT(RTK_LAYOUT_BVH4_TRIANGLE4I),
#ifdef RTK_SIMD_HAS_8
    LAYOUT_REFIT(RTK_LAYOUT_BVH8_TRIANGLE4V),
#endif
    LAYOUT_REFIT(RTK_LAYOUT_BVH4_TRIANGLE4V),
    LAYOUT_REFIT(RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST),
    /* motion blur: every box of every time segment's tree (build_motion.c) */
#ifdef RTK_SIMD_HAS_8
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4MB, .refit = RTK_SYM(rtk_motion_refit)},
    {.layout = RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST, .refit = RTK_SYM(rtk_motion_refit)},
#endif
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4MB, .refit = RTK_SYM(rtk_motion_refit)},
    {.layout = RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST, .refit = RTK_SYM(rtk_motion_refit)},
    /* a dynamic scene's top level, over the same objects (objects.c) */
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .refit = RTK_SYM(rtk_objects_refit)},
    {0},
};

static const rtk_objects_entry objects[] = {
    {.layout = RTK_LAYOUT_BVH4_OBJECT, .build = RTK_SYM(rtk_build_objects)},
    {0},
};

/* Motion blur: one build function, shaping each time segment's tree with
 * the Morton builder at low quality and the binned SAH builder otherwise
 * (spatial splits would cut triangles at planes of one time only); 8-wide
 * nodes first where vectors are 8 wide (Embree's default on AVX2 too).
 * Robust scenes: the same trees, traced with the watertight test. */
#define MOTION_BUILDERS(id, robust_id)                                                                                \
    {.name = "morton", .qualities = MORTON_QUALITIES, .layout = id, .build = RTK_SYM(rtk_build_motion)},             \
        {.name = "sah-binned", .qualities = SAH_QUALITIES | SPATIAL_QUALITIES, .layout = id,                          \
         .build = RTK_SYM(rtk_build_motion)},                                                                          \
        {.name = "morton", .qualities = MORTON_QUALITIES, .layout = robust_id, .build = RTK_SYM(rtk_build_motion)},   \
        {.name = "sah-binned", .qualities = SAH_QUALITIES | SPATIAL_QUALITIES, .layout = robust_id,                   \
         .build = RTK_SYM(rtk_build_motion)}
static const rtk_builder_entry motion_builders[] = {
#ifdef RTK_SIMD_HAS_8
    MOTION_BUILDERS(RTK_LAYOUT_BVH8_TRIANGLE4MB, RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST),
#endif
    MOTION_BUILDERS(RTK_LAYOUT_BVH4_TRIANGLE4MB, RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST),
#undef MOTION_BUILDERS
    {0},
};

static const rtk_backend_desc desc = {
    .struct_size = sizeof(rtk_backend_desc),
    .name = RTK_STR(RTK_BACKEND_NAME),
    .builders = builders,
    .layouts = layouts,
    .kernels = kernels,
    .layout_io = layout_io,
    .layout_refit = layout_refit,
    .objects = objects,
    .motion_builders = motion_builders,
    .caps = RTK_BACKEND_CAP_QUERY_FILTER | RTK_BACKEND_CAP_USER_POINTS,
};

#define HEADER_SYM RTK_CAT(RTK_CAT(rtk_backend_, RTK_BACKEND_NAME), _header)
#define NEGOTIATE_SYM RTK_CAT(RTK_CAT(rtk_backend_, RTK_BACKEND_NAME), _negotiate)

RTK_BACKEND_EXPORT extern const rtk_backend_header HEADER_SYM;
const rtk_backend_header HEADER_SYM = {
    .magic = RTK_BACKEND_MAGIC,
    .struct_size = sizeof(rtk_backend_header),
    .name = RTK_STR(RTK_BACKEND_NAME),
    .level = RTK_BACKEND_LEVEL,
    .interface_version = RTK_BACKEND_INTERFACE_VERSION,
    .cpu_requires = RTK_BACKEND_CPU_REQUIRES,
};

RTK_BACKEND_EXPORT int NEGOTIATE_SYM(const rtk_backend_offer *offer, rtk_backend_answer *answer);
int NEGOTIATE_SYM(const rtk_backend_offer *offer, rtk_backend_answer *answer)
{
    if (!offer || !answer || offer->struct_size < offsetof(rtk_backend_offer, cpu_features) + sizeof(uint64_t) ||
        answer->struct_size < offsetof(rtk_backend_answer, desc) + sizeof(void *))
        return -1;
    /* This backend speaks interface version 1 only. */
    if (offer->version_min > RTK_BACKEND_INTERFACE_VERSION || offer->version_max < RTK_BACKEND_INTERFACE_VERSION)
        return 1;
    answer->version = RTK_BACKEND_INTERFACE_VERSION;
    answer->desc = &desc;
    return 0;
}
