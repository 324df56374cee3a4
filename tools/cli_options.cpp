#include "cli_options.hpp"

namespace tessera::tools {

std::string bytes_text(std::uint64_t bytes) {
    static const char* const units[] = {"KiB", "MiB", "GiB", "TiB"};
    if (bytes == 0) return "0";
    std::string unit;
    for (const char* u : units) {
        if (bytes % 1024 != 0) break;
        bytes /= 1024;
        unit = u;
    }
    return std::to_string(bytes) + unit;
}

CLI::Validator bytes_transform() {
    CLI::Validator v = CLI::AsSizeValue(false);
    v.description("");
    return v;
}

}  // namespace tessera::tools
