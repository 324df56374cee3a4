#!/usr/bin/env bash
# Serving benchmark: `tessera serve` (gRPC StreamTiles and HTTP) against nginx serving the same
# tiles as static files, on this machine, in one run, interleaved (the machine is shared and
# noisy: compare ratios, not absolute numbers). By default both servers, wrk and the load
# generator share the same cores, unpinned; SERVER_CPUS and LOAD_CPUS (below) keep them apart.
#
#  1. peak throughput, ROUNDS interleaved rounds of SECONDS each:
#       nginx        wrk -t2 -c64 (random tile URLs, bench/wrk_tiles.lua)
#       tessera HTTP wrk -t2 -c64, the same URLs
#       floor        wrk -t2 -c64, the same URLs from bench/floor_server: the tiles in memory, one recv
#                    and one send per request and nothing else, so what any HTTP server could reach
#                    here in the same minutes (peak only)
#       tessera gRPC serve_load --rate 0 (closed loop: PEAK_VIEWERS streams, outstanding set topped up to WINDOW)
#  2. latency under an open-model load (fixed offered rate; latency from the scheduled send time)
#     at half of each one's own median peak, with serve_load: HTTP for nginx and tessera
#     (64 keep-alive connections), gRPC for tessera (VIEWERS viewers ticking at 60 Hz); and gRPC
#     once more with the peak's PEAK_VIEWERS, whose frames each ask for 4x as many tiles (bursts).
#  3. the same, all three at one common rate (the lowest of the three half-peaks): latency at equal load.
# Why two viewer counts: the closed loop needs few, deep streams to find the server's peak, but at
# half of it 4 viewers each ask for ~440 tiles per 60 Hz frame, and a tile's latency then includes
# serving the rest of its frame's burst. 16 viewers (~110 tiles per frame each) is still far more
# than a real viewer asks for; both results are reported.
# Prints a table and writes WORKDIR/results.json (every run's JSON under WORKDIR/runs/).
#
#   bench/serve_vs_nginx.sh [ROUNDS] [SECONDS] [WORKDIR]      defaults: 3 10 build/bench-serve
#   env: PEAK_VIEWERS (4), WINDOW (512), VIEWERS (16), CONNECTIONS (64), TESSERA, SERVE_LOAD, EXPORT_TILES,
#        FLOOR_SERVER, FLOOR_ARGS (e.g. --uring: the floor through io_uring, where built with liburing;
#        --sendfile: payloads by sendfile(2)),
#        SERVER_CPUS and LOAD_CPUS (taskset CPU lists, both or neither; e.g. 0-1 and 2-15): on a
#        machine with cores to spare, the servers run on the first and wrk and serve_load on the
#        second, so that the load tools take no CPU from the servers; each server then runs one
#        loop (nginx: one worker) per server CPU and wrk one thread per load CPU (at most 16)
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
secs=${2:-10}
work=$(realpath -m "${3:-build/bench-serve}")
peak_viewers=${PEAK_VIEWERS:-4}
server_cpus=${SERVER_CPUS:-}
load_cpus=${LOAD_CPUS:-}
viewers=${VIEWERS:-16}
window=${WINDOW:-512}
conns=${CONNECTIONS:-64}
tessera=${TESSERA:-build/tessera}
load=${SERVE_LOAD:-build/bench/serve_load}
exporter=${EXPORT_TILES:-build/bench/export_tiles}
floor=${FLOOR_SERVER:-build/bench/floor_server}
read -r -a floor_args <<< "${FLOOR_ARGS:-}"
# Unpinned (the default): servers and load tools share every core. Pinned: taskset prefixes, and
# thread counts from the sizes of the CPU lists.
server_pin=(); load_pin=(); server_threads=$(nproc); ngx_workers=auto; wrk_threads=2; grpc_client_threads=1
tsr_threads=()  # unpinned: tessera's own defaults (one loop and one reader per core)
placement="$(nproc) cores; servers, wrk and serve_load all share them"
if [ -n "$server_cpus$load_cpus" ]; then
  [ -n "$server_cpus" ] && [ -n "$load_cpus" ] || { echo "SERVER_CPUS and LOAD_CPUS go together" >&2; exit 2; }
  # Each list: CPUs this process may use, none in both (taskset itself drops CPUs that do not exist).
  read -r server_threads load_threads < <(python3 - "$server_cpus" "$load_cpus" <<'PY'
import os, sys
def cpus(name, text):
    out = set()
    try:
        for part in text.split(","):
            lo, _, hi = part.partition("-")
            out |= set(range(int(lo), int(hi or lo) + 1))
    except ValueError:
        sys.exit(f"{name}: not a CPU list (like 0-1,4): {text}")
    if not out:
        sys.exit(f"{name}: no CPUs in {text}")
    missing = sorted(out - os.sched_getaffinity(0))
    if missing:
        sys.exit(f"{name}: CPUs {missing} are not among this machine's usable CPUs {sorted(os.sched_getaffinity(0))}")
    return out
s, l = cpus("SERVER_CPUS", sys.argv[1]), cpus("LOAD_CPUS", sys.argv[2])
if s & l:
    sys.exit(f"SERVER_CPUS and LOAD_CPUS share CPUs {sorted(s & l)}: the point is to keep them apart")
print(len(s), len(l))
PY
  ) || true
  [ -n "${load_threads:-}" ] || exit 2
  server_pin=(taskset -c "$server_cpus"); load_pin=(taskset -c "$load_cpus")
  ngx_workers=$server_threads
  wrk_threads=$(( load_threads < 16 ? load_threads : 16 ))
  wrk_threads=$(( wrk_threads < conns ? wrk_threads : conns ))  # wrk needs a connection per thread
  tsr_threads=(--http-threads "$server_threads" --io-threads "$server_threads")
  grpc_client_threads=$load_threads
  placement="servers on CPUs $server_cpus ($server_threads), wrk and serve_load on CPUs $load_cpus ($load_threads)"
