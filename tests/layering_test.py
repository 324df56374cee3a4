#!/usr/bin/env python3
"""Layers: no public header and nothing under client/gl includes another part's internals, and
the build path stands apart from the client.

No file under an include/ folder includes a header of a src/ folder, and the GL renderer
(client/gl) includes only its own src/ files and public headers, never client/src or another
part's src/ (docs/client.md, "Public headers"). Generated headers (tessera.pb.h) are not in any
src/ folder and pass. The shared vocabulary (core/) includes only itself, and what `tessera build`
compiles (core/, storage/, scene/, tools/cmd_build.cpp, tools/atlas_build.*) includes no client
header (docs/client.md, "Public headers"). Prints each offending line and exits 1; exits 0 naming
how many files it checked.
  layering_test.py [REPO_ROOT]
"""
import os
import re
import sys

INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"')


def main():
    root = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), ".."))
    gl_src = os.path.join(root, "client", "gl", "src")
    internal = {}  # a src/ folder's header, by the name an include would use -> where it is
    for dirpath, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if not d.startswith((".", "build")) and d not in ("node_modules", "shared")]
        parts = os.path.relpath(dirpath, root).split(os.sep)
        if "src" in parts:
            below = parts[parts.index("src") + 1:]
            for name in files:
                if name.endswith((".hpp", ".h")):
                    internal.setdefault("/".join(below + [name]), os.path.join(dirpath, name))
                    internal.setdefault(name, os.path.join(dirpath, name))
    bad, checked = [], 0
    # The build path: no tessera/client/ header; core/: tessera/<name>.hpp of its own only.
    build_path = [os.path.join(root, d) for d in ("core", "storage", "scene")]
    build_files = [os.path.join(root, "tools", f) for f in ("cmd_build.cpp", "atlas_build.cpp", "atlas_build.hpp")]
    for top in build_path:
        for dirpath, dirs, files in os.walk(top):
            build_files += [os.path.join(dirpath, f) for f in files if f.endswith((".hpp", ".h", ".cpp"))]
    for path in build_files:
        if not os.path.isfile(path):
            bad.append(f"{os.path.relpath(path, root)}: missing (the build path's files moved? update this test)")
            continue
        checked += 1
        in_core = os.path.relpath(path, root).startswith("core" + os.sep)
        with open(path, encoding="utf-8") as f:
            for n, line in enumerate(f, 1):
                m = INCLUDE.match(line)
                if not m:
                    continue
                target = m.group(1)
                if target.startswith("tessera/client/"):
                    bad.append(f"{os.path.relpath(path, root)}:{n}: the build path includes \"{target}\", a client header")
                elif in_core and target.startswith("tessera/") and (
                        "/" in target[len("tessera/"):] or not os.path.isfile(os.path.join(root, "core", "include", target))):
                    bad.append(f"{os.path.relpath(path, root)}:{n}: core/ includes \"{target}\", not a core header")
    for part in ("core", "scene", "client", "storage", "server", "protocol"):
        for dirpath, dirs, files in os.walk(os.path.join(root, part)):
            dirs[:] = [d for d in dirs if d not in ("build",)]
            rel = os.path.relpath(dirpath, root)
            in_include = "/include" in "/" + rel + "/" and "/src" not in "/" + rel + "/"
            in_gl = rel == os.path.join("client", "gl") or rel.startswith(os.path.join("client", "gl") + os.sep)
            if not (in_include or in_gl):
                continue
            for name in files:
                if not name.endswith((".hpp", ".h", ".cpp")):
                    continue
                path = os.path.join(dirpath, name)
                checked += 1
                with open(path, encoding="utf-8") as f:
                    for n, line in enumerate(f, 1):
                        m = INCLUDE.match(line)
                        if not m or m.group(1).startswith("tessera/"):
                            continue
                        target = m.group(1)
                        own = in_gl and not in_include and os.path.isfile(os.path.join(gl_src, target))
                        if target in internal and not own:
                            bad.append(f"{os.path.relpath(path, root)}:{n}: includes \"{target}\", an internal header "
                                       f"({os.path.relpath(internal[target], root)})")
    for b in bad:
        print(b)
    if checked == 0:
        print("layering_test: no files found under", root)
        return 1
    print(f"{checked} files checked, {len(bad)} bad includes")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
