#!/usr/bin/env python3
"""The client's public headers stand alone and keep protobuf and gRPC out of their users' builds.

Each header under client/*/include, scene/include and core/include is compiled on its own (so it
includes what it uses) with only the public include folders (core, storage, client, scene) on the path, and the compiler's dependency list
(-MM is not enough: protobuf and gRPC live under /usr/include, a system folder, so -M) is checked
for any file of protobuf, gRPC, Abseil or the generated tessera.pb.h. A header that includes
<google/protobuf/...> or <grpcpp/...> fails here even though those headers are installed.

  public_headers_test.py --cxx CXX --source-dir DIR
"""
import argparse
import pathlib
import subprocess
import sys

FORBIDDEN = ("/google/protobuf/", "/grpcpp/", "/grpc/", "/absl/", "tessera.pb.h", "tessera.grpc.pb.h")
INCLUDE_DIRS = ("core/include", "storage/include", "client/include", "client/net/include", "scene/include",
                "client/gl/include")
HEADER_ROOTS = ("core/include", "client/include", "client/net/include", "scene/include", "client/gl/include")


def dependencies(cxx: str, src: pathlib.Path, header: pathlib.Path, include_dirs=None) -> list[str]:
    """The files `header` pulls in; include_dirs (absolute) replaces the source tree's folders."""
    flags = [f"-I{d}" for d in include_dirs] if include_dirs else [f"-I{src / d}" for d in INCLUDE_DIRS]
    p = subprocess.run([cxx, "-std=c++20", "-x", "c++", "-M", *flags, str(header)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{header} does not compile on its own:\n{p.stderr.strip()[:2000]}")
    # Make-rule syntax: "header.o: a.hpp b.hpp \\\n c.hpp ...".
    return [t for t in p.stdout.replace("\\\n", " ").split()[1:] if t]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cxx", required=True)
    ap.add_argument("--source-dir", required=True, type=pathlib.Path)
    args = ap.parse_args()
    headers = sorted(h for root in HEADER_ROOTS for h in (args.source_dir / root).rglob("*.hpp"))
    if len(headers) < 10:
        print(f"FAIL: only {len(headers)} public headers found under {HEADER_ROOTS}", file=sys.stderr)
        return 1
    failures = 0
    for h in headers:
        name = h.relative_to(args.source_dir)
        try:
            deps = dependencies(args.cxx, args.source_dir, h)
        except RuntimeError as e:
            print(f"FAIL  {e}")
            failures += 1
            continue
        bad = [d for d in deps if any(f in d for f in FORBIDDEN)]
        if bad:
            print(f"FAIL  {name} pulls in {len(bad)} protobuf/gRPC/Abseil files, first {bad[0]}")
            failures += 1
        else:
            print(f"ok    {name}: {len(deps)} files, none of protobuf, gRPC or Abseil")
    print(f"{len(headers) - failures} of {len(headers)} public headers stand alone without protobuf or gRPC")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