fi
for b in "$tessera" "$load" "$exporter" "$floor"; do
  [ -x "$b" ] || { echo "build first: ninja -C build tessera serve_load export_tiles floor_server ($b missing)" >&2; exit 1; }
done
command -v nginx >/dev/null || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq nginx-light >/dev/null; }
command -v wrk >/dev/null || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq wrk >/dev/null; }
mkdir -p "$work/runs" "$work/nginx/tmp"
rm -f "$work"/runs/*.json

store="$work/terrain.tsr"
static="$work/static"
urls="$static/urls.txt"
[ -f "$store" ] || "$tessera" build procedural:terrain:16384 -o "$store" -q
if [ ! -f "$urls" ] || [ "$urls" -ot "$store" ]; then
  rm -rf "$static"
  "$exporter" "$store" "$static"
fi

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

# ---- nginx: a minimal static file server on 127.0.0.1 -------------------------------------------
ngx_port=$(free_port)
cat > "$work/nginx/nginx.conf" <<EOF
worker_processes $ngx_workers;
user root;
daemon off;
pid $work/nginx/nginx.pid;
error_log $work/nginx/error.log warn;
events { worker_connections 4096; }
http {
  default_type image/jpeg;
  sendfile on;
  tcp_nopush on;
  tcp_nodelay on;
  access_log off;
  keepalive_timeout 65;
  keepalive_requests 1000000;
  open_file_cache max=16384 inactive=60s;
  open_file_cache_valid 60s;
  client_body_temp_path $work/nginx/tmp/body;
  proxy_temp_path $work/nginx/tmp/proxy;
  fastcgi_temp_path $work/nginx/tmp/fastcgi;
  uwsgi_temp_path $work/nginx/tmp/uwsgi;
  scgi_temp_path $work/nginx/tmp/scgi;
  server {
    listen 127.0.0.1:$ngx_port;
    # The exported files sit at $static/{name}/tiles/{level}/{x}/{y}: tessera's URLs map onto them.
    location /v1/stores/ { alias $static/; }
  }
}
EOF
"${server_pin[@]}" nginx -c "$work/nginx/nginx.conf" -e "$work/nginx/error.log" &
ngx_pid=$!

# ---- tessera serve --------------------------------------------------------------------------------
"${server_pin[@]}" "$tessera" serve --store "$store" --grpc 127.0.0.1:0 --http 127.0.0.1:0 "${tsr_threads[@]}" \
  2> "$work/tessera.log" &
tsr_pid=$!
"${server_pin[@]}" "$floor" "$static" --threads "$server_threads" "${floor_args[@]}" > "$work/floor.log" 2>&1 &
floor_pid=$!
# SIGTERM; SIGKILL (said so) if one is still there 15 s later (tessera drains for up to 10 s).
stop() {  # pid name
  kill "$1" 2>/dev/null || return 0
  for _ in $(seq 1 75); do kill -0 "$1" 2>/dev/null || { wait "$1" 2>/dev/null || true; return 0; }; sleep 0.2; done
  echo "warning: $2 (pid $1) did not exit within 15 s of SIGTERM; killed" >&2
  kill -KILL "$1" 2>/dev/null || true
  wait "$1" 2>/dev/null || true
}
cleanup() {
  stop "$tsr_pid" "tessera serve"
  stop "$ngx_pid" nginx
  stop "$floor_pid" floor_server
}
trap cleanup EXIT

listening=""
for _ in $(seq 1 100); do
  listening=$(grep -m1 '"msg":"listening"' "$work/tessera.log" || true)
  [ -n "$listening" ] && break
  sleep 0.1
done
[ -n "$listening" ] || { echo "tessera serve did not start:" >&2; cat "$work/tessera.log" >&2; exit 1; }
tsr_http=$(sed -E 's/.*"http":"([^"]*)".*/\1/' <<< "$listening")
tsr_grpc=$(sed -E 's/.*"grpc":"([^"]*)".*/\1/' <<< "$listening")
ngx_http="127.0.0.1:$ngx_port"
for _ in $(seq 1 300); do grep -q '^listening' "$work/floor.log" && break; sleep 0.1; done
grep -q '^listening' "$work/floor.log" || { echo "floor_server did not start:" >&2; cat "$work/floor.log" >&2; exit 1; }
floor_http=$(sed -nE 's/^listening ([0-9.]+:[0-9]+).*/\1/p' "$work/floor.log")
for _ in $(seq 1 100); do curl -sf -o /dev/null "http://$ngx_http$(head -1 "$urls")" && break; sleep 0.1; done

