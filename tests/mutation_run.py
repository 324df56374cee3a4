#!/usr/bin/env python3
"""Mutation run: does the suite notice when the code that matters is broken on purpose?

Each mutation in tests/mutations.json replaces one snippet of one source file (it must occur
exactly once), rebuilds the named targets in the build directory, and runs the ctest tests its
regex selects. The mutation is *killed* when a selected test fails, *survives* when they all
pass, and is *invalid* (left out of the score) when it does not build. The file is restored after each mutation, whatever happens, and the
targets are rebuilt from the clean sources at the end.

Not part of the README's test command (it rebuilds dozens of times): run it by hand on a clean
tree with a full build, and record the score in docs/reliability.md.

    tests/mutation_run.py [--build build] [--only id,id] [--out table.md] [--catalogue tests/mutations.json]

Exit status: 0 when the score reaches --goal (default 90 %), 1 when it does not, 2 on a usage or
set-up error (a dirty file, a stale snippet, a regex that selects no test).
"""
import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def fail(msg):
    print(f"mutation_run: {msg}", file=sys.stderr)
    sys.exit(2)


def run(cmd, timeout):
    try:
        p = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=timeout)
        return p.returncode, p.stdout
    except subprocess.TimeoutExpired as e:
        return 124, (e.stdout or b"").decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")


def load(path, only):
    with open(path) as f:
        muts = json.load(f)
    ids = set()
    for m in muts:
        for key in ("id", "area", "file", "find", "replace", "build", "ctest", "why"):
            if key not in m:
                fail(f"{m.get('id', '?')}: no '{key}'")
        if m["id"] in ids:
            fail(f"{m['id']}: duplicate id")
        ids.add(m["id"])
    if only:
        wanted = set(only.split(","))
        unknown = wanted - ids
        if unknown:
            fail(f"unknown ids: {', '.join(sorted(unknown))}")
        muts = [m for m in muts if m["id"] in wanted]
    return muts


def check(m):
    path = os.path.join(ROOT, m["file"])
    if not os.path.isfile(path):
        fail(f"{m['id']}: no file {m['file']}")
    text = open(path).read()
    n = text.count(m["find"])
    if n != 1:
        fail(f"{m['id']}: the snippet occurs {n} times in {m['file']} (stale catalogue?)")
    if subprocess.run(["git", "diff", "--quiet", "--", m["file"]], cwd=ROOT).returncode != 0:
        fail(f"{m['id']}: {m['file']} has uncommitted changes: run on a clean tree")
    return path, text


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default="build", help="build directory (configured, fully built)")
    ap.add_argument("--catalogue", default=os.path.join("tests", "mutations.json"))
    ap.add_argument("--only", help="comma-separated mutation ids")
    ap.add_argument("--out", help="write the result table (markdown) here")
    ap.add_argument("--goal", type=float, default=90.0, help="kill percentage needed for exit 0")
    ap.add_argument("--timeout", type=int, default=600, help="seconds per build and per test run")
    ap.add_argument("--check", action="store_true",
                    help="only check that every snippet occurs exactly once in its file (a ctest: the catalogue follows the code)")
    args = ap.parse_args()
    if args.check:
        muts = load(os.path.join(ROOT, args.catalogue), args.only)
        stale = []
        for m in muts:
            path = os.path.join(ROOT, m["file"])
            n = open(path).read().count(m["find"]) if os.path.isfile(path) else -1
            if n != 1:
                stale.append(f"{m['id']}: " + (f"no file {m['file']}" if n < 0 else f"the snippet occurs {n} times in {m['file']}"))
        for line in stale:
            print("stale: " + line, flush=True)
        if stale:
            fail(f"{len(stale)} of {len(muts)} mutations no longer match the code: update tests/mutations.json")
        print(f"all {len(muts)} mutation snippets occur exactly once", flush=True)
        return
    build = os.path.join(ROOT, args.build) if not os.path.isabs(args.build) else args.build
    if not os.path.isfile(os.path.join(build, "build.ninja")):
        fail(f"{build} is not a configured ninja build directory")
    muts = load(os.path.join(ROOT, args.catalogue), args.only)
    for m in muts:  # every snippet checked before anything is touched
        check(m)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, stdout=subprocess.PIPE, text=True).stdout.strip()

    rows, killed, invalid, all_targets = [], 0, 0, set()
    started = time.time()
    for i, m in enumerate(muts, 1):
        path, original = check(m)
        all_targets.update(m["build"])
        t0 = time.time()
        try:
            with open(path, "w") as f:
                f.write(original.replace(m["find"], m["replace"], 1))
            rc, out = run(["ninja", "-C", build] + m["build"], args.timeout)
            if rc != 0:  # a mutant that does not compile says nothing about the tests
                verdict, detail = "invalid", "does not build: " + next((ln.strip() for ln in out.splitlines() if "error:" in ln), "?")[:160]
            else:
                rc, out = run(["ctest", "--test-dir", build, "-R", m["ctest"], "-j2", "--timeout", "300", "--output-on-failure"], args.timeout)
                if "No tests were found" in out:
                    fail(f"{m['id']}: ctest regex '{m['ctest']}' selects no test")
                failed = [ln.split(" - ")[-1].strip() for ln in out.splitlines() if ln.strip().endswith(("(Failed)", "(Timeout)", "(SEGFAULT)", "(Subprocess aborted)", "(Child aborted)"))]
                total = next((ln for ln in out.splitlines() if "tests passed" in ln or "tests failed" in ln), "").strip()
                if rc != 0:
                    verdict, detail = "killed", f"{total}; first: {failed[0] if failed else '?'}"
                else:
                    verdict, detail = "survived", total
        finally:
            with open(path, "w") as f:
                f.write(original)
        killed += verdict == "killed"
        invalid += verdict == "invalid"
        rows.append((m, verdict, detail))
        print(f"[{i}/{len(muts)}] {m['id']}: {verdict} ({detail}) {time.time() - t0:.0f} s", flush=True)

    print("rebuilding the clean tree ...", flush=True)
    rc, out = run(["ninja", "-C", build] + sorted(all_targets), 3600)
    if rc != 0:
        print(out[-4000:])
        fail("the clean rebuild failed")

    valid = len(muts) - invalid
    score = 100.0 * killed / max(valid, 1)
    lines = [f"Mutation run at {commit}: {killed} of {valid} killed ({score:.1f} %), {time.time() - started:.0f} s"
             + (f"; {invalid} more did not build (fix the catalogue)" if invalid else "") + ".", "",
             "| id | area | what it breaks | result |", "|---|---|---|---|"]
    for m, verdict, detail in rows:
        lines.append(f"| `{m['id']}` | {m['area']} | {m['why']} | {verdict}: {detail} |")
    table = "\n".join(lines) + "\n"
    print(table)
    if args.out:
        with open(args.out, "w") as f:
            f.write(table)
    return 0 if score >= args.goal and invalid == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
