#!/usr/bin/env python3
"""tessera-server, the deployments' binary: none of the client's libraries (GL, EGL, GLFW, X11,
OpenImageIO, tinyobjloader) among its dependencies, a small resident size (and the full tessera's
within 20 MiB), and it serves what the full `tessera` builds: /readyz, a tile byte for byte as
`tessera serve` sends it, and a PNG tile."""
import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import urllib.request

import serve_util

FORBIDDEN = re.compile(r"lib(GL|GLX|GLdispatch|EGL|OpenGL|gbm|glfw|epoxy|X11|xcb|OpenImageIO|tinyobjloader|opencv)", re.I)


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def serve(binary, store):
    """Starts BINARY serve on ephemeral ports; returns (process, http port) once it listens."""
    p = subprocess.Popen([binary, "serve", "--store", store, "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0",
                          "--watch-interval", "0"], stderr=subprocess.PIPE, text=True)
    ports = serve_util.wait_listening(p)
    if not ports:
        fail(f"{binary} serve exited {p.wait()} before listening")
    return p, ports[1]


def get(port, path):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=30) as r:
        return r.status, r.headers.get("Content-Type"), r.read()


def stop(p):
    p.send_signal(signal.SIGTERM)
    if p.wait(timeout=60) != 0:
        fail(f"serve exited {p.returncode} on SIGTERM")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tessera", required=True)
    ap.add_argument("--server", required=True)
    a = ap.parse_args()

    ldd = subprocess.run(["ldd", a.server], capture_output=True, text=True, check=True).stdout
    libs = [l.split()[0] for l in ldd.splitlines() if l.strip()]
    bad = [l for l in libs if FORBIDDEN.search(l)]
    if bad:
        fail("tessera-server links client libraries: " + " ".join(bad))
    print(f"tessera-server: {len(libs)} shared libraries, none of GL/EGL/GLFW/X11/OpenImageIO/tinyobjloader")

    # Resident size at rest (--version): neither binary loads OpenImageIO (an on-demand module)
    # nor anything it does not need; the full tessera within 20 MiB, the server within 16 MiB.
    # Sanitizer builds carry shadow memory and runtimes: the bound is the release build's
    # (tests/CMakeLists.txt sets TESSERA_SANITIZE for a sanitizer build's script tests).
    sanitized = bool(os.environ.get("TESSERA_SANITIZE"))
    for binary, name, bound_mib in ((a.server, "tessera-server", 16), (a.tessera, "tessera", 20)):
        t = subprocess.run(["/usr/bin/time", "-f", "%M", binary, "--version"], capture_output=True, text=True)
        if t.returncode != 0 or not t.stdout.startswith(name + " "):
            fail(f"{name} --version: exit {t.returncode}, {t.stdout!r}")
        rss_kib = int(t.stderr.strip().splitlines()[-1])
        print(f"{name} --version: {rss_kib / 1024:.1f} MiB peak resident (bound {bound_mib} MiB)")
        if not sanitized and rss_kib > bound_mib * 1024:
            fail(f"{name} --version peaks at {rss_kib / 1024:.1f} MiB resident (bound {bound_mib} MiB)")

    # The full binary's commands are not there, and say so.
    r = subprocess.run([a.server, "view"], capture_output=True, text=True)
    if r.returncode == 0 or "view" not in r.stderr:
        fail(f"tessera-server view: exit {r.returncode}, {r.stderr!r}")

    with tempfile.TemporaryDirectory() as d:
        store = os.path.join(d, "terrain.tsr")
        subprocess.run([a.tessera, "build", "procedural:terrain:700", "-o", store, "--tile-size", "128"],
                       check=True, capture_output=True)
        info = json.loads(subprocess.run([a.server, "inspect", "--json", store], capture_output=True, text=True,
                                         check=True).stdout)
        if info.get("width") != 700:
            fail(f"tessera-server inspect --json: {info}")
        subprocess.run([a.server, "verify", store], check=True, capture_output=True)

        replies = {}
        for binary in (a.server, a.tessera):
            p, port = serve(binary, store)
            try:
                if get(port, "/readyz")[0] != 200:
                    fail(f"{binary}: /readyz not 200")
                replies[binary] = get(port, "/v1/stores/terrain/tiles/0/1/2")
                png = get(port, "/v1/stores/terrain/tiles/1/0/0?format=png")
                if png[1] != "image/png" or not png[2].startswith(b"\x89PNG\r\n\x1a\n"):
                    fail(f"{binary}: PNG tile is {png[1]}, {png[2][:8]!r}")
            finally:
                stop(p)
        if replies[a.server] != replies[a.tessera]:
            fail("tessera-server and tessera serve answer a tile differently")
        print(f"served /readyz, a {len(replies[a.server][2])}-byte tile (as tessera serve sends it) and a PNG tile")
    print("PASS")


if __name__ == "__main__":
    main()
