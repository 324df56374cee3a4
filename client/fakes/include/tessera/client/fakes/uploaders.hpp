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
    void write_page_table(const PageTableWrite& write) override;
    void set_slot_weights(std::span<const SlotWeight> weights) override;

    // Blend weights as the runtime set them (255 until set), and what they show: a slot whose
    // weight went down is fading out until a page is written into it or the weight rises again.
    std::uint8_t weight(SlotId slot) const { return slot < weights_.size() ? weights_[slot] : 255; }
    std::vector<SlotId> below_full() const;  // slots drawn blended: fading in, fading out or kept
    std::vector<SlotId> fading_out() const;  // slots whose weight is falling and above 0
    std::size_t weight_calls() const { return weight_calls_; }
    std::size_t fade_outs() const { return fade_outs_; }  // times a slot's weight started falling
    // Times a falling weight rose again to below 255 with no page written: a leaving page kept.
    std::size_t fade_backs() const { return fade_backs_; }
    // Pages written into a slot whose weight was falling and above 0: a page still drawn while
    // it leaves was overwritten (a runtime bug).
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
    std::vector<std::uint8_t> weights_;
    std::vector<std::uint8_t> falling_;
    std::vector<SlotId> written_;  // slots written since the last set_slot_weights
    std::size_t weight_calls_ = 0, fade_outs_ = 0, fade_backs_ = 0, written_while_leaving_ = 0;
};

// Discards every call: a viewer with no GPU (load tests, benchmarks).
class NullUploader final : public PageUploader {
public:
    explicit NullUploader(PagePoolFormat format = {}) : format_(format) {}
    PagePoolFormat pool_format() const override { return format_; }
    void upload_page(SlotId, const PageKey&, std::span<const std::uint8_t>, std::uint32_t) override {}
    void write_page_table(const PageTableWrite&) override {}

private:
    PagePoolFormat format_;
};

}  // namespace tessera::client
