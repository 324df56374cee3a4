#!/usr/bin/env python3
"""Stores in object storage and behind plain HTTP: tessera-server serves s3://BUCKET/KEY.tsr from an
S3 implementation (s3rver, from npm: path-style addressing, access keys, ranges, ETags, If-Match;
it does not check V4 signatures, so remote_source_test checks the signer against AWS's published
example) and http://HOST/PATH.tsr from nginx, tile for tile as it serves the same file from disk;
a replaced object is served as a new version after a rescan, never mixed with the old one (four
clients read while it is replaced; the RAM cache is off so every read reaches the object); an
unknown access key and a missing object are clear errors at start; the remote counters move."""
import argparse
import datetime
import http.server
import threading
import hashlib
import hmac
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

import serve_util

KEY = SECRET = "S3RVER"  # s3rver's built-in credentials


def wait_for_port(port):
    """Until something listens on 127.0.0.1:port (10 s at most)."""
    for _ in range(200):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.05)
    fail(f"nothing listens on port {port}")


def fail(msg):
    print("FAIL: " + msg, flush=True)
    sys.exit(1)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def sigv4_put(endpoint, bucket, key, body):
    """PUT an object with AWS Signature V4 (what any S3 client does), independent of Tessera's signer."""
    host = endpoint.split("//", 1)[1]
    now = datetime.datetime.now(datetime.timezone.utc)
    amz, date = now.strftime("%Y%m%dT%H%M%SZ"), now.strftime("%Y%m%d")
    payload = hashlib.sha256(body).hexdigest()
    path = f"/{bucket}/{key}"
    headers = {"host": host, "x-amz-content-sha256": payload, "x-amz-date": amz}
    canonical = "\n".join(["PUT", path, "", "".join(f"{k}:{headers[k]}\n" for k in sorted(headers)),
                           ";".join(sorted(headers)), payload])
    scope = f"{date}/us-east-1/s3/aws4_request"
    to_sign = "\n".join(["AWS4-HMAC-SHA256", amz, scope, hashlib.sha256(canonical.encode()).hexdigest()])
    k = hmac.new(("AWS4" + SECRET).encode(), date.encode(), hashlib.sha256).digest()
    for part in ("us-east-1", "s3", "aws4_request"):
        k = hmac.new(k, part.encode(), hashlib.sha256).digest()
    sig = hmac.new(k, to_sign.encode(), hashlib.sha256).hexdigest()
    req = urllib.request.Request(endpoint + path, data=body, method="PUT")
    for h, v in headers.items():
        if h != "host":
            req.add_header(h, v)
    req.add_header("Authorization", f"AWS4-HMAC-SHA256 Credential={KEY}/{scope}, SignedHeaders={';'.join(sorted(headers))}, Signature={sig}")
    with urllib.request.urlopen(req, timeout=30) as r:
        if r.status != 200:
            fail(f"PUT {path}: {r.status}")


def serve(binary, stores, env=None, expect_fail=False, extra=()):
    args = [binary, "serve", "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0", "--watch-interval", "0", "--log-format", "json",
            *extra]
    for s in stores:
        args += ["--store", s]
    p = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, env=env)
    lines = []
    ports = serve_util.wait_listening(p, lines)
    if ports:
        if expect_fail:
            stop(p)
            fail("serve started although it should not have")
        return p, ports[1]
    rc = p.wait()
    if expect_fail:
        return rc, "".join(lines)
    fail(f"serve exited {rc}:\n{''.join(lines)}")


def stop(p):
    p.send_signal(signal.SIGTERM)
    p.wait(timeout=60)


def get(port, path):
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=30) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as e:
        return e.code, dict(e.headers), e.read()


def tiles_of(port, store, keys):
    return {k: get(port, f"/v1/stores/{store}/tiles/{k[0]}/{k[1]}/{k[2]}")[2] for k in keys}


def metric(port, name):
    body = get(port, "/metrics")[2].decode()
    m = re.search(rf"^{name}(?:{{[^}}]*}})? ([0-9.e+]+)$", body, re.M)
    return float(m.group(1)) if m else None


