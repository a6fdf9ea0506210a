#!/bin/bash
# rtktool's commands end to end: convert a bundled mesh to .rtkm (with the
# clean-ups), trace the result, build and dump its BVH, inspect the dump
# alone and commit it again, and refuse bad input with a clear message and
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
expect 0 "active backend:" -- "$tool" info
expect 0 "examples:" -- "$tool" info --help
expect 2 "unknown argument '--bogus'" -- "$tool" info --bogus
expect 1 "RTK_ERROR_INVALID_CONFIG" -- "$tool" info --config isa=avx9,bogus=1
expect 0 "examples:" -- "$tool" convert --help
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
# a write that fails (here a file size limit of 100 KiB) leaves the file it
# was to replace byte for byte, and no temporary file beside it
cp "$work/bunny.rtkm" "$work/keep.rtkm"
"$tool" build "$data/bunny.ply" --dump "$work/keep.rtkb" >/dev/null || fail "build --dump"
cp "$work/keep.rtkb" "$work/keep-old.rtkb"
cp "$work/bunny.png" "$work/keep.png"
big=(trace "$data/bunny.ply" --size 512x512 --frames 1 --threads 1 -o "$work/keep.png")
for cmd in "convert $data/bunny.ply $work/keep.rtkm" "build $data/bunny.ply --dump $work/keep.rtkb"; do
    # shellcheck disable=SC2086
    out=$( (ulimit -f 100; "$tool" $cmd) 2>&1 ); rc=$?
    [ "$rc" = 1 ] || fail "'$cmd' under a file size limit exited $rc: $out"
    grep -qF "write failed: File too large (the previous file, if any, is unchanged)" <<<"$out" ||
        fail "'$cmd' under a file size limit: $out"
done
out=$( (ulimit -f 20; "$tool" "${big[@]}") 2>&1 ); rc=$?
[ "$rc" = 1 ] && grep -qF "the previous file, if any, is unchanged" <<<"$out" || fail "trace -o under a limit: $rc $out"
cmp -s "$work/bunny.rtkm" "$work/keep.rtkm" || fail "a failed convert changed the file it was replacing"
cmp -s "$work/keep-old.rtkb" "$work/keep.rtkb" || fail "a failed build --dump changed the file it was replacing"
cmp -s "$work/bunny.png" "$work/keep.png" || fail "a failed trace -o changed the image it was replacing"
! ls "$work"/.keep* >/dev/null 2>&1 || fail "a failed write left its temporary file: $(ls -a "$work")"

# build: statistics, JSON, dump, picture; the dump read alone and with its mesh
expect 0 "SAH cost:" -- "$tool" build "$work/bunny.rtkm" --dump "$work/bunny.rtkb" --png "$work/boxes.png"
[ -s "$work/boxes.png" ] || fail "no picture of the boxes"
expect 0 '"triangles": 69451' -- "$tool" build "$data/bunny.ply" --json --quality high --isa scalar
expect 0 '"build_mtris_per_second"' -- "$tool" build "$data/bunny.ply" --json --compact
expect 0 "checked (offsets, counts, checksums" -- "$tool" build --load "$work/bunny.rtkb"
expect 0 '"mesh": null' -- "$tool" build --load "$work/bunny.rtkb" --json
expect 0 "10000 identical, 0 ties settled differently, 0 different" -- \
    "$tool" build --load "$work/bunny.rtkb" "$data/bunny.ply" --verify 10000
expect 0 "dump:" -- "$tool" build "$data/bunny.ply" --compact --isa sse41 --dump "$work/compact.rtkb"
expect 0 "bvh4.triangle4i" -- "$tool" build --load "$work/compact.rtkb" "$data/bunny.ply" --verify 2000
# robust: vertex leaves; a robust compact dump loads as one again and traces like a build
expect 0 "triangle4v" -- "$tool" build "$data/bunny.ply" --robust
expect 0 "dump:" -- "$tool" build "$data/bunny.ply" --robust --compact --dump "$work/robust.rtkb"
expect 0 "bvh4.triangle4i.robust" -- "$tool" build --load "$work/robust.rtkb" "$data/bunny.ply" --verify 2000
# a builder and a layout chosen whatever the quality; a dump in a layout the
# default backend would not pick loads all the same, and only in its layout
expect 0 '"builder": "morton"' -- "$tool" build "$data/bunny.ply" --json --quality high --builder morton
expect 0 'bvh4.triangle4, sah-spatial builder' -- \
    "$tool" build "$data/bunny.ply" --builder sah-spatial --layout bvh4.triangle4 --dump "$work/b4.rtkb"
expect 0 "2000 identical, 0 ties settled differently, 0 different" -- \
    "$tool" build --load "$work/b4.rtkb" "$data/bunny.ply" --verify 2000
