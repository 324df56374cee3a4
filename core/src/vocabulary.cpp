// Names of the shared vocabulary's values (tessera/tile.hpp, tessera/result.hpp).
#include "tessera/result.hpp"
#include "tessera/tile.hpp"

namespace tessera {

const char* errc_name(Errc code) {
    switch (code) {
        case Errc::invalid_argument: return "invalid argument";
        case Errc::not_found: return "not found";
        case Errc::io_error: return "I/O error";
        case Errc::corrupt: return "corrupt";
        case Errc::unsupported: return "unsupported";
        case Errc::out_of_range: return "out of range";
        case Errc::resource_exhausted: return "resource exhausted";
        case Errc::cancelled: return "cancelled";
    }
    return "unknown";
}

std::string_view to_string(Codec c) {
    switch (c) {
        case Codec::raw: return "raw";
        case Codec::zstd: return "zstd";
        case Codec::jpeg: return "jpeg";
        case Codec::bc1: return "bc1";
        case Codec::bc4: return "bc4";
        case Codec::bc5: return "bc5";
        case Codec::bc7: return "bc7";
        case Codec::layers: return "layers";
    }
    return "?";
}

std::string_view to_string(TileKind k) {
    switch (k) {
        case TileKind::absent: return "absent";
        case TileKind::present: return "present";
        case TileKind::uniform: return "uniform";
    }
    return "?";
}

std::string_view to_string(TileStatus s) {
    switch (s) {
        case TileStatus::ok: return "OK";
        case TileStatus::not_found: return "NOT_FOUND";
        case TileStatus::out_of_range: return "OUT_OF_RANGE";
        case TileStatus::invalid_argument: return "INVALID_ARGUMENT";
        case TileStatus::resource_exhausted: return "RESOURCE_EXHAUSTED";
        case TileStatus::deadline_exceeded: return "DEADLINE_EXCEEDED";
        case TileStatus::data_loss: return "DATA_LOSS";
        case TileStatus::unavailable: return "UNAVAILABLE";
        case TileStatus::internal: return "INTERNAL";
    }
    return "UNKNOWN";
}

std::optional<Codec> parse_codec(std::string_view s) {
    if (s == "raw") return Codec::raw;
    if (s == "zstd") return Codec::zstd;
    if (s == "jpeg" || s == "jpg") return Codec::jpeg;
    if (s == "bc1") return Codec::bc1;
    if (s == "bc4") return Codec::bc4;
    if (s == "bc5") return Codec::bc5;
    if (s == "bc7") return Codec::bc7;
    return std::nullopt;
}

}  // namespace tessera