# All serve the same bytes under the same URLs.
for u in $(shuf -n 20 --random-source=<(yes) "$urls"); do
  cmp -s <(curl -sf "http://$ngx_http$u") <(curl -sf "http://$tsr_http$u") || { echo "nginx and tessera differ on $u" >&2; exit 1; }
  cmp -s <(curl -sf "http://$ngx_http$u") <(curl -sf "http://$floor_http$u") || { echo "nginx and floor_server differ on $u" >&2; exit 1; }
done
echo "nginx $ngx_http (pid $ngx_pid), tessera serve http $tsr_http grpc $tsr_grpc (pid $tsr_pid), floor $floor_http (pid $floor_pid); $(wc -l < "$urls") tiles"
echo "$placement"

# CPU seconds (user + system) used so far by a process and its children's threads (nginx: workers).
cpu_of() {
  local total=0 p
  for p in "$1" $(ps -o pid= --ppid "$1"); do
    [ -r "/proc/$p/stat" ] || continue
    total=$((total + $(awk '{print $14 + $15}' "/proc/$p/stat")))
  done
  echo "$total"
}
hz=$(getconf CLK_TCK)
busy_all() { awk '/^cpu /{print $2 + $3 + $4 + $7 + $8 + $9; exit}' /proc/stat; }  # every process, in ticks
# GNU time on PATH (type -P skips the shell's keyword), else Debian's package.
timer=$(type -P time || true)
[ -n "$timer" ] || { apt-get update -qq && apt-get install -y -qq time >/dev/null && timer=/usr/bin/time; }

