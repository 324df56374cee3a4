#!/usr/bin/env python3
"""Lints the deployment files in deploy/ without Docker, a cluster or a running systemd.

    python3 tests/deploy_lint.py [--tessera BUILD/tessera] [--deploy-dir DIR]

Checks, each printed as ok / FAIL / SKIP lines under its heading. SKIP is only for what is optional:
Docker Compose, promtool and kubectl (not installed by tools/setup.sh), and the checks that need a
binary when none is given. A missing systemd-analyze (setup.sh --tests installs systemd), a systemd too old
for `security --offline`, or a --tessera binary that does not run is a FAIL: on a machine set up by
setup.sh those checks must run, and a skip would let the ctest run pass without them.

  systemd     deploy/tessera.service: `systemd-analyze verify` on a copy whose ExecStart points at
              --tessera (a stub when none is given), `systemd-analyze security --offline` exposure,
              and the directives the unit must keep (sandboxing, reload, stop, limits).
  config      deploy/tessera.conf: `key = value` syntax (docs/server.md, "Config file"); every key (commented-out examples
              too) is a long option of `tessera serve --help`.
  runtime     `tessera serve --config tessera.conf` on loopback ports with an empty store
              directory: the file is really read (a bad value in a probe file is refused),
              /readyz, /healthz and /metrics answer, SIGTERM exits 0.
  compose     deploy/compose.yaml: structure (build, ports, volumes, healthcheck, restart, grace).
  prometheus  deploy/prometheus.yml: job `tessera`, its targets; `promtool check config` if present.
  kubernetes  deploy/kubernetes/*.yaml: every document has apiVersion/kind/metadata.name; probes,
              ports, selectors, volumes, security context; `kubectl kustomize` if present.
  dockerfile  deploy/Dockerfile: instructions, stages, COPY --from, base tags, EXPOSE, user,
              healthcheck; deploy/Dockerfile.dockerignore keeps every source file in the context.
  cross       the same ports, endpoints and drain budget everywhere; every `tessera serve` flag
              used anywhere exists (needs a binary whose `serve --help` works).

Exit status: 0 when nothing failed (SKIPs allowed), 1 otherwise. Needs python3 and PyYAML
(Debian: python3-yaml).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

try:
    import yaml
except ImportError:  # pragma: no cover - environment problem, not a lint failure
    print("deploy_lint: FAIL: PyYAML is missing (Debian: apt-get install python3-yaml)")
    sys.exit(1)

# Ports, paths and names every file must agree on.
GRPC_PORT = 50051
HTTP_PORT = 8080
STORE_DIR = "/srv/tessera"
HEALTH_PATH = "/healthz"
READY_PATH = "/readyz"
DEFAULT_DRAIN_MS = 10000  # ServerConfig::drain_timeout


# ---------------------------------------------------------------------------------------------
# Reporting


class Report:
    def __init__(self) -> None:
        self.failures: list[str] = []
        self.skips: list[str] = []
        self.section = ""

    def begin(self, name: str) -> None:
        self.section = name
        print(f"== {name}")

    def ok(self, msg: str) -> None:
        print(f"  ok    {msg}")

    def fail(self, msg: str) -> None:
        self.failures.append(f"{self.section}: {msg}")
        lines = msg.splitlines() or [""]
        print(f"  FAIL  {lines[0]}")
        for line in lines[1:]:
            print(f"        {line}")

    def skip(self, msg: str) -> None:
        self.skips.append(f"{self.section}: {msg}")
        print(f"  SKIP  {msg}")

    def check(self, cond: bool, ok_msg: str, fail_msg: str | None = None) -> bool:
        if cond:
            self.ok(ok_msg)
        else:
            self.fail(fail_msg or f"expected: {ok_msg}")
        return cond


# ---------------------------------------------------------------------------------------------
# Shared helpers


def run(cmd: list[str], env: dict | None = None, timeout: int = 60) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          env=env, timeout=timeout, check=False)


def option_values(args: list[str]) -> dict[str, list[str | None]]:
    """--name VALUE / --name=VALUE pairs of an argument vector (value None for a trailing flag)."""
    out: dict[str, list[str | None]] = {}
    i = 0
    while i < len(args):
        a = str(args[i])
        if a.startswith("--") and len(a) > 2:
            if "=" in a:
                name, value = a[2:].split("=", 1)
            else:
                name = a[2:]
                value = None
                if i + 1 < len(args) and not str(args[i + 1]).startswith("--"):
                    value = str(args[i + 1])
                    i += 1
            out.setdefault(name, []).append(value)
        i += 1
    return out


def host_port(value: str | None) -> tuple[str, int] | None:
    if not value:
        return None
    m = re.fullmatch(r"(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]*):(\d{1,5})", value)
    if not m or int(m.group(2)) > 65535:
        return None
    return m.group(1), int(m.group(2))


def check_serve_args(rep: Report, where: str, args: list[str], in_container: bool) -> dict:
    """The listener flags of a `tessera serve` command line; returns option_values(args)."""
    opts = option_values(args)
    for flag, port in (("grpc", GRPC_PORT), ("http", HTTP_PORT)):
        vals = opts.get(flag)
        if not vals:
            rep.fail(f"{where}: no --{flag} HOST:PORT (the default binds 127.0.0.1, "
                     "unreachable from outside a container)" if in_container
                     else f"{where}: no --{flag}")
            continue
        hp = host_port(vals[-1])
        if hp is None:
            rep.fail(f"{where}: --{flag} {vals[-1]!r} is not HOST:PORT")
            continue
        rep.check(hp[1] == port, f"{where}: --{flag} port {hp[1]}",
                  f"{where}: --{flag} port {hp[1]}, expected {port} (as EXPOSE and the manifests)")
        if in_container:
            rep.check(hp[0] in ("0.0.0.0", "[::]", ""), f"{where}: --{flag} binds all interfaces",
                      f"{where}: --{flag} binds {hp[0]!r}: unreachable from outside the container "
                      "(use 0.0.0.0)")
    if in_container:
        dirs = opts.get("store-dir", [])
        rep.check(STORE_DIR in dirs, f"{where}: --store-dir {STORE_DIR}",
                  f"{where}: --store-dir {STORE_DIR} missing (got {dirs})")
    for name, vals in opts.items():
        if name in ("drain-timeout", "request-timeout", "watch-interval", "io-threads",
                    "http-threads", "max-viewers", "max-batch", "max-pending", "max-connections"):
            for v in vals:
                if v is None or not re.fullmatch(r"\d+", v):
                    rep.fail(f"{where}: --{name} {v!r} is not a whole number")
    return opts


def drain_ms(opts: dict) -> int:
    vals = opts.get("drain-timeout")
    if vals and vals[-1] and re.fullmatch(r"\d+", vals[-1]):
        return int(vals[-1])
    return DEFAULT_DRAIN_MS


def parse_duration(text) -> float | None:
    """Compose / systemd style durations: 15s, 1m30s, 500ms, 2min, or a bare number of seconds."""
    if isinstance(text, (int, float)):
        return float(text)
    if not isinstance(text, str):
        return None
    s = text.strip().replace(" ", "")
    if re.fullmatch(r"\d+(\.\d+)?", s):
        return float(s)
    units = {"us": 1e-6, "ms": 1e-3, "s": 1, "sec": 1, "m": 60, "min": 60, "h": 3600}
    total = 0.0
    pos = 0
    for m in re.finditer(r"(\d+(?:\.\d+)?)(us|ms|sec|min|s|m|h)", s):
        if m.start() != pos:
            return None
        total += float(m.group(1)) * units[m.group(2)]
        pos = m.end()
    return total if pos == len(s) and pos > 0 else None


def image_tag_problem(ref: str) -> str | None:
    """Why an image reference is not pinned (None when it names a tag other than latest)."""
    if "@sha256:" in ref:
        return None
    last = ref.rsplit("/", 1)[-1]
    if ":" not in last:
        return f"{ref!r} has no tag (that is :latest)"
    tag = last.rsplit(":", 1)[1]
    if tag == "latest" or not tag:
        return f"{ref!r} uses the latest tag"
    if "$" in tag:
        return f"{ref!r}: unresolved variable in the tag"
    return None


class Context:
    """What one check learns and another needs."""

    def __init__(self, deploy: Path, tessera: Path | None) -> None:
        self.deploy = deploy
        self.tessera = tessera
        self.serve_options: set[str] | None = None  # long options of `tessera serve --help`
        self.serve_skip_reason = ""
        self.serve_args: list[tuple[str, list[str]]] = []  # (where, argv after `serve`)
        self.expose_ports: set[int] | None = None
        self.compose_ports: set[int] | None = None
        self.k8s_ports: set[int] | None = None


# ---------------------------------------------------------------------------------------------
# `tessera serve --help`


def load_serve_options(ctx: Context) -> None:
    if ctx.tessera is None:
        ctx.serve_skip_reason = "no --tessera BINARY given"
        return
    if not os.access(ctx.tessera, os.X_OK):
        ctx.serve_skip_reason = f"{ctx.tessera} is not an executable"
        return
    try:
        p = run([str(ctx.tessera), "serve", "--help"], timeout=30)
    except (OSError, subprocess.TimeoutExpired) as e:
        ctx.serve_skip_reason = f"`{ctx.tessera} serve --help` could not run: {e}"
        return
    text = p.stdout + p.stderr
    # CLI11 answers an unknown subcommand's --help with the top-level help (and status 0).
    if p.returncode != 0 or not re.search(r"^Usage:.*\bserve\b", text, re.M):
        ctx.serve_skip_reason = (f"`{ctx.tessera.name} serve --help` does not describe a serve "
                                 f"subcommand (status {p.returncode}): not built yet?")
        return
    ctx.serve_options = set(re.findall(r"--([A-Za-z0-9][A-Za-z0-9_-]*)", text))


def check_options_known(rep: Report, ctx: Context, where: str, names) -> None:
    if ctx.serve_options is None:
        return
    unknown = sorted(n for n in set(names) if n not in ctx.serve_options)
    rep.check(not unknown, f"{where}: every option is a `tessera serve` option",
              f"{where}: not options of `tessera serve`: " + ", ".join("--" + n for n in unknown))


# ---------------------------------------------------------------------------------------------
# (a) systemd unit


def parse_unit(text: str) -> dict[str, list[tuple[str, str]]]:
    sections: dict[str, list[tuple[str, str]]] = {}
    current = None
    logical = ""
    for raw in text.splitlines():
        line = raw.rstrip()
        if not logical and (not line.strip() or line.lstrip()[:1] in "#;"):
            continue
        if line.endswith("\\"):
            logical += line[:-1] + " "
            continue
        line = logical + line
        logical = ""
        s = line.strip()
        if s.startswith("[") and s.endswith("]"):
            current = s[1:-1]
            sections.setdefault(current, [])
        elif "=" in s and current is not None:
            k, v = s.split("=", 1)
            sections[current].append((k.strip(), v.strip()))
    return sections


def unit_values(sections, section: str, key: str) -> list[str]:
    """All assignments of KEY (an empty assignment resets the list, as in systemd)."""
    vals: list[str] = []
    for k, v in sections.get(section, []):
        if k == key:
            if v == "":
                vals = [""]
            else:
                vals = [x for x in vals if x != ""] + [v]
    return vals


def check_systemd(rep: Report, ctx: Context) -> None:
    rep.begin("systemd: tessera.service")
    unit = ctx.deploy / "tessera.service"
    if not unit.is_file():
        rep.fail(f"{unit} is missing")
        return
    text = unit.read_text()
    sec = parse_unit(text)
    for s in ("Unit", "Service", "Install"):
        rep.check(s in sec, f"[{s}] section", f"no [{s}] section")
    svc = lambda k: unit_values(sec, "Service", k)  # noqa: E731

    # ExecStart: the installed binary, `serve`, the config file of this directory.
    exec_start = svc("ExecStart")
    argv: list[str] = []
    if len(exec_start) != 1:
        rep.fail(f"expected one ExecStart=, found {len(exec_start)}")
    else:
        argv = shlex.split(exec_start[0].lstrip("-@:+!"))
        rep.check(argv[:2] == ["/usr/local/bin/tessera-server", "serve"],
                  "ExecStart runs /usr/local/bin/tessera-server serve (cmake --install prefix /usr/local)",
                  f"ExecStart should run `/usr/local/bin/tessera-server serve ...`, got {exec_start[0]!r}")
        opts = option_values(argv[2:])
        conf = (opts.get("config") or [None])[-1]
        rep.check(conf == "/etc/tessera/tessera.conf", "ExecStart reads --config /etc/tessera/tessera.conf",
                  f"ExecStart --config is {conf!r}, expected /etc/tessera/tessera.conf "
                  "(where deploy/tessera.conf is installed)")
        ctx.serve_args.append(("tessera.service ExecStart", argv[2:]))

    expect = {
        "Type": {"simple", "exec", "notify"},
        "KillSignal": {"SIGTERM"},
        "Restart": {"on-failure", "always"},
        "ProtectSystem": {"strict"},
        "ProtectHome": {"yes", "true", "tmpfs"},
        "PrivateTmp": {"yes", "true"},
        "NoNewPrivileges": {"yes", "true"},
        "LimitNOFILE": {"65536"},
    }
    for key, allowed in expect.items():
        vals = svc(key)
        got = vals[-1] if vals else None
        rep.check(got in allowed, f"{key}={got}", f"{key}= is {got!r}, expected one of {sorted(allowed)}")

    reload = " ".join(svc("ExecReload"))
    rep.check(re.search(r"\bkill\s+(-HUP|-s\s*HUP|--signal\s+HUP)\s+\$MAINPID", reload) is not None,
              "ExecReload sends SIGHUP to $MAINPID (rescans the stores)",
              f"ExecReload= should be `/bin/kill -HUP $MAINPID`, got {reload!r}")
    stop = parse_duration((svc("TimeoutStopSec") or ["90"])[-1])
    rep.check(stop is not None and 0 < stop <= 120, f"TimeoutStopSec={stop:g}s" if stop else "TimeoutStopSec",
              f"TimeoutStopSec= {svc('TimeoutStopSec')} is not a sensible drain budget")
    user = svc("User")
    dynamic = (svc("DynamicUser") or ["no"])[-1] in ("yes", "true")
    rep.check(dynamic or (user and user[-1] not in ("root", "0")),
              "runs as a non-root user (DynamicUser= or User=)", "neither DynamicUser=yes nor a non-root User=")
    caps = svc("CapabilityBoundingSet")
    rep.check(caps == [""], "CapabilityBoundingSet= is empty",
              f"CapabilityBoundingSet= should be set empty, got {caps}")
    families = set(" ".join(svc("RestrictAddressFamilies")).split())
    rep.check(families and families <= {"AF_INET", "AF_INET6", "AF_UNIX"} and "~" not in "".join(families),
              "RestrictAddressFamilies= allows only AF_INET AF_INET6 AF_UNIX",
              f"RestrictAddressFamilies= is {sorted(families)}")
    filt = " ".join(svc("SystemCallFilter")).split()
    rep.check("@system-service" in filt, "SystemCallFilter= allows @system-service only",
              f"SystemCallFilter= lacks @system-service: {filt}")
    ro = " ".join(svc("ReadOnlyPaths")).split()
    rep.check(any(p.lstrip("-+") == STORE_DIR for p in ro), f"ReadOnlyPaths= has {STORE_DIR}",
              f"ReadOnlyPaths= lacks {STORE_DIR}: {ro}")
    rep.check(bool(svc("MemoryMax")), f"MemoryMax={''.join(svc('MemoryMax')[-1:])}", "no MemoryMax=")
    wanted = " ".join(unit_values(sec, "Install", "WantedBy")).split()
    rep.check("multi-user.target" in wanted, "WantedBy=multi-user.target",
              f"[Install] WantedBy= lacks multi-user.target: {wanted}")

    # The drain must end before systemd's SIGKILL.
    conf_opts = read_conf_options(ctx.deploy / "tessera.conf")
    if stop is not None:
        drain = DEFAULT_DRAIN_MS
        if conf_opts and "drain-timeout" in conf_opts and re.fullmatch(r"\d+", conf_opts["drain-timeout"]):
            drain = int(conf_opts["drain-timeout"])
        rep.check(drain < stop * 1000, f"drain-timeout {drain} ms < TimeoutStopSec {stop:g} s",
                  f"tessera.conf drain-timeout {drain} ms does not end before TimeoutStopSec={stop:g}s")

    verify_with_systemd_analyze(rep, ctx, unit, text)


def verify_with_systemd_analyze(rep: Report, ctx: Context, unit: Path, text: str) -> None:
    sa = shutil.which("systemd-analyze")
    if sa is None:
        rep.fail("systemd-analyze not found: unit not verified by systemd (tools/setup.sh --tests installs systemd)")
        return
    with tempfile.TemporaryDirectory(prefix="tessera-unit-") as tmp:
        tmpdir = Path(tmp)
        binary = ctx.tessera.resolve() if ctx.tessera and os.access(ctx.tessera, os.X_OK) else None
        if binary is None:
            # verify checks that every Exec*= program exists and is executable: give it a stub.
            binary = tmpdir / "bin" / "tessera"
            binary.parent.mkdir()
            binary.write_text("#!/bin/sh\nexit 0\n")
            binary.chmod(0o755)
        if re.search(r"\s", str(binary)):
            # ExecStart= splits on white space: verify a link to the binary instead.
            link = tmpdir / "bin" / "tessera"
            link.parent.mkdir(exist_ok=True)
            link.symlink_to(binary)
            binary = link
        if re.search(r"\s", str(binary)):
            rep.fail(f"temporary directory {tmpdir} has white space: unit not verified (set TMPDIR)")
            return
        # Point every Exec*= that runs a `tessera` at the binary we have (paths only, no other edit).
        rewritten = re.sub(r"^(Exec[A-Za-z]+=[-@:+!]*)(/\S*/)?tessera(-server)?(?=\s|$)",
                           lambda m: m.group(1) + str(binary), text, flags=re.M)
        copy = tmpdir / unit.name
        copy.write_text(rewritten)
        helptext = run([sa, "--help"]).stdout
        cmd = [sa, "verify", "--man=no"]
        if "--recursive-errors" in helptext:
            cmd.append("--recursive-errors=no")  # errors in multi-user.target etc. are not ours
        cmd.append(str(copy))
        env = dict(os.environ, SYSTEMD_LOG_TARGET="console", SYSTEMD_LOG_LEVEL="info",
                   SYSTEMD_LOG_COLOR="0", SYSTEMD_COLORS="0", SYSTEMD_PAGER="cat", PAGER="cat")
        try:
            p = run(cmd, env=env, timeout=120)
        except subprocess.TimeoutExpired:
            rep.fail("systemd-analyze verify timed out")
            return
        lines = [l for l in (p.stdout + p.stderr).splitlines() if l.strip()]
        mine = [l for l in lines if unit.name in l or str(tmpdir) in l]
        if p.returncode != 0 or mine:
            shown = (mine or lines)[:20]
            rep.fail(f"systemd-analyze verify (status {p.returncode}, ExecStart -> {binary}):\n"
                     + "\n".join(l.replace(str(tmpdir) + "/", "") for l in shown))
        else:
            rep.ok(f"systemd-analyze verify: no warnings (ExecStart -> {binary})")

        if "--offline" in helptext and "--threshold" in helptext:
            # Exposure on systemd's 0-10 scale; the threshold argument is in tenths.
            p = run([sa, "security", "--offline=true", "--threshold=30", "--no-pager", str(copy)], env=env)
            m = re.search(r"Overall exposure level for \S+: (\S+) (\S+)", p.stdout + p.stderr)
            score = f"{m.group(1)} (systemd: {m.group(2)})" if m else "?"
            if m is None:
                rep.fail(f"systemd-analyze security --offline failed (status {p.returncode}):\n"
                         + "\n".join((p.stdout + p.stderr).strip().splitlines()[-5:]))
            else:
                rep.check(p.returncode == 0, f"systemd-analyze security: exposure {score}, at most 3.0",
                          f"systemd-analyze security: exposure {score}, above 3.0: sandboxing was weakened")
        else:
            rep.fail("systemd-analyze has no `security --offline` (systemd 252, Debian 12's, has it): "
                     "exposure not rated")


# ---------------------------------------------------------------------------------------------
# (f) tessera.conf


CONF_VALUE = re.compile(r'"(?:[^"\\]|\\.)*"|\'[^\']*\'|\[.*\]|[-+]?\d+(\.\d+)?|true|false|[A-Za-z0-9_./:-]+')


def parse_conf(path: Path):
    """(active, commented, errors): key -> value; commented-out `# key = value` lines apart."""
    active: dict[str, str] = {}
    commented: dict[str, str] = {}
    errors: list[str] = []
    for n, raw in enumerate(path.read_text().splitlines(), 1):
        line = raw.strip()
        if not line:
            continue
        if line[0] in "#;":
            m = re.fullmatch(r"[#;]+\s*([a-z][a-z0-9-]*)\s*=\s*(.+)", line)
            if m:
                commented[m.group(1)] = m.group(2).strip()
            continue
        if re.fullmatch(r"\[[A-Za-z0-9_.-]*\]", line):
            continue  # a section: [serve] holds the subcommand's options
        m = re.fullmatch(r"([A-Za-z][A-Za-z0-9_.-]*)\s*=\s*(.*?)\s*(?:#.*)?", line)
        if not m:
            errors.append(f"line {n}: not `key = value`: {raw!r}")
            continue
        key, value = m.group(1), m.group(2)
        key = key.split(".", 1)[1] if key.startswith("serve.") else key
        if not CONF_VALUE.fullmatch(value):
            errors.append(f"line {n}: {key}: value {value!r} is not a quoted string, number, "
                          "boolean or [list]")
        if key in active and not key.startswith("store"):
            errors.append(f"line {n}: {key} given twice")
        active[key] = value.strip("\"'")
    return active, commented, errors


def read_conf_options(path: Path) -> dict[str, str] | None:
    if not path.is_file():
        return None
    return parse_conf(path)[0]


def check_conf(rep: Report, ctx: Context) -> None:
    rep.begin("config: tessera.conf")
    path = ctx.deploy / "tessera.conf"
    if not path.is_file():
        rep.fail(f"{path} is missing")
        return
    active, commented, errors = parse_conf(path)
    for e in errors:
        rep.fail(e)
    if not errors:
        rep.ok(f"CLI11 config syntax ({len(active)} keys, {len(commented)} commented-out examples)")
    rep.check(active.get("store-dir") == STORE_DIR or active.get("store-dir", "").startswith("["),
              f"store-dir = {STORE_DIR}", f"store-dir is {active.get('store-dir')!r}, expected {STORE_DIR}")
    for flag in ("grpc", "http"):
        if flag in active:
            rep.check(host_port(active[flag]) is not None, f"{flag} = {active[flag]} (HOST:PORT)",
                      f"{flag} = {active[flag]!r} is not HOST:PORT")
    for k in ("drain-timeout", "request-timeout", "watch-interval"):
        if k in active:
            rep.check(re.fullmatch(r"\d+", active[k]) is not None, f"{k} = {active[k]} ms",
                      f"{k} = {active[k]!r}: expected whole milliseconds")
    if "cache-size" in active:
        rep.check(re.fullmatch(r"\d+\s*([KMGT]i?B?|[kmgt]i?b?|B|b)?", active["cache-size"]) is not None,
                  f"cache-size = {active['cache-size']}",
                  f"cache-size = {active['cache-size']!r}: expected a size such as 256MiB")
    if ctx.serve_options is None:
        rep.skip(f"keys not checked against `tessera serve --help`: {ctx.serve_skip_reason}")
        return
    unknown = sorted(k for k in active if k not in ctx.serve_options)
    rep.check(not unknown, "every key is a `tessera serve` long option",
              "keys that are not `tessera serve` options (CLI11 rejects the file): " + ", ".join(unknown))
    unknown = sorted(k for k in commented if k not in ctx.serve_options)
    rep.check(not unknown, "every commented-out example key is a `tessera serve` long option",
              "commented-out example keys that are not `tessera serve` options: " + ", ".join(unknown))


def free_port() -> int:
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def http_get(url: str, timeout: float = 2.0) -> tuple[int, str]:
    import urllib.error
    import urllib.request
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            return r.status, r.read(65536).decode("utf-8", "replace")
    except urllib.error.HTTPError as e:
        return e.code, ""
    except OSError:
        return 0, ""


def check_serve_runtime(rep: Report, ctx: Context) -> None:
    """Starts `tessera serve --config tessera.conf` on loopback ports: the file must be read (an
    invalid value in it is refused), the probes' endpoints must answer, SIGTERM must exit 0."""
    rep.begin("runtime: tessera serve --config tessera.conf")
    if ctx.serve_options is None:
        rep.skip(f"not started: {ctx.serve_skip_reason}")
        return
    conf = ctx.deploy / "tessera.conf"
    if not conf.is_file():
        rep.fail(f"{conf} is missing")
        return
    import signal
    import time
    with tempfile.TemporaryDirectory(prefix="tessera-serve-") as tmp:
        tmpdir = Path(tmp)
        stores = tmpdir / "stores"
        stores.mkdir()
        log = tmpdir / "serve.log"

        def start(config: Path, http_port: int) -> subprocess.Popen:
            # The listeners and the stores come from the command line (which wins over the file):
            # loopback, a free port, an empty directory.
            with open(log, "w") as out:
                return subprocess.Popen([str(ctx.tessera), "serve", "--config", str(config),
                                         "--store-dir", str(stores), "--grpc", "127.0.0.1:0",
                                         "--http", f"127.0.0.1:{http_port}"],
                                        stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

        def stop(proc: subprocess.Popen, timeout: float) -> int | None:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            try:
                return proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                return None

        def log_tail() -> str:
            return "\n".join(log.read_text(errors="replace").strip().splitlines()[-5:])

        # 1. Is the file read at all? A value the option's validator refuses must stop the server.
        probe = tmpdir / "probe.conf"
        probe.write_text("drain-timeout = -1\n")
        proc = start(probe, free_port())
        try:
            rc = proc.wait(timeout=5)  # a config error stops it while parsing, long before this
        except subprocess.TimeoutExpired:
            rc = None
        if rc is None:
            stop(proc, 15)
            rep.fail("`tessera serve --config FILE` ignores FILE: it started with `drain-timeout = -1` in it, "
                     "so tessera.conf (and the systemd unit) would have no effect. CLI11 reads set_config() "
                     "files on the main App only (CLIUtils/CLI11#1056); a subcommand must read its file itself.")
        elif rc != 0:
            rep.ok(f"--config FILE is read: an invalid drain-timeout in it is refused (status {rc})")
        else:
            rep.fail("`tessera serve` exited 0 at once with `drain-timeout = -1` in its config file:\n" + log_tail())

        # 2. The shipped file: starts, answers the probes' endpoints, drains on SIGTERM.
        port = free_port()
        proc = start(conf, port)
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 20
        ready = 0
        while time.monotonic() < deadline and proc.poll() is None:
            ready, _ = http_get(base + READY_PATH, timeout=1)
            if ready == 200:
                break
            time.sleep(0.2)
        if proc.poll() is not None:
            rep.fail(f"`tessera serve --config tessera.conf` exited with status {proc.returncode}:\n" + log_tail())
            return
        rep.check(ready == 200, f"{READY_PATH} answers 200 (stores loaded)", f"{READY_PATH} answered {ready}, "
                  "not 200, within 20 s")
        code, body = http_get(base + HEALTH_PATH)
        rep.check(code == 200, f"{HEALTH_PATH} answers 200", f"{HEALTH_PATH} answered {code}")
        code, body = http_get(base + "/metrics")
        rep.check(code == 200 and "# TYPE" in body, "/metrics answers Prometheus text",
                  f"/metrics answered {code}" + ("" if "# TYPE" in body else " without Prometheus text"))
        active = parse_conf(conf)[0]
        drain = int(active["drain-timeout"]) if re.fullmatch(r"\d+", active.get("drain-timeout", "")) else DEFAULT_DRAIN_MS
        rc = stop(proc, drain / 1000 + 10)
        rep.check(rc == 0, "SIGTERM: drains and exits 0",
                  f"after SIGTERM: status {rc if rc is not None else 'none (killed after the drain budget)'}:\n"
                  + log_tail())


# ---------------------------------------------------------------------------------------------
# (b) compose.yaml


def compose_port(entry) -> tuple[int, int | None] | None:
    """(container port, published port) of a compose ports entry."""
    if isinstance(entry, dict):
        try:
            return int(entry["target"]), int(entry["published"]) if "published" in entry else None
        except (KeyError, ValueError, TypeError):
            return None
    s = str(entry).split("/")[0]
    parts = s.rsplit(":", 2) if s.count(":") <= 2 else None
    if not parts or not all(re.fullmatch(r"\d+", p) for p in parts[-2:] if p) or not parts[-1]:
        return None
    return int(parts[-1]), int(parts[-2]) if len(parts) >= 2 and parts[-2] else None


def compose_volume(entry) -> tuple[str, str, bool] | None:
    """(source, target, read-only) of a compose volumes entry."""
    if isinstance(entry, dict):
        return str(entry.get("source", "")), str(entry.get("target", "")), bool(entry.get("read_only"))
    s = str(entry)
    m = re.fullmatch(r"(\$\{[^}]*\}|[^:]*):([^:]+)(?::([a-z,]+))?", s)
    if not m:
        return None
    return m.group(1), m.group(2), "ro" in (m.group(3) or "").split(",")


def healthcheck_port(cmd) -> tuple[str, int] | None:
    text = " ".join(cmd) if isinstance(cmd, list) else str(cmd)
    m = re.search(r"https?://[^/\s:]+:(\d+)(/\S*)", text)
    return (m.group(2), int(m.group(1))) if m else None


def check_compose(rep: Report, ctx: Context) -> None:
    rep.begin("compose: compose.yaml")
    path = ctx.deploy / "compose.yaml"
    if not path.is_file():
        rep.fail(f"{path} is missing")
        return
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        rep.fail(f"not valid YAML: {e}")
        return
    if not isinstance(doc, dict) or not isinstance(doc.get("services"), dict):
        rep.fail("no `services:` mapping")
        return
    rep.ok("parses; has services")
    services = doc["services"]
    t = services.get("tessera")
    if not isinstance(t, dict):
        rep.fail("no `tessera` service")
        return

    build = t.get("build")
    if isinstance(build, dict):
        context = (path.parent / str(build.get("context", "."))).resolve()
        dockerfile = context / str(build.get("dockerfile", "Dockerfile"))
        rep.check(context == ctx.deploy.resolve().parent, "build.context is the repository root (..)",
                  f"build.context {build.get('context')!r} is not the repository root (..)")
        rep.check(dockerfile.resolve() == (ctx.deploy / "Dockerfile").resolve(),
                  "build.dockerfile is deploy/Dockerfile",
                  f"build.dockerfile {build.get('dockerfile')!r} does not name deploy/Dockerfile")
    else:
        rep.fail("tessera: `build:` should be a mapping with context and dockerfile")
    if "image" in t:
        p = image_tag_problem(str(t["image"]))
        rep.check(p is None, f"tessera image {t['image']}", f"tessera image: {p}")

    command = t.get("command")
    opts = {}
    if isinstance(command, list):
        args = [str(a) for a in command]
        opts = check_serve_args(rep, "compose tessera command", args, in_container=True)
        ctx.serve_args.append(("compose.yaml tessera command", args))
    elif command is not None:
        rep.fail("tessera: `command:` should be a list (exec form), not a string")

    ports = [compose_port(p) for p in t.get("ports") or []]
    if any(p is None for p in ports) or not ports:
        rep.fail(f"tessera: unreadable or missing ports: {t.get('ports')}")
    else:
        ctx.compose_ports = {p[0] for p in ports}
        rep.check(ctx.compose_ports == {GRPC_PORT, HTTP_PORT},
                  f"tessera publishes container ports {sorted(ctx.compose_ports)}",
                  f"tessera container ports {sorted(ctx.compose_ports)}, expected {[GRPC_PORT, HTTP_PORT]}")

    vols = [compose_volume(v) for v in t.get("volumes") or []]
    stores = [v for v in vols if v and v[1] == STORE_DIR]
    if not stores:
        rep.fail(f"tessera: no volume mounted at {STORE_DIR}")
    else:
        src, _, ro = stores[0]
        rep.check(ro, f"stores mounted read-only at {STORE_DIR}", f"the {STORE_DIR} mount is not read-only (:ro)")
        rep.check("TESSERA_STORES" in src, f"store source {src}",
                  f"store source {src!r} should be ${{TESSERA_STORES:-./stores}}")

    hc = t.get("healthcheck")
    if not isinstance(hc, dict) or "test" not in hc:
        rep.fail("tessera: no healthcheck.test")
    else:
        hp = healthcheck_port(hc["test"])
        rep.check(hp is not None and hp[0] == HEALTH_PATH and hp[1] == HTTP_PORT,
                  f"healthcheck probes http://...:{HTTP_PORT}{HEALTH_PATH}",
                  f"healthcheck.test should fetch http://127.0.0.1:{HTTP_PORT}{HEALTH_PATH}: {hc['test']}")
        if isinstance(hc["test"], list):
            rep.check(hc["test"][:1] in (["CMD"], ["CMD-SHELL"]), "healthcheck.test is CMD form",
                      f"healthcheck.test must start with CMD or CMD-SHELL: {hc['test'][:1]}")
        for k in ("interval", "timeout", "start_period"):
            if k in hc:
                rep.check(parse_duration(hc[k]) is not None, f"healthcheck.{k} {hc[k]}",
                          f"healthcheck.{k} {hc[k]!r} is not a duration")
    rep.check(t.get("restart") == "unless-stopped", "restart: unless-stopped",
              f"restart is {t.get('restart')!r}, expected unless-stopped")
    grace = parse_duration(t.get("stop_grace_period", "10s"))
    if grace is None:
        rep.fail(f"stop_grace_period {t.get('stop_grace_period')!r} is not a duration")
    else:
        rep.check(drain_ms(opts) < grace * 1000,
                  f"drain-timeout {drain_ms(opts)} ms < stop_grace_period {grace:g} s",
                  f"drain-timeout {drain_ms(opts)} ms does not end before stop_grace_period {grace:g} s")
    sig = t.get("stop_signal", "SIGTERM")
    rep.check(sig in ("SIGTERM", "TERM", 15), f"stop_signal {sig}", f"stop_signal {sig!r}, expected SIGTERM")

    prom = services.get("prometheus")
    if not isinstance(prom, dict):
        rep.fail("no `prometheus` service")
    else:
        img = str(prom.get("image", ""))
        rep.check(img.startswith("prom/prometheus") and image_tag_problem(img) is None,
                  f"prometheus image {img}", f"prometheus image {img!r}: expected prom/prometheus:<pinned tag>"
                  + (f" ({image_tag_problem(img)})" if image_tag_problem(img) else ""))
        pvols = [compose_volume(v) for v in prom.get("volumes") or []]
        cfg = [v for v in pvols if v and Path(v[0]).name == "prometheus.yml"]
        if not cfg:
            rep.fail("prometheus: deploy/prometheus.yml is not mounted")
        else:
            rep.check((path.parent / cfg[0][0]).resolve() == (ctx.deploy / "prometheus.yml").resolve(),
                      f"prometheus mounts {cfg[0][0]} at {cfg[0][1]}",
                      f"prometheus mounts {cfg[0][0]!r}, not ./prometheus.yml beside compose.yaml")
            flags = [str(a) for a in prom.get("command") or []]
            cf = [a.split("=", 1)[1] for a in flags if a.startswith("--config.file=")]
            want = cf[-1] if cf else "/etc/prometheus/prometheus.yml"
            rep.check(cfg[0][1] == want, f"prometheus reads {want}",
                      f"prometheus mounts its config at {cfg[0][1]} but reads {want}")
        pports = [compose_port(p) for p in prom.get("ports") or []]
        rep.check(any(p and p[0] == 9090 for p in pports), "prometheus publishes 9090",
                  f"prometheus ports {prom.get('ports')} lack 9090")
    for name, s in services.items():
        for v in (s or {}).get("volumes") or []:
            cv = compose_volume(v)
            if cv and not cv[0].startswith(("/", ".", "$", "~")) and cv[0]:
                rep.check(cv[0] in (doc.get("volumes") or {}), f"{name}: named volume {cv[0]} declared",
                          f"{name}: named volume {cv[0]!r} is not declared under top-level volumes:")

    docker = shutil.which("docker")
    if docker and run([docker, "compose", "version"]).returncode == 0:
        p = run([docker, "compose", "-f", str(path), "config", "-q"], timeout=60)
        rep.check(p.returncode == 0, "docker compose config -q", f"docker compose config:\n{p.stderr.strip()}")
    else:
        rep.skip("docker compose not available: compose file not checked by Compose itself")


# ---------------------------------------------------------------------------------------------
# (c) prometheus.yml


def check_prometheus(rep: Report, ctx: Context) -> None:
    rep.begin("prometheus: prometheus.yml")
    path = ctx.deploy / "prometheus.yml"
    if not path.is_file():
        rep.fail(f"{path} is missing")
        return
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        rep.fail(f"not valid YAML: {e}")
        return
    if not isinstance(doc, dict) or not isinstance(doc.get("scrape_configs"), list):
        rep.fail("no scrape_configs list")
        return
    rep.ok("parses; has scrape_configs")
    names = [j.get("job_name") for j in doc["scrape_configs"] if isinstance(j, dict)]
    rep.check(len(names) == len(set(names)) and len(names) == len(doc["scrape_configs"]),
              "job names present and unique", f"job names missing or repeated: {names}")
    jobs = [j for j in doc["scrape_configs"] if isinstance(j, dict) and j.get("job_name") == "tessera"]
    if not jobs:
        rep.fail("no scrape config with job_name: tessera")
        return
    job = jobs[0]
    interval = job.get("scrape_interval", (doc.get("global") or {}).get("scrape_interval", "1m"))
    rep.check(parse_duration(interval) == 15, f"scrape_interval {interval}",
              f"scrape_interval {interval!r}, expected 15s")
    timeout = job.get("scrape_timeout", (doc.get("global") or {}).get("scrape_timeout", "10s"))
    if parse_duration(timeout) is not None and parse_duration(interval) is not None:
        rep.check(parse_duration(timeout) <= parse_duration(interval), f"scrape_timeout {timeout}",
                  f"scrape_timeout {timeout} exceeds scrape_interval {interval}")
    rep.check(job.get("metrics_path", "/metrics") == "/metrics", "metrics_path /metrics",
              f"metrics_path {job.get('metrics_path')!r}, expected /metrics")
    rep.check(job.get("scheme", "http") in ("http", "https"), f"scheme {job.get('scheme', 'http')}",
              f"scheme {job.get('scheme')!r}")
    targets = [t for sc in job.get("static_configs") or [] if isinstance(sc, dict)
               for t in sc.get("targets") or []]
    if not targets:
        rep.fail("job tessera has no static_configs targets")
    for t in targets:
        hp = host_port(str(t))
        rep.check(hp is not None and hp[0] != "" and not str(t).startswith(("http:", "https:")),
                  f"target {t} is HOST:PORT", f"target {t!r} is not HOST:PORT (no scheme, no path)")
    compose_hosts = {"tessera"}
    rep.check(any(host_port(str(t)) == ("tessera", HTTP_PORT) for t in targets),
              f"a target is tessera:{HTTP_PORT} (the compose service)",
              f"no target tessera:{HTTP_PORT}; compose names the service {sorted(compose_hosts)}")
    promtool = shutil.which("promtool")
    if promtool:
        p = run([promtool, "check", "config", str(path)])
        rep.check(p.returncode == 0, "promtool check config", f"promtool check config:\n{(p.stdout + p.stderr).strip()}")
    else:
        rep.skip("promtool not found: not checked by Prometheus itself")


# ---------------------------------------------------------------------------------------------
# (d) Kubernetes manifests


def check_kubernetes(rep: Report, ctx: Context) -> None:
    rep.begin("kubernetes: kubernetes/*.yaml")
    kdir = ctx.deploy / "kubernetes"
    files = sorted(p for p in kdir.glob("*") if p.suffix in (".yaml", ".yml")) if kdir.is_dir() else []
    if not files:
        rep.fail(f"no manifests in {kdir}")
        return
    docs: list[tuple[str, dict]] = []
    for f in files:
        try:
            loaded = [d for d in yaml.safe_load_all(f.read_text()) if d is not None]
        except yaml.YAMLError as e:
            rep.fail(f"{f.name}: not valid YAML: {e}")
            continue
        for i, d in enumerate(loaded):
            where = f"{f.name}[{i}]"
            if not isinstance(d, dict):
                rep.fail(f"{where}: not a mapping")
                continue
            missing = [k for k in ("apiVersion", "kind") if not d.get(k)]
            if not (d.get("metadata") or {}).get("name"):
                missing.append("metadata.name")
            if missing:
                rep.fail(f"{where}: missing {', '.join(missing)}")
                continue
            docs.append((f"{f.name} {d['kind']}/{d['metadata']['name']}", d))
    rep.ok(f"{len(files)} files, {len(docs)} documents with apiVersion, kind and metadata.name")
    kinds = lambda k: [(w, d) for w, d in docs if d["kind"] == k]  # noqa: E731
    pvcs = {d["metadata"]["name"]: d for _, d in kinds("PersistentVolumeClaim")}
    deployments = kinds("Deployment")
    if not deployments:
        rep.fail("no Deployment")
    pod_labels: list[dict] = []
    container_ports: dict[str, int] = {}  # name -> port, over all containers
    for where, d in deployments:
        spec = d.get("spec") or {}
        tmpl = spec.get("template") or {}
        labels = (tmpl.get("metadata") or {}).get("labels") or {}
        pod_labels.append(labels)
        sel = (spec.get("selector") or {}).get("matchLabels") or {}
        rep.check(sel and all(labels.get(k) == v for k, v in sel.items()),
                  f"{where}: selector matches the pod labels",
                  f"{where}: spec.selector.matchLabels {sel} does not match template labels {labels}")
        hpas = [h for _, h in kinds("HorizontalPodAutoscaler")
                if ((h.get("spec") or {}).get("scaleTargetRef") or {}).get("name") == d["metadata"]["name"]]
        if hpas:  # the autoscaler owns the replica count; a fixed one would be reset by every apply
            rep.check("replicas" not in spec, f"{where}: no fixed replicas (the HorizontalPodAutoscaler sets them)",
                      f"{where}: spec.replicas {spec.get('replicas')} fights the HorizontalPodAutoscaler: leave it out")
        else:
            rep.check(int(spec.get("replicas", 1)) >= 2, f"{where}: replicas {spec.get('replicas', 1)}",
                      f"{where}: replicas {spec.get('replicas', 1)}, expected at least 2")
        ann = (tmpl.get("metadata") or {}).get("annotations") or {}
        rep.check(ann.get("prometheus.io/scrape") == "true" and str(ann.get("prometheus.io/port")) == str(HTTP_PORT)
                  and ann.get("prometheus.io/path", "/metrics") == "/metrics",
                  f"{where}: prometheus.io/scrape, port {HTTP_PORT}, path /metrics annotations",
                  f"{where}: pod annotations should be prometheus.io/scrape: \"true\", prometheus.io/port: "
                  f"\"{HTTP_PORT}\", prometheus.io/path: /metrics (strings), got {ann}")
        pod = tmpl.get("spec") or {}
        psc = pod.get("securityContext") or {}
        volumes = {v.get("name"): v for v in pod.get("volumes") or []}
        for vname, v in volumes.items():
            claim = (v.get("persistentVolumeClaim") or {}).get("claimName")
            if claim:
                rep.check(claim in pvcs, f"{where}: volume {vname} claims {claim}",
                          f"{where}: volume {vname} claims {claim!r}, which no manifest defines")
                if claim in pvcs:
                    modes = (pvcs[claim].get("spec") or {}).get("accessModes") or []
                    rep.check("ReadOnlyMany" in modes, f"PVC {claim} is ReadOnlyMany",
                              f"PVC {claim} accessModes {modes}: the replicas share it read-only (ReadOnlyMany)")
        containers = pod.get("containers") or []
        if not containers:
            rep.fail(f"{where}: no containers")
        for c in containers:
            cw = f"{where} container {c.get('name')}"
            problem = image_tag_problem(str(c.get("image", "")))
            rep.check(problem is None, f"{cw}: image {c.get('image')}", f"{cw}: image {problem}")
            ports = {p.get("name"): int(p.get("containerPort", 0)) for p in c.get("ports") or []}
            container_ports.update(ports)
            rep.check(ports.get("grpc") == GRPC_PORT and ports.get("http") == HTTP_PORT,
                      f"{cw}: ports grpc {GRPC_PORT}, http {HTTP_PORT}",
                      f"{cw}: ports should be grpc {GRPC_PORT} and http {HTTP_PORT}, got {ports}")
            ctx.k8s_ports = set(ports.values())
            for probe, path in (("livenessProbe", HEALTH_PATH), ("readinessProbe", READY_PATH),
                                ("startupProbe", None)):
                pr = c.get(probe)
                if pr is None and path is None:
                    continue
                get = (pr or {}).get("httpGet") or {}
                want = path or get.get("path")
                ok = bool(get) and get.get("path") == want and want in (HEALTH_PATH, READY_PATH) and (
                    get.get("port") in ports or get.get("port") == HTTP_PORT or get.get("port") == "http")
                rep.check(ok, f"{cw}: {probe} GET {get.get('path')} on port {get.get('port')}",
                          f"{cw}: {probe} should be httpGet {path or HEALTH_PATH} on the http port, got {pr}")
            args = [str(a) for a in (c.get("command") or [])[2:] + (c.get("args") or [])]
            opts = check_serve_args(rep, cw + " args", args, in_container=True)
            ctx.serve_args.append((cw + " args", args))
            res = c.get("resources") or {}
            rep.check(bool(res.get("requests")) and bool(res.get("limits")) and "memory" in (res.get("limits") or {}),
                      f"{cw}: resource requests and limits (memory limit {(res.get('limits') or {}).get('memory')})",
                      f"{cw}: needs resources.requests and resources.limits with a memory limit")
            sc = c.get("securityContext") or {}
            non_root = sc.get("runAsNonRoot", psc.get("runAsNonRoot")) is True
            uid = sc.get("runAsUser", psc.get("runAsUser"))
            rep.check(non_root and uid not in (0, "0"), f"{cw}: runAsNonRoot (uid {uid})",
                      f"{cw}: runAsNonRoot must be true and runAsUser not 0")
            rep.check(sc.get("readOnlyRootFilesystem") is True, f"{cw}: readOnlyRootFilesystem",
                      f"{cw}: securityContext.readOnlyRootFilesystem must be true")
            rep.check(sc.get("allowPrivilegeEscalation") is False, f"{cw}: allowPrivilegeEscalation false",
                      f"{cw}: securityContext.allowPrivilegeEscalation must be false")
            mounts = {m.get("mountPath"): m for m in c.get("volumeMounts") or []}
            sm = mounts.get(STORE_DIR)
            rep.check(sm is not None and sm.get("readOnly") is True and sm.get("name") in volumes,
                      f"{cw}: stores volume mounted read-only at {STORE_DIR}",
                      f"{cw}: needs a readOnly volumeMount of a declared volume at {STORE_DIR}")
            # Drain: preStop sleep + --drain-timeout must end inside the grace period.
            grace = int(pod.get("terminationGracePeriodSeconds", 30))
            pre = (((c.get("lifecycle") or {}).get("preStop") or {}).get("exec") or {}).get("command") or []
            sleep = 0.0
            if pre[:1] == ["sleep"] and len(pre) == 2:
                sleep = parse_duration(str(pre[1])) or 0.0
            elif (((c.get("lifecycle") or {}).get("preStop") or {}).get("sleep") or {}).get("seconds"):
                sleep = float(c["lifecycle"]["preStop"]["sleep"]["seconds"])
            rep.check(sleep > 0, f"{cw}: preStop waits {sleep:g} s for endpoint removal",
                      f"{cw}: no preStop sleep: the pod gets SIGTERM while still in the Service endpoints")
            rep.check(sleep + drain_ms(opts) / 1000 < grace,
                      f"{cw}: preStop {sleep:g} s + drain {drain_ms(opts) / 1000:g} s < terminationGracePeriodSeconds {grace}",
                      f"{cw}: preStop {sleep:g} s + --drain-timeout {drain_ms(opts) / 1000:g} s do not fit in "
                      f"terminationGracePeriodSeconds {grace}")
    services = kinds("Service")
    if not services:
        rep.fail("no Service")
    # gRPC through a headless Service (every pod's address, for the clients' round robin), HTTP
    # through a ClusterIP one (kube-proxy spreads its short requests).
    headless = [w for w, s in services if (s.get("spec") or {}).get("clusterIP") == "None"
                and any(p.get("name") == "grpc" for p in (s.get("spec") or {}).get("ports") or [])]
    rep.check(bool(headless), f"headless Service for gRPC: {headless}",
              "no headless Service (clusterIP: None) with a grpc port: clients cannot balance over the pods")
    cluster = [w for w, s in services if (s.get("spec") or {}).get("clusterIP") != "None"
               and any(p.get("name") == "http" for p in (s.get("spec") or {}).get("ports") or [])]
    rep.check(bool(cluster), f"ClusterIP Service for HTTP: {cluster}", "no ClusterIP Service with an http port")
    for where, s in services:
        spec = s.get("spec") or {}
        sel = spec.get("selector") or {}
        rep.check(bool(sel) and any(all(l.get(k) == v for k, v in sel.items()) for l in pod_labels),
                  f"{where}: selector matches the Deployment's pods",
                  f"{where}: selector {sel} matches no Deployment pod labels")
        ports = {p.get("name"): p for p in spec.get("ports") or []}
        if not ports:
            rep.fail(f"{where}: no ports")
        for name, port, proto in (("grpc", GRPC_PORT, "grpc"), ("http", HTTP_PORT, None)):
            p = ports.get(name)
            if p is None:
                continue
            target = p.get("targetPort", p.get("port"))
            resolved = container_ports.get(target) if isinstance(target, str) else target
            rep.check(p.get("port") == port and resolved == port,
                      f"{where}: port {name} {p.get('port')} -> {target}",
                      f"{where}: port {name} should be {port} targeting container port {port}, got "
                      f"port {p.get('port')} targetPort {target!r}")
            if proto:
                rep.check(p.get("appProtocol") == proto, f"{where}: port {name} appProtocol {proto}",
                          f"{where}: port {name} should have appProtocol: {proto}")
    for where, h in kinds("HorizontalPodAutoscaler"):
        spec = h.get("spec") or {}
        ref = spec.get("scaleTargetRef") or {}
        names = [d["metadata"]["name"] for _, d in deployments]
        rep.check(h.get("apiVersion") == "autoscaling/v2" and ref.get("kind") == "Deployment" and ref.get("name") in names,
                  f"{where}: scales Deployment {ref.get('name')} (autoscaling/v2)",
                  f"{where}: scaleTargetRef {ref} is not one of the Deployments {names} (autoscaling/v2)")
        lo, hi = spec.get("minReplicas", 1), spec.get("maxReplicas", 0)
        rep.check(isinstance(lo, int) and isinstance(hi, int) and 2 <= lo <= hi, f"{where}: {lo} to {hi} replicas",
                  f"{where}: minReplicas {lo} / maxReplicas {hi}: expected 2 <= min <= max")
        metrics = spec.get("metrics") or []
        cpu = [m for m in metrics if ((m.get("resource") or {}).get("name")) == "cpu"]
        rep.check(bool(cpu), f"{where}: scales on CPU", f"{where}: no cpu resource metric")
        for _, d in deployments:
            for c in (((d.get("spec") or {}).get("template") or {}).get("spec") or {}).get("containers") or []:
                req = ((c.get("resources") or {}).get("requests") or {})
                rep.check("cpu" in req, f"{where}: container {c.get('name')} requests cpu (utilization needs it)",
                          f"{where}: container {c.get('name')} has no cpu request: CPU utilization is undefined")
    for where, k in kinds("Kustomization"):
        listed = [str(r) for r in k.get("resources") or []]
        missing = [r for r in listed if not (kdir / r).exists()]
        rep.check(not missing, f"{where}: resources exist", f"{where}: resources not found: {missing}")
        unlisted = [f.name for f in files if f.name not in listed and f.name != "kustomization.yaml"]
        rep.check(not unlisted, f"{where}: lists every manifest", f"{where}: manifests not listed: {unlisted}")
    kubectl = shutil.which("kubectl")
    if kubectl and (kdir / "kustomization.yaml").is_file():
        p = run([kubectl, "kustomize", str(kdir)], timeout=60)
        rep.check(p.returncode == 0, "kubectl kustomize renders the manifests (offline)",
                  f"kubectl kustomize:\n{p.stderr.strip()}")
    else:
        rep.skip("kubectl not found (or no kustomization.yaml): manifests not rendered by kustomize")


# ---------------------------------------------------------------------------------------------
# (e) Dockerfile


DOCKERFILE_INSTRUCTIONS = {
    "ADD", "ARG", "CMD", "COPY", "ENTRYPOINT", "ENV", "EXPOSE", "FROM", "HEALTHCHECK", "LABEL",
    "MAINTAINER", "ONBUILD", "RUN", "SHELL", "STOPSIGNAL", "USER", "VOLUME", "WORKDIR",
}


def dockerfile_instructions(text: str) -> list[tuple[int, str, str]]:
    """(line number, KEYWORD, arguments) per instruction: continuations joined, comments and
    heredoc bodies dropped."""
    lines = text.splitlines()
    escape = "\\"
    for line in lines:  # parser directives: only at the very top
        m = re.fullmatch(r"#\s*([a-zA-Z]+)\s*=\s*(\S+)\s*", line)
        if not m:
            break
        if m.group(1).lower() == "escape":
            escape = m.group(2)
    out: list[tuple[int, str, str]] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        start = i + 1
        i += 1
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        logical = line
        while logical.rstrip().endswith(escape) and i < len(lines):
            logical = logical.rstrip()[:-1]
            nxt = lines[i]
            i += 1
            if nxt.lstrip().startswith("#"):
                logical += escape  # comment lines inside a continuation are dropped
                continue
            logical += " " + nxt
        parts = logical.strip().split(None, 1)
        keyword = parts[0].upper()
        args = parts[1] if len(parts) > 1 else ""
        out.append((start, keyword, args))
        for m in re.finditer(r"<<(-?)([\"']?)([A-Za-z_][A-Za-z0-9_]*)\2", args if keyword in ("RUN", "COPY", "ADD") else ""):
            while i < len(lines):
                body = lines[i]
                i += 1
                if (body.strip() if m.group(1) else body) == m.group(3):
                    break
    return out


def expand_vars(s: str, env: dict[str, str]) -> str:
    def sub(m):
        name = m.group(1) or m.group(3)
        default = m.group(2)
        val = env.get(name)
        if val in (None, "") and default is not None:
            return default
        return val if val is not None else m.group(0)
    return re.sub(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}|\$([A-Za-z_][A-Za-z0-9_]*)", sub, s)


def json_array(args: str) -> list[str] | None:
    try:
        v = json.loads(args)
    except ValueError:
        return None
    return v if isinstance(v, list) and all(isinstance(x, str) for x in v) else None


def check_dockerfile(rep: Report, ctx: Context) -> None:
    rep.begin("dockerfile: Dockerfile")
    path = ctx.deploy / "Dockerfile"
    if not path.is_file():
        rep.fail(f"{path} is missing")
        return
    instrs = dockerfile_instructions(path.read_text())
    bad = [(n, k) for n, k, _ in instrs if k not in DOCKERFILE_INSTRUCTIONS]
    for n, k in bad:
        rep.fail(f"line {n}: unknown instruction {k!r}")
    for n, k, a in instrs:
        if k == "ONBUILD":
            inner = a.split(None, 1)[0].upper() if a.strip() else ""
            if inner not in DOCKERFILE_INSTRUCTIONS or inner in ("ONBUILD", "FROM", "MAINTAINER"):
                rep.fail(f"line {n}: ONBUILD {inner!r} is not allowed")
    if not bad:
        rep.ok(f"{len(instrs)} instructions, all valid keywords")
    if not instrs:
        rep.fail("no instructions")
        return
    first_non_arg = next((k for _, k, _ in instrs if k != "ARG"), None)
    rep.check(first_non_arg == "FROM", "the first instruction is FROM (ARG allowed before it)",
              f"the first instruction after any ARG is {first_non_arg}, not FROM")

    global_args: dict[str, str] = {}
    stages: list[dict] = []  # name, image, index, instrs
    seen_from = False
    for n, k, a in instrs:
        if k == "ARG" and not seen_from:
            for tok in shlex.split(a):
                name, _, default = tok.partition("=")
                global_args[name] = default
        if k == "FROM":
            seen_from = True
            toks = [t for t in a.split() if not t.startswith("--")]
            if not toks:
                rep.fail(f"line {n}: FROM without an image")
                continue
            image = expand_vars(toks[0], global_args)
            name = None
            if len(toks) == 3 and toks[1].upper() == "AS":
                name = toks[2].lower()
            elif len(toks) != 1:
                rep.fail(f"line {n}: FROM should be `FROM IMAGE [AS NAME]`: {a!r}")
            if name and any(s["name"] == name for s in stages):
                rep.fail(f"line {n}: stage name {name!r} used twice")
            prior = {s["name"] for s in stages if s["name"]}
            if image.lower() in prior:
                rep.ok(f"line {n}: FROM stage {image}")
            else:
                problem = image_tag_problem(image)
                rep.check(problem is None, f"line {n}: FROM {image}" + (f" AS {name}" if name else ""),
                          f"line {n}: base image {problem}")
            stages.append({"name": name, "image": image, "line": n, "instrs": []})
        elif stages:
            stages[-1]["instrs"].append((n, k, a))
    rep.check(len(stages) >= 2, f"{len(stages)} build stages (multi-stage)",
              f"{len(stages)} FROM stage(s): expected a builder stage and a runtime stage")

    for idx, st in enumerate(stages):
        for n, k, a in st["instrs"]:
            if k not in ("COPY", "ADD"):
                continue
            m = re.search(r"--from=(\S+)", a)
            if not m:
                continue
            ref = m.group(1).lower()
            earlier = [s["name"] for s in stages[:idx]]
            ok = ref in earlier or (ref.isdigit() and int(ref) < idx)
            rep.check(ok, f"line {n}: COPY --from={m.group(1)} names an earlier stage",
                      f"line {n}: COPY --from={m.group(1)}: no earlier stage of that name "
                      f"(stages before it: {[s for s in earlier if s]})")

    if not stages:
        return
    final = stages[-1]
    fin = lambda key: [(n, a) for n, k, a in final["instrs"] if k == key]  # noqa: E731
    # The runtime stage: what it exposes, runs and checks.
    ports: set[int] = set()
    for n, a in fin("EXPOSE"):
        for tok in a.split():
            m = re.fullmatch(r"(\d+)(/(tcp|udp))?", tok)
            if not m:
                rep.fail(f"line {n}: EXPOSE {tok!r} is not PORT[/tcp|udp]")
            else:
                ports.add(int(m.group(1)))
    ctx.expose_ports = ports
    rep.check(ports == {GRPC_PORT, HTTP_PORT}, f"EXPOSE {' '.join(map(str, sorted(ports)))}",
              f"EXPOSE {sorted(ports)}, expected {[GRPC_PORT, HTTP_PORT]}")
    users = fin("USER")
    user = users[-1][1].split(":")[0].strip() if users else "root"
    rep.check(user not in ("root", "0", ""), f"runs as USER {users[-1][1] if users else ''}",
              "the final stage runs as root: add USER (a numeric uid lets Kubernetes check runAsNonRoot)")
    vols = " ".join(a for _, a in fin("VOLUME"))
    rep.check(STORE_DIR in vols, f"VOLUME {STORE_DIR}", f"no VOLUME {STORE_DIR}")
    sig = fin("STOPSIGNAL")
    rep.check(bool(sig) and sig[-1][1].strip() in ("SIGTERM", "15", "TERM"), "STOPSIGNAL SIGTERM",
              f"STOPSIGNAL should be SIGTERM, got {sig[-1][1] if sig else None!r}")
    hcs = fin("HEALTHCHECK")
    if not hcs:
        rep.fail("no HEALTHCHECK")
    else:
        n, a = hcs[-1]
        m = re.search(r"\bCMD\b\s*(.*)$", a)
        cmd = m.group(1) if m else ""
        arr = json_array(cmd) if cmd.startswith("[") else None
        if cmd.startswith("[") and arr is None:
            rep.fail(f"line {n}: HEALTHCHECK CMD is not a valid JSON array")
        hp = healthcheck_port(arr if arr is not None else cmd)
        rep.check(hp is not None and hp[0] == HEALTH_PATH and hp[1] == HTTP_PORT,
                  f"HEALTHCHECK fetches :{HTTP_PORT}{HEALTH_PATH}",
                  f"line {n}: HEALTHCHECK should fetch http://127.0.0.1:{HTTP_PORT}{HEALTH_PATH}: {a!r}")
        tool = (arr[0] if arr else cmd.split()[0] if cmd.split() else "")
        if tool == "curl":
            installs = " ".join(a for _, k, a in [(n2, k2, a2) for n2, k2, a2 in final["instrs"]] if k == "RUN")
            rep.check(re.search(r"\bcurl\b", installs) is not None, "curl is installed in the runtime stage",
                      "HEALTHCHECK uses curl but the runtime stage never installs it")
        for flag in re.findall(r"--(interval|timeout|start-period|start-interval)=(\S+)", a):
            rep.check(parse_duration(flag[1]) is not None, f"HEALTHCHECK --{flag[0]}={flag[1]}",
                      f"line {n}: HEALTHCHECK --{flag[0]}={flag[1]} is not a duration")
    ep = fin("ENTRYPOINT")
    ep_arr = json_array(ep[-1][1]) if ep else None
    rep.check(ep_arr == ["tessera-server", "serve"], 'ENTRYPOINT ["tessera-server", "serve"] (exec form: signals reach it)',
              f"ENTRYPOINT should be [\"tessera-server\", \"serve\"] in exec form, got {ep[-1][1] if ep else None!r}")
    cmds = fin("CMD")
    cmd_arr = json_array(cmds[-1][1]) if cmds else None
    if cmd_arr is None:
        rep.fail(f"CMD should be a JSON array of `tessera serve` arguments, got {cmds[-1][1] if cmds else None!r}")
    else:
        check_serve_args(rep, "CMD", cmd_arr, in_container=True)
        ctx.serve_args.append(("Dockerfile CMD", cmd_arr))
    for n, k, a in instrs:
        if k in ("CMD", "ENTRYPOINT", "SHELL") and a.strip().startswith("[") and json_array(a) is None:
            rep.fail(f"line {n}: {k} looks like exec form but is not a JSON array of strings")

    check_dockerignore(rep, ctx)


def dockerignore_regex(pattern: str) -> re.Pattern:
    p = pattern.strip().lstrip("/")
    p = os.path.normpath(p) if p else p
    out = ""
    i = 0
    while i < len(p):
        c = p[i]
        if p.startswith("**/", i):
            out += "(?:.*/)?"
            i += 3
        elif p.startswith("**", i):
            out += ".*"
            i += 2
        elif c == "*":
            out += "[^/]*"
            i += 1
        elif c == "?":
            out += "[^/]"
            i += 1
        elif c == "[":
            j = p.find("]", i)
            if j < 0:
                out += re.escape(c)
                i += 1
            else:
                out += "[" + p[i + 1:j].replace("\\", "\\\\") + "]"
                i = j + 1
        else:
            out += re.escape(c)
            i += 1
    return re.compile(out + r"(?:/.*)?\Z")  # a match on a directory excludes what is inside


def check_dockerignore(rep: Report, ctx: Context) -> None:
    ign = ctx.deploy / "Dockerfile.dockerignore"
    root = ctx.deploy.resolve().parent
    if not ign.is_file():
        if not (root / ".dockerignore").is_file():
            rep.fail("no deploy/Dockerfile.dockerignore nor .dockerignore: the whole tree (build/ too) "
                     "goes into the build context")
        return
    rules = []
    for line in ign.read_text().splitlines():
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        neg = s.startswith("!")
        rules.append((neg, dockerignore_regex(s[1:] if neg else s), s))
    # Tracked files and new ones not yet added (but not ignored ones such as build/).
    p = (run(["git", "-C", str(root), "ls-files", "--cached", "--others", "--exclude-standard"])
         if shutil.which("git") and (root / ".git").exists() else None)
    if p is not None and p.returncode == 0 and p.stdout.strip():
        files = p.stdout.splitlines()
    else:  # not a git checkout (a copy, a source archive): every file .gitignore does not name
        patterns = [ln.strip() for ln in (root / ".gitignore").read_text().splitlines()
                    if ln.strip() and not ln.startswith("#")] if (root / ".gitignore").is_file() else []

        def ignored(rel: str, name: str, is_dir: bool) -> bool:
            for pat in patterns:
                anchored, dir_only = pat.startswith("/"), pat.endswith("/")
                body = pat.strip("/")
                if dir_only and not is_dir:
                    continue
                if fnmatch.fnmatch(name, body) and (not anchored or rel == "."):
                    return True
            return False

        files = []
        for dirpath, dirnames, filenames in os.walk(root):
            rel = os.path.relpath(dirpath, root)
            dirnames[:] = [d for d in dirnames if d != ".git" and not ignored(rel, d, True)]
            files += [os.path.normpath(os.path.join(rel, f)) for f in filenames if not ignored(rel, f, False)]
    needed = [f for f in files if not f.startswith(("deploy/", ".ci/", "docs/", ".git"))
              and f not in ("README.md", ".gitignore")]
    excluded = []
    for f in needed:
        out = False
        for neg, rx, _ in rules:
            if rx.match(f):
                out = not neg
        if out:
            excluded.append(f)
    rep.check(not excluded, f"Dockerfile.dockerignore keeps all {len(needed)} source files in the context",
              "Dockerfile.dockerignore drops source files the build needs: " + ", ".join(excluded[:10])
              + (" ..." if len(excluded) > 10 else ""))
    for probe in ("build/CMakeCache.txt", ".git/HEAD"):
        hit = False
        for neg, rx, _ in rules:
            if rx.match(probe):
                hit = not neg
        rep.check(hit, f"Dockerfile.dockerignore leaves out {probe.split('/')[0]}/",
                  f"Dockerfile.dockerignore does not leave out {probe.split('/')[0]}/")


# ---------------------------------------------------------------------------------------------
# Cross-file consistency


def check_cross(rep: Report, ctx: Context) -> None:
    rep.begin("cross: ports and `tessera serve` flags")
    sets = {"Dockerfile EXPOSE": ctx.expose_ports, "compose ports": ctx.compose_ports,
            "Kubernetes containerPorts": ctx.k8s_ports}
    known = {k: v for k, v in sets.items() if v}
    if len(known) >= 2:
        first = next(iter(known.values()))
        rep.check(all(v == first for v in known.values()),
                  "the same ports everywhere: " + ", ".join(f"{k} {sorted(v)}" for k, v in known.items()),
                  "ports differ: " + ", ".join(f"{k} {sorted(v)}" for k, v in known.items()))
    if ctx.serve_options is None:
        rep.skip(f"`tessera serve` flags not checked: {ctx.serve_skip_reason}")
        return
    rep.ok(f"`tessera serve --help` lists {len(ctx.serve_options)} long options")
    for where, args in ctx.serve_args:
        check_options_known(rep, ctx, where, option_values(args).keys())


# ---------------------------------------------------------------------------------------------


def main() -> int:
    here = Path(__file__).resolve().parent
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--deploy-dir", type=Path, default=here.parent / "deploy",
                    help="the deploy/ directory to lint (default: the one beside tests/)")
    ap.add_argument("--tessera", type=Path, default=None,
                    help="the tessera binary: the unit's ExecStart is pointed at it for systemd-analyze "
                         "verify, and `serve --help` checks the flags (default: $TESSERA_BINARY, else "
                         "build/tessera when it exists)")
    args = ap.parse_args()
    tessera = args.tessera
    if tessera is None and os.environ.get("TESSERA_BINARY"):
        tessera = Path(os.environ["TESSERA_BINARY"])
    if tessera is None and (here.parent / "build" / "tessera").is_file():
        tessera = here.parent / "build" / "tessera"
    deploy = args.deploy_dir
    if not deploy.is_dir():
        print(f"deploy_lint: FAIL: {deploy} is not a directory")
        return 1
    ctx = Context(deploy, tessera.resolve() if tessera else None)
    load_serve_options(ctx)
    print(f"deploy_lint: {deploy.resolve()}; binary: {ctx.tessera or 'none'}"
          + ("" if ctx.serve_options is not None else f" ({ctx.serve_skip_reason})"))
    rep = Report()
    if ctx.tessera is not None and ctx.serve_options is None:
        # A binary was named (ctest always names one): the checks that need it must run.
        rep.begin("binary")
        rep.fail(f"--tessera given but unusable: {ctx.serve_skip_reason}")
    for check in (check_systemd, check_conf, check_serve_runtime, check_compose, check_prometheus, check_kubernetes,
                  check_dockerfile, check_cross):
        try:
            check(rep, ctx)
        except Exception as e:  # a malformed file must read as a lint failure, not a traceback
            rep.fail(f"internal error while checking ({type(e).__name__}: {e})")
    print()
    if rep.failures:
        print(f"deploy_lint: {len(rep.failures)} failure(s), {len(rep.skips)} skipped:")
        for f in rep.failures:
            print(f"  - {f}")
        return 1
    print(f"deploy_lint: OK ({len(rep.skips)} check(s) skipped, see SKIP above)" if rep.skips
          else "deploy_lint: OK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
