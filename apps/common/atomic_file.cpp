#include "atomic_file.hpp"

#include <fmt/format.h>

#include <filesystem>
#include <fstream>
#include <system_error>


#include "failure.hpp"
#include "tessera/storage/output_file.hpp"

namespace tessera::tools {

void check_writable(const std::string& path) {
    namespace fs = std::filesystem;
    const fs::path target(path);
    if (Status st = storage::check_output_file(path); !st) throw Failure(st.error().message);
    const fs::path probe = storage::temp_path_beside(path, "probe");
    storage::track_temp_path(probe.string());
    const bool made = std::ofstream(probe, std::ios::binary | std::ios::trunc).good();
    std::error_code ec;
    fs::remove(probe, ec);
    storage::untrack_temp_path(probe.string());
    if (!made) {
        const fs::path dir = target.parent_path().empty() ? fs::path(".") : target.parent_path();
        throw Failure(fmt::format("cannot write '{}': {}", path,
                                  fs::is_directory(dir, ec) ? "no permission to create files in " + dir.string()
                                                            : "no directory " + dir.string()));
    }
}

void write_file_atomically(const std::string& path, const std::function<void(std::ostream&)>& write) {
    namespace fs = std::filesystem;
    const fs::path target(path);
    if (Status st = storage::check_output_file(path); !st) throw Failure(st.error().message);
    // The process id keeps two writers of one path apart; tracked, so an interrupted command
    // (tools/interrupt.hpp) removes it.
    const fs::path temp = storage::temp_path_beside(path, "tmp");
    storage::track_temp_path(temp.string());
    struct Untrack {
        std::string path;
        ~Untrack() { storage::untrack_temp_path(path); }
    } untrack{temp.string()};
    {
        std::ofstream out(temp, std::ios::binary | std::ios::trunc);
        if (out) write(out);
        if (!out) {
            std::error_code ec;
            fs::remove(temp, ec);
            throw Failure(fmt::format("cannot write '{}'", path));
        }
    }
    std::error_code ec;
    fs::rename(temp, target, ec);
    if (ec) {
        const std::string why = ec.message();
        fs::remove(temp, ec);
        throw Failure(fmt::format("cannot write '{}': {}", path, why));
    }
}

}  // namespace tessera::tools
