#pragma once
// The error every application and command reports to its user: thrown inside, printed by the
// command line's main as one line, "tessera: error: <what>", with exit status `code`.
#include <stdexcept>
#include <string>

namespace tessera::tools {

struct Failure : std::runtime_error {
    int code;
    explicit Failure(const std::string& what, int exit_code = 1) : std::runtime_error(what), code(exit_code) {}
};

}  // namespace tessera::tools
