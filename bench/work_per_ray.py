#!/usr/bin/env python3
"""Work per single ray of rtk avx2 and Embree isa=avx2 on the same rays, counted by callgrind.

Runs `rtktool bench MESH --only trace --isa avx2 --api single --threads 1 --repeat 1` under
callgrind once per ray set (collecting inside rtk_intersect1, rtk_occluded1, rtcIntersect1 and
rtcOccluded1, with the cache simulation), reads the counts per instruction and prints, per ray
of each set and library:

  instr    instructions in the API call (entry, dispatch, kernel)
  loads    data reads
  nodes    node tests: executions of `vmovmskps` on a 256-bit register (each 8-wide box test
           ends in one, in both libraries' avx2 kernels; nothing else there uses one)
  blocks   leaf blocks tested: executions of the most executed `vmovmskps` on a 128-bit
           register (the triangle test of a block of four; the script prints its address),
           leaving out those run exactly once per ray (the rays' set-up)
  L1 miss  simulated first-level data misses (32 KiB, 8 ways), and
  L2 miss  simulated last-level misses, the level set to this VM's 1 MiB second level

The bench makes the diffuse and shadow rays from Embree's hits of the camera rays, so Embree's
counts in every set include those 1 x primary calls; the primary set's run (Embree traced 3 x:
the making, then isa=avx2 and its default, both avx2 under valgrind) is subtracted by thirds.
Embree's default library runs the avx2 kernels under valgrind (which has no AVX-512), so its
counts are averaged in.  Not a speed benchmark (rtktool bench measures speed beside Embree):
this shows whether the two libraries do the same work per ray.

With --section twolevel it counts the two-level section instead (rtktool bench --only twolevel):
the path tracer's rays through the 16 instances and through the dynamic scene of 16 pieces,
each render its own callgrind dump (--dump-before=render_image), per call of the four functions
(rays counted by the calls themselves: the executions of their first instruction).  Node tests
are the 8-wide ones (256-bit `vmovmskps`): Embree's whole two-level tree, rtk's objects' trees;
rtk's top level tests 4-wide boxes with the same 128-bit instruction as its triangle tests,
inlined into one function, so they are not counted apart.  With --section forest, the forest
section's (rtktool bench --only forest --forest N): one render per library.

usage: bench/work_per_ray.py [--rtktool build/bin/rtktool] [--size 256x192]
                             [--sets primary,diffuse,shadow,incoherent,sun] MESH
       bench/work_per_ray.py --section twolevel [--render 128x96x1] MESH
       bench/work_per_ray.py --section forest [--forest 10000] [--render 128x96x1] MESH
"""
import argparse
import collections
import concurrent.futures
import os
import re
import subprocess
import sys
import tempfile

API = ["rtk_intersect1", "rtk_occluded1", "rtcIntersect1", "rtcOccluded1"]


def run_callgrind(rtktool, mesh, ray_set, size, out, log):
    cmd = ["valgrind", "--tool=callgrind", "--dump-instr=yes", "--cache-sim=yes", "--D1=32768,8,64",
           "--LL=1048576,16,64", "--callgrind-out-file=" + out]
    cmd += ["--toggle-collect=" + f for f in API]
    cmd += [rtktool, "bench", mesh, "--only", "trace", "--isa", "avx2", "--api", "single", "--rays", ray_set,
            "--threads", "1", "--size", size, "--repeat", "1", "-o", out + ".bench"]
    with open(log, "w") as f:
        subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, check=True)
    return ray_counts(log)


def ray_counts(log):
    """The bench's ray count per set, from its output."""
    text = open(log).read()
    m = re.search(r"trace: (\d+) primary rays .*?, (\d+) diffuse, (\d+) shadow, (\d+) incoherent, (\d+) sun", text)
    if not m:
        sys.exit("no ray counts in " + log)
    return dict(zip(("primary", "diffuse", "shadow", "incoherent", "sun"), (int(g) for g in m.groups())))


def parse(path, names=None):
    """{object: {address: [event counts]}} of self cost, and the event names.  names: the object
    names of earlier dumps of the same run (callgrind names each object once per run)."""
    names = names if names is not None else {"ob": {}}  # (object names only: costs are per object and address)
    costs = collections.defaultdict(lambda: collections.defaultdict(lambda: None))
    events, positions = [], ["line"]
    obj = None
    last = []
    skip = False

    def name(kind, s):
        m = re.match(r"\((\d+)\)(?: (.*))?$", s)
        if not m:
            return s
        if m.group(2) is not None:
            names[kind][m.group(1)] = m.group(2)
        return names[kind][m.group(1)]

    for line in open(path):
        line = line.rstrip("\n")
        if line.startswith("events:"):
            events = line.split()[1:]
        elif line.startswith("positions:"):
            positions = line.split()[1:]
            last = [0] * len(positions)
        elif line.startswith("ob="):
            obj = name("ob", line[3:])
        elif line.startswith("cob="):
            name("ob", line[4:])
        elif line.startswith("calls="):
            skip = True  # the next cost line is the call's inclusive cost
        elif line and (line[0].isdigit() or line[0] in "+-*"):
            toks = line.split()
            pos = []
            for i in range(len(positions)):
                t = toks[i]
                if t == "*":
                    v = last[i]
                elif t[0] in "+-":
                    v = last[i] + (1 if t[0] == "+" else -1) * int(t[1:], 0)
                else:
                    v = int(t, 0)
                pos.append(v)
            last = pos
            if skip:
                skip = False
                continue
            vals = [int(x) for x in toks[len(positions):]]
            vals += [0] * (len(events) - len(vals))
            cur = costs[obj][pos[0]]
            costs[obj][pos[0]] = vals if cur is None else [a + b for a, b in zip(cur, vals)]
    return costs, events


