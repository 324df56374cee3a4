#!/usr/bin/env python3
"""The client library as an outside project uses it: installed, found, linked, run.

1. `cmake --install BUILD --component dev --prefix TMP/prefix`: headers, static libraries and
   the CMake package land there.
2. Every installed header compiles on its own with only the installed tree on the include path,
   and its dependency list (`g++ -MM`-style, system headers included) names no protobuf, gRPC or
   src/ header.
3. examples/ (which sets no C++ standard: the targets carry C++20) is configured against the
   installed tree alone (find_package(Tessera)), built, and
   run headless against `tessera serve` on a store built here: vt_minimal must print fallback 0
   (every page of its last view resident) and PSNR >= 45 dB against the reference renderer.
   The last frame is saved as a PNG (kept in $TESSERA_KEEP_FRAME_DIR when set, to look at).
Prints what it checked; exits 1 on the first failure.
  install_test.py --build BUILD_DIR --source REPO_ROOT --tessera TESSERA
"""
import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import pathlib
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from public_headers_test import FORBIDDEN, dependencies  # noqa: E402  (the same check, on the installed tree)


def run(cmd, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if r.returncode != 0:
        sys.exit(f"FAIL: {' '.join(cmd)} exited {r.returncode}\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}")
    return r


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--tessera", required=True)
    a = ap.parse_args()
    work = tempfile.mkdtemp(prefix="tessera-install-")
    try:
        prefix = os.path.join(work, "prefix")
        run(["cmake", "--install", a.build, "--component", "dev", "--prefix", prefix])
        config = os.path.join(prefix, "lib", "cmake", "Tessera", "TesseraConfig.cmake")
        if not os.path.isfile(config):
            sys.exit(f"FAIL: no {config} after the install")
        include = os.path.join(prefix, "include")
        headers = sorted(os.path.relpath(os.path.join(d, f), include)
                         for d, _, fs in os.walk(include) for f in fs if f.endswith(".hpp"))
        if len(headers) < 20:
            sys.exit(f"FAIL: only {len(headers)} headers installed")
        for must in ("tessera/client/runtime.hpp", "tessera/client/gl/renderer.hpp", "tessera/storage/store_reader.hpp"):
            if must not in headers:
                sys.exit(f"FAIL: {must} not installed")
        # The builder's headers declare what only the builder's library (not installed) defines.
        for never in ("tessera/storage/builder.hpp", "tessera/storage/image_source.hpp", "tessera/storage/sparse_source.hpp",
                      "tessera/storage/remote_source.hpp", "tessera/storage/store_json.hpp", "tessera/storage/atlas.hpp"):
            if never in headers:
                sys.exit(f"FAIL: {never} is installed, but its library is not part of the package")
        bad = []
        for h in headers:
            try:
                deps = dependencies("g++", pathlib.Path(include), pathlib.Path(include, h), include_dirs=[include])
            except RuntimeError as e:
                bad.append(f"{h}: against the installed tree alone: {e}")
                continue
            bad += [f"{h} pulls {d}" for d in deps if any(f in d for f in FORBIDDEN) or "/src/" in d]
        if bad:
            sys.exit("FAIL: public headers:\n" + "\n".join(bad))
        print(f"ok: {len(headers)} installed headers compile alone; none pulls protobuf, gRPC or a src/ header")

        # The example, as an outside project: only the installed tree on CMAKE_PREFIX_PATH.
        ex_build = os.path.join(work, "examples")
        gen = ["-G", "Ninja"] if shutil.which("ninja") else []
        t0 = time.time()
        run(["cmake", "-S", os.path.join(a.source, "examples"), "-B", ex_build, *gen,
             f"-DCMAKE_PREFIX_PATH={prefix}", "-DCMAKE_BUILD_TYPE=Release"])
        run(["cmake", "--build", ex_build])
        exe = os.path.join(ex_build, "vt_minimal")
        print(f"ok: examples/ configured and built against the installed package in {time.time() - t0:.1f} s")

        store = os.path.join(work, "terrain.tsr")
        run([a.tessera, "build", "procedural:terrain:2048", "-o", store, "-q"])
        frame_png = os.path.join(os.environ.get("TESSERA_KEEP_FRAME_DIR", work), "vt_minimal.png")
        port = free_port()
        server = subprocess.Popen([a.tessera, "serve", "--store", store, "--grpc", f"127.0.0.1:{port}", "--http", "127.0.0.1:0"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.time() + 30
            while time.time() < deadline:
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=1).close()
                    break
                except OSError:
                    if server.poll() is not None:
                        sys.exit(f"FAIL: tessera serve exited: {server.stderr.read()[-2000:]}")
                    time.sleep(0.2)
            r = run([exe, f"grpc://127.0.0.1:{port}/terrain", "--frames", "60", "--size", "256x144",
                     "--reference", store, "--save", frame_png], timeout=240)
        finally:
            server.terminate()
            server.wait(timeout=30)
        result = json.loads(r.stdout.strip().splitlines()[-1])
        print("vt_minimal:", json.dumps(result))
        problems = []
        if result["textured_pixels"] < 256 * 144 // 4:
            problems.append(f"only {result['textured_pixels']} textured pixels")
        if result["fallback"] != 0:
            problems.append(f"fallback {result['fallback']} (want 0)")
        if result["psnr_db"] < 45:
            problems.append(f"PSNR {result['psnr_db']} dB against the reference (want >= 45)")
        if result["gl_errors"] != 0:
            problems.append(f"{result['gl_errors']} GL errors")
        with open(frame_png, "rb") as f:
            if f.read(8) != b"\x89PNG\r\n\x1a\n":
                problems.append("--save wrote no PNG")
        if problems:
            sys.exit("FAIL: " + "; ".join(problems))
        print("ok: the installed example rendered the store over gRPC: fallback 0, "
              f"PSNR {result['psnr_db']} dB, {result['settle_frames']} frames to settle")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
