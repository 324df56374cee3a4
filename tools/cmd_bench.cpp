// tessera bench: the command line (docs/bench.md). The application is apps/bench.
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <memory>

#include "bench.hpp"
#include "cli_options.hpp"
#include "commands.hpp"
#include "path_option.hpp"

namespace tessera::tools {

Command add_bench(CLI::App& app) {
    auto a = std::make_shared<BenchOptions>();
    CLI::App* c = app.add_subcommand(
        "bench", "Sweep tile size, border, codec, feedback scale, pool, bias policy, upload budget, latency and "
                 "prefetch: run time against error, with Pareto fronts and a recommended default");
    add_texels_option(*c, a->texels, "texels per side of the procedural terrain", CLI::Range(256u, 16384u));
    c->add_option("--frames", a->frames, "frames per point (the path at 60 frames per second)")
        ->check(CLI::Range(2u, 100000u))
        ->capture_default_str();
    c->add_option("--resolution", a->resolution, "WIDTHxHEIGHT of the viewer")->capture_default_str();
    c->add_option("--path", a->path, camera_path_help())->capture_default_str();
    c->add_option("--out", a->out, "directory for stores, bench.csv, bench.json and pareto_*.svg")
        ->capture_default_str()
        ->check(CLI::Validator([](std::string& v) { return v.empty() ? std::string("an empty path names no directory") : std::string(); },
                               "", "directory"));
    c->add_option("--psnr-every", a->psnr_every, "compare with the reference every N frames")
        ->check(CLI::Range(1u, 100000u))
        ->capture_default_str();
    c->add_option("--only", a->only, "sweeps to run besides the baseline: " + fmt::format("{}", fmt::join(bench_sweeps(), ", ")))
        ->delimiter(',')
        ->check(CLI::IsMember(bench_sweeps()));
    c->add_flag("--quick", a->quick,
                "a tiny sweep for tests: baseline, zstd and 20 ms latency; 30 frames at 128x72 unless given");
    return [a, c]() -> int {
        a->resolution_given = c->count("--resolution") > 0;
        a->frames_given = c->count("--frames") > 0;
        return run_bench(*a);
    };
}

}  // namespace tessera::tools
