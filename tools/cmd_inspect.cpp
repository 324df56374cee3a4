// tessera inspect STORE [--json]
#include <fmt/format.h>

#include "commands.hpp"
#include "store_summary.hpp"
#include "tessera/storage/store_json.hpp"
#include "tessera/storage/store_reader.hpp"

namespace tessera::tools {

Command add_inspect(CLI::App& app) {
    struct Args {
        std::string store;
        bool json = false;
    };
    auto a = std::make_shared<Args>();
    CLI::App* c = app.add_subcommand("inspect", "Show a store's header, levels, tile counts and compression");
    c->add_option("store", a->store, "Store file (.tsr)")->required();
    c->add_flag("--json", a->json, "Print JSON instead of a table");
    return [a]() -> int {
        auto reader = storage::StoreReader::open(a->store);
        if (!reader) throw Failure(reader.error().message);
        if (a->json) fmt::print("{}\n", storage::store_json(a->store, (*reader)->info()).dump(2));
        else print_store_summary(a->store, (*reader)->info());
        return 0;
    };
}

}  // namespace tessera::tools
