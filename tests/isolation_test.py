#!/usr/bin/env python3
"""Isolation (docs/server.md, "Isolation"): one slow store or a flood of heavy renders must not
stall what the server does for everyone else.

1. Slow origin. One store is served from an HTTP range origin that, once the store is open,
   answers every request only after SLOW_S seconds; another store is a local file (the server's
   RAM cache off, so every local tile is a read on the executor). While 64 clients ask for the
   slow store's tiles (and 8 gRPC viewers ask for them too, in closed loop, `bench/serve_load`),
   the local store's tiles over HTTP and over gRPC (`tessera loadtest`) keep
   p99 <= 25 ms and <= 5x their own baseline measured in the same run; every slow request ends
   with data, 503 or 504, none later than --request-timeout + 1 s; the server's threads and RSS
   stay bounded.
2. Heavy renders. 24 clients ask large IIIF renders (full/max, pct:50, 2000x2000 regions with
   rotation, png and jpg) of a 16384x16384 store with the web cache off: tiles of another store
   keep p99 <= 25 ms, the server's RSS stays <= 256 MiB, and renders past the limits are answered
   503 with Retry-After at once.
"""
import argparse
import http.client
import http.server
import json
import os
import random
import signal
import socketserver
import subprocess
import sys
import tempfile
import threading
import time

import serve_util

SLOW_S = 6.0          # the slow origin's wait before each answer (>= 5 s)
TIMEOUT_MS = 3000     # the server's --request-timeout in the slow-origin part
P99_LIMIT_MS = 25.0
SANITIZED = bool(os.environ.get("TESSERA_SANITIZE"))


def fail(msg):
    print("FAIL: " + msg, flush=True)
    sys.exit(1)


def pct(values, q):
    if not values:
        return float("nan")
    v = sorted(values)
    return v[min(len(v) - 1, int(q * len(v)))]


class RangeOrigin(http.server.BaseHTTPRequestHandler):
    """One file with ranges and a strong ETag; every answer after `delay` seconds."""
    protocol_version = "HTTP/1.1"
    data = b""
    delay = 0.0
    etag = '"isolation-v1"'
    requests = 0
    lock = threading.Lock()

    def log_message(self, *args):
        pass

    def answer(self, body):
        with self.lock:
            RangeOrigin.requests += 1
        if self.delay:
            time.sleep(self.delay)
        rng = self.headers.get("Range")
        status, part = 200, self.data
        if rng:
            a, b = rng.split("=")[1].split("-")
            part, status = self.data[int(a):int(b) + 1], 206
        try:
            self.send_response(status)
            self.send_header("ETag", self.etag)
            self.send_header("Content-Length", str(len(part)))
            if status == 206:
                self.send_header("Content-Range", f"bytes {a}-{b}/{len(self.data)}")
            self.end_headers()
            if body:
                self.wfile.write(part)
        except OSError:
            pass  # the server gave up on this request (its deadline): expected

    def do_HEAD(self):
        self.answer(False)

    def do_GET(self):
        self.answer(True)


class ThreadingServer(socketserver.ThreadingMixIn, http.server.HTTPServer):
    daemon_threads = True
    request_queue_size = 256


def build(tessera, spec, out, *extra):
    r = subprocess.run([tessera, "build", spec, "-o", out, *extra], capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"tessera build {spec} failed ({r.returncode}):\n{r.stderr}")


def start_server(tessera, args):
    p = subprocess.Popen([tessera, "serve", "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0", "--watch-interval", "0",
                          "--log-format", "json", *args], stderr=subprocess.PIPE, text=True)
    lines = []
    ports = serve_util.wait_listening(p, lines)
    if not ports:
        fail(f"serve exited {p.wait()}:\n{''.join(lines)}")
    return p, ports


def stop_server(p):
    p.send_signal(signal.SIGTERM)
    try:
        p.wait(timeout=60)
    except subprocess.TimeoutExpired:
        p.kill()
        fail("the server did not stop within 60 s of SIGTERM")


