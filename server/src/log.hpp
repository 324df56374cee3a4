#pragma once
// Structured logs: one line per event on stderr, JSON (default; for collectors) or text (for
// people). Thread-safe; a line is written with one write() so lines never interleave.
#include <cstdint>
#include <initializer_list>
#include <string>
#include <string_view>

namespace tessera::server {

enum class LogLevel { debug = 0, info = 1, warn = 2, error = 3 };
enum class LogFormat { json, text };

// One key = value pair of a log line. Explicit constructors: a string literal must not decay to bool.
struct LogField {
    enum class Kind { string, int64, uint64, float64, boolean };
    std::string_view key;
    Kind kind;
    std::string_view s;
    std::int64_t i = 0;
    std::uint64_t u = 0;
    double d = 0;
    bool b = false;
    LogField(std::string_view k, std::string_view v) : key(k), kind(Kind::string), s(v) {}
    LogField(std::string_view k, const char* v) : key(k), kind(Kind::string), s(v) {}
    LogField(std::string_view k, const std::string& v) : key(k), kind(Kind::string), s(v) {}
    LogField(std::string_view k, int v) : key(k), kind(Kind::int64), i(v) {}
    LogField(std::string_view k, long v) : key(k), kind(Kind::int64), i(v) {}
    LogField(std::string_view k, long long v) : key(k), kind(Kind::int64), i(v) {}
    LogField(std::string_view k, unsigned v) : key(k), kind(Kind::uint64), u(v) {}
    LogField(std::string_view k, unsigned long v) : key(k), kind(Kind::uint64), u(v) {}
    LogField(std::string_view k, unsigned long long v) : key(k), kind(Kind::uint64), u(v) {}
    LogField(std::string_view k, double v) : key(k), kind(Kind::float64), d(v) {}
    LogField(std::string_view k, bool v) : key(k), kind(Kind::boolean), b(v) {}
};

class Logger {
public:
    explicit Logger(LogFormat format = LogFormat::json, LogLevel min_level = LogLevel::info, int fd = 2)
        : format_(format), min_level_(min_level), fd_(fd) {}
    void log(LogLevel level, std::string_view msg, std::initializer_list<LogField> fields = {});
    void debug(std::string_view msg, std::initializer_list<LogField> f = {}) { log(LogLevel::debug, msg, f); }
    void info(std::string_view msg, std::initializer_list<LogField> f = {}) { log(LogLevel::info, msg, f); }
    void warn(std::string_view msg, std::initializer_list<LogField> f = {}) { log(LogLevel::warn, msg, f); }
    void error(std::string_view msg, std::initializer_list<LogField> f = {}) { log(LogLevel::error, msg, f); }
    bool enabled(LogLevel level) const { return level >= min_level_; }

private:
    LogFormat format_;
    LogLevel min_level_;
    int fd_;
};

}  // namespace tessera::server
