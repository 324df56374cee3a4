// TileSource over a Tessera server: TileStreamClient does the connection, the replace-semantics
// batches, the bounded receive buffer and the reconnects; this maps textures to store names.
#include <algorithm>
#include <map>
#include <mutex>
#include <vector>

#include "tessera/client/tile_source.hpp"

namespace tessera::client {

namespace {

class GrpcSource final : public TileSource {
public:
    explicit GrpcSource(TileStreamOptions options) : target_(options.target), client_(TileStreamClient::create(options)) {}

    Result<storage::StoreInfo> bind(TextureId texture, const std::string& store) override {
        auto meta = client_->get_store(store, std::chrono::seconds(10));
        if (!meta) return meta.error();
        std::lock_guard lock(mu_);
        // A texture bound again (its id reused after a refused add_texture) leaves its old store.
        if (auto old = names_.find(texture); old != names_.end()) std::erase(textures_[old->second], texture);
        names_[texture] = store;
        if (std::find(textures_[store].begin(), textures_[store].end(), texture) == textures_[store].end())
            textures_[store].push_back(texture);
        scenes_[store] = {meta->info.store_id, meta->has_scene};
        return std::move(meta->info);
    }

    Result<std::optional<std::string>> scene(const std::string& store) override {
        std::pair<std::uint64_t, bool> bound;
        {
            std::lock_guard lock(mu_);
            auto it = scenes_.find(store);
            if (it == scenes_.end()) return make_error(Errc::invalid_argument, "store '" + store + "' is not bound");
            bound = it->second;
        }
        if (!bound.second) return std::optional<std::string>{};
        auto text = client_->get_scene(store, bound.first, std::chrono::seconds(30));
        if (!text) return text.error();
        return std::optional<std::string>{std::move(*text)};
    }

    void set_requests(std::uint64_t frame, std::span<const SourceRequest> requests) override {
        std::vector<TileRequest> batch;
        batch.reserve(requests.size());
        {
            std::lock_guard lock(mu_);
            for (const auto& r : requests) {
                auto it = names_.find(r.page.texture);
                if (it == names_.end()) continue;
                batch.push_back(TileRequest{it->second, r.page.tile(), r.priority});
            }
        }
        client_->send_batch(frame, std::move(batch));
    }

    std::size_t poll(std::vector<SourceTile>& out, std::size_t max) override {
        received_.clear();
        const std::size_t n = client_->poll(received_, nullptr, max);
        std::lock_guard lock(mu_);
        for (auto& r : received_) {
            auto it = textures_.find(r.store);
            if (it == textures_.end()) continue;
            // Replies name the store, not the texture: each texture bound to it gets one (one that
            // did not ask counts it stale and drops it).
            const std::vector<TextureId>& bound = it->second;
            for (std::size_t i = 0; i < bound.size(); ++i) {
                const bool last = i + 1 == bound.size();
                out.push_back(SourceTile{PageKey{bound[i], static_cast<std::uint8_t>(r.key.level), r.key.x, r.key.y},
                                         r.store_version, r.status, last ? std::move(r.message) : r.message,
                                         last ? std::move(r.data) : r.data, r.received});
            }
        }
        return n;
    }

    bool available() const override { return client_->state() == ConnectionState::connected; }
    SourceLink link() const override {
        return SourceLink{available(), client_->last_error(), client_->stats().streams_refused};
    }
    std::string describe() const override { return "tessera server " + target_; }

private:
    std::string target_;
    std::unique_ptr<TileStreamClient> client_;
    std::mutex mu_;
    std::map<TextureId, std::string> names_;
    std::map<std::string, std::vector<TextureId>> textures_;  // a store may back several textures
    std::map<std::string, std::pair<std::uint64_t, bool>> scenes_;  // store -> (version bound, has a scene)
    std::vector<ReceivedTile> received_;  // poll() is called from one thread (the runtime's)
};

}  // namespace

std::unique_ptr<TileSource> make_grpc_source(TileStreamOptions options) {
    return std::make_unique<GrpcSource>(std::move(options));
}

}  // namespace tessera::client