expect 2 "--layout bvh4.triangle4i, but the dump holds a bvh4.triangle4 tree" -- \
    "$tool" trace "$data/bunny.ply" --load "$work/b4.rtkb" --layout bvh4.triangle4i --size 8x8
expect 1 "config builder='sweep': backend" -- "$tool" build "$data/bunny.ply" --builder sweep
expect 1 "no such layout" -- "$tool" trace "$data/bunny.ply" --isa scalar --layout bvh8.triangle4 --size 8x8
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n' >"$work/tri.obj"
expect 1 "was built over another mesh" -- "$tool" build --load "$work/bunny.rtkb" "$work/tri.obj"
expect 0 "build:      none: the tree of $work/bunny.rtkb" -- \
    "$tool" trace "$data/bunny.ply" --load "$work/bunny.rtkb" --size 64x48 --frames 1 -o "$work/loaded.png"
"$tool" trace "$data/bunny.ply" --size 64x48 --frames 1 -o "$work/built.png" >/dev/null || fail "trace"
cmp -s "$work/loaded.png" "$work/built.png" || fail "the image traced with the dump differs from the built one"
expect 1 "was built over another mesh" -- "$tool" trace "$work/tri.obj" --load "$work/bunny.rtkb" --size 8x8
head -c 3000 "$work/bunny.rtkb" >"$work/cut.rtkb"
expect 1 "cut.rtkb: file is 3000 bytes" -- "$tool" build --load "$work/cut.rtkb"
cp "$work/bunny.rtkb" "$work/flip.rtkb"
printf '\x01' | dd of="$work/flip.rtkb" bs=1 seek=5000 conv=notrunc 2>/dev/null
expect 1 "checksum mismatch (damaged file)" -- "$tool" build --load "$work/flip.rtkb"
expect 1 "not an .rtkb file" -- "$tool" build --load "$work/bunny.rtkm"
expect 2 "must end in .rtkb" -- "$tool" build "$data/bunny.ply" --dump "$work/out.bin"
expect 2 "--quality wants low, medium or high" -- "$tool" build "$data/bunny.ply" --quality best
expect 2 "usage: rtktool build" -- "$tool" build
expect 0 "examples:" -- "$tool" build --help

# trace: modes, APIs, cameras, JSON, the progress bar, bad arguments
for mode in eyelight normals ao diffuse; do
    expect 0 "render:     $mode, 48x32, 2 spp" -- \
        "$tool" trace "$data/bunny.ply" --mode $mode --size 48x32 --spp 2 --frames 1 -o "$work/$mode.png"
    "$tool" trace "$data/bunny.ply" --mode $mode --size 48x32 --spp 2 --frames 1 --isa scalar \
        -o "$work/$mode-single.png" >/dev/null || fail "trace $mode"
    for api in packet4 packet8 packet16 stream; do
        expect 0 "$api API" -- "$tool" trace "$data/bunny.ply" --mode $mode --api $api --size 48x32 --spp 2 \
            --frames 1 --isa scalar -o "$work/$mode-$api.png"
        cmp -s "$work/$mode-single.png" "$work/$mode-$api.png" || fail "$mode: $api image differs from single rays"
    done
    # streams give every ray its single call's answer on every backend: the same image
    "$tool" trace "$data/bunny.ply" --mode $mode --size 48x32 --spp 2 --frames 1 -o "$work/$mode-best.png" \
        >/dev/null || fail "trace $mode"
    expect 0 "rays in flight" -- "$tool" trace "$data/bunny.ply" --mode $mode --api stream --size 48x32 --spp 2 \
        --frames 1 -o "$work/$mode-best-stream.png"
    cmp -s "$work/$mode-best.png" "$work/$mode-best-stream.png" || fail "$mode: the stream image differs"
done
expect 0 "shadow" -- "$tool" trace "$data/bunny.ply" --mode diffuse --bounces 0 --size 32x32 --frames 1 \
    -o "$work/d.png"
expect 0 " 0 bounce" -- "$tool" trace "$data/bunny.ply" --mode diffuse --bounces 0 --size 32x32 --frames 1 \
    -o "$work/d.png"
cam=$("$tool" trace "$data/bunny.ply" --size 40x30 --frames 1 -o "$work/framed.png" | sed -n 's/^camera: *--camera //p')
[ -n "$cam" ] || fail "trace printed no camera"
expect 0 "camera:     --camera $cam" -- "$tool" trace "$data/bunny.ply" --size 40x30 --frames 1 --camera "$cam" \
    -o "$work/given.png"