# run NAME SERVER_PID COMMAND...: runs it, saves its JSON as runs/NAME.json with the CPU seconds
# the server, the load tool and everything else on the machine (other_cpu_s: noise) used meanwhile.
run() {
  local name=$1 pid=$2; shift 2
  local out="$work/runs/$name.json" c0 c1 b0 b1 t0 t1 log
  c0=$(cpu_of "$pid"); b0=$(busy_all); t0=$(date +%s.%N)
  log=$("$timer" -f 'CLIENT_CPU %U %S' "$@" 2>&1) || { echo "$log" >&2; exit 1; }
  c1=$(cpu_of "$pid"); b1=$(busy_all); t1=$(date +%s.%N)
  local json client
  if grep -q '^WRK_JSON ' <<< "$log"; then json=$(grep -m1 '^WRK_JSON ' <<< "$log" | cut -d' ' -f2-); else json=$(cat "$out.tmp"); rm -f "$out.tmp"; fi
  client=$(grep -m1 '^CLIENT_CPU ' <<< "$log" | awk '{print $2 + $3}')
  python3 - "$out" "$(( c1 - c0 ))" "$(( b1 - b0 ))" "$hz" "$client" "$t0" "$t1" "$json" <<'PY'
import json, sys
out, ticks, busy, hz, client, t0, t1, text = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]), float(sys.argv[6]), float(sys.argv[7]), sys.argv[8]
j = json.loads(text)
j["run_wall_s"] = t1 - t0
j["server_cpu_s"] = ticks / hz
j["client_cpu_s"] = client
j["other_cpu_s"] = max(0.0, busy / hz - ticks / hz - client)
json.dump(j, open(out, "w"))
PY
  echo "  $name: $(grep -v '^{' <<< "$log" | grep -E 'tiles/s|Requests/sec' | head -1 | sed 's/^ *//')"
}
wrk_run() {  # name pid host:port
  run "$1" "$2" "${load_pin[@]}" wrk -t"$wrk_threads" -c"$conns" -d"${secs}s" -s bench/wrk_tiles.lua "http://$3" -- "$urls" "$r"
}
grpc_peak() {
  run "$1" "$tsr_pid" "${load_pin[@]}" "$load" --grpc "$tsr_grpc" --store terrain --url-file "$urls" --rate 0 --duration "$secs" \
    --warmup 1 --viewers "$peak_viewers" --window "$window" --client-threads "$grpc_client_threads" --seed "$r" \
    --json "$work/runs/$1.json.tmp"
}

echo "warm-up (page cache, open file cache, tessera's tile cache)"
r=0
"${load_pin[@]}" wrk -t"$wrk_threads" -c"$conns" -d3s -s bench/wrk_tiles.lua "http://$ngx_http" -- "$urls" 0 >/dev/null
"${load_pin[@]}" wrk -t"$wrk_threads" -c"$conns" -d3s -s bench/wrk_tiles.lua "http://$tsr_http" -- "$urls" 0 >/dev/null
"${load_pin[@]}" wrk -t"$wrk_threads" -c"$conns" -d1s -s bench/wrk_tiles.lua "http://$floor_http" -- "$urls" 0 >/dev/null
"${load_pin[@]}" "$load" --grpc "$tsr_grpc" --store terrain --url-file "$urls" --rate 0 --duration 2 --warmup 0 --json /dev/null >/dev/null

echo "peak throughput: $rounds rounds of ${secs}s, interleaved"
for r in $(seq 1 "$rounds"); do
  if [ $((r % 2)) = 1 ]; then
    wrk_run "peak-nginx-$r" "$ngx_pid" "$ngx_http"; wrk_run "peak-tessera-http-$r" "$tsr_pid" "$tsr_http"
    wrk_run "peak-floor-$r" "$floor_pid" "$floor_http"; grpc_peak "peak-tessera-grpc-$r"
  else
    grpc_peak "peak-tessera-grpc-$r"; wrk_run "peak-floor-$r" "$floor_pid" "$floor_http"
    wrk_run "peak-tessera-http-$r" "$tsr_pid" "$tsr_http"; wrk_run "peak-nginx-$r" "$ngx_pid" "$ngx_http"
  fi
