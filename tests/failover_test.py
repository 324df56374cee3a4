#!/usr/bin/env python3
"""Several replicas: a headless viewer on the flyover (240 frames at 60 Hz, paced) streams from
three servers given as one list; the server it streams from is killed with SIGKILL mid-run. The
viewer finishes with exit 0; no server answers a tile request with an error (their refused,
deadline, invalid and data-loss counters stay 0); another server sends its first tile within 1 s
of the kill (read from the servers' own counters, polled every 10 ms); the viewer's per-frame
stats have all 240 frames with at most 1 s of them without a server; and fallback over the run
stays <= 1%. Then the same with a single server killed and restarted on
its port; then two replicas, the viewer's one stalled (SIGSTOP), whose stream must move to the
other within 15 s (keepalive pings: 10 s, and the reconnect). Prints the figures docs/benchmarks.md quotes.

Under a sanitizer (TESSERA_SANITIZE in the environment, tests/CMakeLists.txt) the bound on fallback is
5%: a server restarted under ThreadSanitizer, beside other sanitized tests on two cores, was
measured at 2.4% with 0.5 s unserved, as without a sanitizer. The bounds on time without a
server, which a failover that does not work breaks, are the same."""
import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request

import serve_util



def fail(msg):
    print("FAIL: " + msg, flush=True)
    sys.exit(1)


def start_server(binary, store, grpc="127.0.0.1:0"):
    p = subprocess.Popen([binary, "serve", "--store", store, "--grpc", grpc, "--http", "127.0.0.1:0", "--watch-interval", "0"],
                         stderr=subprocess.PIPE, text=True)
    ports = serve_util.wait_listening(p)
    if not ports:
        fail(f"server exited {p.wait()} before listening")
    return p, ports[0], ports[1]


def tiles_sent(http_port):
    try:
        body = urllib.request.urlopen(f"http://127.0.0.1:{http_port}/metrics", timeout=2).read().decode()
    except OSError:
        return -1
    m = re.search(r"^tessera_tiles_sent_total(?:\{[^}]*\})? ([0-9.e+]+)", body, re.M)
    return float(m.group(1)) if m else 0


ERROR_COUNTERS = ("tessera_grpc_requests_refused_total", "tessera_grpc_requests_deadline_exceeded_total",
                  "tessera_grpc_requests_invalid_total", "tessera_grpc_data_loss_total")


def failed_requests(http_port):
    """Tile requests a server answered with an error (refused, deadline, invalid, data loss)."""
    body = urllib.request.urlopen(f"http://127.0.0.1:{http_port}/metrics", timeout=2).read().decode()
    total = 0.0
    for name in ERROR_COUNTERS:
        total += sum(float(v) for v in re.findall(rf"^{name}(?:\{{[^}}]*\}})? ([0-9.e+]+)", body, re.M))
    return total


def busiest(servers):
    """(index, tiles sent by each) of the server the viewer streams from: the one that has sent
    tiles. On a loaded machine the warm-up may still be opening the stream: waits, 20 s at most."""
    for _ in range(200):
        sent = [tiles_sent(h) for _, _, h in servers]
        if max(sent) > 0:
            break
        time.sleep(0.1)
    return max(range(len(servers)), key=lambda k: sent[k]), sent


def check_frames(frames, what, max_down_frames):
    """The per-frame stats the viewer wrote: every frame there, unserved time never decreasing,
    and the frames without a server at most max_down_frames."""
    if len(frames) != 240:
        fail(f"{what}: {len(frames)} frames in the stats, not 240")
    down = sum(1 for f in frames if not f["connected"])
    for a, b in zip(frames, frames[1:]):
        if b["unserved_s"] < a["unserved_s"]:
            fail(f"{what}: unserved time went down at frame {b['frame']}")
    if down > max_down_frames:
        fail(f"{what}: {down} frames without a server (bound {max_down_frames})")
    return down