def proc_status(pid):
    """(threads, RSS in MiB) of a process, from /proc."""
    threads = rss = 0
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("Threads:"):
                threads = int(line.split()[1])
            elif line.startswith("VmRSS:"):
                rss = int(line.split()[1]) / 1024
    return threads, rss


class Sampler(threading.Thread):
    """The server's threads and RSS every 100 ms while it runs."""

    def __init__(self, pid):
        super().__init__(daemon=True)
        self.pid, self.stop, self.threads, self.rss = pid, threading.Event(), [], []

    def run(self):
        while not self.stop.is_set():
            try:
                t, r = proc_status(self.pid)
            except OSError:
                return
            self.threads.append(t)
            self.rss.append(r)
            time.sleep(0.1)


def timed_get(conn, path):
    """(status, headers, ms) of one GET on a kept-alive connection; an error's body is the
    header "body"."""
    t0 = time.perf_counter()
    conn.request("GET", path)
    r = conn.getresponse()
    body = r.read()
    headers = dict(r.getheaders())
    if r.status >= 400:
        headers["body"] = body[:200].decode(errors="replace")
    return r.status, headers, (time.perf_counter() - t0) * 1000


def client_loop(port, next_path, stop, results, lock, backoff_s, odd=None):
    """Asks next_path(rng) again and again on one kept-alive connection until `stop`; each answer
    as (status, ms, Retry-After) into `results` (0 and the error for a broken connection), the
    bodies of answers other than 200, 503 and 504 into `odd`; waits `backoff_s` after a 503."""
    def run(seed):
        rng = random.Random(seed)
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
        while not stop.is_set():
            try:
                status, headers, ms = timed_get(conn, next_path(rng))
            except (OSError, http.client.HTTPException) as e:
                with lock:
                    results.append((0, 0.0, str(e)))
                conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
                continue
            with lock:
                results.append((status, ms, headers.get("Retry-After")))
                if odd is not None and status not in (200, 503, 504):
                    odd.append(headers.get("body"))
            if status == 503:
                time.sleep(backoff_s)
    return run