done

# Half of each one's own median peak.
read -r half_ngx half_http half_grpc < <(python3 - "$work/runs" <<'PY'
import json, glob, statistics, sys, os
d = sys.argv[1]
def peak(kind):
    vals = []
    for f in glob.glob(os.path.join(d, f"peak-{kind}-*.json")):
        j = json.load(open(f))
        vals.append(j["requests"] / (j["duration_us"] / 1e6) if "requests" in j else j["tiles_per_s"])
    return statistics.median(vals)
print(*(round(peak(k) / 2) for k in ("nginx", "tessera-http", "tessera-grpc")))
PY
)
http_open() {  # name pid host:port rate
  run "$1" "$2" "${load_pin[@]}" "$load" --http "$3" --url-file "$urls" --rate "$4" --duration "$secs" --warmup 1 \
    --connections "$conns" --seed "$r" --json "$work/runs/$1.json.tmp"
}
grpc_open() {  # name rate [viewers]
  run "$1" "$tsr_pid" "${load_pin[@]}" "$load" --grpc "$tsr_grpc" --store terrain --url-file "$urls" --rate "$2" --duration "$secs" \
    --warmup 1 --viewers "${3:-$viewers}" --client-threads "$grpc_client_threads" --seed "$r" --json "$work/runs/$1.json.tmp"
}
echo "open-model latency at half of each peak (nginx $half_ngx/s, tessera HTTP $half_http/s, gRPC $half_grpc/s)"
for r in $(seq 1 "$rounds"); do
  if [ $((r % 2)) = 1 ]; then
    http_open "half-nginx-$r" "$ngx_pid" "$ngx_http" "$half_ngx"; http_open "half-tessera-http-$r" "$tsr_pid" "$tsr_http" "$half_http"
    grpc_open "half-tessera-grpc-$r" "$half_grpc"
  else
    grpc_open "half-tessera-grpc-$r" "$half_grpc"
    http_open "half-tessera-http-$r" "$tsr_pid" "$tsr_http" "$half_http"; http_open "half-nginx-$r" "$ngx_pid" "$ngx_http" "$half_ngx"
  fi
  grpc_open "burst-tessera-grpc-$r" "$half_grpc" "$peak_viewers"
done
common=$(printf '%s\n' "$half_ngx" "$half_http" "$half_grpc" | sort -n | head -1)
echo "open-model latency at one common rate, $common/s"
for r in $(seq 1 "$rounds"); do
  if [ $((r % 2)) = 1 ]; then
    http_open "same-nginx-$r" "$ngx_pid" "$ngx_http" "$common"; http_open "same-tessera-http-$r" "$tsr_pid" "$tsr_http" "$common"
    grpc_open "same-tessera-grpc-$r" "$common"
  else
    grpc_open "same-tessera-grpc-$r" "$common"
    http_open "same-tessera-http-$r" "$tsr_pid" "$tsr_http" "$common"; http_open "same-nginx-$r" "$ngx_pid" "$ngx_http" "$common"
  fi
done

