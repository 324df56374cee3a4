// TileSource over .tsr files read directly: a few reader threads serve the newest request set,
// highest priority first (worker_source.hpp holds the queues).
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <mutex>

#include "tessera/client/tile_source.hpp"
#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/store_scene.hpp"
#include "worker_source.hpp"

namespace tessera::client {

namespace {

class LocalStoreSource final : public detail::WorkerSource {
public:
    LocalStoreSource(unsigned threads, std::size_t max_buffered) : WorkerSource(max_buffered) { start(threads); }
    ~LocalStoreSource() override { stop(); }

    Result<storage::StoreInfo> bind(TextureId texture, const std::string& store) override {
        auto reader = storage::StoreReader::open(store);
        if (!reader) return reader.error();
        storage::StoreInfo info = (*reader)->info();
        std::lock_guard lock(readers_mu_);
        readers_[texture] = std::move(*reader);
        store_ids_[store] = info.store_id;
        return info;
    }

    Result<std::optional<std::string>> scene(const std::string& store) override {
        std::uint64_t id = 0;
        {
            std::lock_guard lock(readers_mu_);
            auto it = store_ids_.find(store);
            if (it == store_ids_.end()) return make_error(Errc::invalid_argument, "store '" + store + "' is not bound");
            id = it->second;
        }
        const auto path = storage::find_scene_beside(store, id);
        if (!path) return std::optional<std::string>{};
        std::ifstream f(*path, std::ios::binary);
        std::string text(std::istreambuf_iterator<char>(f), {});
        if (f.bad() || (!f.eof() && !f)) return make_error(Errc::io_error, "cannot read the scene '" + *path + "'");
        return std::optional<std::string>{std::move(text)};
    }

    bool available() const override { return true; }
    std::string describe() const override { return "local store"; }

private:
    void produce(SourceTile& t) override {
        std::shared_ptr<storage::StoreReader> reader;
        {
            std::lock_guard lock(readers_mu_);
            auto it = readers_.find(t.page.texture);
            if (it != readers_.end()) reader = it->second;
        }
        if (!reader) {
            t.status = TileStatus::not_found;
            t.message = "no store bound to texture " + std::to_string(t.page.texture);
            return;
        }
        t.store_version = reader->info().store_id;
        auto tile = reader->read_tile(t.page.tile());
        if (!tile) {
            const Errc code = tile.error().code;
            t.status = code == Errc::corrupt        ? TileStatus::data_loss
                       : code == Errc::out_of_range ? TileStatus::out_of_range
                                                    : TileStatus::internal;
            t.message = tile.error().message;
            return;
        }
        t.data = TileData{tile->kind, reader->info().codec, tile->checksum, std::move(tile->bytes)};
    }

    std::mutex readers_mu_;
    std::map<TextureId, std::shared_ptr<storage::StoreReader>> readers_;
    std::map<std::string, std::uint64_t> store_ids_;  // bound store file -> its id (for its scene)
};

}  // namespace

std::unique_ptr<TileSource> make_local_store_source(unsigned threads, std::size_t max_buffered) {
    return std::make_unique<LocalStoreSource>(threads, max_buffered);
}

}  // namespace tessera::client
