-- wrk script for bench/serve_vs_nginx.sh: every request is a tile URL drawn uniformly at random
-- from a URL list, and the run ends with one JSON line (prefixed "WRK_JSON ") for the script.
--   wrk -s bench/wrk_tiles.lua URL -- urls.txt [SEED]
local threads = {}
local counter = 0

function setup(thread)
  counter = counter + 1
  thread:set("id", counter)
  table.insert(threads, thread)
end

function init(args)
  urls = {}
  for line in io.lines(args[1]) do
    if line:sub(1, 1) == "/" then urls[#urls + 1] = line end
  end
  local seed = tonumber(args[2] or "1")
  math.randomseed(seed * 7919 + id)
end

function request()
  return wrk.format("GET", urls[math.random(#urls)])
end

function done(summary, latency, requests)
  local e = summary.errors
  io.write(string.format(
    'WRK_JSON {"requests":%d,"duration_us":%d,"bytes":%d,"errors":{"connect":%d,"read":%d,"write":%d,"status":%d,"timeout":%d},'
      .. '"latency_ms":{"p50":%.4f,"p90":%.4f,"p99":%.4f,"p99_9":%.4f,"max":%.4f,"mean":%.4f}}\n',
    summary.requests, summary.duration, summary.bytes, e.connect, e.read, e.write, e.status, e.timeout,
    latency:percentile(50) / 1000, latency:percentile(90) / 1000, latency:percentile(99) / 1000,
    latency:percentile(99.9) / 1000, latency.max / 1000, latency.mean / 1000))
end