python3 - "$work" "$static" "$(git rev-parse --short HEAD)" "$rounds" "$secs" "$viewers" "$window" "$conns" "$peak_viewers" "$(head -1 "$work/floor.log")" "$placement" <<'PY'
import glob, json, os, platform, statistics, subprocess, sys
work, static, commit, rounds, secs, viewers, window, conns, peak_viewers, floor_banner, placement = sys.argv[1:12]
runs = os.path.join(work, "runs")
sizes = [os.path.getsize(os.path.join(dp, f)) for dp, _, fs in os.walk(os.path.join(static)) for f in fs if f != "urls.txt"]
mean_tile = sum(sizes) / len(sizes)
def load(pattern):
    out = []
    for f in sorted(glob.glob(os.path.join(runs, pattern))):
        j = json.load(open(f))
        if "requests" in j:  # wrk: payload bytes estimated from the mean tile size (uniform draws)
            s = j["duration_us"] / 1e6
            errors = sum(j["errors"].values())
            j = {"tiles_per_s": j["requests"] / s, "mb_per_s": j["requests"] / s * mean_tile / 1e6,
                 "wire_mb_per_s": j["bytes"] / s / 1e6, "errors": errors, "latency_ms": j["latency_ms"],
                 "seconds": s, "tiles": j["requests"], "tool": "wrk",
                 **{k: j[k] for k in ("server_cpu_s", "client_cpu_s", "other_cpu_s", "run_wall_s")}}
        else:
            j["tool"] = "serve_load"
        w = j["run_wall_s"]
        j["server_cores"], j["client_cores"], j["other_cores"] = j["server_cpu_s"] / w, j["client_cpu_s"] / w, j["other_cpu_s"] / w
        j["tiles_per_server_cpu_s"] = j["tiles_per_s"] / j["server_cores"] if j["server_cores"] else None
        out.append(j)
    return out
def med(rs, f):
    return statistics.median(f(r) for r in rs)
try:
    model = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
    model = next((l.split(":", 1)[1].strip() for l in model.splitlines() if l.startswith("Model name")), platform.processor())
except OSError:
    model = platform.processor()
res = {"commit": commit, "machine": f"{os.cpu_count()} cores, {model}, {platform.machine()}", "placement": placement,
       "store": "procedural:terrain:16384, JPEG q90, 256^2 tiles", "tiles": len(sizes), "mean_tile_bytes": mean_tile,
       "rounds": int(rounds), "seconds_per_run": float(secs), "viewers": int(viewers), "peak_viewers": int(peak_viewers), "window": int(window),
       "connections": int(conns), "peers": {}}
rows = []
for key, label in (("nginx", "nginx (static files)"), ("tessera-http", "tessera HTTP"), ("tessera-grpc", "tessera gRPC")):
    peak, half, same = load(f"peak-{key}-*.json"), load(f"half-{key}-*.json"), load(f"same-{key}-*.json")
    p = {"peak_runs": peak, "half_runs": half, "same_runs": same,
         "peak_tiles_per_s": med(peak, lambda r: r["tiles_per_s"]), "peak_mb_per_s": med(peak, lambda r: r["mb_per_s"]),
         "peak_tiles_per_server_cpu_s": med(peak, lambda r: r["tiles_per_server_cpu_s"] or 0),
         "peak_errors": sum(r["errors"] for r in peak),
         "peak_server_cores": med(peak, lambda r: r["server_cores"]),
         "peak_client_cores": med(peak, lambda r: r["client_cores"]),
         "peak_other_cores": med(peak, lambda r: r["other_cores"]),
         "half_other_cores": med(half, lambda r: r["other_cores"]),
         "half_offered_tiles_per_s": half[0]["offered_tiles_per_s"],
         "half_tiles_per_s": med(half, lambda r: r["tiles_per_s"]), "half_errors": sum(r["errors"] + r["lost"] for r in half)}
    for q in ("p50", "p99", "p99_9", "max"):
        p[f"half_{q}_ms"] = med(half, lambda r: r["latency_ms"][q])
    p["half_p99_ms_runs"] = [r["latency_ms"]["p99"] for r in half]
    p["same_offered_tiles_per_s"] = same[0]["offered_tiles_per_s"]
    p["same_errors"] = sum(r["errors"] + r["lost"] for r in same)
    for q in ("p50", "p99", "p99_9", "max"):
        p[f"same_{q}_ms"] = med(same, lambda r: r["latency_ms"][q])
    p["same_p99_ms_runs"] = [r["latency_ms"]["p99"] for r in same]
    if key == "tessera-grpc":
        p["peak_duplicates_per_s"] = med(peak, lambda r: r["duplicates"] / (r["seconds"] + r["warmup_s"]))
        p["peak_batch_requests_per_s"] = med(peak, lambda r: r["batch_requests"] / (r["seconds"] + r["warmup_s"]))
        p["half_duplicates"] = sum(r["duplicates"] for r in half)
        p["half_dropped"] = sum(r["dropped"] for r in half)
        # Server side (TileReply.server_micros: the latest batch listing the tile -> handed to gRPC).
        p["half_server_p50_ms"] = med(half, lambda r: r["server_latency_ms"]["p50"])
        p["half_server_p99_ms"] = med(half, lambda r: r["server_latency_ms"]["p99"])
        p["same_server_p99_ms"] = med(same, lambda r: r["server_latency_ms"]["p99"])
        burst = load(f"burst-{key}-*.json")
        p["burst_runs"] = burst
        p["burst_batch_requests"] = med(burst, lambda r: r["batch_requests"] / max(r["batches"], 1))
        p["burst_errors"] = sum(r["errors"] + r["lost"] for r in burst)
        for q in ("p50", "p99", "p99_9"):
            p[f"burst_{q}_ms"] = med(burst, lambda r: r["latency_ms"][q])
        p["burst_server_p99_ms"] = med(burst, lambda r: r["server_latency_ms"]["p99"])
    res["peers"][key] = p
    rows.append((label, p))
