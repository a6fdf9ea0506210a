#!/usr/bin/env bash
# Distribution: the core installed with only some backends, by component
# and from the Debian packages cpack makes.  An application linking only
# the core picks the best backend installed, lists only the installed ones
# (none rejected: a missing backend is absent, not an error), and fails
# with a clear message when none is installed.
set -euo pipefail
build=$1 src=$2 work=$3
rm -rf "$work" && mkdir -p "$work"
cpu_has() { grep -qw "$1" /proc/cpuinfo; }
best=scalar
cpu_has sse4_1 && best=sse41

report() { # prefix-or-root libdir -> the report program's output
  local inc=$1 lib=$2
  cc ${RTK_SANITIZE_FLAGS:-} -I"$inc" "$src/tests/install/backends_report.c" -o "$work/report" -L"$lib" -lrtk -Wl,-rpath,"$lib"
  env -u RTK_ISA -u RTK_BACKEND_PATH "$work/report" || true
}

# 1. cmake --install by component: core, dev, scalar and sse41 only
prefix=$work/prefix
for c in core dev backend_scalar backend_sse41; do
  cmake --install "$build" --prefix "$prefix" --component "$c" >/dev/null
done
libdir=$(dirname "$(find "$prefix" -name 'librtk.so.*' | head -1)")
ls "$libdir/rtk"
[ "$(ls "$libdir/rtk" | wc -l)" = 2 ]
out=$(report "$prefix/include" "$libdir")
echo "$out"
grep -q "^active: $best$" <<<"$out"
[ "$(grep -c '^backend ' <<<"$out")" = 2 ]
! grep -q "rejected" <<<"$out" || { echo "a backend was rejected"; exit 1; }
# no backend at all: a clear error naming the directory searched
rm "$libdir"/rtk/librtk_backend_*.so
out=$(report "$prefix/include" "$libdir")
echo "$out"
grep -q "^error: .*no usable rtk backend. Searched: $libdir/rtk" <<<"$out"
grep -q "no librtk_backend_\*.so files there" <<<"$out"

# 2. the Debian packages: names, versions, dependencies, contents
cpack --config "$build/CPackConfig.cmake" -G DEB -B "$work/pkgs" >/dev/null
cd "$work/pkgs"
version=$(dpkg-deb -f librtk_*.deb Version)
for p in librtk-dev rtk-tools librtk-backend-scalar librtk-backend-sse41 librtk-backend-avx librtk-backend-avx2; do
  deps=$(dpkg-deb -f "${p}"_*.deb Depends)
  echo "$p: Depends: $deps"
  grep -q "librtk (= $version)" <<<"$deps"
done
# (listings captured first: grep -q closing a pipe early would kill
# dpkg-deb with SIGPIPE, which pipefail reports)
core=$(dpkg-deb -c librtk_*.deb) dev=$(dpkg-deb -c librtk-dev_*.deb) avx2=$(dpkg-deb -c librtk-backend-avx2_*.deb)
grep -q 'lib/librtk.so.0 -> librtk.so.0' <<<"$core"
! grep -q 'include/' <<<"$core" || { echo "librtk ships headers"; exit 1; }
grep -q 'include/rtk/rtk.h' <<<"$dev"
grep -q 'lib/librtk.so -> librtk.so.0' <<<"$dev"
grep -q 'rtk/librtk_backend_avx2.so$' <<<"$avx2"
# unpacked together, the core and one backend package work
root=$work/root
for p in librtk librtk-dev librtk-backend-scalar; do dpkg-deb -x "${p}"_*.deb "$root"; done
libdir=$(dirname "$(find "$root" -name 'librtk.so.0' | head -1)")
out=$(report "$root/usr/include" "$libdir")
echo "$out"
grep -q "^active: scalar$" <<<"$out"
[ "$(grep -c '^backend ' <<<"$out")" = 1 ]
echo "packages test passed"
