#!/usr/bin/env python3
"""Deferred HTTP answers (docs/server.md, "Isolation"): what the executor does for a request must
reach the client, and each kind of work is admitted as its kind.

1. A slow answer outlives the idle timeout. A store behind a range origin that answers after
   1 s, served with --idle-timeout 500 ms and --request-timeout 3000 ms: a tile comes back 200
   after the origin's wait (the connection is not closed as idle while its answer is being read),
   and with the origin at 5 s the answer is 504 by the request's deadline + 1 s.
2. A render found by a read is admitted as a render. A JPEG store of 1024-texel tiles whose
   interior tile (1, 1) is uniform: its DZI tile is read, found uniform, and then has to be
   rendered from three rows of 1024² tiles (about 30 MiB estimated). With --render-memory 16MiB
   that render can never be admitted: 500 naming --render-memory, no Retry-After; with the
   defaults it is rendered by a render worker
   (tessera_work_wait_seconds_count{kind="render"} counts it) and is a 1024² JPEG.
3. The stop cuts what waits on an origin. With the origin at 20 s, --request-timeout 8000,
   --drain-timeout 1000 and --store-inflight 1, a SIGTERM while one tile request waits on the
   origin and two more wait in the store's lane ends the process with 0 within the drain timeout
   + 1 s: the drain waits its 1 s, then the remote read is cancelled, not waited for until its
   deadline (which overran the stop's watchdog: exit 1 after 2.5 s), and the waiting requests
   are answered as the stop ends.
"""
import argparse
import http.client
import os
import re
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib

import isolation_test as iso

fail = iso.fail


def get(port, path, timeout=30):
    """(status, headers, body, seconds) of one GET on a fresh connection."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    t0 = time.perf_counter()
    try:
        conn.request("GET", path)
        r = conn.getresponse()
        body = r.read()
        return r.status, dict(r.getheaders()), body, time.perf_counter() - t0
    except (http.client.HTTPException, OSError) as e:
        fail(f"GET {path}: no answer after {time.perf_counter() - t0:.2f} s ({type(e).__name__}: {e})")
    finally:
        conn.close()


def slow_answers(tessera, tmp):
    origin, url = iso.serve_from_origin(tessera, "procedural:terrain:1024", os.path.join(tmp, "remote.tsr"))
    p, (_, port) = iso.start_server(tessera, ["--store", url, "--cache-size", "0", "--idle-timeout", "500",
                                              "--request-timeout", "3000"])
    try:
        iso.RangeOrigin.delay = 1.0
        status, _, body, s = get(port, "/v1/stores/slow/tiles/0/1/1")
        print(f"origin at 1 s: {status}, {len(body)} bytes after {s:.2f} s", flush=True)
        if status != 200 or not body or s < 0.95:
            fail(f"expected 200 with the tile after the origin's 1 s, got {status} ({len(body)} bytes) after {s:.2f} s")
        iso.RangeOrigin.delay = 5.0
        status, headers, body, s = get(port, "/v1/stores/slow/tiles/0/2/1")
        print(f"origin at 5 s: {status} after {s:.2f} s", flush=True)
        if status != 504 or not 2.9 <= s <= 4.0:
            fail(f"expected 504 by the 3 s deadline (+1 s), got {status} after {s:.2f} s: {body[:200]!r}")
    finally:
        iso.RangeOrigin.delay = 0
        iso.stop_server(p)
        origin.shutdown()


def stop_cuts_slow_reads(tessera, tmp):
    origin, url = iso.serve_from_origin(tessera, "procedural:terrain:1024", os.path.join(tmp, "remote-stop.tsr"))
    p, (_, port) = iso.start_server(tessera, ["--store", url, "--cache-size", "0", "--request-timeout", "8000",
                                              "--drain-timeout", "1000", "--store-inflight", "1"])
    try:
        iso.RangeOrigin.delay = 20.0

        def ask(x):
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
            try:
                conn.request("GET", f"/v1/stores/slow/tiles/0/{x}/3")
                conn.getresponse().read()
            except (http.client.HTTPException, OSError):
                pass  # cut with the server: either way is fine here
            finally:
                conn.close()

        for x in (1, 2, 3):  # one read, two waiting in the lane (--store-inflight 1)
            threading.Thread(target=ask, args=(x,), daemon=True).start()
        time.sleep(0.5)  # the first read is waiting on the origin
        t0 = time.perf_counter()
        p.send_signal(signal.SIGTERM)
        try:
            rc = p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            fail("the server did not stop within 30 s of SIGTERM")
        s = time.perf_counter() - t0
        err = p.stderr.read() if p.stderr else ""
        print(f"SIGTERM with a read waiting on a 20 s origin and two in the lane: exit {rc} after {s:.2f} s", flush=True)
        if rc != 0 or s > 2.0:  # the 1 s drain + 1 s
            fail(f"expected exit 0 within the 1 s drain + 1 s, got {rc} after {s:.2f} s: {err[-400:]}")
    finally:
        iso.RangeOrigin.delay = 0
        if p.poll() is None:
            p.kill()
        origin.shutdown()


def write_png(path, w, h, pixel_row):
    """An 8-bit RGB PNG, written here (no imaging library): pixel_row(y) -> w*3 bytes."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    z = zlib.compressobj(1)
    parts = [z.compress(b"\0" + pixel_row(y)) for y in range(h)]
    parts.append(z.flush())
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) +
                chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b""))


