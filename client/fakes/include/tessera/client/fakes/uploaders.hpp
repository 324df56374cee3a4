#pragma once
// Uploaders for programs without a GPU: FakeUploader records every call (tests), NullUploader
// discards pixels (the load tester's viewers, benchmarks). Not part of the runtime library: link
// tessera::client_fakes.
#include <cstddef>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "tessera/client/upload.hpp"

namespace tessera::client {

// Records every call, copying the data, for tests.
class FakeUploader final : public PageUploader {
public:
    explicit FakeUploader(PagePoolFormat format = {}) : format_(format) {}
    PagePoolFormat pool_format() const override { return format_; }

    struct PageCall {
        std::uint64_t seq = 0;  // order among all calls, from 0
        SlotId slot = kNoSlot;
        PageKey page;
        std::uint32_t tile_size = 0;
        std::vector<std::uint8_t> data;  // the page as uploaded, in pool_format()
    };
    struct BlockCall {
        std::uint64_t seq = 0;
        TextureId texture = 0;
        std::uint8_t level = 0;
        std::uint32_t bx = 0, by = 0;
        std::vector<std::uint32_t> entries;  // empty: unallocated
    };
    struct TableCall {
        std::uint64_t seq = 0;
        TextureId texture = 0;
        std::uint8_t level = 0;
        std::uint32_t x0 = 0, y0 = 0, w = 0, h = 0;
        std::vector<std::uint32_t> entries;
    };

    void upload_page(SlotId slot, const PageKey& page, std::span<const std::uint8_t> page_data, std::uint32_t tile_size) override;
    void upload_page_table(TextureId texture, std::uint8_t level, std::uint32_t x0, std::uint32_t y0, std::uint32_t w,
                           std::uint32_t h, std::span<const std::uint32_t> entries) override;
    void upload_page_table_block(TextureId texture, std::uint8_t level, std::uint32_t bx, std::uint32_t by,
                                 std::span<const std::uint32_t> entries) override;

    // Fading out like a renderer that takes `frames` calls of take_faded_out (one per runtime
    // frame) to fade a page out, and, as the renderer, gives the slot back one call after its
    // weight reached 0 (a frame in which the feedback may still see it and cancel); 0 (the
    // default): does not fade out.
    void set_fade_out_frames(std::uint32_t frames) { fade_out_frames_ = frames; }
    bool fades_out() const override { return fade_out_frames_ > 0; }
    void fade_out(SlotId slot) override;
    void cancel_fade_out(SlotId slot) override;
    void take_faded_out(std::vector<SlotId>& out) override;
    std::size_t fade_out_calls() const { return fade_out_calls_; }
    // cancel_fade_out calls for a slot that was leaving, and for one that was not (a runtime bug).
    std::size_t fade_out_cancels() const { return fade_out_cancels_; }
    std::size_t stray_cancels() const { return stray_cancels_; }
    // Of fade_out_cancels(), those of a page that had faded out but was not yet given back.
    std::size_t cancelled_after_fading_out() const { return cancelled_gone_; }
    const std::vector<SlotId>& cancelled() const { return cancelled_; }  // every cancel_fade_out, in order
    // Slots leaving now (faded out and not yet given back included), and pages written into a
    // slot while it was leaving (a runtime bug).
    std::vector<SlotId> leaving() const;
    std::size_t written_while_leaving() const { return written_while_leaving_; }

    const std::vector<PageCall>& pages() const { return pages_; }
    const std::vector<TableCall>& tables() const { return tables_; }
    const std::vector<BlockCall>& blocks() const { return blocks_; }
    // Calls whose data had the wrong size (a page not page_upload_bytes of pool_format(), entries
    // != w * h, a block's entries neither kBlockEntries nor empty).
    std::size_t malformed() const { return malformed_; }
    void clear();

private:
    PagePoolFormat format_;
    std::uint64_t seq_ = 0;
    std::vector<PageCall> pages_;
    std::vector<TableCall> tables_;
    std::vector<BlockCall> blocks_;
    std::size_t malformed_ = 0;
    std::uint32_t fade_out_frames_ = 0;
    std::vector<std::pair<SlotId, std::uint32_t>> leaving_;  // slot, take_faded_out calls left
    std::vector<SlotId> cancelled_;
    std::vector<SlotId> gone_;     // faded out, given back by the next take_faded_out
    std::size_t cancelled_gone_ = 0;
    std::size_t fade_out_calls_ = 0, written_while_leaving_ = 0, fade_out_cancels_ = 0, stray_cancels_ = 0;
};

// Discards every call: a viewer with no GPU (load tests, benchmarks).
class NullUploader final : public PageUploader {
public:
    explicit NullUploader(PagePoolFormat format = {}) : format_(format) {}
    PagePoolFormat pool_format() const override { return format_; }
    void upload_page(SlotId, const PageKey&, std::span<const std::uint8_t>, std::uint32_t) override {}
    void upload_page_table(TextureId, std::uint8_t, std::uint32_t, std::uint32_t, std::uint32_t, std::uint32_t,
                           std::span<const std::uint32_t>) override {}

private:
    PagePoolFormat format_;
};

}  // namespace tessera::client
