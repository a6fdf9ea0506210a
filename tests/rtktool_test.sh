#!/bin/bash
# rtktool's commands end to end: convert a bundled mesh to .rtkm (with the
# clean-ups), trace the result, and refuse bad input with a clear message and
# a non-zero exit.  Usage: rtktool_test.sh RTKTOOL DATA_DIR WORK_DIR
set -u
tool=$1 data=$2 work=$3
rm -rf "$work" && mkdir -p "$work" || exit 1
fail() { echo "FAIL: $*"; exit 1; }
expect() { # expect WANT_EXIT NEEDLE -- command...
    local want=$1 needle=$2; shift 3
    out=$("$@" 2>&1); rc=$?
    [ "$rc" = "$want" ] || fail "'$*' exited $rc, expected $want: $out"
    grep -qF -- "$needle" <<<"$out" || fail "'$*' output lacks '$needle': $out"
}
expect 0 "wrote:    $work/bunny.rtkm: 35947 vertices, 69451 triangles" -- \
    "$tool" convert "$data/bunny.ply" "$work/bunny.rtkm"
expect 0 "merged:" -- "$tool" convert "$data/bunny.ply" "$work/clean.rtkm" --merge-vertices --drop-degenerate
expect 0 "mesh:       $work/bunny.rtkm: 35947 vertices, 69451 triangles" -- \
    "$tool" trace "$work/bunny.rtkm" --size 64x48 --frames 1 --threads 1 -o "$work/bunny.png"
[ -s "$work/bunny.png" ] || fail "no image"
expect 0 "wrote:" -- "$tool" convert "$work/bunny.rtkm" "$work/again.rtkm"
cmp -s "$work/bunny.rtkm" "$work/again.rtkm" || fail ".rtkm -> .rtkm is not byte for byte the same"
expect 2 "must end in .rtkm" -- "$tool" convert "$data/bunny.ply" "$work/out.bin"
expect 1 "No such file" -- "$tool" convert "$work/missing.ply" "$work/out.rtkm"
head -c 100 "$work/bunny.rtkm" >"$work/cut.rtkm"
expect 1 "truncated or malformed header" -- "$tool" trace "$work/cut.rtkm" --size 8x8 --frames 1
expect 2 "usage: rtktool convert" -- "$tool" convert
expect 0 "usage: rtktool convert" -- "$tool" convert --help
echo "rtktool end to end: ok"