cmp -s "$work/framed.png" "$work/given.png" || fail "the printed camera does not give the same image"
expect 0 '"mode": "ao"' -- "$tool" trace "$data/bunny.ply" --mode ao --json --size 16x16 --frames 1 -o "$work/j.png"
expect 0 '"ao": 0' -- "$tool" trace "$data/bunny.ply" --json --size 16x16 --frames 1 -o "$work/j.png"
expect 2 "--mode wants eyelight, normals, ao or diffuse" -- "$tool" trace "$data/bunny.ply" --mode toon
expect 2 "--api wants single, packet4" -- "$tool" trace "$data/bunny.ply" --api packet32
expect 2 "--camera wants EX,EY,EZ/TX,TY,TZ" -- "$tool" trace "$data/bunny.ply" --camera 1,2,3
expect 2 "eye and target must differ" -- "$tool" trace "$data/bunny.ply" --camera 1,2,3/1,2,3
expect 2 "--spp wants a whole number 1..65536" -- "$tool" trace "$data/bunny.ply" --spp 0
expect 2 "--threads wants a whole number" -- "$tool" trace "$data/bunny.ply" --threads x
expect 2 "--size wants WxH" -- "$tool" trace "$data/bunny.ply" --size 10x10x
expect 0 "examples:" -- "$tool" trace --help
# the progress bar: none when stderr is not a terminal, drawn on one (script
# gives the command a terminal) for a render longer than a second (4 s here
# optimised; under the sanitizers with 8 samples the render took 0.8 s on a CI
# machine of session 42 and drew no bar, so 32 there: about 3 s)
samples=64
case ${RTK_TEST_SANITIZED:-0} in 0) ;; *) samples=32 ;; esac
slow=(trace "$data/bunny.ply" --isa scalar --threads 1 --mode ao --ao-samples $samples --size 800x600 --frames 1
      -o "$work/slow.png")
"$tool" "${slow[@]}" 2>"$work/stderr.txt" >/dev/null || fail "slow trace"
! grep -q "rtktool trace \[" "$work/stderr.txt" || fail "a progress bar on stderr that is not a terminal"
if command -v script >/dev/null; then
    script -qec "$(printf '%q ' "$tool" "${slow[@]}")" /dev/null >"$work/tty.txt" 2>&1 || fail "trace on a terminal"
    grep -q "rtktool trace \[#" "$work/tty.txt" || fail "no progress bar on a terminal: $(cat "$work/tty.txt")"
else
    echo "script(1) missing: progress bar on a terminal not checked"
fi

