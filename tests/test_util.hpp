#pragma once
// Helpers shared by the tests: scratch directories, running the tessera binary, file bytes.
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <stdexcept>
#include <string>
#include <vector>

namespace tessera::test {

// A fresh directory under /tmp, removed with its contents at scope exit.
class ScratchDir {
public:
    ScratchDir() {
        std::string tmpl = (std::filesystem::temp_directory_path() / "tessera-test-XXXXXX").string();
        if (!::mkdtemp(tmpl.data())) std::abort();
        path_ = tmpl;
    }
    ~ScratchDir() {
        std::error_code ec;
        std::filesystem::remove_all(path_, ec);
    }
    ScratchDir(const ScratchDir&) = delete;
    ScratchDir& operator=(const ScratchDir&) = delete;
    std::string file(const std::string& name) const { return (path_ / name).string(); }
    const std::filesystem::path& path() const { return path_; }
    // Names of every entry in the directory (to check nothing stray was left behind).
    std::vector<std::string> entries() const {
        std::vector<std::string> out;
        for (const auto& e : std::filesystem::directory_iterator(path_)) out.push_back(e.path().filename().string());
        return out;
    }

private:
    std::filesystem::path path_;
};

struct RunResult {
    int exit_code = -1;
    std::string out;  // stdout and stderr together
};

// Runs `PROGRAM ARGS` through the shell, capturing output.
inline RunResult run_program(const std::string& program, const std::string& args) {
    RunResult r;
    const std::string cmd = program + " " + args + " 2>&1";
    FILE* p = ::popen(cmd.c_str(), "r");
    if (!p) return r;
    std::array<char, 4096> buf{};
    std::size_t n;
    while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
    const int status = ::pclose(p);
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    return r;
}

// Runs `tessera ARGS` through the shell, capturing output.
inline RunResult run_tessera(const std::string& args) { return run_program(TESSERA_BINARY, args); }

// A store built once per build tree and shared by every test process that asks for the same
// build arguments: ctest runs each test in a process of its own, and a large store costs seconds
// to build (minutes under ThreadSanitizer). The builder is deterministic (the same arguments give
// the same bytes) and renames whole files into place, so concurrent first builds are harmless.
// Tests must not modify the file: they copy it first. Entries live under a directory named after
// the tessera binary (size, mtime): a rebuilt binary builds afresh and removes the old entries.
// Throws std::runtime_error when the build fails.
inline std::string cached_store(const std::string& build_args, const std::string& file) {
    namespace fs = std::filesystem;
    std::error_code ec;
    const auto binary_size = fs::file_size(TESSERA_BINARY, ec);
    const auto binary_time = fs::last_write_time(TESSERA_BINARY, ec).time_since_epoch().count();
    const fs::path root = TESSERA_TEST_STORE_CACHE;
    const std::string binary_key = std::to_string(binary_size) + "-" + std::to_string(binary_time);
    // The file keeps its name (a server names a store after its file): the arguments pick the directory.
    const fs::path dir = root / binary_key / std::to_string(std::hash<std::string>{}(build_args));
    const fs::path out = dir / file;
    if (fs::exists(out, ec)) return out.string();
    for (const auto& e : fs::directory_iterator(root, ec))
        if (e.path().filename() != binary_key) fs::remove_all(e.path(), ec);  // entries of older binaries
    fs::create_directories(dir, ec);
    const RunResult r = run_tessera("build " + build_args + " -o " + out.string() + " --quiet");
    if (r.exit_code != 0 || !fs::exists(out, ec)) throw std::runtime_error("build " + build_args + " failed: " + r.out);
    return out.string();
}

inline std::vector<std::uint8_t> read_file(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    return std::vector<std::uint8_t>(std::istreambuf_iterator<char>(f), {});
}

inline void write_file(const std::string& path, const std::vector<std::uint8_t>& bytes) {
    std::ofstream f(path, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

}  // namespace tessera::test