def disassemble(path, addrs):
    """{address: instruction text} for the given addresses of a shared object."""
    lo, hi = min(addrs), max(addrs) + 16
    out = subprocess.run(["objdump", "-d", "--no-show-raw-insn", "--start-address=%#x" % lo,
                          "--stop-address=%#x" % hi, path], capture_output=True, text=True, check=True).stdout
    text = {}
    for line in out.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s*(.*)", line)
        if m:
            text[int(m.group(1), 16)] = m.group(2)
    return text


def entry_addresses(path, names):
    """The addresses of the exported functions `names` in a shared object."""
    out = subprocess.run(["nm", "-D", "--defined-only", path], capture_output=True, text=True, check=True).stdout
    found = {}
    for line in out.splitlines():
        t = line.split()
        if len(t) == 3 and t[2] in names:
            found[t[2]] = int(t[0], 16)
    return found


def twolevel(a):
    """Work per ray of the two-level (or forest) section's path tracer, per scene and library."""
    tmp = a.reuse or tempfile.mkdtemp(prefix="work_per_ray.")
    out, log = os.path.join(tmp, "twolevel.out"), os.path.join(tmp, "twolevel.log")
    # the renders in the bench's order: the two-level section's passes in turns (every library's
    # instances, then every library's dynamic scene), the forest's one library after another
    scenes = ("forest %s" % a.forest,) if a.section == "forest" else ("instances", "dynamic")
    if not a.reuse:
        print("callgrind: the %s section of %s ..." % (a.section, a.mesh), file=sys.stderr)
        cmd = ["valgrind", "--tool=callgrind", "--dump-instr=yes", "--cache-sim=yes", "--D1=32768,8,64",
               "--LL=1048576,16,64", "--callgrind-out-file=" + out, "--dump-before=render_image"]
        cmd += ["--toggle-collect=" + f for f in API]
        cmd += [a.rtktool, "bench", a.mesh, "--only", a.section, "--isa", "avx2", "--threads", "1", "--builds", "1",
                "--repeat", "1", "--render", a.render, "--forest", a.forest, "-o", out + ".bench"]
        with open(log, "w") as f:
            subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, check=True)
    # the dumps: out.1 before the first render, then one per render (the last at exit, in `out`
    # or out.N), in the bench's order
    parts = sorted((p for p in os.listdir(tmp) if re.match(r"twolevel\.out(\.\d+)?(-\d+)?$", p)),
                   key=lambda p: [int(x) for x in re.findall(r"\d+", p[len("twolevel.out"):])] or [1 << 30])
    names = {"ob": {}}
    dumps = [parse(os.path.join(tmp, p), names) for p in parts]
    dumps = [d for d in dumps if any("librtk" in o or "libembree3" in o for o in d[0])]
    libs = [("embree isa=avx2", "libembree3", ("rtcIntersect1", "rtcOccluded1")),
            ("embree default", "libembree3", ("rtcIntersect1", "rtcOccluded1")),
            ("rtk avx2", "librtk", ("rtk_intersect1", "rtk_occluded1"))]
    if len(dumps) != len(scenes) * len(libs):
        sys.exit("expected %d renders in %s, found %d" % (len(scenes) * len(libs), tmp, len(dumps)))
    print("%s, the %s section's path tracer (%s); per ray (a call of intersect1 or occluded1)"
          % (os.path.basename(a.mesh), a.section, a.render))
    print("  %-12s %-16s %9s %8s %8s %7s %8s %8s" % ("scene", "library", "rays", "instr", "loads", "nodes",
                                                  "L1 miss", "L2 miss"))
    for k, (costs, events) in enumerate(dumps):
        lib, key, entries = libs[k % len(libs)]
        col = {e: i for i, e in enumerate(events)}
        total = collections.Counter()
        rays = 0
        per_addr = collections.defaultdict(dict)
        for obj, table in costs.items():
            if key not in os.path.basename(obj):
                continue
            if "librtk.so" in os.path.basename(obj) or "libembree3" in os.path.basename(obj):
                for addr in entry_addresses(obj, entries).values():
                    if table.get(addr) is not None:
                        rays += table[addr][col["Ir"]]
            for addr, vals in table.items():
                for e, i in col.items():
                    total[e] += vals[i]
                per_addr[obj][addr] = vals[col["Ir"]]
        nodes = 0
        for obj, table in per_addr.items():
            hot = [addr for addr, ir in table.items() if ir > 0]
            if not hot:
                continue
            text = disassemble(obj, hot)
            nodes += sum(table[addr] for addr in hot if text.get(addr, "").startswith("vmovmskps %ymm"))
        n = float(rays or 1)
        print("  %-12s %-16s %9d %8.1f %8.1f %7.2f %8.2f %8.2f" % (
            scenes[k // len(libs)], lib, rays, total["Ir"] / n, total["Dr"] / n, nodes / n,
            total["D1mr"] / n, total["DLmr"] / n))
    print("(nodes: 8-wide node tests; Embree's top level is made of them, rtk's 4-wide one is not counted)")
    print("raw callgrind output and logs:", tmp)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mesh")
    ap.add_argument("--rtktool", default="build/bin/rtktool")
    ap.add_argument("--size", default="256x192")
    ap.add_argument("--sets", default="primary,diffuse,shadow")
    ap.add_argument("--from", dest="reuse", help="read the callgrind output of an earlier run in this directory "
                    "(of the same build: the counts are placed by the libraries' addresses)")
    ap.add_argument("--section", default="trace", choices=("trace", "twolevel", "forest"))
    ap.add_argument("--forest", default="10000", help="forest: the instance count")
    ap.add_argument("--render", default="128x96x1", help="twolevel: the path tracer's image and samples")
    a = ap.parse_args()
    if a.section in ("twolevel", "forest"):
        twolevel(a)
        return
    sets = a.sets.split(",")
    if "primary" not in sets:
        sets.insert(0, "primary")  # (needed to take out the making of the other sets)
    tmp = a.reuse or tempfile.mkdtemp(prefix="work_per_ray.")

    def one(s):
        out, log = os.path.join(tmp, s + ".out"), os.path.join(tmp, s + ".log")
        if a.reuse:
            counts = ray_counts(log)
        else:
            print("callgrind: %s rays of %s ..." % (s, a.mesh), file=sys.stderr)
            counts = run_callgrind(a.rtktool, a.mesh, s, a.size, out, log)
        return parse(out) + (counts,)

    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:  # (two runs at once)
        runs = dict(zip(sets, pool.map(one, sets)))
    events = runs["primary"][1]
    col = {e: i for i, e in enumerate(events)}
    print("%s, %s camera rays; per ray of each set (Embree: its two libraries' average, the making of the"
          " rays taken out)" % (os.path.basename(a.mesh), a.size))
    print("  %-8s %-16s %8s %8s %7s %7s %8s %8s" % ("set", "library", "instr", "loads", "nodes", "blocks",
                                                   "L1 miss", "L2 miss"))
    prim = runs["primary"][0]
    for s in sets:
        costs, _, counts = runs[s]
        n = counts[s]
        for lib, key in (("embree isa=avx2", "libembree3"), ("rtk avx2", "librtk")):
            total = collections.Counter()
            per_addr = collections.defaultdict(collections.Counter)
            for obj, table in costs.items():
                if key not in os.path.basename(obj):
                    continue
                for addr, vals in table.items():
                    v = list(vals)
                    if key == "libembree3":
                        # 3 primary passes in the primary run (making, two libraries), 1 in the others
                        p = prim.get(obj, {}).get(addr)
                        if p is not None:
                            v = [x - y / 3.0 for x, y in zip(v, p)]
                        v = [x / (2.0 * n) for x in v]
                    else:
                        v = [x / float(n) for x in v]
                    for e, i in col.items():
                        total[e] += v[i]
                    per_addr[obj][addr] = v[col["Ir"]]
            nodes = blocks = 0.0
            block_site = None
            for obj, table in per_addr.items():
                hot = [addr for addr, ir in table.items() if ir > 0.01]
                if not hot:
                    continue
                text = disassemble(obj, hot)
                for addr in hot:
                    t = text.get(addr, "")
                    if t.startswith("vmovmskps %ymm"):
                        nodes += table[addr]
                    elif t.startswith("vmovmskps %xmm") and abs(table[addr] - 1.0) > 5e-4 and table[addr] > blocks:
                        blocks, block_site = table[addr], "%s+%#x" % (os.path.basename(obj), addr)
            print("  %-8s %-16s %8.1f %8.1f %7.2f %7.3f %8.2f %8.2f" % (
                s, lib, total["Ir"], total["Dr"], nodes, blocks, total["D1mr"], total["DLmr"]))
            print("  %-8s %-16s (leaf block test at %s)" % ("", "", block_site))
    print("raw callgrind output and logs:", tmp)


if __name__ == "__main__":
    main()