def view(tessera, target, stats, outage_at, action, frames=240):
    """Runs the viewer; `action()` at `outage_at` seconds into the run. Returns (rc, output, fallback %,
    unserved s, per-frame records)."""
    v = subprocess.Popen([tessera, "view", "--store", f"grpc://{target}/terrain", "--headless", "--size", "320x180", "--frames", str(frames),
                          "--fps", "60", "--pace", "--path", "flyover", "--stats", stats],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(outage_at)
        action()
        out, _ = v.communicate(timeout=300)
    finally:
        if v.poll() is None:
            v.kill()
            v.wait()
    fb = re.search(r"^fallback\s+([0-9.]+)%", out, re.M)
    unserved = re.search(r"^server\s+([0-9.]+) s unserved", out, re.M)
    if not fb or not unserved:
        fail(f"viewer summary lacks fallback or server lines:\n{out}")
    with open(stats) as f:
        frames = json.load(f)["frames"]
    return v.returncode, out, float(fb.group(1)), float(unserved.group(1)), frames


SANITIZED = bool(os.environ.get("TESSERA_SANITIZE"))
FALLBACK_BOUND = 5.0 if SANITIZED else 1.0  # percent
# Seconds from the stall to the other replica's first tile: 10 s of keepalive (a ping every 6 s,
# 4 s to answer it), then the reconnect and a new stream's first tile on a busy 2-core machine.
STALL_BOUND = 20.0 if SANITIZED else 15.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tessera", required=True)
    ap.add_argument("--server", required=True)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        store = os.path.join(d, "terrain.tsr")
        subprocess.run([a.tessera, "build", "-q", "procedural:terrain:8192", "-o", store], check=True)

        # Three replicas behind one list; kill the one serving the viewer.
        servers = [start_server(a.server, store) for _ in range(3)]
        target = ",".join(f"127.0.0.1:{g}" for _, g, _ in servers)
        killed = {}

        def kill_busiest():
            i, sent = busiest(servers)
            killed.update(index=i, sent=sent, failed=failed_requests(servers[i][2]))
            servers[i][0].send_signal(signal.SIGKILL)
            t_kill = time.monotonic()
            # The time to the first tile after the kill, from the servers' own counters: the
            # first moment another server has sent more tiles than before the kill.
            others = [k for k in range(3) if k != i]
            while time.monotonic() - t_kill < 10:
                if any(tiles_sent(servers[k][2]) > max(sent[k], 0) for k in others):
                    killed["resumed_s"] = time.monotonic() - t_kill
                    break
                time.sleep(0.01)

        try:
            rc, out, fallback, unserved, frames = view(a.tessera, target, os.path.join(d, "a.json"), 1.5, kill_busiest)
            after = [tiles_sent(h) for _, _, h in servers]
            failed_after = [failed_requests(h) for k, (_, _, h) in enumerate(servers) if k != killed["index"]]
        finally:
            for p, _, _ in servers:
                if p.poll() is None:
                    p.terminate()
                p.wait()
        down = check_frames(frames, "replicas", 60)
        resumed = killed.get("resumed_s")
        print(f"replicas: killed server {killed['index']} (tiles sent before {killed['sent']}, after {after}); viewer exit {rc}, "
              f"fallback {fallback:.4f}%, {unserved:.2f} s unserved; another server's first tile "
              f"{resumed if resumed is None else round(resumed, 3)} s after the kill; {down} frames without a server; "
              f"failed requests {killed['failed']:g} before the kill, {failed_after} after")
        if rc != 0:
            fail(f"the viewer exited {rc}:\n{out}")
        if killed["failed"] != 0 or any(x != 0 for x in failed_after):
            fail(f"tile requests answered with errors: {killed['failed']:g} by the killed server, {failed_after} by the others")
        if resumed is None or resumed > 1.0:
            fail(f"no other server sent a tile within 1 s of the kill (first after {resumed} s)")
        if sum(x for i, x in enumerate(after) if i != killed["index"] and x > 0) <= sum(
                x for i, x in enumerate(killed["sent"]) if i != killed["index"] and x > 0):
            fail("no other server sent tiles after the kill")
        if unserved > 1.0:
            fail(f"{unserved} s without a server (bound 1 s)")
        if fallback > FALLBACK_BOUND:
            fail(f"fallback {fallback}% over the run (bound {FALLBACK_BOUND:g}%)")

        # One server, killed and restarted on its port.
        p, grpc, http = start_server(a.server, store)
        restarted = {}

        def restart():
            # Only once the viewer is streaming (a viewer still starting when its only server goes
            # away exits with an error, by design): on a loaded machine that may take longer than
            # the 1.5 s before this runs; 20 s at most.
            for _ in range(200):
                if tiles_sent(http) > 0:
                    break
                time.sleep(0.1)
            p.send_signal(signal.SIGKILL)
            p.wait()
            time.sleep(0.3)
            restarted["server"] = start_server(a.server, store, f"127.0.0.1:{grpc}")

        try:
            rc, out, fallback, unserved, frames = view(a.tessera, f"127.0.0.1:{grpc}", os.path.join(d, "b.json"), 1.5, restart)
        finally:
            for q in (p, restarted.get("server", (None,))[0]):
                if q and q.poll() is None:
                    q.terminate()
                    q.wait()
        down = check_frames(frames, "restart", 90)
        print(f"restart: viewer exit {rc}, fallback {fallback:.4f}%, {unserved:.2f} s unserved (0.3 s with no server listening), "
              f"{down} frames without a server")
        if rc != 0:
            fail(f"the viewer exited {rc}:\n{out}")
        if unserved > 1.3:
            fail(f"{unserved} s without a server (bound 1 s after the restart)")
        if fallback > FALLBACK_BOUND:
            fail(f"fallback {fallback}% over the run (bound {FALLBACK_BOUND:g}%)")

        # Two replicas; the one serving the viewer stalls (SIGSTOP: its connection stays open and
        # silent). Its unanswered keepalive ping ends the stream within 10 s, and the other
        # replica takes over (it took 40 s, and a stall shorter than that was never left).
        servers = [start_server(a.server, store) for _ in range(2)]
        target = ",".join(f"127.0.0.1:{g}" for _, g, _ in servers)
        stalled = {}

        def stall_busiest():
            i, sent = busiest(servers)
            other = 1 - i
            servers[i][0].send_signal(signal.SIGSTOP)
            stalled.update(index=i)
            t_stop = time.monotonic()
            # The viewer keeps asking for new pages along the path; the other replica's counter
            # moves once the stream is on it.
            while time.monotonic() - t_stop < STALL_BOUND + 1:
                if tiles_sent(servers[other][2]) > max(sent[other], 0):
                    stalled["resumed_s"] = time.monotonic() - t_stop
                    break
                time.sleep(0.05)

        try:
            rc, out, fallback, unserved, frames = view(a.tessera, target, os.path.join(d, "c.json"), 1.5, stall_busiest, frames=1200)
        finally:
            for p, _, _ in servers:
                if p.poll() is None:
                    p.send_signal(signal.SIGCONT)
                    p.terminate()
                p.wait()
        resumed = stalled.get("resumed_s")
        print(f"stall: server {stalled.get('index')} stopped; viewer exit {rc}; the other replica's first tile "
              f"{resumed if resumed is None else round(resumed, 3)} s after the stop; fallback {fallback:.4f}%")
        if rc != 0:
            fail(f"the viewer exited {rc}:\n{out}")
        if resumed is None or resumed > STALL_BOUND:
            fail(f"the other replica sent no tile within {STALL_BOUND:g} s of the stall (first after {resumed} s):\n{out}")
    print("PASS")


if __name__ == "__main__":
    main()
