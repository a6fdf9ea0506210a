/*
 * Settings of the avx backend beyond its compiler flags and CPU requirements
 * (both in CMakeLists.txt, rtk_add_backend).  Define RTK_OVERRIDE_* here to
 * replace a common kernel with a hand-tuned one (see
 * backends/common/backend_entry.c); none is needed yet.
 */
#ifndef RTK_BACKEND_CONFIG_H
#define RTK_BACKEND_CONFIG_H

/* Rays in flight per stream call (traverse_stream.h; 8 in the other
 * backends): against 8, dragon.ply's incoherent and sun streams 8-11%
 * faster, procedural:4M's within 2% (rtktool bench, 1 thread, AMD EPYC,
 * docs/benchmarks/streams.md); sse41 was 3-10% slower at 16. */
#define RTK_STREAM_K 16
#endif
