#!/usr/bin/env python3
"""Builds the tessera-server container image from Debian 12 packages, without a registry.

    deploy/build-image.py [--binary build/tessera-server] [--out build/image]

The root filesystem holds tessera-server and the Debian packages of exactly the shared libraries
it links (found with ldd and dpkg -S on this Debian 12 machine, fetched and unpacked by mmdebstrap),
plus ca-certificates, a `tessera` user (uid/gid 10001) and /srv/tessera for the stores. No shell,
no package manager, no GL or OpenImageIO. Output, under --out:

    rootfs/                     the root filesystem (run it with chroot or unshare, see docs)
    tessera-server-oci.tar      an OCI image archive of it: `podman load -i`, `docker load -i`,
                                `skopeo copy oci-archive:...`; entrypoint `tessera-server serve`

Needs root (mmdebstrap unpacks as root to keep file owners) and Debian's package mirror
(--mirror, default http://deb.debian.org/debian). See deploy/README.md.
"""
import argparse
import gzip
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import tarfile
import time

VERSION = "0.1.0"
UID = GID = 10001
EXTRA_PACKAGES = ["ca-certificates"]  # object storage and other HTTPS peers


def die(msg):
    print(f"build-image: error: {msg}", file=sys.stderr)
    sys.exit(1)


def step(msg):
    print(f"build-image: {msg}", flush=True)


def library_packages(binary):
    """The Debian packages that hold the shared libraries `binary` loads."""
    out = subprocess.run(["ldd", binary], capture_output=True, text=True)
    if out.returncode != 0:
        die(f"ldd {binary}: {out.stderr.strip()}")
    paths = []
    for line in out.stdout.splitlines():
        parts = line.split()
        if "not found" in line:
            die(f"{binary} needs a library this machine lacks: {line.strip()}")
        if "=>" in parts and len(parts) >= 3 and parts[2].startswith("/"):
            paths.append(parts[2])
        elif parts and parts[0].startswith("/"):  # the dynamic loader
            paths.append(parts[0])
    packages = set()
    for p in paths:
        candidates = [p, os.path.realpath(p)]
        candidates += ["/usr" + c for c in candidates if not c.startswith("/usr/")]
        candidates += [c[4:] for c in candidates if c.startswith("/usr/")]
        for c in candidates:
            r = subprocess.run(["dpkg", "-S", c], capture_output=True, text=True)
            if r.returncode == 0:
                packages.add(r.stdout.split(":")[0].strip())
                break
        else:
            die(f"no Debian package holds {p} (dpkg -S)")
    return sorted(packages)


