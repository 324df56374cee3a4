#!/usr/bin/env python3
"""The deployment image: deploy/build-image.py builds its root filesystem from Debian packages and
an OCI archive of it; tessera-server then runs from that root filesystem alone (a mount namespace,
chroot, the image's user 10001, the stores bind-mounted read-only), tells the service manager it is
ready only once listening (the notify protocol, as systemd's Type=notify reads it), answers /readyz
and serves a tile byte for byte as the same binary outside the image does, and drains on SIGTERM.
Podman runs the archive too where it works (in many sandboxes it cannot: that part is reported)."""
import argparse
import hashlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tarfile
import tempfile
import time
import urllib.request

import serve_util

FORBIDDEN = re.compile(r"lib(GL|GLX|EGL|OpenGL|gbm|glfw|epoxy|X11|OpenImageIO|tinyobjloader)\b", re.I)


def fail(msg):
    print("FAIL: " + msg, flush=True)
    sys.exit(1)


def get(port, path):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=30) as r:
        return r.status, r.read()


def wait_listening(p, what):
    lines = []
    ports = serve_util.wait_listening(p, lines)
    if not ports:
        fail(f"{what} exited {p.wait()} before listening; its stderr:\n" + "".join(lines[-20:]))
    return ports[1]


def sanitizer_files_into(rootfs, env):
    """A sanitizer build's options name files on this machine (suppressions) that the image's root
    lacks, and the sanitizer stops the server when it cannot read them. Returns the shell commands
    that copy them onto a tmpfs over the image's /tmp (in the private mount namespace, so the
    image itself is untouched) and points `env`'s options there."""
    commands = []
    for key in sorted(k for k in env if k.endswith("SAN_OPTIONS")):
        options = []
        for option in env[key].split(":"):
            name, _, value = option.partition("=")
            if name == "suppressions" and value:
                inside = f"/tmp/{key.lower()}.supp"
                commands.append(f'cp "{value}" "{rootfs}{inside}"')
                option = f"{name}={inside}"
            options.append(option)
        env[key] = ":".join(options)
    if not commands:
        return ""
    return f'mount -t tmpfs tmpfs "{rootfs}/tmp" && ' + " && ".join(commands) + " && "


