#include "tessera/client/page.hpp"

namespace tessera::client {

namespace {
constexpr PageFormat kAll[] = {PageFormat::rgba8, PageFormat::bc1,  PageFormat::bc4,  PageFormat::bc5,
                               PageFormat::bc7,   PageFormat::r16,  PageFormat::r16f, PageFormat::r32f};
}  // namespace

std::string_view to_string(PageFormat f) {
    switch (f) {
        case PageFormat::rgba8: return "rgba8";
        case PageFormat::bc1: return "bc1";
        case PageFormat::bc4: return "bc4";
        case PageFormat::bc5: return "bc5";
        case PageFormat::bc7: return "bc7";
        case PageFormat::r16: return "r16";
        case PageFormat::r16f: return "r16f";
        case PageFormat::r32f: return "r32f";
    }
    return "?";
}

std::optional<PageFormat> parse_page_format(std::string_view s) {
    for (PageFormat f : kAll)
        if (to_string(f) == s) return f;
    return std::nullopt;
}

}  // namespace tessera::client
