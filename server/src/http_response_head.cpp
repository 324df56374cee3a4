#include "http_response_head.hpp"

#include <charconv>

#include <boost/beast/http/status.hpp>

namespace tessera::server {

namespace {

void append_header(std::string& out, std::string_view name, std::string_view value) {
    out.append(name);
    out.append(": ", 2);
    out.append(value);
    out.append("\r\n", 2);
}

void append_number(std::string& out, std::size_t v) {
    char buf[24];
    const auto end = std::to_chars(buf, buf + sizeof buf, v).ptr;
    out.append(buf, static_cast<std::size_t>(end - buf));
}

}  // namespace

void write_response_head(std::string& out, const HttpResponse& r, unsigned version, bool keep_alive,
                         std::size_t content_length) {
    namespace http = boost::beast::http;
    out.clear();
    out.append(version == 10 ? "HTTP/1.0 " : "HTTP/1.1 ");
    append_number(out, r.status);
    out.push_back(' ');
    const auto reason = http::obsolete_reason(http::int_to_status(r.status));
    out.append(reason.data(), reason.size());
    out.append("\r\n", 2);
    if (!r.content_type.empty()) append_header(out, "Content-Type", r.content_type);
    for (const auto& [k, v] : r.headers) append_header(out, k, v);
    if (!bodiless_status(r.status)) {
        out.append("Content-Length: ");
        append_number(out, content_length);
        out.append("\r\n", 2);
    }
    if (version >= 11 && !keep_alive) append_header(out, "Connection", "close");
    else if (version < 11 && keep_alive) append_header(out, "Connection", "keep-alive");
    out.append("\r\n", 2);
}

}  // namespace tessera::server
