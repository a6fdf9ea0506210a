#!/usr/bin/env bash
# Installs the build tree into a fresh prefix, keeps only the core and ONE
# backend (scalar), and builds the example against the installed tree twice:
# with find_package(rtk) and with pkg-config. Both must run on that backend.
set -euo pipefail
build=$1 src=$2 work=$3
rm -rf "$work" && mkdir -p "$work"
prefix=$work/prefix
cmake --install "$build" --prefix "$prefix" >/dev/null
libdir=$prefix/lib
[ -d "$libdir/rtk" ] || libdir=$(dirname "$(find "$prefix" -name librtk.so | head -1)")
ls "$libdir/rtk"/librtk_backend_*.so >/dev/null
find "$libdir/rtk" -name 'librtk_backend_*.so' ! -name librtk_backend_scalar.so -delete
# The core exports only rtk_ symbols.
bad=$(nm -D --defined-only "$libdir/librtk.so" | awk '{print $3}' | grep -v '^rtk_' || true)
[ -z "$bad" ] || { echo "librtk.so exports non-rtk symbols: $bad"; exit 1; }

san=()
if [ -n "${RTK_SANITIZE_FLAGS:-}" ]; then san=($RTK_SANITIZE_FLAGS); fi
# 1. CMake package
cmake -S "$src/examples" -B "$work/cmake" -DCMAKE_PREFIX_PATH="$prefix" \
      -DCMAKE_BUILD_RPATH="$libdir" -DCMAKE_C_FLAGS="${san[*]:-}" >/dev/null
cmake --build "$work/cmake" >/dev/null
out=$(env -u RTK_ISA -u RTK_BACKEND_PATH "$work/cmake/minimal")
echo "find_package: $out"
grep -q "backend scalar: hit primitive 0 at t = 1" <<<"$out"
# docs/GUIDE.md's program, with the counts of its picture (the same on
# every backend)
out=$(env -u RTK_ISA -u RTK_BACKEND_PATH "$work/cmake/guide")
echo "guide: $(tail -1 <<<"$out")"
grep -q "guide: backend scalar, 1536 rays, 790 hits (ground 596, fence 85, spheres 109), 42 in shadow" <<<"$out"
# 2. pkg-config
export PKG_CONFIG_PATH=$libdir/pkgconfig
cc ${san[@]+"${san[@]}"} "$src/examples/minimal.c" -o "$work/minimal_pc" $(pkg-config --cflags --libs rtk) -lm \
   -Wl,-rpath,"$(pkg-config --variable=libdir rtk)"
out=$(env -u RTK_ISA -u RTK_BACKEND_PATH "$work/minimal_pc")
echo "pkg-config: $out"
grep -q "backend scalar: hit primitive 0 at t = 1" <<<"$out"
# The example links only the core.
# (ldd's output is captured first: grep -q closing the pipe early would make
# ldd die of SIGPIPE, which pipefail reports as a failure.)
deps=$(ldd "$work/minimal_pc")
grep -q librtk.so <<<"$deps"
! grep -q librtk_backend <<<"$deps" || { echo "the example links a backend: $deps"; exit 1; }
echo "install test passed"
