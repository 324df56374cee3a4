#include "height_layer.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <thread>
#include <vector>

#include "tessera/half_float.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/layers.hpp"
#include "tessera/storage/store_reader.hpp"

namespace tessera::tools {

std::optional<std::size_t> height_layer(const storage::StoreInfo& info) {
    for (std::size_t i = 0; i < info.layers.size(); ++i)
        if (info.layers[i].name == "height" && info.layers[i].channels == 1) return i;
    return std::nullopt;
}

namespace {

float sample_at(const std::uint8_t* p, storage::SampleType t) {
    switch (t) {
        case storage::SampleType::u8: return float(*p);
        case storage::SampleType::u16: {
            std::uint16_t v;
            std::memcpy(&v, p, 2);
            return float(v);
        }
        case storage::SampleType::f16: {
            std::uint16_t v;
            std::memcpy(&v, p, 2);
            return half_to_float(v);
        }
        case storage::SampleType::f32: {
            float v;
            std::memcpy(&v, p, 4);
            return v;
        }
    }
    return 0;
}

}  // namespace

Result<HeightLayerRead> read_height_layer(client::TileSource& source, client::TextureId texture, const storage::StoreInfo& info,
                                          std::size_t layer, std::uint32_t samples_across, std::chrono::milliseconds timeout) {
    if (layer >= storage::layer_count(info)) return make_error(Errc::invalid_argument, fmt::format("no layer {}", layer));
    const storage::StoreInfo part_info = storage::layer_store_info(info, layer);
    if (part_info.channels != 1) return make_error(Errc::invalid_argument, "a height layer has one channel");
    // The coarsest level wide enough (levels are finest first).
    std::uint32_t level = 0;
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        if (std::max(info.levels[l].width, info.levels[l].height) >= samples_across) level = l;
    const auto& li = info.levels[level];

    std::vector<client::SourceRequest> requests;
    for (std::uint32_t y = 0; y < li.tiles_y; ++y)
        for (std::uint32_t x = 0; x < li.tiles_x; ++x)
            requests.push_back({client::PageKey{texture, static_cast<std::uint8_t>(level), x, y}, 1.0f});
    source.set_requests(1, requests);

    HeightLayerRead out;
    out.level = level;
    out.tiles = requests.size();
    auto field = std::make_shared<scene::HeightField>();
    field->width = li.width;
    field->height = li.height;
    field->texels_per_sample = std::ldexp(1.0, int(level));  // store levels round up: not width / size
    field->samples.assign(std::size_t(li.width) * li.height, 0.0f);
    const std::uint32_t P = info.tile_payload, B = info.border, ts = info.tile_size();
    const std::size_t sb = storage::sample_bytes(part_info.sample_type);
    std::vector<bool> seen(requests.size(), false);
    std::size_t done = 0;
    std::uint64_t frame = 1;
    bool retry = false;
    std::vector<client::SourceTile> arrived;
    std::vector<std::uint8_t> samples;
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    const auto fail = [&](Error e) {
        source.set_requests(++frame, {});
        return e;
    };
    while (done < requests.size()) {
        if (std::chrono::steady_clock::now() > deadline)
            return fail(Error{Errc::io_error, fmt::format("height layer: {} of {} tiles of level {} arrived in {} s", done,
                                                             requests.size(), level, timeout.count() / 1000.0)});
        if (retry) {  // what has not arrived, again, after a pause
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
            std::vector<client::SourceRequest> again;
            for (std::size_t i = 0; i < requests.size(); ++i)
                if (!seen[i]) again.push_back(requests[i]);
            source.set_requests(++frame, again);
            retry = false;
        }
        arrived.clear();
        if (source.poll(arrived) == 0) {
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
            continue;
        }
        for (auto& t : arrived) {
            if (t.page.texture != texture || t.page.level != level || t.page.x >= li.tiles_x || t.page.y >= li.tiles_y) continue;
            const std::size_t index = std::size_t(t.page.y) * li.tiles_x + t.page.x;
            if (seen[index]) continue;
            seen[index] = true;
            ++done;
            const std::string where = fmt::format("height layer: tile {}/{}/{}", level, t.page.x, t.page.y);
            if (t.status == TileStatus::unavailable || t.status == TileStatus::resource_exhausted ||
                t.status == TileStatus::deadline_exceeded) {  // the server's to retry: ask again
                seen[index] = false;
                --done;
                retry = true;
                continue;
            }
            if (t.status != TileStatus::ok) return fail(Error{Errc::io_error, where + ": " + t.message});
            if (t.data.kind == TileKind::absent) continue;  // no data: the sea floor, 0
            storage::Tile tile{t.page.tile(), t.data.kind, false, 0, std::move(t.data.payload)};
            if (info.layered()) {
                auto parts = storage::split_layers(info, tile.bytes);
                if (!parts) return fail(Error{parts.error().code, where + ": " + parts.error().message});
                if ((*parts)[layer].kind == TileKind::absent) continue;
                tile = storage::layer_tile(tile.key, (*parts)[layer]);
            }
            if (Status st = storage::decode_tile(part_info, tile, samples); !st)
                return fail(Error{st.error().code, where + ": " + st.error().message});
            // The interior [B, B + P) of the tile is level samples [x * P, (x + 1) * P).
            const std::uint32_t x0 = t.page.x * P, y0 = t.page.y * P;
            const std::uint32_t w = std::min(P, li.width - x0), h = std::min(P, li.height - y0);
            for (std::uint32_t y = 0; y < h; ++y)
                for (std::uint32_t x = 0; x < w; ++x)
                    field->samples[std::size_t(y0 + y) * li.width + x0 + x] =
                        sample_at(samples.data() + (std::size_t(B + y) * ts + B + x) * sb, part_info.sample_type);
        }
    }
    source.set_requests(++frame, {});

    // To [0, 1]: integers by their range, floats by what they hold.
    float lo = 0, hi = 1;
    if (part_info.sample_type == storage::SampleType::u8) hi = 255;
    else if (part_info.sample_type == storage::SampleType::u16) hi = 65535;
    else {
        const auto [mn, mx] = std::minmax_element(field->samples.begin(), field->samples.end());
        if (!std::isfinite(*mn) || !std::isfinite(*mx))
            return make_error(Errc::corrupt, fmt::format("height layer: level {} holds a NaN or an infinity", level));
        lo = *mn;
        hi = *mx > *mn ? *mx : *mn + 1;
    }
    for (float& v : field->samples) v = (v - lo) / (hi - lo);
    out.field = std::move(field);
    return out;
}

}  // namespace tessera::tools
