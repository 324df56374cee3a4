#pragma once
// "HOST:PORT" as every address in Tessera is written: listening addresses (--http, --grpc), gRPC
// targets, origin URLs' authorities and HTTP Host headers. One parser, so that all of them agree
// on brackets and on what a port is.
#include <cstdint>
#include <optional>
#include <string_view>

namespace tessera {

struct HostPort {
    std::string_view host;  // as written, less the brackets of an IPv6 literal
    std::string_view port;  // the characters after the port's colon (empty: none, or "HOST:")
    bool has_port = false;  // a port's colon was there
    bool bracketed = false; // HOST was "[...]"
};

// Splits at the port's colon: after the closing ']' of a bracketed host, else the last ':' (so an
// unbracketed host may itself hold colons; callers that take a plain name refuse them). Nothing
// when a '[' has no ']' or the ']' is followed by something other than ":PORT".
std::optional<HostPort> split_host_port(std::string_view text);

// A port: one to five decimal digits, at most 65535 (0 included; callers that need a real port
// refuse it). Nothing for anything else: empty, signs, spaces, 65536 and more.
std::optional<std::uint16_t> parse_port(std::string_view digits);

}  // namespace tessera