def write_rootfs(binary, rootfs, packages, mirror):
    if os.path.exists(rootfs):
        shutil.rmtree(rootfs)
    sources = [f"deb {mirror} bookworm main", f"deb {mirror} bookworm-updates main",
               f"deb {mirror}-security bookworm-security main" if mirror.endswith("/debian") else None]
    cmd = ["mmdebstrap", "--variant=extract", "--mode=root", "--quiet", "--include=" + ",".join(packages),
           "--dpkgopt=path-exclude=/usr/share/doc/*", "--dpkgopt=path-exclude=/usr/share/man/*",
           "--dpkgopt=path-exclude=/usr/share/locale/*", "bookworm", rootfs] + [s for s in sources if s]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        die("mmdebstrap failed:\n" + (r.stderr or r.stdout).strip()[-3000:])
    # Empty mount points for the runtime, the stores' directory, the binary, the user.
    for d in ("proc", "sys", "dev", "tmp", "run", "srv/tessera", "usr/local/bin", "etc"):
        os.makedirs(os.path.join(rootfs, d), exist_ok=True)
    os.chmod(os.path.join(rootfs, "tmp"), 0o1777)
    os.chown(os.path.join(rootfs, "srv/tessera"), UID, GID)
    for entry in os.listdir(os.path.join(rootfs, "dev")):  # the runtime provides /dev
        p = os.path.join(rootfs, "dev", entry)
        shutil.rmtree(p) if os.path.isdir(p) and not os.path.islink(p) else os.remove(p)
    target = os.path.join(rootfs, "usr/local/bin/tessera-server")
    shutil.copy2(binary, target)
    if shutil.which("strip"):  # debug information stays with the build tree
        subprocess.run(["strip", "--strip-debug", target], check=True)
    with open(os.path.join(rootfs, "etc/passwd"), "w") as f:
        f.write(f"root:x:0:0:root:/root:/usr/sbin/nologin\ntessera:x:{UID}:{GID}:Tessera:/nonexistent:/usr/sbin/nologin\n")
    with open(os.path.join(rootfs, "etc/group"), "w") as f:
        f.write(f"root:x:0:\ntessera:x:{GID}:\n")
    # The CA bundle: --variant=extract runs no maintainer scripts, so ca-certificates' postinst
    # (update-ca-certificates) never made /etc/ssl/certs/ca-certificates.crt. Made here from its
    # certificates, and OpenSSL's default locations (/usr/lib/ssl) pointed at it.
    certs = []
    for dirpath, _, filenames in sorted(os.walk(os.path.join(rootfs, "usr/share/ca-certificates"))):
        certs += [os.path.join(dirpath, f) for f in sorted(filenames) if f.endswith(".crt")]
    if not certs:
        die("ca-certificates brought no certificates")
    os.makedirs(os.path.join(rootfs, "etc/ssl/certs"), exist_ok=True)
    with open(os.path.join(rootfs, "etc/ssl/certs/ca-certificates.crt"), "w") as bundle:
        for c in certs:
            text = open(c).read()
            bundle.write(text if text.endswith("\n") else text + "\n")
    os.makedirs(os.path.join(rootfs, "usr/lib/ssl"), exist_ok=True)
    for link, target in (("usr/lib/ssl/certs", "/etc/ssl/certs"), ("usr/lib/ssl/cert.pem", "/etc/ssl/certs/ca-certificates.crt")):
        path = os.path.join(rootfs, link)
        if not os.path.lexists(path):
            os.symlink(target, path)
    # Nothing may be missing: every library resolves inside the root filesystem.
    for d in ("var/cache/apt", "var/lib/apt/lists"):
        shutil.rmtree(os.path.join(rootfs, d), ignore_errors=True)


