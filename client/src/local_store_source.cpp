// TileSource over .tsr files read directly: a few reader threads serve the newest request set,
// highest priority first. Owner of its threads; its queues: the request set (replaced whole,
// bounded by what the runtime asks for) and the output buffer (max_buffered tiles).
#include <algorithm>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <map>
#include <mutex>
#include <thread>
#include <unordered_set>

#include "tessera/client/tile_source.hpp"
#include "tessera/storage/store_reader.hpp"

namespace tessera::client {

namespace {

class LocalStoreSource final : public TileSource {
public:
    LocalStoreSource(unsigned threads, std::size_t max_buffered) : max_buffered_(std::max<std::size_t>(1, max_buffered)) {
        for (unsigned i = 0; i < std::max(1u, threads); ++i) workers_.emplace_back([this] { work(); });
    }
    ~LocalStoreSource() override {
        {
            std::lock_guard lock(mu_);
            stop_ = true;
        }
        cv_.notify_all();
        for (auto& t : workers_) t.join();
    }

    Result<storage::StoreInfo> bind(TextureId texture, const std::string& store) override {
        auto reader = storage::StoreReader::open(store);
        if (!reader) return reader.error();
        storage::StoreInfo info = (*reader)->info();
        std::lock_guard lock(mu_);
        readers_[texture] = std::move(*reader);
        return info;
    }

    void set_requests(std::uint64_t, std::span<const SourceRequest> requests) override {
        std::lock_guard lock(mu_);
        pending_.assign(requests.begin(), requests.end());
        // Ascending priority: the next one is at the back. Already read or being read: skip.
        std::stable_sort(pending_.begin(), pending_.end(),
                         [](const SourceRequest& a, const SourceRequest& b) { return a.priority < b.priority; });
        std::erase_if(pending_, [&](const SourceRequest& r) { return in_flight_.contains(r.page); });
        wanted_.clear();
        for (const auto& r : requests) wanted_.insert(r.page);
        // Read but not yet polled, and no longer wanted: dropped.
        std::erase_if(out_, [&](const SourceTile& t) {
            if (wanted_.contains(t.page)) return false;
            in_flight_.erase(t.page);
            return true;
        });
        cv_.notify_all();
    }

    std::size_t poll(std::vector<SourceTile>& out, std::size_t max) override {
        std::lock_guard lock(mu_);
        std::size_t n = 0;
        while (n < max && !out_.empty()) {
            in_flight_.erase(out_.front().page);
            out.push_back(std::move(out_.front()));
            out_.pop_front();
            ++n;
        }
        if (n) cv_.notify_all();
        return n;
    }

    bool available() const override { return true; }
    std::string describe() const override { return "local store"; }

private:
    void work() {
        for (;;) {
            SourceRequest r;
            std::shared_ptr<storage::StoreReader> reader;
            {
                std::unique_lock lock(mu_);
                cv_.wait(lock, [&] { return stop_ || (!pending_.empty() && out_.size() < max_buffered_); });
                if (stop_) return;
                r = pending_.back();
                pending_.pop_back();
                in_flight_.insert(r.page);
                auto it = readers_.find(r.page.texture);
                if (it != readers_.end()) reader = it->second;
            }
            SourceTile t;
            t.page = r.page;
            if (!reader) {
                t.status = 1;  // TILE_NOT_FOUND
                t.message = "no store bound to texture " + std::to_string(r.page.texture);
            } else {
                t.store_version = reader->info().store_id;
                auto tile = reader->read_tile({r.page.level, r.page.x, r.page.y});
                if (!tile) {
                    t.status = tile.error().code == Errc::corrupt ? 6 : tile.error().code == Errc::out_of_range ? 2 : 8;
                    t.message = tile.error().message;
                } else {
                    t.kind = static_cast<std::uint8_t>(tile->kind);  // absent 0, present 1, uniform 2
                    t.codec = tile->kind == storage::TileKind::uniform ? 3
                              : tile->kind == storage::TileKind::absent ? 4
                                                                        : static_cast<std::uint8_t>(reader->info().codec);
                    t.checksum = tile->checksum;
                    t.payload = std::move(tile->bytes);
                }
            }
            t.received = std::chrono::steady_clock::now();
            std::lock_guard lock(mu_);
            if (!wanted_.contains(t.page)) {
                in_flight_.erase(t.page);  // superseded while it was read
                continue;
            }
            out_.push_back(std::move(t));
        }
    }

    const std::size_t max_buffered_;
    std::mutex mu_;
    std::condition_variable cv_;
    bool stop_ = false;
    std::map<TextureId, std::shared_ptr<storage::StoreReader>> readers_;
    std::vector<SourceRequest> pending_;
    std::unordered_set<PageKey, PageKeyHash> wanted_;
    std::unordered_set<PageKey, PageKeyHash> in_flight_;  // being read or waiting in out_
    std::deque<SourceTile> out_;
    std::vector<std::thread> workers_;
};

}  // namespace

std::unique_ptr<TileSource> make_local_store_source(unsigned threads, std::size_t max_buffered) {
    return std::make_unique<LocalStoreSource>(threads, max_buffered);
}

}  // namespace tessera::client
