#!/usr/bin/env python3
"""The smallest GPU page pool that holds a camera path at full detail: bytes of pool per screen pixel.

For every combination of path, resolution, page format and page size asked for, bisects the
pool size (pages) of `tessera view --headless` between --lo and --hi for the smallest pool
whose run meets the floor: fallback at most --max-fallback of the textured pixels over the path
(the viewer's own count against the unbiased level, docs/viewer.md "Measures"), LoD bias 0 in
every frame, and the first view reached full detail. A smaller pool only ever falls back more, so
the bisection keeps (largest failing, smallest passing) and stops when they are within
--precision of each other. Pages below --lo are never tried. Reported per combination: the smallest passing pool in pages, MiB and
bytes per screen pixel (pool bytes / (width x height), with each page's second level when the
format carries one), beside the requests per second and tile latency of that run.

Stores: the procedural terrain (--texels), built once per page size into --work with
`tessera build --tile-size`; pages of 256 (248 + a 4-texel border on each side) and 128.
Each run plays the whole path (about 20 s of path at 60 frames per second; a failing pool also
waits out the 20 s warm-up timeout), so a combination costs several minutes on llvmpipe: pick
what to measure. Writes WORK/pool_floor.json and prints a Markdown table.

  bench/pool_floor.py [--tessera build/tessera] [--paths flyover,walk,whip]
                      [--sizes 1280x720,1920x1080] [--formats rgba8,bc1,bc7] [--tiles 128,256]
                      [--texels 16384] [--lo 16] [--hi 2048] [--precision 0.05]
                      [--max-fallback 0.0001] [--work build/pool-floor]
"""
import argparse
import itertools
import json
import math
import os
import re
import subprocess
import sys
import time

SUMMARY = {
    # The viewer prints the pool in KiB below 1 MiB.
    "pool": re.compile(r"^GPU pool\s+(\d+) pages of (\S+), ([\d.]+) KiB per page, ([\d.]+) (KiB|MiB) in all"),
    "frames": re.compile(r"^frames\s+(\d+) in ([\d.]+) s"),
    "warmup": re.compile(r"^first view\s+(full detail|NOT at full detail)"),
    "fallback": re.compile(r"^fallback\s+([\d.]+)% of textured pixels"),
    "bias": re.compile(r"^LoD bias\s+mean ([\d.-]+), max ([\d.-]+)"),
    "latency": re.compile(r"^tile latency\s+p50 ([\d.]+) ms, p99 ([\d.]+) ms"),
    "pages": re.compile(r"^pages\s+(\d+) requested, (\d+) uploaded, (\d+) evicted"),
}


def parse_summary(text):
    out = {}
    for line in text.splitlines():
        line = line.strip()
        for key, rx in SUMMARY.items():
            m = rx.match(line)
            if m:
                out[key] = m.groups()
    missing = [k for k in ("pool", "frames", "fallback", "bias") if k not in out]
    if missing:
        raise RuntimeError(f"tessera view printed no {', '.join(missing)} line:\n{text[-3000:]}")
    return out


def run_view(a, store, path, size, fmt, pool):
    cmd = [a.tessera, "view", "--headless", "--store", store, "--path", path, "--size", size,
           "--page-format", fmt, "--pool", str(pool)]
    t0 = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {r.returncode}:\n{r.stderr[-3000:]}")
    s = parse_summary(r.stdout + "\n" + r.stderr)
    w, h = (int(v) for v in size.split("x"))
    # From the page's size, not the total the viewer prints rounded to 0.1 MiB (2 % at 2 MiB).
    pool_mib = pool * float(s["pool"][2]) / 1024
    frames, seconds = int(s["frames"][0]), float(s["frames"][1])
    res = {
        "pool_pages": pool,
        "pool_mib": pool_mib,
        "bytes_per_pixel": pool_mib * 1024 * 1024 / (w * h),
        "page_kib": float(s["pool"][2]),
        "fallback_pct": float(s["fallback"][0]),
        "lod_bias_max": float(s["bias"][1]),
        "warmup_complete": s.get("warmup", ("full detail",))[0] == "full detail",
        "frames": frames,
        "requests_per_s": int(s["pages"][0]) / seconds if "pages" in s and seconds > 0 else None,
        "tile_latency_p50_ms": float(s["latency"][0]) if "latency" in s else None,
        "tile_latency_p99_ms": float(s["latency"][1]) if "latency" in s else None,
        "wall_s": round(time.time() - t0, 1),
    }
    res["meets_floor"] = (res["fallback_pct"] <= a.max_fallback * 100 and res["lod_bias_max"] == 0
                          and res["warmup_complete"])
    return res


