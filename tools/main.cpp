// tessera: build, inspect, verify and serve streaming virtual texture stores, view and load-test
// them. tessera-server (TESSERA_SERVER_BINARY): serve, inspect and verify only, for deployments --
// no GL, GLFW, OpenImageIO or tinyobjloader among its libraries.
#include <malloc.h>

#include <cstdio>
#include <cstring>
#include <exception>
#include <map>
#include <string>

#include "cli_options.hpp"
#include "commands.hpp"

#if defined(__SANITIZE_ADDRESS__)
// AddressSanitizer builds (docs/reliability.md): a small quarantine, and freed memory given back to
// the system promptly, so that the server's memory bounds measure memory in use rather than ASan's
// holding area for freed blocks (256 MiB by default). ASAN_OPTIONS still overrides these.
extern "C" const char* __asan_default_options() {
    return "quarantine_size_mb=4:thread_local_quarantine_size_kb=64:allocator_release_to_os_interval_ms=50";
}
#endif

namespace {

// "run 'tessera view --help' for the options"
std::string help_hint(const std::string& program, const std::string& subcommand, const char* what) {
    return "run '" + program + (subcommand.empty() ? "" : " " + subcommand) + " --help' for the " + what;
}

}  // namespace

int main(int argc, char** argv) {
    using namespace tessera::tools;
    // Big row and tile buffers come and go all the time; a fixed mmap threshold makes glibc hand
    // them back to the OS on free instead of keeping them in the heap (the default raises the
    // threshold after the first free, which inflates peak RSS by tens of MiB).
    mallopt(M_MMAP_THRESHOLD, 1 << 20);
    // Fixing the threshold also fixes the trim threshold at its 128 KiB default: a freed tile
    // buffer at the top of a thread's arena would go back to the OS and the next request's pages
    // be faulted in and zeroed again. Keep up to 8 MiB of free top per arena instead.
    mallopt(M_TRIM_THRESHOLD, 8 << 20);
#ifdef TESSERA_SERVER_BINARY
    CLI::App app{"Tessera's tile server (serve, inspect and verify stores; the full `tessera` builds and views them)",
                 "tessera-server"};
    app.set_version_flag("--version", "tessera-server 0.1.0");
#else
    CLI::App app{"Tessera: streaming virtual textures (tile stores, server, client runtime)", "tessera"};
    app.set_version_flag("--version", "tessera 0.1.0");
#endif
    app.require_subcommand(1);
    std::map<CLI::App*, Command> commands;
    auto reg = [&](Command (*add)(CLI::App&)) {
        const std::size_t before = app.get_subcommands({}).size();
        Command c = add(app);
        commands[app.get_subcommands({})[before]] = std::move(c);
    };
#ifdef TESSERA_SERVER_BINARY
    // The full binary's other commands: say where they are rather than "a subcommand is required".
    for (const char* other : {"build", "source", "view", "loadtest", "bench", "demo"})
        if (argc > 1 && std::strcmp(argv[1], other) == 0) {
            std::fprintf(stderr, "tessera-server: error: '%s' is a command of the full tessera binary; tessera-server only serves, "
                                 "inspects and verifies stores\n", other);
            return 2;
        }
    reg(add_inspect);
    reg(add_verify);
    reg(add_serve);
#else
    reg(add_build);
    reg(add_inspect);
    reg(add_verify);
    reg(add_source);
    reg(add_serve);
    reg(add_view);
    reg(add_loadtest);
    reg(add_bench);
    reg(add_demo);
#endif
    require_finite_numbers(app);
    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        // One line: the error, and the help that lists the options of the subcommand it came from
        // (CLI11 records a subcommand as parsed before it parses the subcommand's arguments).
        const std::string name = app.get_name();
        const auto parsed = app.get_subcommands();
        const std::string help = parsed.empty() ? help_hint(name, "", "commands") : help_hint(name, parsed.back()->get_name(), "options");
        // An error of a hidden option starts ": " (CLI11 2.1 leaves its name out; its message names it).
        std::string what = e.what();
        if (what.rfind(": ", 0) == 0) what.erase(0, 2);
        // No command parsed and a first word that is none: name it, not "a subcommand is required".
        if (parsed.empty() && argc > 1 && argv[1][0] != '-')
            what = std::string("'") + argv[1] + "' is not a command";
        else if (parsed.empty() && argc > 1 && what.find("subcommand is required") != std::string::npos)
            what = std::string("no command before '") + argv[1] + "'";
        std::fprintf(stderr, "%s: error: %s (%s)\n", name.c_str(), what.c_str(), help.c_str());
        return 2;
    }
    try {
        for (auto& [sub, run] : commands)
            if (sub->parsed()) return run();
    } catch (const Failure& f) {
        std::fprintf(stderr, "%s: error: %s\n", app.get_name().c_str(), f.what());
        return f.code;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "%s: error: %s\n", app.get_name().c_str(), e.what());
        return 1;
    }
    return 0;
}
