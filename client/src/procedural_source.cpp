// procedural:coords:... textures: tiles made on demand by worker threads (worker_source.hpp).
#include "procedural_source.hpp"

#include <xxhash.h>

#include <algorithm>
#include <charconv>
#include <map>
#include <mutex>
#include <vector>

#include "tessera/storage/image_source.hpp"
#include "worker_source.hpp"

namespace tessera::client {

namespace {

constexpr std::string_view kPrefix = "procedural:";
constexpr std::string_view kCoords = "procedural:coords:";

std::vector<std::string_view> split(std::string_view s) {
    std::vector<std::string_view> out;
    for (;;) {
        const auto colon = s.find(':');
        out.push_back(s.substr(0, colon));
        if (colon == std::string_view::npos) return out;
        s.remove_prefix(colon + 1);
    }
}

Result<std::uint64_t> number(const std::string& spec, std::string_view what, std::string_view text) {
    std::uint64_t v = 0;
    auto [p, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (text.empty() || ec != std::errc() || p != text.data() + text.size())
        return Error{Errc::invalid_argument, "'" + spec + "': " + std::string(what) + " '" + std::string(text) + "' is not a number"};
    return v;
}

}  // namespace

Result<storage::StoreInfo> procedural_store_info(const std::string& spec) {
    const std::string usage = " (expected procedural:coords:SIZE[:TILE_SIZE[:BORDER]])";
    if (spec.rfind(kCoords, 0) != 0) {
        if (spec.rfind(kPrefix, 0) == 0)
            return Error{Errc::invalid_argument, "unknown on-demand procedural texture '" + spec + "'" + usage +
                                                     "; procedural:terrain is a build input (`tessera build`)"};
        return Error{Errc::invalid_argument, "'" + spec + "' is not a procedural texture" + usage};
    }
    const auto fields = split(std::string_view(spec).substr(kCoords.size()));
    if (fields.size() > 3) return Error{Errc::invalid_argument, "'" + spec + "': too many fields" + usage};
    auto size = number(spec, "size", fields[0]);
    if (!size) return size.error();
    std::uint64_t tile = 256, border = 4;
    if (fields.size() > 1) {
        auto t = number(spec, "tile size", fields[1]);
        if (!t) return t.error();
        tile = *t;
    }
    if (fields.size() > 2) {
        auto b = number(spec, "border", fields[2]);
        if (!b) return b.error();
        border = *b;
    }
    if (*size < 1 || *size > storage::kMaxProceduralSize)
        return Error{Errc::invalid_argument, "'" + spec + "': size must be 1 to " + std::to_string(storage::kMaxProceduralSize) +
                                                 " texels per side, got " + std::to_string(*size)};
    if (tile < 64 || tile > 1024 || (tile & (tile - 1)) != 0)
        return Error{Errc::invalid_argument,
                     "'" + spec + "': tile size must be a power of two from 64 to 1024, got " + std::to_string(tile)};
    if (border % 2 != 0 || border > tile / 4)
        return Error{Errc::invalid_argument, "'" + spec + "': border must be even and at most " + std::to_string(tile / 4) +
                                                 ", got " + std::to_string(border)};
    storage::StoreInfo info;
    info.width = info.height = static_cast<std::uint32_t>(*size);
    info.tile_payload = static_cast<std::uint32_t>(tile - 2 * border);
    info.border = static_cast<std::uint32_t>(border);
    info.channels = 4;
    info.sample_type = storage::SampleType::u8;
    info.colour_space = storage::ColourSpace::linear;
    info.codec = Codec::raw;
    info.has_alpha = true;
    info.levels = storage::level_geometry(info.width, info.height, info.tile_payload);
    for (auto& l : info.levels) l.present = std::uint64_t(l.tiles_x) * l.tiles_y;
    // The version a disk cache keys on: the canonical spec, so equal geometry shares entries.
    const std::string canonical = std::string(kCoords) + std::to_string(*size) + ":" + std::to_string(tile) + ":" +
                                  std::to_string(border);
    info.store_id = XXH3_64bits(canonical.data(), canonical.size());
    return info;
}

namespace {

class ProceduralSource final : public detail::WorkerSource {
public:
    ProceduralSource(unsigned threads, std::size_t max_buffered) : WorkerSource(max_buffered) { start(threads); }
    ~ProceduralSource() override { stop(); }

    Result<storage::StoreInfo> bind(TextureId texture, const std::string& store) override {
        auto info = procedural_store_info(store);
        if (!info) return info.error();
        std::lock_guard lock(mu_);
        textures_[texture] = std::make_shared<const storage::StoreInfo>(*info);
        return info;
    }

    bool available() const override { return true; }
    std::string describe() const override { return "procedural"; }

private:
    void produce(SourceTile& t) override {
        std::shared_ptr<const storage::StoreInfo> info;
        {
            std::lock_guard lock(mu_);
            auto it = textures_.find(t.page.texture);
            if (it != textures_.end()) info = it->second;
        }
        if (!info) {
            t.status = TileStatus::not_found;
            t.message = "no procedural texture bound to texture " + std::to_string(t.page.texture);
            return;
        }
        t.store_version = info->store_id;
        if (!info->contains(t.page.tile())) {
            t.status = TileStatus::out_of_range;
            t.message = "tile (" + std::to_string(t.page.level) + ", " + std::to_string(t.page.x) + ", " +
                        std::to_string(t.page.y) + ") is outside the texture";
            return;
        }
        auto& payload = t.data.payload;
        payload.resize(std::size_t(info->tile_size()) * info->tile_size() * 4);
        storage::coords_tile(*info, t.page.tile(), payload);
        t.data.kind = TileKind::present;
        t.data.codec = Codec::raw;
        t.data.checksum = XXH3_64bits(payload.data(), payload.size());
    }

    std::mutex mu_;
    std::map<TextureId, std::shared_ptr<const storage::StoreInfo>> textures_;
};

}  // namespace

std::unique_ptr<TileSource> make_procedural_source(unsigned threads, std::size_t max_buffered) {
    return std::make_unique<ProceduralSource>(threads, max_buffered);
}

}  // namespace tessera::client
