#pragma once
// Where the runtime gets tiles it has in no cache: a Tessera server over gRPC, or a .tsr file read
// directly (no server needed). Both follow the protocol's rule: each request set replaces the
// previous one, so requests nobody needs any more are cancelled at the source.
//
// A source serves several virtual textures; bind() names the store behind each texture id.
// Every call is non-blocking: sources own their threads and their bounded queues.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "tessera/client/page.hpp"
#include "tessera/client/net/tile_stream_client.hpp"
#include "tessera/result.hpp"
#include "tessera/storage/types.hpp"

namespace tessera::client {

struct SourceRequest {
    PageKey page;
    float priority = 0;
};

// One arrived tile of a texture. `data` is moved along, never copied, from the source to the caches.
struct SourceTile {
    PageKey page;
    std::uint64_t store_version = 0;
    TileStatus status = TileStatus::ok;
    std::string message;  // when status is not ok
    TileData data;        // when status is ok
    // When the tile reached the client (read off the stream, read from the store, or delivered by
    // an emulated link); zero when the source does not say. Polling may happen a frame later.
    std::chrono::steady_clock::time_point received{};
};

// How a source's link to its server stands. A local source is always connected.
struct SourceLink {
    bool connected = true;
    std::string last_error;             // the last stream error ("UNAVAILABLE: ..."), or empty
    std::uint64_t streams_refused = 0;  // streams the server ended with RESOURCE_EXHAUSTED (too many viewers)
};

class TileSource {
public:
    virtual ~TileSource() = default;
    // The store behind a texture id, and its geometry (for requests and decoding).
    virtual Result<storage::StoreInfo> bind(TextureId texture, const std::string& store) = 0;
    // Replaces the outstanding request set (the newest frame wins).
    virtual void set_requests(std::uint64_t frame, std::span<const SourceRequest> requests) = 0;
    // Moves up to max arrived tiles into out (appending); returns how many it took. A reply for a
    // store bound to several textures is appended once per texture.
    virtual std::size_t poll(std::vector<SourceTile>& out, std::size_t max = SIZE_MAX) = 0;
    // False while a remote source is disconnected (rendering goes on with what is resident).
    virtual bool available() const = 0;
    // available() with what a remote source knows about its link (default: available() alone).
    virtual SourceLink link() const { return SourceLink{available(), {}, 0}; }
    virtual std::string describe() const = 0;
    // The scene that travels with a bound store (an atlas OBJ's text, docs/atlas.md): beside a
    // store file, or from its server. nullopt when it has none (the default for sources that
    // cannot carry one); an error when it has one that cannot be read.
    virtual Result<std::optional<std::string>> scene(const std::string& store) {
        (void)store;
        return std::optional<std::string>{};
    }
};

// Reads stores directly. `threads` readers serve the newest request set, highest priority first;
// at most `max_buffered` read tiles wait to be polled (beyond it, reading pauses).
std::unique_ptr<TileSource> make_local_store_source(unsigned threads = 1, std::size_t max_buffered = 256);

// A Tessera server, through TileStreamClient (reconnects with backoff by itself).
std::unique_ptr<TileSource> make_grpc_source(TileStreamOptions options);

}  // namespace tessera::client
