#pragma once
// The `tessera` subcommands. Each registers its flags on the CLI11 app and returns the exit code
// when run; errors inside a command are thrown as tools::Failure and printed by main as one line.
#include <CLI/CLI.hpp>

#include <functional>
#include <string>

#include "failure.hpp"

namespace tessera::tools {

using Command = std::function<int()>;

Command add_build(CLI::App& app);
Command add_inspect(CLI::App& app);
Command add_verify(CLI::App& app);
Command add_source(CLI::App& app);
Command add_demo(CLI::App& app);
Command add_serve(CLI::App& app);
Command add_view(CLI::App& app);
Command add_loadtest(CLI::App& app);
Command add_bench(CLI::App& app);

}  // namespace tessera::tools