floor_peak = load("peak-floor-*.json")
res["floor"] = {"server": floor_banner, "peak_runs": floor_peak,
                "peak_tiles_per_s": med(floor_peak, lambda r: r["tiles_per_s"]),
                "peak_tiles_per_server_cpu_s": med(floor_peak, lambda r: r["tiles_per_server_cpu_s"] or 0),
                "peak_server_cores": med(floor_peak, lambda r: r["server_cores"]),
                "peak_client_cores": med(floor_peak, lambda r: r["client_cores"]),
                "peak_errors": sum(r["errors"] for r in floor_peak)}
fl = res["floor"]
ng = res["peers"]["nginx"]
res["ratios"] = {
    "http_over_floor_tiles_per_s": res["peers"]["tessera-http"]["peak_tiles_per_s"] / fl["peak_tiles_per_s"],
    "nginx_over_floor_tiles_per_s": ng["peak_tiles_per_s"] / fl["peak_tiles_per_s"],
    "floor_over_nginx_tiles_per_s": fl["peak_tiles_per_s"] / ng["peak_tiles_per_s"],
    "grpc_over_nginx_tiles_per_s": res["peers"]["tessera-grpc"]["peak_tiles_per_s"] / ng["peak_tiles_per_s"],
    "http_over_nginx_tiles_per_s": res["peers"]["tessera-http"]["peak_tiles_per_s"] / ng["peak_tiles_per_s"],
    "grpc_over_nginx_p99_at_half": res["peers"]["tessera-grpc"]["half_p99_ms"] / ng["half_p99_ms"],
    "http_over_nginx_p99_at_half": res["peers"]["tessera-http"]["half_p99_ms"] / ng["half_p99_ms"],
    "grpc_over_nginx_tiles_per_server_cpu_s": res["peers"]["tessera-grpc"]["peak_tiles_per_server_cpu_s"] / ng["peak_tiles_per_server_cpu_s"],
    "http_over_nginx_tiles_per_server_cpu_s": res["peers"]["tessera-http"]["peak_tiles_per_server_cpu_s"] / ng["peak_tiles_per_server_cpu_s"],
}
print(f"\n{res['machine']} ({placement}), commit {commit}; medians of {rounds} interleaved rounds of {secs}s; "
      f"gRPC peak {peak_viewers} viewers x {window} outstanding, open model {viewers} viewers at 60 Hz")
print(f"{'server':22} {'peak tiles/s':>12} {'MB/s':>7} {'tiles/CPU-s':>11} | {'half: offered':>13} {'achieved':>9} {'p50 ms':>7} {'p99 ms':>7} {'p99.9 ms':>8} {'errors':>6}")
for label, p in rows:
    print(f"{label:22} {p['peak_tiles_per_s']:12.0f} {p['peak_mb_per_s']:7.0f} {p['peak_tiles_per_server_cpu_s']:11.0f} | "
          f"{p['half_offered_tiles_per_s']:13.0f} {p['half_tiles_per_s']:9.0f} {p['half_p50_ms']:7.2f} {p['half_p99_ms']:7.2f} "
          f"{p['half_p99_9_ms']:8.2f} {p['half_errors']:6d}")