def probe(port, store, keys, seconds, out, errors):
    """GETs of `keys` in turn for `seconds`, latencies (ms) into `out`; non-200s into `errors`."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    end = time.monotonic() + seconds
    i = 0
    while time.monotonic() < end:
        level, x, y = keys[i % len(keys)]
        i += 1
        try:
            status, _, ms = timed_get(conn, f"/v1/stores/{store}/tiles/{level}/{x}/{y}")
        except (OSError, http.client.HTTPException) as e:
            errors.append(str(e))
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
            continue
        if status != 200:
            errors.append(f"status {status}")
        out.append(ms)
        time.sleep(0.002)


def tile_keys(port, store):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    conn.request("GET", f"/v1/stores/{store}")
    info = json.loads(conn.getresponse().read())
    keys = []
    for l in info["level_info"]:
        for y in range(l["tiles_y"]):
            for x in range(l["tiles_x"]):
                keys.append((l["level"], x, y))
    return keys


def loadtest(tessera, grpc_port, store, seconds, out_json):
    """`tessera loadtest` on one viewer in the background; its JSON says the tile latency."""
    return subprocess.Popen([tessera, "loadtest", "--server", f"127.0.0.1:{grpc_port}", "--store", store, "--viewers", "1",
                             "--fps", "30", "--path", "whip", "--pool", "48", "--duration", str(seconds), "--warmup", "0.5", "--quiet",
                             "--json", out_json], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def loadtest_p99(p, out_json):
    _, err = p.communicate(timeout=120)
    if p.returncode != 0:
        fail(f"tessera loadtest exited {p.returncode}:\n{err}")
    with open(out_json) as f:
        j = json.load(f)
    run = j["runs"][0] if "runs" in j else j
    lat = run.get("latency_ms") or run.get("tile_latency_ms") or {}
    tiles = run.get("tiles") or run.get("tiles_received") or 0
    return float(lat["p99"]), tiles, run


def serve_from_origin(tessera, spec, path):
    """Builds `spec` into `path` and serves its bytes from a RangeOrigin on a free port:
    (origin, the store's URL). RangeOrigin.delay sets how slow it answers."""
    build(tessera, spec, path)
    with open(path, "rb") as f:
        RangeOrigin.data = f.read()
    origin = ThreadingServer(("127.0.0.1", 0), RangeOrigin)
    threading.Thread(target=origin.serve_forever, daemon=True).start()
    return origin, f"http://127.0.0.1:{origin.server_address[1]}/slow.tsr"


def serve_load_binary(tessera):
    """bench/serve_load beside the tessera binary (the build makes both)."""
    path = os.path.join(os.path.dirname(os.path.abspath(tessera)), "bench", "serve_load")
    if not os.access(path, os.X_OK):
        fail(f"{path} is missing: build the serve_load target")
    return path


def slow_origin(tessera, tmp):
    local = os.path.join(tmp, "local.tsr")
    remote_file = os.path.join(tmp, "remote.tsr")
    build(tessera, "procedural:terrain:8192", local)
    origin, remote_url = serve_from_origin(tessera, "procedural:terrain:2048", remote_file)

    p, (grpc_port, http_port) = start_server(tessera, ["--store", local, "--store", remote_url, "--cache-size", "0",
                                                       "--request-timeout", str(TIMEOUT_MS)])
    try:
        local_keys = tile_keys(http_port, "local")
        slow_keys = tile_keys(http_port, "slow")
        random.Random(1).shuffle(local_keys)

        # Baseline: the local store over HTTP and gRPC, nothing else running.
        base_http, errors = [], []
        lt_json = os.path.join(tmp, "base.json")
        lt = loadtest(tessera, grpc_port, "local", 3, lt_json)
        probe(http_port, "local", local_keys, 3.0, base_http, errors)
        base_grpc, base_tiles, _ = loadtest_p99(lt, lt_json)
        if errors:
            fail(f"baseline local tiles failed: {errors[:3]}")
        base_p99 = pct(base_http, 0.99)
        print(f"baseline: local HTTP p99 {base_p99:.2f} ms over {len(base_http)} tiles; gRPC p99 {base_grpc:.2f} ms "
              f"over {base_tiles} tiles", flush=True)

        # The origin turns slow; 64 clients ask for the slow store's tiles.
        RangeOrigin.delay = SLOW_S
        sampler = Sampler(p.pid)
        sampler.start()
        t_rest, rss_rest = proc_status(p.pid)
        stop = threading.Event()
        slow_results = []  # (status, ms, retry_after)
        odd = []  # bodies of unexpected answers
        slow_lock = threading.Lock()

        def slow_path(rng):
            level, x, y = slow_keys[rng.randrange(len(slow_keys))]
            return f"/v1/stores/slow/tiles/{level}/{x}/{y}"

        slow_client = client_loop(http_port, slow_path, stop, slow_results, slow_lock, 0.05, odd)

        clients = [threading.Thread(target=slow_client, args=(i,), daemon=True) for i in range(64)]
        for c in clients:
            c.start()
        # gRPC viewers of the slow store too: their reads may hold only the remote store's share
        # of the gRPC I/O threads, never the threads the local store's viewers need.
        load_seconds = 2 * TIMEOUT_MS / 1000 + 2
        slow_grpc = subprocess.Popen([serve_load_binary(tessera), "--grpc", f"127.0.0.1:{grpc_port}", "--store", "slow",
                                      "--store-file", remote_file, "--rate", "0", "--viewers", "8", "--window", "64",
                                      "--duration", str(load_seconds + 2), "--warmup", "0", "--json", os.devnull],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        time.sleep(1.0)  # the slow store's lane fills
        load_http = []
        lt_json = os.path.join(tmp, "load.json")
        lt = loadtest(tessera, grpc_port, "local", load_seconds, lt_json)
        probe(http_port, "local", local_keys, load_seconds, load_http, errors)
        load_grpc, load_tiles, _ = loadtest_p99(lt, lt_json)
        stop.set()
        try:
            _, slow_err = slow_grpc.communicate(timeout=load_seconds + TIMEOUT_MS / 1000 + 30)
        except subprocess.TimeoutExpired:
            slow_grpc.kill()
            fail("the slow store's gRPC viewers did not end")
        if slow_grpc.returncode != 0:
            fail(f"serve_load on the slow store exited {slow_grpc.returncode}: {slow_err[-500:]}")
        for c in clients:
            c.join(timeout=TIMEOUT_MS / 1000 + 10)
        sampler.stop.set()
        sampler.join()
        if errors:
            fail(f"local tiles failed while the origin was slow: {errors[:3]}")
        load_p99 = pct(load_http, 0.99)
        statuses = {}
        for s, _, _ in slow_results:
            statuses[s] = statuses.get(s, 0) + 1
        slowest = max(ms for _, ms, _ in slow_results)
        print(f"slow origin: local HTTP p99 {load_p99:.2f} ms over {len(load_http)} tiles (max "
              f"{max(load_http):.1f} ms); gRPC p99 {load_grpc:.2f} ms over {load_tiles} tiles; slow store answers "
              f"{statuses}, slowest {slowest:.0f} ms; server threads {t_rest} at rest, max {max(sampler.threads)}; "
              f"RSS {rss_rest:.0f} MiB at rest, max {max(sampler.rss):.0f} MiB", flush=True)

        limit = P99_LIMIT_MS * (4 if SANITIZED else 1)
        if load_p99 > limit or load_p99 > 5 * max(base_p99, 1.0):
            fail(f"local HTTP tiles p99 {load_p99:.2f} ms while the origin was slow (baseline {base_p99:.2f} ms; limits "
                 f"{limit} ms and 5x the baseline)")
        if load_grpc > limit or load_grpc > 5 * max(base_grpc, 1.0):
            fail(f"local gRPC tiles p99 {load_grpc:.2f} ms while the origin was slow (baseline {base_grpc:.2f} ms)")
        if any(s not in (200, 503, 504) for s, _, _ in slow_results):
            fail(f"slow store answers other than 200, 503 and 504: {statuses}: {odd[:3]}")
        if statuses.get(504, 0) == 0:
            fail(f"no slow request reached its deadline (504): {statuses}")
        if any(s == 503 and not ra for s, _, ra in slow_results):
            fail("a 503 without Retry-After")
        if slowest > TIMEOUT_MS + 1000:
            fail(f"a slow request took {slowest:.0f} ms, past its deadline ({TIMEOUT_MS} ms) + 1 s")
        # gRPC's own pool may start a few threads under the loadtest's stream; nothing may grow
        # with the 64 slow requests.
        if max(sampler.threads) > t_rest + 16:
            fail(f"the server's threads grew with slow requests: {t_rest} at rest, {max(sampler.threads)} under load")
        if max(sampler.rss) > rss_rest + 64:
            fail(f"the server's RSS grew by more than 64 MiB: {rss_rest:.0f} -> {max(sampler.rss):.0f} MiB")
        m = http.client.HTTPConnection("127.0.0.1", http_port, timeout=30)
        m.request("GET", "/metrics")
        metrics = m.getresponse().read().decode()
        for needle in ('tessera_store_work_expired_total{store="slow"}', 'tessera_store_work_queued{store="slow"}',
                       'tessera_work_wait_seconds_count{kind="read"}'):
            if needle not in metrics:
                fail(f"/metrics lacks {needle}")
    finally:
        RangeOrigin.delay = 0
        stop_server(p)
        origin.shutdown()


def heavy_renders(tessera, tmp):
    big = os.path.join(tmp, "big.tsr")
    small = os.path.join(tmp, "small.tsr")
    t0 = time.monotonic()
    build(tessera, "procedural:terrain:16384", big)
    print(f"built the 16384x16384 store in {time.monotonic() - t0:.1f} s", flush=True)
    build(tessera, "procedural:terrain:2048", small)
    p, (_, http_port) = start_server(tessera, ["--store", big, "--store", small, "--web-cache", "0", "--cache-size", "64MiB"])
    try:
        small_keys = tile_keys(http_port, "small")
        errors = []
        warm = []
        probe(http_port, "small", small_keys, 1.0, warm, errors)  # in the RAM cache
        t_rest, rss_rest = proc_status(p.pid)
        sampler = Sampler(p.pid)
        sampler.start()
        stop = threading.Event()
        results = []
        lock = threading.Lock()
        # Some ask more than the server renders (pct:50 of 16384² is past maxWidth): 400 at once.
        asks = ["full/max/0/default.jpg", "full/max/90/default.png", "full/pct:50/0/default.jpg",
                "pct:25,25,50,50/max/0/default.jpg", "full/pct:12.5/180/gray.png"]

        def render_path(rng):
            if rng.random() < 0.5:
                x, y = rng.randrange(0, 16384 - 2000), rng.randrange(0, 16384 - 2000)
                return f"/iiif/big/{x},{y},2000,2000/max/{rng.choice([90, 180, 270])}/default.{rng.choice(['png', 'jpg'])}"
            return "/iiif/big/" + rng.choice(asks)

        render_client = client_loop(http_port, render_path, stop, results, lock, 0.2)

        clients = [threading.Thread(target=render_client, args=(i,), daemon=True) for i in range(24)]
        for c in clients:
            c.start()
        time.sleep(1.0)
        load = []
        probe(http_port, "small", small_keys, 10.0, load, errors)
        stop.set()
        for c in clients:
            c.join(timeout=120)
        sampler.stop.set()
        sampler.join()
        statuses = {}
        for s, _, _ in results:
            statuses[s] = statuses.get(s, 0) + 1
        refused_ms = [ms for s, ms, _ in results if s == 503]
        p99 = pct(load, 0.99)
        print(f"heavy renders: small-store tiles p99 {p99:.2f} ms over {len(load)} (max {max(load):.1f} ms); IIIF "
              f"answers {statuses}; 503s answered in p99 {pct(refused_ms, 0.99):.1f} ms; RSS {rss_rest:.0f} MiB at rest, "
              f"max {max(sampler.rss):.0f} MiB; threads max {max(sampler.threads)}", flush=True)
        if errors:
            fail(f"small-store tiles failed during the renders: {errors[:3]}")
        limit = P99_LIMIT_MS * (4 if SANITIZED else 1)
        if p99 > limit:
            fail(f"small-store tiles p99 {p99:.2f} ms during heavy renders (limit {limit} ms)")
        if not SANITIZED and max(sampler.rss) > 256:
            fail(f"the server's RSS reached {max(sampler.rss):.0f} MiB during heavy renders (limit 256 MiB)")
        if statuses.get(200, 0) == 0:
            fail(f"no render was served: {statuses}")
        if statuses.get(503, 0) == 0:
            fail(f"24 clients of heavy renders were never refused: {statuses}")
        if any(s == 503 and not ra for s, _, ra in results):
            fail("a refused render without Retry-After")
        if any(s not in (200, 400, 503, 504) for s, _, _ in results):
            fail(f"IIIF answers other than 200, 400, 503 and 504: {statuses}")
        if pct(refused_ms, 0.5) > 50:
            fail(f"refusals are not at once: median {pct(refused_ms, 0.5):.1f} ms")
    finally:
        stop_server(p)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tessera", required=True)
    ap.add_argument("--part", choices=["all", "slow-origin", "renders"], default="all")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if a.part in ("all", "slow-origin"):
            slow_origin(a.tessera, tmp)
        if a.part in ("all", "renders"):
            heavy_renders(a.tessera, tmp)
    print("PASS", flush=True)


if __name__ == "__main__":
    main()