class FlakyOrigin(http.server.BaseHTTPRequestHandler):
    """Serves one file with ranges and an ETag, but answers 503 to the first two tries of each
    request (fail_first), and waits `delay` seconds before each range (a far origin)."""
    data = b""
    tries = {}
    lock = threading.Lock()
    fail_first = 2
    delay = 0.0
    etag = '"v1"'
    last_modified = None  # sent when set
    if_match = []  # the If-Match header of each range GET (None when absent)
    if_unmodified = []  # the If-Unmodified-Since header of each range GET

    def log_message(self, *args):
        pass

    def answer(self, body):
        key = (self.command, self.headers.get("Range"))
        with self.lock:
            n = self.tries[key] = self.tries.get(key, 0) + 1
        if n <= self.fail_first:
            self.send_response(503)
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        rng = self.headers.get("Range")
        if rng and self.command == "GET":
            with self.lock:
                self.if_match.append(self.headers.get("If-Match"))
                self.if_unmodified.append(self.headers.get("If-Unmodified-Since"))
        status, part = 200, self.data
        if rng and self.delay:
            time.sleep(self.delay)
        if rng:
            a, b = rng.split("=")[1].split("-")
            part, status = self.data[int(a):int(b) + 1], 206
        self.send_response(status)
        self.send_header("ETag", self.etag)
        if self.last_modified:
            self.send_header("Last-Modified", self.last_modified)
        self.send_header("Content-Length", str(len(part) if status == 206 else len(self.data)))
        if status == 206:
            self.send_header("Content-Range", f"bytes {a}-{b}/{len(self.data)}")
        self.end_headers()
        if body:
            self.wfile.write(part)

    def do_HEAD(self):
        self.answer(False)

    def do_GET(self):
        self.answer(True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tessera", required=True)
    ap.add_argument("--server", required=True)
    ap.add_argument("--s3rver", required=True)
    a = ap.parse_args()
    for tool in (a.s3rver, shutil.which("nginx") or "/usr/sbin/nginx"):
        if not os.path.exists(tool):
            fail(f"{tool} is missing (tools/setup.sh --tests installs it)")

    with tempfile.TemporaryDirectory() as d:
        one, two = os.path.join(d, "one.tsr"), os.path.join(d, "two.tsr")
        subprocess.run([a.tessera, "build", "-q", "procedural:terrain:1200", "-o", one, "--tile-size", "128"], check=True)
        subprocess.run([a.tessera, "build", "-q", "procedural:terrain:1000", "-o", two, "--tile-size", "128", "--quality", "60"],
                       check=True)
        keys = [(0, x, y) for x in range(0, 10, 3) for y in range(0, 10, 4)] + [(2, 1, 1), (4, 0, 0), (3, 0, 0)]
        wanted = [(0, x, y) for x in range(5) for y in range(4)]  # the coalescing part's tiles

        # The reference: the same file from disk.
        p, port = serve(a.server, [one])
        want = tiles_of(port, "one", sorted(set(keys) | set(wanted)))
        want_info = json.loads(get(port, "/v1/stores/one")[2])
        stop(p)
        p, port = serve(a.server, [two])
        want_two = tiles_of(port, "two", [(0, 0, 0), (0, 7, 7), (3, 0, 0)])
        stop(p)

        # --- S3 (s3rver, signatures checked) ---
        s3dir = os.path.join(d, "s3")
        os.makedirs(s3dir)
        s3port = free_port()
        s3 = subprocess.Popen([a.s3rver, "-d", s3dir, "-a", "127.0.0.1", "-p", str(s3port), "--configure-bucket", "tiles", "-s"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            endpoint = f"http://127.0.0.1:{s3port}"
            wait_for_port(s3port)
            sigv4_put(endpoint, "tiles", "maps/terrain.tsr", open(one, "rb").read())
            env = dict(os.environ, AWS_ACCESS_KEY_ID=KEY, AWS_SECRET_ACCESS_KEY=SECRET, AWS_ENDPOINT_URL=endpoint,
                       AWS_REGION="us-east-1")
            # No RAM cache: every tile read below goes to the object, also while it is replaced.
            p, port = serve(a.server, ["s3://tiles/maps/terrain.tsr"], env, extra=["--cache-size", "0"])
            try:
                info = json.loads(get(port, "/v1/stores/terrain")[2])
                if info.get("width") != want_info["width"] or info.get("levels") != want_info["levels"]:
                    fail(f"store info over S3: {info}")
                got = tiles_of(port, "terrain", keys)
                bad = [k for k in keys if got[k] != want[k]]
                if bad:
                    fail(f"tiles over S3 differ from the file's: {bad}")
                requests, read = metric(port, "tessera_remote_requests"), metric(port, "tessera_remote_read_bytes")
                print(f"S3: {len(keys)} tiles as from disk; {requests:.0f} requests, {read:.0f} bytes read")
                if not requests or not read:
                    fail("remote counters did not move")

                # Replace the object while four clients read tiles of both versions' shape: every
                # answer is exactly the old store's tile under the old version or the new store's
                # under the new one (never mixed), or a 503/504 to retry; the next rescan then
                # opens the new version.
                status, headers, _ = get(port, "/v1/stores/terrain/tiles/0/0/0")
                old_version = headers.get("ETag")
                old_store_version = headers.get("X-Tessera-Store-Version")
                both = [(0, 0, 0), (3, 0, 0)]
                reading, seen, mixed = True, {}, []
                seen_lock = threading.Lock()

                def reader():
                    while reading:
                        for k in both:
                            st, hd, body = get(port, f"/v1/stores/terrain/tiles/{k[0]}/{k[1]}/{k[2]}")
                            version = hd.get("X-Tessera-Store-Version")
                            if st == 200:
                                kind = "old" if body == want[k] else "new" if body == want_two[k] else "neither"
                                if kind == "neither" or (kind == "old") != (version == old_store_version):
                                    mixed.append((k, kind, version))
                            label = "-" if st != 200 else "old" if version == old_store_version else "new"
                            with seen_lock:
                                seen[(st, label)] = seen.get((st, label), 0) + 1

                readers = [threading.Thread(target=reader) for _ in range(4)]
                for t in readers:
                    t.start()
                time.sleep(0.3)
                sigv4_put(endpoint, "tiles", "maps/terrain.tsr", open(two, "rb").read())
                time.sleep(0.5)  # reads of the replaced object under the old version's ETag
                p.send_signal(signal.SIGHUP)
                for _ in range(300):  # the rescan: up to 30 s on a loaded machine (seen over 10 s with -j2)
                    time.sleep(0.1)
                    status, headers, body = get(port, "/v1/stores/terrain/tiles/0/0/0")
                    # Only a tile served under another version ends the wait: a 503 or 504 (the
                    # replaced object's reads failing until the rescan) carries no ETag either.
                    if status == 200 and headers.get("ETag") != old_version:
                        break
                # Let the readers reach the new version too: one may still be waiting out a read of
                # the replaced object (answered 504 at the request deadline) when the rescan lands.
                for _ in range(300):
                    with seen_lock:
                        if seen.get((200, "new"), 0) > 0:
                            break
                    time.sleep(0.1)
                time.sleep(0.3)
                reading = False
                for t in readers:
                    t.join()
                print(f"S3: reads while the object was replaced (status, version): {sorted(seen.items())}")
                if mixed:
                    fail(f"{len(mixed)} answers mixed the two versions, first {mixed[0]}")
                if seen.get((200, "old"), 0) == 0 or seen.get((200, "new"), 0) == 0:
                    fail(f"the readers did not see both versions served: {seen}")
                if any(st not in (200, 503, 504) for st, _ in seen):
                    fail(f"answers other than 200, 503 and 504 while the object was replaced: {seen}")
                if body != want_two[(0, 0, 0)]:
                    fail(f"after replacing the object: status {status}, the tile is not the new store's")
                for k, v in want_two.items():
                    if get(port, f"/v1/stores/terrain/tiles/{k[0]}/{k[1]}/{k[2]}")[2] != v:
                        fail(f"tile {k} after the replacement is not the new store's")
                print("S3: the replaced object is served as a new version after SIGHUP")
            finally:
                stop(p)

            # Clear errors at start: an unknown access key, a missing object.
            rc, log = serve(a.server, ["s3://tiles/maps/terrain.tsr"], dict(env, AWS_ACCESS_KEY_ID="NOSUCHKEY"), expect_fail=True)
            if rc == 0 or "access denied" not in log:
                fail(f"an unknown access key: exit {rc}, log {log[-400:]}")
            rc, log = serve(a.server, ["s3://tiles/maps/none.tsr"], env, expect_fail=True)
            if rc == 0 or "no such object" not in log:
                fail(f"a missing object: exit {rc}, log {log[-400:]}")
            print("S3: an unknown access key and a missing object fail at start with a message")
        finally:
            s3.terminate()
            s3.wait()

        # --- plain HTTP range requests (nginx) ---
        www = os.path.join(d, "www")
        os.makedirs(www)
        shutil.copy(one, os.path.join(www, "terrain.tsr"))
        for path, mode in ((d, 0o755), (www, 0o755), (os.path.join(www, "terrain.tsr"), 0o644)):
            os.chmod(path, mode)  # nginx's workers drop root
        nport = free_port()
        conf = os.path.join(d, "nginx.conf")
        with open(conf, "w") as f:
            f.write(f"""daemon off; pid {d}/nginx.pid; error_log {d}/nginx-error.log;
events {{ worker_connections 64; }}
http {{ access_log {d}/nginx-access.log; client_body_temp_path {d}/body; proxy_temp_path {d}/proxy;
  fastcgi_temp_path {d}/fcgi; uwsgi_temp_path {d}/uwsgi; scgi_temp_path {d}/scgi;
  server {{ listen 127.0.0.1:{nport}; root {www}; }} }}
""")
        nginx = subprocess.Popen([shutil.which("nginx") or "/usr/sbin/nginx", "-c", conf, "-p", d],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            wait_for_port(nport)
            p, port = serve(a.server, [f"http://127.0.0.1:{nport}/terrain.tsr"])
            try:
                got = tiles_of(port, "terrain", keys)
                bad = [k for k in keys if got[k] != want[k]]
                if bad:
                    fail(f"tiles over HTTP differ from the file's: {bad}")
                ranges = sum(1 for line in open(os.path.join(d, "nginx-access.log")) if '" 206 ' in line)
                print(f"nginx: {len(keys)} tiles as from disk, {ranges} range requests answered 206")
                if ranges == 0:
                    fail("nginx answered no range request")
            finally:
                stop(p)
        finally:
            nginx.terminate()
            nginx.wait()

        # --- an origin that fails twice before each answer: retried with backoff, served intact ---
        FlakyOrigin.data = open(one, "rb").read()
        origin = http.server.ThreadingHTTPServer(("127.0.0.1", 0), FlakyOrigin)
        threading.Thread(target=origin.serve_forever, daemon=True).start()
        try:
            p, port = serve(a.server, [f"http://127.0.0.1:{origin.server_address[1]}/flaky.tsr"])
            try:
                got = tiles_of(port, "flaky", keys[:5])
                bad = [k for k in keys[:5] if got[k] != want[k]]
                if bad:
                    fail(f"tiles from the flaky origin differ: {bad}")
                retries, requests = metric(port, "tessera_remote_retries"), metric(port, "tessera_remote_requests")
                distinct = len(FlakyOrigin.tries)
                print(f"flaky origin: 5 tiles intact; {requests:.0f} requests of which {retries:.0f} retries for {distinct} distinct requests")
                if retries < 2 * distinct:
                    fail(f"expected at least {2 * distinct} retries, counted {retries}")
                # Every range read is pinned to the version opened: If-Match with its strong ETag.
                unpinned = [v for v in FlakyOrigin.if_match if v != '"v1"']
                if not FlakyOrigin.if_match or unpinned:
                    fail(f"{len(unpinned)} of {len(FlakyOrigin.if_match)} range reads without If-Match \"v1\": {unpinned[:3]}")
                print(f"flaky origin: all {len(FlakyOrigin.if_match)} range reads carried If-Match \"v1\"")
            finally:
                stop(p)
        finally:
            origin.shutdown()

        # --- an origin whose ETag is weak (as nginx's with gzip, many CDNs): If-Match would never
        # match it; the version is pinned by If-Unmodified-Since and the answers' total size ---
        FlakyOrigin.fail_first, FlakyOrigin.etag, FlakyOrigin.tries = 0, 'W/"v1"', {}
        FlakyOrigin.last_modified, FlakyOrigin.if_match, FlakyOrigin.if_unmodified = "Wed, 02 Dec 2026 10:00:00 GMT", [], []
        origin = http.server.ThreadingHTTPServer(("127.0.0.1", 0), FlakyOrigin)
        threading.Thread(target=origin.serve_forever, daemon=True).start()
        try:
            p, port = serve(a.server, [f"http://127.0.0.1:{origin.server_address[1]}/weak.tsr"])
            try:
                got = tiles_of(port, "weak", keys[:5])
                if any(got[k] != want[k] for k in keys[:5]):
                    fail("tiles from an origin with a weak ETag differ (or were refused)")
                print("weak ETag: 5 tiles as from disk")
                unpinned = [v for v in FlakyOrigin.if_unmodified if v != FlakyOrigin.last_modified]
                if not FlakyOrigin.if_unmodified or unpinned or any(FlakyOrigin.if_match):
                    fail(f"{len(unpinned)} of {len(FlakyOrigin.if_unmodified)} range reads not pinned by If-Unmodified-Since "
                         f"(If-Match sent {sum(1 for v in FlakyOrigin.if_match if v)} times)")
                print(f"weak ETag: all {len(FlakyOrigin.if_unmodified)} range reads carried If-Unmodified-Since")
            finally:
                stop(p)
        finally:
            origin.shutdown()
        FlakyOrigin.etag, FlakyOrigin.last_modified = '"v1"', None

        # --- 16 clients missing the same tiles at once, from a far origin: one read per tile ---
        FlakyOrigin.fail_first, FlakyOrigin.delay, FlakyOrigin.tries = 0, 0.2, {}
        origin = http.server.ThreadingHTTPServer(("127.0.0.1", 0), FlakyOrigin)
        threading.Thread(target=origin.serve_forever, daemon=True).start()
        try:
            p, port = serve(a.server, [f"http://127.0.0.1:{origin.server_address[1]}/far.tsr"])
            try:
                barrier = threading.Barrier(16)
                errors = []

                def client():
                    for k in wanted:
                        barrier.wait()
                        if get(port, f"/v1/stores/far/tiles/{k[0]}/{k[1]}/{k[2]}")[2] != want[k]:
                            errors.append(k)

                threads = [threading.Thread(target=client) for _ in range(16)]
                t0 = time.time()
                for t in threads:
                    t.start()
                for t in threads:
                    t.join()
                elapsed = time.time() - t0
                read = metric(port, "tessera_store_tiles_read_total")
                saved = metric(port, "tessera_store_reads_saved_total")
                hits = metric(port, "tessera_cache_hits_total")
                print(f"coalescing: 16 clients x {len(wanted)} tiles from a 200 ms origin in {elapsed:.1f} s: "
                      f"{read:.0f} tiles read, {saved:.0f} joined a read in flight, {hits:.0f} cache hits")
                if errors:
                    fail(f"wrong tiles: {errors[:5]}")
                if read != len(wanted):
                    fail(f"{read:.0f} store reads for {len(wanted)} distinct tiles")
                if saved + hits != 16 * len(wanted) - len(wanted):
                    fail(f"joined + hits = {saved + hits:.0f}, expected {15 * len(wanted)}")
            finally:
                stop(p)
        finally:
            origin.shutdown()
    print("PASS")


if __name__ == "__main__":
    main()