print(f"\ncores busy (median; {os.cpu_count()} in all): server / load tool / everything else (noise); per-run p99 at half load")
for label, p in rows:
    noise = ", ".join("%.2f" % r["other_cores"] for r in p["half_runs"])
    p99s = ", ".join("%.2f" % x for x in p["half_p99_ms_runs"])
    print(f"  {label:22} peak {p['peak_server_cores']:.2f} / {p['peak_client_cores']:.2f} / {p['peak_other_cores']:.2f}"
          f"   half: noise {noise} cores, p99 {p99s} ms")
print(f"\nat one common rate, {rows[0][1]['same_offered_tiles_per_s']:.0f} tiles/s offered to each:")
for label, p in rows:
    noise = ", ".join("%.2f" % r["other_cores"] for r in p["same_runs"])
    print(f"  {label:22} p50 {p['same_p50_ms']:.2f} ms, p99 {p['same_p99_ms']:.2f} ms, p99.9 {p['same_p99_9_ms']:.2f} ms, "
          f"errors {p['same_errors']}; per run p99 {', '.join('%.2f' % x for x in p['same_p99_ms_runs'])} ms, noise {noise} cores")
r = res["ratios"]
print(f"\nfloor ({fl['server']}): peak {fl['peak_tiles_per_s']:.0f} tiles/s (runs {', '.join('%.0f' % x['tiles_per_s'] for x in fl['peak_runs'])}), "
      f"{fl['peak_tiles_per_server_cpu_s']:.0f} tiles per server CPU-s, cores server / wrk {fl['peak_server_cores']:.2f} / {fl['peak_client_cores']:.2f}, errors {fl['peak_errors']}")
print(f"peak tiles/s against the floor: tessera HTTP {r['http_over_floor_tiles_per_s']:.2f}x, nginx {r['nginx_over_floor_tiles_per_s']:.2f}x "
      f"(the floor is {r['floor_over_nginx_tiles_per_s']:.2f}x nginx: what one receive and one send per request reach here)")
print(f"tessera/nginx peak tiles/s: gRPC {r['grpc_over_nginx_tiles_per_s']:.2f}x (target >= 2.5), HTTP {r['http_over_nginx_tiles_per_s']:.2f}x (target >= 1.3)")
print(f"tessera/nginx tiles per server CPU-second: gRPC {r['grpc_over_nginx_tiles_per_server_cpu_s']:.2f}x, HTTP {r['http_over_nginx_tiles_per_server_cpu_s']:.2f}x")
print(f"p99 at half peak: gRPC {res['peers']['tessera-grpc']['half_p99_ms']:.2f} ms, HTTP {res['peers']['tessera-http']['half_p99_ms']:.2f} ms, "
      f"nginx {ng['half_p99_ms']:.2f} ms (target < 5 ms)")
g = res["peers"]["tessera-grpc"]
print(f"gRPC server side (server_micros) at half load: p50 {g['half_server_p50_ms']:.2f} ms, p99 {g['half_server_p99_ms']:.2f} ms")
print(f"gRPC at half peak with the peak's {peak_viewers} viewers (~{g['burst_batch_requests']:.0f} tiles per batch): p50 {g['burst_p50_ms']:.2f} ms, "
      f"p99 {g['burst_p99_ms']:.2f} ms, p99.9 {g['burst_p99_9_ms']:.2f} ms, errors {g['burst_errors']} (server p99 {g['burst_server_p99_ms']:.2f} ms)")
print(f"gRPC duplicates (tiles sent twice: re-listed while on the wire): {g['peak_duplicates_per_s']:.0f}/s at peak, {g['half_duplicates']} in the half-load runs")
json.dump(res, open(os.path.join(work, "results.json"), "w"), indent=2)
PY
echo "JSON: $work/results.json"
