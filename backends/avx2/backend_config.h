/*
 * Settings of the avx2 backend beyond its compiler flags and CPU requirements
 * (both in CMakeLists.txt, rtk_add_backend).  Define RTK_OVERRIDE_* here to
 * replace a common kernel with a hand-tuned one (see
 * backends/common/backend_entry.c); none is needed yet.
 */
#ifndef RTK_BACKEND_CONFIG_H
#define RTK_BACKEND_CONFIG_H

/* Rays in flight per stream call (traverse_stream.h; 8 in the other
 * backends).  Against 8, rtktool bench's stream rows on 1 thread (AMD EPYC,
 * docs/benchmarks/streams.md): incoherent and sun rays 6-15% faster on
 * dragon.ply and procedural:4M, diffuse 2-3%; 24 was no faster than 16.
 * The slots come from the heap, a few KB each. */
#define RTK_STREAM_K 16
#endif
