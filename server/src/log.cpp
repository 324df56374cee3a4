#include "log.hpp"

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>

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

void append_json_string(std::string& out, std::string_view s) {
    out += '"';
    for (unsigned char c : s) {
        switch (c) {
            case '"': out += "\\\""; break;
            case '\\': out += "\\\\"; break;
            case '\n': out += "\\n"; break;
            case '\r': out += "\\r"; break;
            case '\t': out += "\\t"; break;
            default:
                if (c < 0x20) {
                    char buf[8];
                    std::snprintf(buf, sizeof buf, "\\u%04x", c);
                    out += buf;
                } else {
                    out += static_cast<char>(c);
                }
        }
    }
    out += '"';
}

void append_value(std::string& out, const LogField& f, bool json) {
    char buf[64];
    switch (f.kind) {
        case LogField::Kind::string:
            if (json) append_json_string(out, f.s);
            else if (f.s.find_first_of(" \"=") != std::string_view::npos) append_json_string(out, f.s);
            else out += f.s;
            return;
        case LogField::Kind::int64: std::snprintf(buf, sizeof buf, "%lld", static_cast<long long>(f.i)); break;
        case LogField::Kind::uint64: std::snprintf(buf, sizeof buf, "%llu", static_cast<unsigned long long>(f.u)); break;
        case LogField::Kind::float64:
            if (std::isfinite(f.d)) std::snprintf(buf, sizeof buf, "%.6g", f.d);
            else std::snprintf(buf, sizeof buf, json ? "null" : "%s", json ? "" : "nan");
            break;
        case LogField::Kind::boolean: std::snprintf(buf, sizeof buf, "%s", f.b ? "true" : "false"); break;
    }
    out += buf;
}

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
    line.reserve(160);
    if (format_ == LogFormat::json) {
        line += "{\"ts\":\"";
        line += ts;
        line += "\",\"level\":\"";
        line += level_name(level);
        line += "\",\"msg\":";
        append_json_string(line, msg);
        for (const auto& f : fields) {
            line += ',';
            append_json_string(line, f.key);
            line += ':';
            append_value(line, f, true);
        }
        line += "}\n";
    } else {
        line += ts;
        line += ' ';
        line += level_name(level);
        line += ' ';
        line += msg;
        for (const auto& f : fields) {
            line += ' ';
            line += f.key;
            line += '=';
            append_value(line, f, false);
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
