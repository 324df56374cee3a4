#!/usr/bin/env python3
"""A renewed TLS certificate is taken up without a restart, on SIGHUP and only then: HTTPS at once,
gRPC within seconds (gRPC watches a private copy of the pair that SIGHUP replaces once the key is
checked to be the certificate's; it never watches --tls-cert itself, so files renewed without a
SIGHUP change nothing); connections already open keep working; a broken renewal leaves the old
certificate in force (docs/protocol.md, "TLS").
  tls_reload_test.py --tessera BIN
"""
import argparse
import hashlib
import os
import signal
import socket
import ssl
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from serve_util import wait_listening  # noqa: E402

failures = []


def check(cond, what):
    print(("ok:   " if cond else "FAIL: ") + what, flush=True)
    if not cond:
        failures.append(what)


def make_cert(d, name):
    key, crt = os.path.join(d, name + ".key"), os.path.join(d, name + ".crt")
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key, "-out", crt, "-days", "2",
                    "-subj", "/CN=" + name, "-addext", "subjectAltName=IP:127.0.0.1"], check=True, capture_output=True)
    return key, crt


def fingerprint_file(crt):
    with open(crt) as f:
        return hashlib.sha256(ssl.PEM_cert_to_DER_cert(f.read())).hexdigest()


def served_fingerprint(port, alpn):
    ctx = ssl.create_default_context()
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    ctx.set_alpn_protocols([alpn])
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s, ctx.wrap_socket(s) as t:
        return hashlib.sha256(t.getpeercert(binary_form=True)).hexdigest()


def install(d, key, crt):
    """Replaces the served files the safe way: each renamed over the old one."""
    for src, dst in [(key, "served.key"), (crt, "served.crt")]:
        tmp = os.path.join(d, dst + ".new")
        with open(src, "rb") as f, open(tmp, "wb") as g:
            g.write(f.read())
        os.replace(tmp, os.path.join(d, dst))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tessera", required=True)
    a = ap.parse_args()
    d = tempfile.mkdtemp(prefix="tessera_tls_")
    store = os.path.join(d, "t.tsr")
    subprocess.run([a.tessera, "build", "procedural:terrain:512", "-o", store, "-q"], check=True)
    old_key, old_crt = make_cert(d, "old")
    new_key, new_crt = make_cert(d, "new")
    _, other_crt = make_cert(d, "other")
    install(d, old_key, old_crt)
    p = subprocess.Popen([a.tessera, "serve", "--store", store, "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0",
                          "--tls-cert", os.path.join(d, "served.crt"), "--tls-key", os.path.join(d, "served.key")],
                         stderr=subprocess.PIPE, text=True)
    try:
        grpc_port, http_port = wait_listening(p)
        old, new = fingerprint_file(old_crt), fingerprint_file(new_crt)
        check(served_fingerprint(http_port, "http/1.1") == old, "HTTP serves the first certificate")
        check(served_fingerprint(grpc_port, "h2") == old, "gRPC serves the first certificate")

        # A keep-alive HTTPS connection opened before the renewal.
        ctx = ssl.create_default_context(cafile=old_crt)
        kept = ctx.wrap_socket(socket.create_connection(("127.0.0.1", http_port), timeout=10), server_hostname="127.0.0.1")

        def ask(conn):
            conn.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
            return conn.recv(4096)

        check(ask(kept).startswith(b"HTTP/1.1 200"), "a connection opened before the renewal works")

        # Renewed files without a SIGHUP: neither side takes them up, even after gRPC's copy has
        # been looked at again (every 2 s).
        install(d, new_key, new_crt)
        time.sleep(3)
        check(served_fingerprint(http_port, "http/1.1") == old, "without SIGHUP, HTTPS keeps the first certificate")
        check(served_fingerprint(grpc_port, "h2") == old,
              "without SIGHUP, gRPC keeps the first certificate (it watches the checked copy, not --tls-cert)")

        p.send_signal(signal.SIGHUP)
        deadline, http_ok, grpc_ok = time.time() + 10, False, False
        while time.time() < deadline and not (http_ok and grpc_ok):
            http_ok = http_ok or served_fingerprint(http_port, "http/1.1") == new
            grpc_ok = grpc_ok or served_fingerprint(grpc_port, "h2") == new
            time.sleep(0.2)
        check(http_ok, "after SIGHUP, new HTTPS connections get the renewed certificate")
        check(grpc_ok, "gRPC takes up the renewed certificate within seconds")
        check(ask(kept).startswith(b"HTTP/1.1 200"), "the connection opened before still works")
        kept.close()

        # A broken renewal (a certificate that is not the key's): the renewed one stays in force.
        install(d, new_key, other_crt)
        p.send_signal(signal.SIGHUP)
        time.sleep(3)
        check(p.poll() is None, "the server is still up after a broken renewal")
        check(served_fingerprint(http_port, "http/1.1") == new, "HTTP keeps the last good certificate")
        check(served_fingerprint(grpc_port, "h2") == new, "gRPC keeps the last good certificate")
    finally:
        p.terminate()
        p.wait(timeout=30)
    if failures:
        print(f"{len(failures)} failures", flush=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
