#pragma once
// The upload side of the render thread (docs/client.md, "One frame, end to end", step 7): pages
// made GPU-ready by the transcode pool wait in an UploadQueue; each frame the render thread takes
// at most a budget of them (pages and bytes), highest priority first, and hands them to a
// PageUploader (the GL renderer, or FakeUploader in tests). The queue holds no pixels: a ReadyPage
// points at staging memory that its producer owns and keeps alive until the page is uploaded or
// dropped.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "tessera/client/page.hpp"

namespace tessera::client {

// How an uploader's pool holds pages: the runtime transcodes every page to this.
struct PagePoolFormat {
    PageFormat format = PageFormat::rgba8;  // layer 0's (the only layer of a one-layer pool)
    // Each upload of a page in a block format carries its half-size second level after it
    // (page_upload_bytes): an atlas with two levels, which the GPU cannot render into for block
    // formats (other formats' second levels are rendered on the GPU).
    bool second_level = false;
    // A multi-layer pool (docs/client.md, "Layers"): the formats of layers 1, 2, ...; empty for one
    // layer. A slot holds one page of every layer; an upload carries them in layer order.
    std::vector<PageFormat> more_layers;

    std::size_t layer_count() const { return 1 + more_layers.size(); }
    PageFormat layer_format(std::size_t layer) const { return layer == 0 ? format : more_layers.at(layer - 1); }
    bool layer_second_level(std::size_t layer) const {
        return second_level && is_block_compressed(layer_format(layer));
    }
    // Bytes of layer `layer` in an upload, and where they start in it.
    std::size_t layer_bytes(std::size_t layer, std::uint32_t tile_size) const {
        return page_upload_bytes(layer_format(layer), tile_size, layer_second_level(layer));
    }
    std::size_t layer_offset(std::size_t layer, std::uint32_t tile_size) const {
        std::size_t at = 0;
        for (std::size_t i = 0; i < layer; ++i) at += layer_bytes(i, tile_size);
        return at;
    }
    // Bytes of one upload: every layer's page.
    std::size_t upload_bytes(std::uint32_t tile_size) const { return layer_offset(layer_count(), tile_size); }
};

// One write of a texture's page table, in the renderer's page-table entry format.
struct PageTableWrite {
    TextureId texture = 0;
    std::uint8_t level = 0;
    // false: the w x h rectangle at (x0, y0) of a dense table, `entries` row-major (w*h of them).
    // true: block (x0, y0) of a sparse table (PageTable::sparse()) now holds `entries`
    // (PageTable::kBlockEntries, rows of kBlockSide), or is unallocated when `entries` is empty
    // (its entries resolve through level + 5); w and h unused.
    bool sparse_block = false;
    std::uint32_t x0 = 0, y0 = 0, w = 0, h = 0;
    std::span<const std::uint32_t> entries;
};

// A slot's blend weight (docs/client.md, "A slot's life"): 255 draws its page as it is, 0 as
// what is above it (its nearest resident ancestor), between them a blend of the two.
struct SlotWeight {
    SlotId slot = kNoSlot;
    std::uint8_t weight = 255;
};

// Where the runtime's pages go: a sink that writes what the runtime's page cache decided (which
// page is in which slot, the page tables, the blend weights) into the renderer's memory. It
// decides nothing itself. Called on the render thread only, from Runtime::frame().
class PageUploader {
public:
    // The format pages must come in (default: RGBA8, one level).
    virtual PagePoolFormat pool_format() const { return {}; }
    // Copy one page (tile_size x tile_size texels in pool_format(), rows top to bottom, border
    // included; pool_format().upload_bytes of them: every layer's page, in layer order) into
    // physical slot `slot`. `page` says which page it is (the GL renderer derives each page's
    // next coarser level from it, clamped at the texture's edges). The span is valid only during
    // the call.
    virtual void upload_page(SlotId slot, const PageKey& page, std::span<const std::uint8_t> page_data,
                             std::uint32_t tile_size) = 0;
    // Write part of a page table (see PageTableWrite).
    virtual void write_page_table(const PageTableWrite& write) = 0;
    // New blend weights of some slots (every slot starts at 255). The default ignores them: an
    // uploader that draws nothing (benchmarks, load tests).
    virtual void set_slot_weights(std::span<const SlotWeight> /*weights*/) {}

