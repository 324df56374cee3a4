#pragma once
// The `key = value` file `tessera serve --config FILE` reads (docs/server.md, "Config file").
// Read here rather than by CLI11, whose reader names neither the file nor the line of an error,
// takes an unclosed quote literally, cuts a quoted value at '#' and splits a bare one at spaces.
#include <stdexcept>
#include <string>
#include <vector>

namespace tessera::tools {

// One key: its values in file order (a repeated key adds to them) and the line it first appears on.
struct ConfigEntry {
    std::string key;  // a long option name without dashes ("serve." and a [serve] section dropped)
    std::vector<std::string> values;
    int line = 0;       // where the key first appears
    int last_line = 0;  // where it last appears (the same line unless it is repeated)
};

struct ConfigFile {
    std::string path;
    std::vector<ConfigEntry> entries;  // in the order the keys first appear

    // "PATH:LINE" of an entry, for errors.
    std::string where(const ConfigEntry& e) const { return path + ":" + std::to_string(e.line); }
};

// An error in a config file; what() is "PATH:LINE: what is wrong" (or "PATH: ..." when the file
// cannot be read).
struct ConfigFileError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// The file's syntax, line by line:
//   # comment, ; comment, blank           ignored
//   [serve]                               a section; [default] too; any other is an error
//   key = value                           a bare value: the text up to a " #" comment, trimmed
//                                         (`[::]:8080` too: a list's ']' ends its line)
//   key = "value" or 'value'              quoted: taken as written ('#' and spaces included)
//   key = [a, "b", 'c']                   several values (the list may go on over lines)
// Throws ConfigFileError on anything else: a line that is no `key = value`, an unclosed quote or
// list, text after a closing quote, an empty bare value (write "" for an empty string).
ConfigFile read_config_file(const std::string& path);

// The keys whose values differ between two readings of a file (added and removed keys too), in
// the order they appear in `after`, then those only in `before`.
std::vector<std::string> changed_keys(const ConfigFile& before, const ConfigFile& after);

// The same, from text (`path` names it in errors).
ConfigFile parse_config_text(const std::string& text, const std::string& path);

}  // namespace tessera::tools