def layer_tar(rootfs, epoch):
    """The root filesystem as one reproducible tar: sorted names, times clamped to `epoch`."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for dirpath, dirnames, filenames in os.walk(rootfs):
            dirnames.sort()
            for name in sorted(dirnames + filenames):
                full = os.path.join(dirpath, name)
                info = tar.gettarinfo(full, arcname=os.path.relpath(full, rootfs))
                info.mtime = min(int(info.mtime), epoch)
                info.uname = info.gname = ""
                if info.isreg():
                    with open(full, "rb") as f:
                        tar.addfile(info, f)
                else:
                    tar.addfile(info)
    return buf.getvalue()


def blob(data):
    return "sha256:" + hashlib.sha256(data).hexdigest(), data


def write_oci_archive(rootfs, path, epoch):
    tar_bytes = layer_tar(rootfs, epoch)
    diff_id = "sha256:" + hashlib.sha256(tar_bytes).hexdigest()
    gz = io.BytesIO()
    with gzip.GzipFile(fileobj=gz, mode="wb", mtime=0, compresslevel=6) as g:
        g.write(tar_bytes)
    layer_digest, layer = blob(gz.getvalue())
    created = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(epoch))
    config = {
        "created": created,
        "architecture": "amd64",
        "os": "linux",
        "config": {
            "User": f"{UID}:{GID}",
            "Env": ["PATH=/usr/local/bin:/usr/bin:/bin"],
            "Entrypoint": ["/usr/local/bin/tessera-server", "serve"],
            "Cmd": ["--store-dir", "/srv/tessera", "--grpc", "0.0.0.0:50051", "--http", "0.0.0.0:8080"],
            "ExposedPorts": {"50051/tcp": {}, "8080/tcp": {}},
            "Volumes": {"/srv/tessera": {}},
            "WorkingDir": "/srv/tessera",
            "StopSignal": "SIGTERM",
            "Labels": {"org.opencontainers.image.title": "tessera-server",
                       "org.opencontainers.image.version": VERSION},
        },
        "rootfs": {"type": "layers", "diff_ids": [diff_id]},
        "history": [{"created": created, "created_by": "deploy/build-image.py (mmdebstrap, Debian 12)"}],
    }
    config_digest, config_bytes = blob(json.dumps(config, sort_keys=True).encode())
    manifest = {
        "schemaVersion": 2,
        "mediaType": "application/vnd.oci.image.manifest.v1+json",
        "config": {"mediaType": "application/vnd.oci.image.config.v1+json", "digest": config_digest,
                   "size": len(config_bytes)},
        "layers": [{"mediaType": "application/vnd.oci.image.layer.v1.tar+gzip", "digest": layer_digest,
                    "size": len(layer)}],
    }
    manifest_digest, manifest_bytes = blob(json.dumps(manifest, sort_keys=True).encode())
    ref = f"tessera-server:{VERSION}"
    index = {
        "schemaVersion": 2,
        "mediaType": "application/vnd.oci.image.index.v1+json",
        "manifests": [{"mediaType": manifest["mediaType"], "digest": manifest_digest, "size": len(manifest_bytes),
                       "annotations": {"org.opencontainers.image.ref.name": ref,
                                       "io.containerd.image.name": "docker.io/library/" + ref}}],
    }
    files = {
        "oci-layout": json.dumps({"imageLayoutVersion": "1.0.0"}).encode(),
        "index.json": json.dumps(index, sort_keys=True).encode(),
        # docker load (older than OCI support) reads this instead of index.json.
        "manifest.json": json.dumps([{"Config": "blobs/sha256/" + config_digest[7:], "RepoTags": [ref],
                                      "Layers": ["blobs/sha256/" + layer_digest[7:]]}]).encode(),
    }
    for digest, data in ((layer_digest, layer), (config_digest, config_bytes), (manifest_digest, manifest_bytes)):
        files["blobs/sha256/" + digest[7:]] = data
    tmp = path + ".tmp"
    with tarfile.open(tmp, "w") as out:
        for d in ("blobs", "blobs/sha256"):
            info = tarfile.TarInfo(d)
            info.type, info.mode, info.mtime = tarfile.DIRTYPE, 0o755, epoch
            out.addfile(info)
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size, info.mode, info.mtime = len(data), 0o644, epoch
            out.addfile(info, io.BytesIO(data))
    os.replace(tmp, path)  # never a half-written archive under the final name
    return layer_digest, len(tar_bytes), len(layer)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--binary", default=os.path.join(here, "..", "build", "tessera-server"))
    ap.add_argument("--out", default=os.path.join(here, "..", "build", "image"))
    ap.add_argument("--mirror", default=os.environ.get("TESSERA_DEBIAN_MIRROR", "http://deb.debian.org/debian"))
    a = ap.parse_args()
    if os.geteuid() != 0:
        die("run as root (mmdebstrap unpacks packages as root to keep their owners)")
    if not shutil.which("mmdebstrap"):
        die("mmdebstrap is missing (apt-get install mmdebstrap; tools/setup.sh --tests installs it)")
    binary = os.path.abspath(a.binary)
    if not os.access(binary, os.X_OK):
        die(f"{binary} is not an executable (build it: cmake --build build --target tessera-server)")
    os.makedirs(a.out, exist_ok=True)
    packages = sorted(set(library_packages(binary)) | set(EXTRA_PACKAGES))
    step(f"{len(packages)} packages: {' '.join(packages)}")
    rootfs = os.path.join(a.out, "rootfs")
    t0 = time.time()
    write_rootfs(binary, rootfs, packages, a.mirror)
    step(f"root filesystem {rootfs} in {time.time() - t0:.1f} s")
    epoch = int(os.environ.get("SOURCE_DATE_EPOCH", os.stat(binary).st_mtime))
    archive = os.path.join(a.out, "tessera-server-oci.tar")
    digest, raw, packed = write_oci_archive(rootfs, archive, epoch)
    step(f"OCI archive {archive}: one layer {raw / 2**20:.1f} MiB ({packed / 2**20:.1f} MiB gzip), {digest[:19]}...")


if __name__ == "__main__":
    main()
