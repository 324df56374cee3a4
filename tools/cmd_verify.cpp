// tessera verify STORE: index and every checksum; exit 0 when sound, 1 with a report otherwise.
#include <fmt/format.h>

#include <chrono>

#include "commands.hpp"
#include "progress.hpp"
#include "tessera/storage/verify.hpp"

namespace tessera::tools {

Command add_verify(CLI::App& app) {
    struct Args {
        std::string store;
        bool decode = false, quiet = false;
    };
    auto a = std::make_shared<Args>();
    CLI::App* c = app.add_subcommand("verify", "Check a store's index and every tile checksum");
    c->add_option("store", a->store, "Store file (.tsr)")->required();
    c->add_flag("--decode", a->decode, "Also decode every tile");
    c->add_flag("-q,--quiet", a->quiet, "Print only problems");
    return [a]() -> int {
        const auto t0 = std::chrono::steady_clock::now();
        auto reader = storage::StoreReader::open(a->store);
        if (!reader) {
            fmt::print("{}: FAILED\n  {}\n", a->store, reader.error().message);
            return 1;
        }
        ProgressBar bar("verify", !a->quiet);
        storage::VerifyOptions opt;
        opt.decode = a->decode;
        opt.progress = [&](std::uint64_t done, std::uint64_t total) {
            bar.update(total ? double(done) / double(total) : 1.0, fmt::format("tiles {}/{}", done, total));
        };
        const storage::VerifyReport rep = storage::verify_store(**reader, opt);
        bar.finish();
        const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (!rep.ok()) {
            fmt::print("{}: FAILED, {} problem(s)\n", a->store, rep.problem_count);
            for (const auto& p : rep.problems) fmt::print("  {}\n", p);
            if (rep.problem_count > rep.problems.size()) fmt::print("  ... and {} more\n", rep.problem_count - rep.problems.size());
            return 1;
        }
        if (!a->quiet)
            fmt::print("{}: OK, {} tiles, {} payloads{}, {} checked in {}\n", a->store, rep.tiles_checked, rep.payloads_checked,
                       a->decode ? " decoded" : "", human_bytes(rep.bytes_checked), human_seconds(secs));
        return 0;
    };
}

}  // namespace tessera::tools
