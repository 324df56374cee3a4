#pragma once
// tessera bench, the application (docs/bench.md): run time against error, a one-factor-at-a-time
// sweep of headless viewer runs; the command line (tools/cmd_bench.cpp) only reads its options.
#include <cstdint>
#include <string>
#include <vector>

namespace tessera::tools {

struct BenchOptions {
    std::uint32_t texels = 2048;
    std::uint32_t frames = 240;
    std::string resolution = "320x180";
    std::string path = "flyover";
    std::string out = "tessera-bench";
    std::uint32_t psnr_every = 8;
    std::vector<std::string> only;
    bool quick = false;
    bool resolution_given = false, frames_given = false;  // --quick shrinks only what was not given
};

// The sweeps --only may name besides the baseline.
const std::vector<std::string>& bench_sweeps();

// Runs the sweep: builds the stores, runs every point, writes bench.csv, bench.json and the
// Pareto plots under o.out, prints the table and the recommended default. Returns the exit status;
// errors are thrown as Failure.
int run_bench(const BenchOptions& o);

}  // namespace tessera::tools
