#pragma once
// A TileSource decorator that emulates a network link between a viewer and its source: added
// one-way latency, uniform jitter and a bandwidth cap (`tessera loadtest --latency --jitter
// --bandwidth`, `tessera bench`). Requests pass straight through (set_requests forwards to the
// inner source, keeping its replace semantics); replies are held back:
//
//   arrival = max(reached_link, link_free) + bytes * 8 / bandwidth + latency + U[0, jitter]
//
// where reached_link is when the tile came from the inner source (its `received` stamp, or the
// poll that took it), and link_free is when the link finished sending the previous tile, so the
// cap serializes tiles in the order they came. A tile is delivered by the first poll() at or after
// its arrival, with `received` set to its arrival. Tiles for requests that were replaced may still
// be delivered, as on a real link. With jitter, tiles may overtake each other.
//
// No thread of its own: the link advances inside poll(). At most `max_in_link` tiles wait in the
// link; beyond that it stops taking tiles from the inner source, whose own bound then pushes back.
// Like every source, poll() is called from one thread.
#include <chrono>
#include <cstdint>
#include <memory>

#include "tessera/client/tile_source.hpp"

namespace tessera::client {

struct EmulatedLink {
    std::chrono::microseconds latency{0}, jitter{0};
    double bandwidth_bits_per_s = 0;  // 0: unlimited
};

std::unique_ptr<TileSource> make_emulated_source(std::unique_ptr<TileSource> inner, EmulatedLink link,
                                                 std::uint64_t seed);

}  // namespace tessera::client
