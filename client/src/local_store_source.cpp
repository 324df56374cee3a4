// TileSource over .tsr files read directly: a few reader threads serve the newest request set,
// highest priority first (worker_source.hpp holds the queues).
#include <map>
#include <memory>
#include <mutex>

#include "tessera/client/tile_source.hpp"
#include "tessera/storage/store_reader.hpp"
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
        return info;
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
};

}  // namespace

std::unique_ptr<TileSource> make_local_store_source(unsigned threads, std::size_t max_buffered) {
    return std::make_unique<LocalStoreSource>(threads, max_buffered);
}

}  // namespace tessera::client