def jpeg_size(data):
    """(width, height) from a JPEG's start-of-frame segment, or None."""
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 9 < len(data):
        if data[i] != 0xFF:
            return None
        marker, length = data[i + 1], struct.unpack(">H", data[i + 2:i + 4])[0]
        if marker in (0xC0, 0xC1, 0xC2):
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return w, h
        i += 2 + length
    return None


def render_counted(port):
    status, _, body, _ = get(port, "/metrics")
    m = re.search(rb'^tessera_work_wait_seconds_count\{kind="render"\} (\d+)', body, re.M)
    if status != 200 or not m:
        fail("/metrics has no tessera_work_wait_seconds_count{kind=\"render\"}")
    return int(m.group(1))


def uniform_interior_render(tessera, tmp):
    # 3048 = 3 payloads of 1016 (1024-texel tiles, border 4). Tile (1, 1) stores texels 1012..2035
    # of both axes: one colour over 900..2199, a pattern elsewhere.
    size, lo, hi = 3048, 900, 2200
    pattern = bytes((x * 7 + (x >> 3) * 13) & 255 for x in range(size * 3 + 256))
    flat = bytes([128, 64, 32]) * (hi - lo)

    def row(y):
        r = pattern[(y % 256):(y % 256) + size * 3]
        return r[:lo * 3] + flat + r[hi * 3:] if lo <= y < hi else r

    png = os.path.join(tmp, "flat.png")
    store = os.path.join(tmp, "flat.tsr")
    write_png(png, size, size, row)
    iso.build(tessera, png, store, "--tile-size", "1024", "--codec", "jpeg")
    dzi_tile = "/dzi/flat_files/12/1_1.jpg"  # 12 = ceil(log2(3048)): full resolution

    p, (_, port) = iso.start_server(tessera, ["--store", store, "--cache-size", "0", "--render-memory", "16MiB"])
    try:
        status, headers, _, _ = get(port, "/v1/stores/flat/tiles/0/1/1")
        if status != 200 or headers.get("X-Tessera-Kind") != "uniform":
            fail(f"the test store's tile (1, 1) should be stored uniform: {status}, {headers.get('X-Tessera-Kind')}")
        status, headers, body, s = get(port, dzi_tile)
        print(f"--render-memory 16MiB: {status} after {s:.2f} s, Retry-After {headers.get('Retry-After')}", flush=True)
        # A DZI tile's size is fixed: waiting cannot make it fit, so no Retry-After (clients
        # would retry it for ever), and a 500 that names the option the operator must raise.
        if status != 500 or "Retry-After" in headers or b"--render-memory" not in body:
            fail(f"expected 500 without Retry-After (the render needs more than --render-memory), got {status} "
                 f"{headers.get('Retry-After')}: {body[:200]!r}")
    finally:
        iso.stop_server(p)

    p, (_, port) = iso.start_server(tessera, ["--store", store, "--cache-size", "0"])
    try:
        before = render_counted(port)
        status, headers, body, s = get(port, dzi_tile)
        after = render_counted(port)
        print(f"defaults: {status}, {headers.get('Content-Type')}, {jpeg_size(body)} after {s:.2f} s; "
              f"renders {before} -> {after}", flush=True)
        if status != 200 or headers.get("Content-Type") != "image/jpeg" or jpeg_size(body) != (1024, 1024):
            fail(f"expected a 1024x1024 JPEG, got {status} {headers.get('Content-Type')} {jpeg_size(body)}")
        if after != before + 1:
            fail(f"the render ran outside the render workers: renders counted {before} -> {after}")
    finally:
        iso.stop_server(p)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tessera", required=True)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        slow_answers(a.tessera, tmp)
        uniform_interior_render(a.tessera, tmp)
        stop_cuts_slow_reads(a.tessera, tmp)
    print("PASS", flush=True)


if __name__ == "__main__":
    sys.exit(main())
