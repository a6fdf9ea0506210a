#!/usr/bin/env bash
# Loader safety: a set-group-ID program ignores RTK_BACKEND_PATH (the core
# reads it with secure_getenv), so whoever runs it cannot make it load
# their code; the same program without the bit honours it.  Needs root (to
# give the program another group) and a file system that honours set-ID
# bits; otherwise the test is skipped (exit 77).
set -euo pipefail
build=$1 src=$2 work=$3
[ "$(id -u)" = 0 ] || { echo "skipped: needs root"; exit 77; }
rm -rf "$work" && mkdir -p "$work"
if command -v findmnt >/dev/null && findmnt -no OPTIONS --target "$work" | grep -qw nosuid; then
  echo "skipped: $work is on a nosuid file system"; exit 77
fi
getent group nogroup >/dev/null || { echo "skipped: no group nogroup"; exit 77; }
cc ${RTK_SANITIZE_FLAGS:-} -I"$src/include" "$src/tests/install/backends_report.c" -o "$work/report" \
   -L"$build/lib" -lrtk -Wl,-rpath,"$build/lib"
chmod 755 "$work" "$work/report"
decoy=$work/decoy
mkdir -p "$decoy"
out=$(RTK_BACKEND_PATH=$decoy "$work/report")
echo "plain: $(grep '^searched' <<<"$out")"
grep -q "^searched: $decoy:" <<<"$out"
chgrp nogroup "$work/report"
chmod g+s "$work/report"
out=$(RTK_BACKEND_PATH=$decoy "$work/report")
echo "setgid: $(grep '^searched' <<<"$out")"
grep -q "^searched: " <<<"$out"
! grep -q "$decoy" <<<"$out" || { echo "the set-group-ID program searched RTK_BACKEND_PATH"; exit 1; }
echo "setgid test passed"