def bisect(a, store, path, size, fmt, log):
    def probe(pool):
        r = run_view(a, store, path, size, fmt, pool)
        log(f"    pool {pool:5d}: fallback {r['fallback_pct']:.4f}%, bias max {r['lod_bias_max']:.2f}, "
            f"{'full detail' if r['warmup_complete'] else 'warm-up timed out'} -> "
            f"{'meets' if r['meets_floor'] else 'misses'} ({r['wall_s']} s)")
        return r
    top = probe(a.hi)
    if not top["meets_floor"]:
        return {"smallest": None, "largest_failing": a.hi, "runs": [top]}
    # Geometric midpoints: the floor may be anywhere from --lo to --hi, and each step halves the
    # log of the ratio between the bounds (8 to 2048 pages: about 8 runs to 5%).
    passing, failing, runs = top, a.lo - 1, [top]
    while passing["pool_pages"] - failing > max(1, int(passing["pool_pages"] * a.precision)):
        mid = int(round(math.sqrt(max(failing, 1) * passing["pool_pages"])))
        mid = min(max(mid, failing + 1), passing["pool_pages"] - 1)
        r = probe(mid)
        runs.append(r)
        if r["meets_floor"]:
            passing = r
        else:
            failing = mid
    return {"smallest": passing, "largest_failing": failing if failing >= a.lo else None, "runs": runs}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tessera", default="build/tessera")
    ap.add_argument("--paths", default="flyover,walk,whip")
    ap.add_argument("--sizes", default="1280x720,1920x1080")
    ap.add_argument("--formats", default="rgba8,bc1,bc7")
    ap.add_argument("--tiles", default="128,256")
    ap.add_argument("--texels", type=int, default=16384)
    ap.add_argument("--lo", type=int, default=16, help="smallest pool tried (the viewer's minimum is 16)")
    ap.add_argument("--hi", type=int, default=2048)
    ap.add_argument("--precision", type=float, default=0.05, help="stop when within this fraction of the pool")
    ap.add_argument("--max-fallback", type=float, default=0.0001, help="fraction of textured pixels (0.0001 = 0.01%%)")
    ap.add_argument("--work", default="build/pool-floor")
    a = ap.parse_args()
    if a.lo < 16:  # tessera view refuses pools under 16 pages
        print(f"--lo {a.lo}: the viewer's smallest pool is 16 pages; bisecting from 16", file=sys.stderr)
        a.lo = 16
    if not (1 <= a.lo < a.hi):
        sys.exit("pool_floor: need 1 <= --lo < --hi")
    if not os.access(a.tessera, os.X_OK):
        sys.exit(f"pool_floor: {a.tessera} is not an executable (build it: ninja -C build tessera)")
    os.makedirs(a.work, exist_ok=True)

    def log(msg):
        print(msg, flush=True)

    stores = {}
    for tile in [int(t) for t in a.tiles.split(",")]:
        store = os.path.join(a.work, f"terrain{a.texels}_{tile}.tsr")
        if not os.path.exists(store):
            log(f"building {store}")
            subprocess.run([a.tessera, "build", f"procedural:terrain:{a.texels}", "-o", store, "--tile-size", str(tile), "-q"],
                           check=True)
        stores[tile] = store

    results = []
    combos = list(itertools.product(a.paths.split(","), a.sizes.split(","), a.formats.split(","), stores))
    for i, (path, size, fmt, tile) in enumerate(combos, 1):
        log(f"[{i}/{len(combos)}] {path} {size} {fmt} pages of {tile}^2")
        b = bisect(a, stores[tile], path, size, fmt, log)
        results.append({"path": path, "size": size, "format": fmt, "tile_size": tile, **b})
        with open(os.path.join(a.work, "pool_floor.json"), "w") as f:
            json.dump({"max_fallback": a.max_fallback, "texels": a.texels, "results": results}, f, indent=1)

    print("\n| path | size | format | page | smallest pool (pages) | MiB | bytes / screen pixel | largest failing | requests/s | tile latency p50 / p99 ms |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---|")
    for r in results:
        s = r["smallest"]
        if s is None:
            print(f"| {r['path']} | {r['size']} | {r['format']} | {r['tile_size']} | > {a.hi} | | | {a.hi} | | |")
            continue
        lat = (f"{s['tile_latency_p50_ms']:.1f} / {s['tile_latency_p99_ms']:.1f}"
               if s["tile_latency_p50_ms"] is not None else "")
        rps = f"{s['requests_per_s']:.0f}" if s["requests_per_s"] is not None else ""
        print(f"| {r['path']} | {r['size']} | {r['format']} | {r['tile_size']} | {s['pool_pages']} | {s['pool_mib']:.1f} | "
              f"{s['bytes_per_pixel']:.2f} | {r['largest_failing'] if r['largest_failing'] is not None else '-'} | {rps} | {lat} |")


if __name__ == "__main__":
    main()
