#pragma once
// The status line and header block of an HTTP/1.x response, written by hand into one reusable
// string: a tile response is then two buffers (this head and the cached payload) in one gather
// write, with no per-header allocations (Beast's fields allocate one node per header).
#include <cstddef>
#include <string>

#include "http_handler.hpp"

namespace tessera::server {

// version: 10 or 11. content_length: written unless the status has no body (1xx, 204, 304),
// also for HEAD (the length the GET would have). keep_alive: the Connection header as Beast's
// message::keep_alive sets it (HTTP/1.1: "close" when false; HTTP/1.0: "keep-alive" when true).
void write_response_head(std::string& out, const HttpResponse& r, unsigned version, bool keep_alive,
                         std::size_t content_length);

// Statuses that never carry a body (RFC 9110: 1xx, 204, 304).
inline bool bodiless_status(unsigned status) { return status == 304 || status == 204 || status < 200; }

}  // namespace tessera::server