def check_archive(path):
    """The OCI archive is complete: every blob its index names exists with its digest and size."""
    with tarfile.open(path) as t:
        names = set(t.getnames())

        def read(name):
            return t.extractfile(name).read()

        if json.loads(read("oci-layout"))["imageLayoutVersion"] != "1.0.0":
            fail("oci-layout")

        def blob(desc):
            data = read("blobs/sha256/" + desc["digest"].split(":")[1])
            if len(data) != desc["size"] or "sha256:" + hashlib.sha256(data).hexdigest() != desc["digest"]:
                fail(f"blob {desc['digest']} does not match its descriptor")
            return data

        index = json.loads(read("index.json"))
        manifest = json.loads(blob(index["manifests"][0]))
        config = json.loads(blob(manifest["config"]))
        layer = blob(manifest["layers"][0])
        if config["config"]["Entrypoint"] != ["/usr/local/bin/tessera-server", "serve"] or config["config"]["User"] != "10001:10001":
            fail(f"image config: {config['config']}")
        import gzip
        import io
        with tarfile.open(fileobj=io.BytesIO(gzip.decompress(layer))) as lt:
            files = lt.getnames()
        if "usr/local/bin/tessera-server" not in files:
            fail("the layer lacks usr/local/bin/tessera-server")
        bad = [f for f in files if FORBIDDEN.search(os.path.basename(f))]
        if bad:
            fail("the image holds client libraries: " + " ".join(bad[:10]))
        if any(f.startswith(("bin/sh", "usr/bin/sh", "usr/bin/apt")) for f in files):
            fail("the image holds a shell or apt")
        print(f"OCI archive: {len(names)} entries, layer {len(layer) / 2**20:.1f} MiB gzip, {len(files)} files, "
              f"entrypoint {' '.join(config['config']['Entrypoint'])}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tessera", required=True)
    ap.add_argument("--server", required=True)
    ap.add_argument("--build-image", required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    t0 = time.time()
    r = subprocess.run([sys.executable, a.build_image, "--binary", a.server, "--out", a.out], capture_output=True, text=True)
    print(r.stdout, end="")
    if r.returncode != 0:
        fail(f"build-image exited {r.returncode}:\n{r.stderr}")
    print(f"image built in {time.time() - t0:.1f} s")
    rootfs = os.path.join(a.out, "rootfs")
    check_archive(os.path.join(a.out, "tessera-server-oci.tar"))
    # HTTPS and S3 stores verify against the system's roots: the bundle OpenSSL looks for is there.
    bundle = os.path.join(rootfs, "etc/ssl/certs/ca-certificates.crt")
    n = open(bundle).read().count("BEGIN CERTIFICATE") if os.path.exists(bundle) else 0
    cert_pem = os.path.join(rootfs, "usr/lib/ssl/cert.pem")
    if n < 100 or not os.path.islink(cert_pem) or os.readlink(cert_pem) != "/etc/ssl/certs/ca-certificates.crt":
        fail(f"the image's CA bundle has {n} certificates, or OpenSSL's cert.pem does not point at it")
    print(f"CA bundle: {n} certificates, /usr/lib/ssl/cert.pem -> /etc/ssl/certs/ca-certificates.crt")

    with tempfile.TemporaryDirectory() as d:
        stores = os.path.join(d, "stores")
        os.makedirs(stores)
        store = os.path.join(stores, "terrain.tsr")
        subprocess.run([a.tessera, "build", "procedural:terrain:700", "-o", store, "--tile-size", "128"],
                       check=True, capture_output=True)
        os.chmod(d, 0o755)
        os.chmod(stores, 0o755)
        os.chmod(store, 0o644)

        # The reference: the same binary outside the image.
        p = subprocess.Popen([a.server, "serve", "--store", store, "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0"],
                             stderr=subprocess.PIPE, text=True)
        port = wait_listening(p, "tessera-server (host)")
        want = get(port, "/v1/stores/terrain/tiles/0/1/2")
        p.send_signal(signal.SIGTERM)
        p.wait(timeout=60)

        # In the image: its own root, its user, the stores read-only, readiness over NOTIFY_SOCKET.
        notify_name = f"tessera-test-{os.getpid()}"
        ns = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        ns.bind("\0" + notify_name)  # abstract: reachable from inside the chroot
        ns.settimeout(60)
        env = dict(os.environ, NOTIFY_SOCKET="@" + notify_name)
        copies = sanitizer_files_into(rootfs, env)
        script = (f'mount --bind -o ro "{stores}" "{rootfs}/srv/tessera" && mount -o remount,bind,ro "{rootfs}/srv/tessera" && '
                  f'mount -t proc proc "{rootfs}/proc" && {copies}'
                  f'exec chroot --userspec=10001:10001 "{rootfs}" /usr/local/bin/tessera-server serve '
                  f'--store-dir /srv/tessera --grpc 127.0.0.1:0 --http 127.0.0.1:0')
        p = subprocess.Popen(["unshare", "--mount", "--pid", "--fork", "--kill-child", "sh", "-c", script],
                             stderr=subprocess.PIPE, text=True, env=env)
        try:
            port = wait_listening(p, "tessera-server in the image")
            msg = ns.recv(4096).decode()
            if "READY=1" not in msg:
                fail(f"first notification is {msg!r}, not READY=1")
            status, ready = get(port, "/readyz")
            if status != 200:
                fail(f"/readyz: {status}")
            got = get(port, "/v1/stores/terrain/tiles/0/1/2")
            if got != want:
                fail("the tile from the image differs from the host's")
            print(f"in the image: READY=1 notified, /readyz 200, a {len(got[1])}-byte tile as the host serves it")
            # SIGTERM to tessera-server itself (unshare's child, pid 1 in its namespace); unshare
            # then exits with its status.
            with open(f"/proc/{p.pid}/task/{p.pid}/children") as f:
                children = [int(c) for c in f.read().split()]
            if len(children) != 1:
                fail(f"unshare has children {children}")
            os.kill(children[0], signal.SIGTERM)
            rc = p.wait(timeout=60)
            if rc != 0:
                fail(f"tessera-server in the image exited {rc} on SIGTERM")
            msg = ns.recv(4096).decode()
            if "STOPPING=1" not in msg:
                fail(f"stop notification is {msg!r}")
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()

    # Podman, where this machine lets it run containers.
    podman = shutil.which("podman")
    if not podman:
        print("podman: not installed; the image ran from its root filesystem (above)")
    else:
        load = subprocess.run([podman, "load", "-i", os.path.join(a.out, "tessera-server-oci.tar")],
                              capture_output=True, text=True, timeout=300)
        run = subprocess.run([podman, "run", "--rm", "--network", "none", "tessera-server:0.1.0", "--help"],
                             capture_output=True, text=True, timeout=300) if load.returncode == 0 else None
        if run and run.returncode == 0 and "Serve tile stores" in run.stdout:
            print("podman: loaded the archive and ran tessera-server serve --help in it")
        else:
            why = (load.stderr if load.returncode else run.stderr).strip().splitlines()
            print(f"podman: cannot run containers here ({why[-1] if why else 'no output'}); the image ran from its root filesystem")
    print("PASS")


if __name__ == "__main__":
    main()