    // Shorthands for write_page_table.
    void upload_page_table(TextureId texture, std::uint8_t level, std::uint32_t x0, std::uint32_t y0, std::uint32_t w,
                           std::uint32_t h, std::span<const std::uint32_t> entries) {
        write_page_table(PageTableWrite{texture, level, false, x0, y0, w, h, entries});
    }
    void upload_page_table_block(TextureId texture, std::uint8_t level, std::uint32_t bx, std::uint32_t by,
                                 std::span<const std::uint32_t> entries) {
        write_page_table(PageTableWrite{texture, level, true, bx, by, 0, 0, entries});
    }

protected:
    // Not deleted through this interface: the runtime only borrows its uploader.
    ~PageUploader() = default;
};

// Memory a page is decoded into, lent by the one who uploads it (docs/client.md, "One frame, end
// to end", step 7). The runtime takes a buffer before a page is transcoded, a transcode thread
// writes the page into it, upload_page reads it, and the runtime gives it back. An uploader whose
// staging memory the GPU reads directly (the GL renderer's mapped pixel buffer) lends it, so a
// page's texels are written once on the CPU, by the transcoder, and never copied again. Without a
// lender (or when it has none free) the runtime decodes into its own memory and upload_page
// copies. Called on the render thread only (the memory is written on the transcode threads).
struct StagingBuffer {
    std::uint32_t id = 0;
    std::span<std::uint8_t> bytes;  // empty: none lent
};

class PageStaging {
public:
    // A buffer of at least `bytes` for one page, or an empty one when none is free now.
    virtual StagingBuffer acquire(std::size_t bytes) = 0;
    // Given back: uploaded (the lender reuses it once the GPU has read it) or never used.
    virtual void release(std::uint32_t id) = 0;

protected:
    ~PageStaging() = default;  // the runtime only borrows its lender
};

// A page ready to upload.
struct ReadyPage {
    PageKey key;
    SlotId slot = kNoSlot;    // where it goes (already unmapped by the residency side)
    float priority = 0.0f;    // higher first (NaN counts as lowest)
    std::uint64_t ticket = 0;  // request ticket; among equal priorities the lower goes first
    std::span<const std::uint8_t> data;  // the page in the pool's format; staging memory owned elsewhere
    std::uint32_t bytes = 0;  // counted against the byte budget (normally data.size())
    std::chrono::steady_clock::time_point requested{};  // for tile latency (request -> mapped)
};

// A bounded priority queue (binary heap) of ready pages with a per-frame budget. Not thread-safe:
// owned by the render thread (the transcode pool hands pages over through its own queue).
class UploadQueue {
public:
    // max_pages_per_frame: pages take_frame returns at most. max_bytes_per_frame: their bytes at
    // most, except that a frame always takes at least one page when any is queued (and
    // max_pages_per_frame > 0), so a page larger than the byte budget cannot block the queue.
    // capacity: pages held at most.
    UploadQueue(std::size_t max_pages_per_frame, std::size_t max_bytes_per_frame, std::size_t capacity);

    // Queue a page. false (and `page` left untouched) when the queue is full.
    bool push(ReadyPage&& page);
    // Append this frame's pages to `out`, highest priority first (ties: lower ticket first),
    // stopping at the first page that does not fit the budgets; the rest stays queued, so the
    // order is strict. Returns how many were appended.
    std::size_t take_frame(std::vector<ReadyPage>& out);
    // Remove the pages `stale` matches (cancelled, slot reassigned, ...). Returns how many.
    std::size_t drop_if(const std::function<bool(const ReadyPage&)>& stale);

    std::size_t size() const { return heap_.size(); }
    bool empty() const { return heap_.empty(); }
    std::size_t capacity() const { return capacity_; }
    std::size_t queued_bytes() const { return queued_bytes_; }
    std::size_t max_pages_per_frame() const { return max_pages_; }
    std::size_t max_bytes_per_frame() const { return max_bytes_; }

private:
    std::size_t max_pages_;
    std::size_t max_bytes_;
    std::size_t capacity_;
    std::size_t queued_bytes_ = 0;
    std::vector<ReadyPage> heap_;  // std::push_heap order: the front is the next to go
};

}  // namespace tessera::client
