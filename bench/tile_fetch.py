#!/usr/bin/env python3
"""Fetches the 32x32 level-0 tiles of store "terrain" from a tessera server's HTTP port with 16
client threads; prints tiles/s and the p50/p99 request latency (bench/remote_stores.sh)."""
import sys, threading, time, urllib.request
port = int(sys.argv[1]); n = 32
keys = [(x, y) for x in range(n) for y in range(n)]
lat = []; lock = threading.Lock()
def worker(part):
    for x, y in part:
        t = time.perf_counter()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/v1/stores/terrain/tiles/0/{x}/{y}") as r: r.read()
        with lock: lat.append(time.perf_counter() - t)
t0 = time.perf_counter()
ts = [threading.Thread(target=worker, args=(keys[i::16],)) for i in range(16)]
[t.start() for t in ts]; [t.join() for t in ts]
el = time.perf_counter() - t0; lat.sort()
print("tiles/s %7.0f  p50 %6.2f ms  p99 %6.2f ms" % (len(keys) / el, 1000 * lat[len(lat)//2], 1000 * lat[int(len(lat)*0.99)]))
