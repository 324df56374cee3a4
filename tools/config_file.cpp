#include "config_file.hpp"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string_view>

namespace tessera::tools {

namespace {

std::string_view trim(std::string_view s) {
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
    return s;
}

bool is_key_char(char c) {
    return std::islower(static_cast<unsigned char>(c)) || std::isdigit(static_cast<unsigned char>(c)) || c == '-';
}

// Reads one value of a line from `s` (leading blanks skipped): a quoted string, or bare text up
// to one of `stops` or a " #" comment. Returns false with `error` set when it is malformed.
class ValueReader {
public:
    explicit ValueReader(std::string_view s) : s_(s) {}

    bool at_end() {
        skip_blanks();
        return s_.empty() || starts_comment();
    }
    char peek() {
        skip_blanks();
        return s_.empty() ? '\0' : s_.front();
    }
    void take(std::size_t n) { s_.remove_prefix(n); }
    std::string_view rest() const { return s_; }

    bool read(std::string_view stops, std::string& value, std::string& error) {
        skip_blanks();
        if (!s_.empty() && (s_.front() == '"' || s_.front() == '\'')) {
            const char q = s_.front();
            const std::size_t close = s_.find(q, 1);
            if (close == std::string_view::npos) {
                error = std::string("unclosed quote (") + q + ")";
                return false;
            }
            value.assign(s_.substr(1, close - 1));
            s_.remove_prefix(close + 1);
            return true;
        }
        std::size_t end = 0;
        // A '#' after a blank, or where the value would start (`grpc = # off`), begins a comment.
        while (end < s_.size() && stops.find(s_[end]) == std::string_view::npos &&
               !(s_[end] == '#' && (end == 0 || std::isspace(static_cast<unsigned char>(s_[end - 1])))))
            ++end;
        value.assign(trim(s_.substr(0, end)));
        s_.remove_prefix(end);
        if (value.empty()) {
            error = "no value (write \"\" for an empty one)";
            return false;
        }
        if (value.find_first_of("\"'") != std::string::npos) {
            error = "a quote inside a bare value (quote the whole value)";
            return false;
        }
        return true;
    }

private:
    void skip_blanks() {
        while (!s_.empty() && std::isspace(static_cast<unsigned char>(s_.front()))) s_.remove_prefix(1);
    }
    bool starts_comment() const { return !s_.empty() && s_.front() == '#'; }