# bench: only in an rtktool built with Embree; otherwise it says so
if "$tool" bench --help >/dev/null 2>&1; then
    # under the sanitizers avx2's kernels only: scalar's instrumented bench
    # was half of this test's time there, and the optimised run checks its rows
    isas=(scalar avx2)
    case ${RTK_TEST_SANITIZED:-0} in 0) ;; *) isas=(avx2) ;; esac
    expect 0 "csv: $work/bench/bench.csv" -- "$tool" bench "$data/bunny.ply" --quick --isa "$(IFS=,; echo "${isas[*]}")" \
        --api single,packet8,stream -o "$work/bench"
    csv="$work/bench/bench.csv"
    for want in "trace,rtk avx2,default,primary,packet8,1," "trace,rtk scalar,default,shadow,single,1," \
                "trace,rtk avx2,default,incoherent,stream,1," "trace,embree isa=avx2,default,sun,stream,1," \
                "trace best api,rtk avx2,default against embree's best " \
                "render,rtk avx2,default,diffuse path tracer,packet8,1," \
                "render,embree default,default,diffuse path tracer,stream,1," \
                "render best api,rtk avx2,default against embree's best " \
                "build,embree default,high:sah-spatial,start,,1," "build,rtk avx2,low:morton,start,,1," \
                "build,rtk avx2,low:morton,diffuse,single,1," "build,rtk avx2,medium:sah-binned,sah cost,,1," \
                "accuracy,embree isa=avx2,robust,edge,single,1," \
                "accuracy,rtk scalar,compact,diffuse,single,1," "accuracy,rtk avx2,robust,edge,single,1," \
                "memory,rtk avx2,bvh8.triangle4," "twolevel,rtk scalar,forest 1000,diffuse path tracer,single,1," \
                "twolevel,embree isa=avx2,forest 1000,memory monitor,,1,"; do
        case $want in *"rtk scalar"*) [[ " ${isas[*]} " == *" scalar "* ]] || continue ;; esac
        grep -qF "bunny.ply,$want" "$csv" || fail "bench.csv lacks a row '$want'"
    done
    ! grep -q "packet16" "$csv" || fail "bench.csv has packet16 rows though --api left them out"
    # the motion and two-level sections trace on every --threads count
    expect 0 "csv: $work/bench2/bench.csv" -- "$tool" bench "$data/bunny.ply" --quick --threads 1,2 \
        --only motion,twolevel --isa avx2 -o "$work/bench2"
    for want in "motion,rtk avx2,2 steps,primary,packet8,2," "motion,embree isa=avx2,5 steps,diffuse,stream,2," \
                "motion,rtk avx2,5 steps,update,,1," "twolevel,rtk avx2,dynamic,diffuse path tracer,single,2," \
                "twolevel,embree isa=avx2,instances,diffuse path tracer,single,1,"; do
        grep -qF "bunny.ply,$want" "$work/bench2/bench.csv" || fail "bench2/bench.csv lacks a row '$want'"
    done
    expect 2 "--forest wants a list" -- "$tool" bench "$data/bunny.ply" --forest 0
    grep -qE '^[^,]*bunny.ply,trace,rtk avx2,default,diffuse,single,1,[0-9.]+,Mrays/s,[0-9.]+$' "$csv" ||
        fail "bench.csv: no rate with its ratio for rtk avx2 diffuse rays"
    # the accuracy harness (closed meshes, once per run): rtk's robust mode
    # has no false miss and no double hit; no library hits a zero-area triangle
    for isa in "${isas[@]}"; do
        for what in "false misses per million" "double hits per million"; do
            grep -qF "procedural:closed,closed,rtk $isa,robust, all,aimed,single,1,0,$what," "$csv" ||
                fail "bench.csv: rtk $isa robust has $what in the closed section (or no row)"
        done
    done
    # two modes of each library: Embree at isa=avx2 and its default, rtk at each of isas
    [ "$(grep -c ', needles,aimed,single,1,0,zero-area hits,' "$csv")" = $((4 + 2 * ${#isas[@]})) ] ||
        fail "bench.csv: a library hit a zero-area triangle (or rows are missing)"
    if command -v gnuplot >/dev/null; then
        for chart in trace build accuracy; do
            [ -s "$work/bench/bunny-$chart.png" ] || fail "no $chart chart"
        done
        [ -s "$work/bench/closed-accuracy.png" ] || fail "no closed-accuracy chart"
    fi
    expect 2 "--api wants a list of single" -- "$tool" bench "$data/bunny.ply" --api packet5
    expect 2 "--only wants a list of trace" -- "$tool" bench "$data/bunny.ply" --only speed
    expect 1 "no backend 'avx9'" -- "$tool" bench "$data/bunny.ply" --isa avx9 -o "$work/bench"
    expect 1 "No such file" -- "$tool" bench "$work/missing.ply" --quick -o "$work/bench"
    # a run that fails leaves the last run's bench.csv as it was
    grep -qF "bench.csv left as it was" <<<"$out" || fail "bench failing: $out"
    grep -qF "bunny.ply,trace,rtk avx2,default,primary,packet8,1," "$csv" || fail "a failed bench run replaced bench.csv"
    no_temporaries() { # file_replace's temporary files (.NAME.XXXXXX) are all gone
        ! ls -A "$work/bench" | grep -q '^\.' || fail "a bench run left temporary files: $(ls -A "$work/bench")"
    }
    # and its charts: a mesh's chart files written before the run failed are
    # removed, leaving the last run's, and a PNG gnuplot fails to draw is put back
    charts=$(cd "$work/bench" && md5sum bunny-trace.* bunny-accuracy.*)
    expect 1 "No such file" -- "$tool" bench "$data/bunny.ply" "$work/missing.ply" --quick --only trace,accuracy \
        --isa avx2 -o "$work/bench"
    [ "$(cd "$work/bench" && md5sum bunny-trace.* bunny-accuracy.*)" = "$charts" ] ||
        fail "a failed bench run replaced bunny's charts"
    no_temporaries
    if [ -s "$work/bench/bunny-accuracy.png" ]; then
        mkdir -p "$work/failing-gnuplot"
        printf '#!/bin/sh\n: >"${1%%.gp}.png"\nexit 1\n' >"$work/failing-gnuplot/gnuplot"
        chmod +x "$work/failing-gnuplot/gnuplot"
        cp "$work/bench/bunny-accuracy.png" "$work/accuracy-before.png"
        PATH="$work/failing-gnuplot:$PATH" expect 0 "bunny-accuracy.gp not drawn (gnuplot failed" -- \
            "$tool" bench "$data/bunny.ply" --quick --only accuracy --isa avx2 -o "$work/bench"
        cmp -s "$work/bench/bunny-accuracy.png" "$work/accuracy-before.png" ||
            fail "a chart gnuplot failed to draw replaced the last one"
        no_temporaries
    fi
    expect 2 "usage: rtktool bench" -- "$tool" bench
else
    expect 1 "unavailable: this rtktool was built without Embree 3" -- "$tool" bench "$data/bunny.ply"
fi
echo "rtktool end to end: ok"
