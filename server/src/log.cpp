#include "log.hpp"

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>

#include <nlohmann/json.hpp>

namespace tessera::server {

namespace {

std::string_view level_name(LogLevel l) {
    switch (l) {
        case LogLevel::debug: return "debug";
        case LogLevel::info: return "info";
        case LogLevel::warn: return "warn";
        case LogLevel::error: return "error";
    }
    return "info";
}

// Keys in the order written (ts, level, msg, then the fields), not sorted as nlohmann::json would.
using Json = nlohmann::ordered_json;

// Six significant digits, as "%.6g" writes them: a log line has no use for more.
double six_digits(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.6g", v);
    return std::strtod(buf, nullptr);
}

Json value_of(const LogField& f) {
    switch (f.kind) {
        case LogField::Kind::string: return f.s;
        case LogField::Kind::int64: return f.i;
        case LogField::Kind::uint64: return f.u;
        case LogField::Kind::float64: return std::isfinite(f.d) ? Json(six_digits(f.d)) : Json(nullptr);
        case LogField::Kind::boolean: return f.b;
    }
    return nullptr;
}

// Compact, and bytes that are not UTF-8 (a request target, a file name) become U+FFFD instead of
// an exception: a log line is always written.
std::string dump(const Json& j) { return j.dump(-1, ' ', false, Json::error_handler_t::replace); }

}  // namespace

void Logger::log(LogLevel level, std::string_view msg, std::initializer_list<LogField> fields) {
    if (!enabled(level)) return;
    const auto now = std::chrono::system_clock::now();
    const auto us = std::chrono::duration_cast<std::chrono::microseconds>(now.time_since_epoch()).count();
    const std::time_t secs = static_cast<std::time_t>(us / 1000000);
    std::tm tm{};
    gmtime_r(&secs, &tm);
    char ts[96];
    std::snprintf(ts, sizeof ts, "%04d-%02d-%02dT%02d:%02d:%02d.%06lldZ", tm.tm_year + 1900, tm.tm_mon + 1,
                  tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, static_cast<long long>(us % 1000000));
    std::string line;
    if (format_ == LogFormat::json) {
        Json j;
        j["ts"] = ts;
        j["level"] = level_name(level);
        j["msg"] = msg;
        for (const auto& f : fields) j[std::string(f.key)] = value_of(f);
        line = dump(j);
        line += '\n';
    } else {
        line.reserve(160);
        line += ts;
        line += ' ';
        line += level_name(level);
        line += ' ';
        line += msg;
        for (const auto& f : fields) {
            line += ' ';
            line += f.key;
            line += '=';
            // Strings bare unless a reader could not tell where they end; everything else as in JSON.
            if (f.kind == LogField::Kind::string && f.s.find_first_of(" \"=") == std::string_view::npos) line += f.s;
            else line += dump(value_of(f));
        }
        line += '\n';
    }
    // One write per line: lines from different threads never interleave (a pipe or file in
    // append mode writes up to PIPE_BUF bytes atomically; longer lines are rare).
    std::size_t off = 0;
    while (off < line.size()) {
        const ssize_t n = ::write(fd_, line.data() + off, line.size() - off);
        if (n <= 0) break;
        off += static_cast<std::size_t>(n);
    }
}

}  // namespace tessera::server