    std::string_view s_;
};

// Where a list's ']' is in one line of it, outside quotes and before a " #" comment (npos if it
// goes on); `used` is where its text ends (at a comment), and `quote_open` says it ended inside a
// quote, which is an error.
std::size_t list_end(std::string_view s, std::size_t& used, bool& quote_open) {
    used = s.size();
    char q = 0;
    for (std::size_t i = 0; i < s.size(); ++i) {
        const char c = s[i];
        if (q != 0) {
            if (c == q) q = 0;
        } else if (c == '"' || c == '\'') {
            q = c;
        } else if (c == ']') {
            return i;
        } else if (c == '#' && (i == 0 || std::isspace(static_cast<unsigned char>(s[i - 1])))) {
            used = i;
            break;
        }
    }
    quote_open = q != 0;
    return std::string_view::npos;
}

}  // namespace

ConfigFile parse_config_text(const std::string& text, const std::string& path) {
    ConfigFile file;
    file.path = path;
    // A UTF-8 byte order mark (some editors write one) is not part of the first key.
    std::istringstream in(text.rfind("\xEF\xBB\xBF", 0) == 0 ? text.substr(3) : text);
    std::string raw;
    int number = 0;
    auto fail = [&](int line, const std::string& what) -> ConfigFileError {
        return ConfigFileError(path + ":" + std::to_string(line) + ": " + what);
    };
    while (std::getline(in, raw)) {
        ++number;
        const int line = number;
        std::string_view s = trim(raw);
        if (s.empty() || s.front() == '#' || s.front() == ';') continue;
        if (s.front() == '[') {
            if (s.back() != ']') throw fail(line, "a section header must end with ']'");
            const std::string_view name = trim(s.substr(1, s.size() - 2));
            if (name != "serve" && name != "default")
                throw fail(line, "unknown section [" + std::string(name) + "] (options go at the top or under [serve])");
            continue;
        }
        const std::size_t eq = s.find('=');
        if (eq == std::string_view::npos)
            throw fail(line, "expected `key = value`, got '" + std::string(s) + "'");
        std::string_view key_text = trim(s.substr(0, eq));
        if (key_text.substr(0, 6) == "serve.") key_text.remove_prefix(6);
        const std::string key(key_text);  // `raw` is reused for a list's further lines
        if (key.empty()) throw fail(line, "no key before '='");
        for (char c : key)
            if (!is_key_char(c))
                throw fail(line, "'" + key + "' is not an option name (lowercase letters, digits and '-', as in "
                                 "`tessera serve --help` without the dashes)");

        std::vector<std::string> values;
        std::string error;
        ValueReader r(s.substr(eq + 1));
        // '[' starts a list, unless the line goes on after its ']': `http = [::]:8080` is one value.
        bool list = false;
        if (r.peek() == '[') {
            bool quote_open = false;
            std::size_t used = 0;
            const std::string_view first = trim(r.rest()).substr(1);
            const std::size_t close = list_end(first, used, quote_open);
            list = close == std::string_view::npos || ValueReader(first.substr(close + 1)).at_end();
        }
        if (list) {
            // A list, which may go on over the following lines until its ']'.
            std::string items;
            std::string_view part = trim(r.rest()).substr(1);
            std::size_t close;
            for (;;) {
                bool quote_open = false;
                std::size_t used = 0;
                close = list_end(part, used, quote_open);
                if (quote_open) throw fail(number, "unclosed quote");
                if (close != std::string_view::npos) break;
                items.append(part.substr(0, used)).push_back('\n');
                std::string next;
                if (!std::getline(in, next)) throw fail(line, "the list of '" + key + "' has no closing ']'");
                ++number;
                raw = std::move(next);
                part = raw;
            }
            items.append(part.substr(0, close));
            ValueReader after(part.substr(close + 1));
            if (!after.at_end()) throw fail(number, "text after the list's ']'");
            ValueReader items_reader(items);
            while (!items_reader.at_end()) {
                std::string v;
                if (!items_reader.read(",", v, error)) throw fail(line, error);
                if (v.find('\n') != std::string::npos) throw fail(line, "expected ',' between the list's values");
                values.push_back(std::move(v));
                if (items_reader.peek() == ',') items_reader.take(1);
                else if (!items_reader.at_end()) throw fail(line, "expected ',' between the list's values");
            }
            if (values.empty()) throw fail(line, "an empty list");
        } else {
            std::string v;
            if (!r.read("", v, error)) throw fail(line, error);
            if (!r.at_end()) throw fail(line, "text after the closing quote");
            values.push_back(std::move(v));
        }

        auto known = std::find_if(file.entries.begin(), file.entries.end(),
                                  [&](const ConfigEntry& e) { return e.key == key; });
        if (known == file.entries.end()) {
            file.entries.push_back({key, std::move(values), line, line});
        } else {
            known->values.insert(known->values.end(), values.begin(), values.end());
            known->last_line = line;
        }
    }
    return file;
}

ConfigFile read_config_file(const std::string& path) {
    std::error_code ec;
    if (std::filesystem::is_directory(path, ec)) throw ConfigFileError(path + " is a directory, not a config file");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw ConfigFileError(path + ": cannot be read");
    std::ostringstream text;
    text << in.rdbuf();
    if (in.bad()) throw ConfigFileError(path + ": cannot be read");
    return parse_config_text(text.str(), path);
}

std::vector<std::string> changed_keys(const ConfigFile& before, const ConfigFile& after) {
    auto find = [](const ConfigFile& f, const std::string& key) -> const ConfigEntry* {
        for (const ConfigEntry& e : f.entries)
            if (e.key == key) return &e;
        return nullptr;
    };
    std::vector<std::string> keys;
    for (const ConfigEntry& e : after.entries) {
        const ConfigEntry* old = find(before, e.key);
        if (old == nullptr || old->values != e.values) keys.push_back(e.key);
    }
    for (const ConfigEntry& e : before.entries)
        if (find(after, e.key) == nullptr) keys.push_back(e.key);
    return keys;
}

}  // namespace tessera::tools
