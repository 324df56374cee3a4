#pragma once
// tessera loadtest, the application (docs/loadtest.md): N simulated viewers in one process, no GL,
// against a Tessera server; the command line (tools/cmd_loadtest.cpp) only reads its options.
#include <cstdint>
#include <string>
#include <vector>

namespace tessera::tools {

struct LoadTestOptions {
    std::string server, store, trace, path;
    std::vector<unsigned> viewers{1};
    double fps = 60, duration = 10, warmup = 2;
    bool ramp = false;
    double ramp_p99_ms = 16, ramp_fallback = 0.001;
    unsigned max_viewers = 64;
    std::uint64_t seed = 1;
    std::string feedback_size = "160x90", view_size = "1280x720";
    std::uint64_t ram_cache = 0;
    std::uint32_t pool = 2048;
    double latency_ms = 0, jitter_ms = 0, bandwidth_mbit = 0;
    unsigned threads = 0;
    double connect_timeout = 5;
    std::string token, token_file, tls_ca;
    bool tls = false;
    std::string json, plot;
    bool quiet = false;
    int server_pid = 0;          // > 0: the server's CPU time is read from /proc/PID/stat
    unsigned replica_cores = 0;  // capacity plan: cores per server replica (0: this machine's)
    unsigned plan_viewers = 10000;
};

// Runs the load test: reaches the server, then each viewer count in turn (or the ramp); prints the
// table (and the capacity plan), writes --json and --plot. Returns the exit status; errors are
// thrown as Failure.
int run_loadtest(LoadTestOptions o);

}  // namespace tessera::tools
