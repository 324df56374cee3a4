// tessera demo: the README's first command. Builds the procedural default store if it is
// missing, verifies it and prints its summary. (The server and the viewer join the demo as they land.)
#include <fmt/format.h>

#include <filesystem>

#include "commands.hpp"
#include "progress.hpp"
#include "store_summary.hpp"
#include "tessera/storage/builder.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/verify.hpp"

namespace tessera::tools {

Command add_demo(CLI::App& app) {
    struct Args {
        std::string dir = "tessera-demo";
        std::uint32_t size = 16384;
        bool rebuild = false;
    };
    auto a = std::make_shared<Args>();
    CLI::App* c = app.add_subcommand("demo", "Build the procedural demo store (if missing), verify it and summarise it");
    c->add_option("--dir", a->dir, "Directory for the demo's files")->capture_default_str();
    c->add_option("--size", a->size, "Texels per side of the procedural terrain")->capture_default_str();
    c->add_flag("--rebuild", a->rebuild, "Build the store even if it exists");
    return [a]() -> int {
        namespace fs = std::filesystem;
        std::error_code ec;
        fs::create_directories(a->dir, ec);
        if (ec) throw Failure(fmt::format("cannot create '{}': {}", a->dir, ec.message()));
        const std::string store = (fs::path(a->dir) / "terrain.tsr").string();
        const std::string input = fmt::format("procedural:terrain:{}", a->size);
        bool build = a->rebuild;
        if (!build) {
            auto existing = storage::StoreReader::open(store);
            build = !existing || existing.value()->info().width != a->size;
        }
        if (build) {
            fmt::print("building {} from {} ...\n", store, input);
            std::fflush(stdout);
            ProgressBar bar("build", true);
            auto r = storage::build_store(input, store, storage::BuildOptions{}, [&](const storage::BuildProgress& p) {
                if (p.writing) bar.update(p.bytes_total ? double(p.bytes_written) / double(p.bytes_total) : 1.0, "writing");
                else bar.update(double(p.rows_done) / double(p.rows_total), fmt::format("tiles {}/{}", p.tiles_done, p.tiles_total));
            });
            bar.finish();
            if (!r) throw Failure(r.error().message);
            fmt::print("built in {} ({:.1f} MP/s)\n", human_seconds(r->seconds), double(r->source_texels) / 1e6 / r->seconds);
        } else {
            fmt::print("using existing {} (--rebuild to build it again)\n", store);
        }
        auto reader = storage::StoreReader::open(store);
        if (!reader) throw Failure(reader.error().message);
        print_store_summary(store, (*reader)->info());
        const auto rep = storage::verify_store(**reader);
        if (!rep.ok()) throw Failure(fmt::format("{} failed verification: {}", store, rep.problems.front()));
        fmt::print("verify     OK: {} tiles, {} payloads, {} checked\n", rep.tiles_checked, rep.payloads_checked,
                   human_bytes(rep.bytes_checked));
        fmt::print("\nmore: tessera inspect {0} --json    tessera verify --decode {0}\n", store);
        return 0;
    };
}

}  // namespace tessera::tools
