#include "tessera/client/fakes/uploaders.hpp"

#include <algorithm>

#include "page_table.hpp"

namespace tessera::client {

void FakeUploader::upload_page(SlotId slot, const PageKey& page, std::span<const std::uint8_t> page_data, std::uint32_t tile_size) {
    if (page_data.size() != format_.upload_bytes(tile_size)) ++malformed_;
    // A write ends a fade (the runtime's deadline); counted: a runtime that waits never does it.
    if (std::erase_if(leaving_, [&](const auto& l) { return l.first == slot; }) + std::erase(gone_, slot) > 0)
        ++written_while_leaving_;
    pages_.push_back(PageCall{seq_++, slot, page, tile_size, std::vector<std::uint8_t>(page_data.begin(), page_data.end())});
}

void FakeUploader::upload_page_table(TextureId texture, std::uint8_t level, std::uint32_t x0, std::uint32_t y0,
                                     std::uint32_t w, std::uint32_t h, std::span<const std::uint32_t> entries) {
    if (entries.size() != std::size_t(w) * h) ++malformed_;
    tables_.push_back(
        TableCall{seq_++, texture, level, x0, y0, w, h, std::vector<std::uint32_t>(entries.begin(), entries.end())});
}

void FakeUploader::upload_page_table_block(TextureId texture, std::uint8_t level, std::uint32_t bx, std::uint32_t by,
                                           std::span<const std::uint32_t> entries) {
    if (!entries.empty() && entries.size() != PageTable::kBlockEntries) ++malformed_;
    blocks_.push_back(BlockCall{seq_++, texture, level, bx, by, std::vector<std::uint32_t>(entries.begin(), entries.end())});
}

void FakeUploader::fade_out(SlotId slot) {
    ++fade_out_calls_;
    leaving_.emplace_back(slot, std::max<std::uint32_t>(fade_out_frames_, 1));
}

void FakeUploader::cancel_fade_out(SlotId slot) {
    cancelled_.push_back(slot);
    if (std::erase_if(leaving_, [&](const auto& l) { return l.first == slot; }) > 0) {
        ++fade_out_cancels_;
    } else if (std::erase(gone_, slot) > 0) {
        ++fade_out_cancels_;
        ++cancelled_gone_;
    } else {
        ++stray_cancels_;
    }
}

void FakeUploader::take_faded_out(std::vector<SlotId>& out) {
    out.insert(out.end(), gone_.begin(), gone_.end());
    gone_.clear();
    for (auto it = leaving_.begin(); it != leaving_.end();) {
        if (--it->second == 0) {
            gone_.push_back(it->first);
            it = leaving_.erase(it);
        } else {
            ++it;
        }
    }
}

std::vector<SlotId> FakeUploader::leaving() const {
    std::vector<SlotId> s;
    for (const auto& l : leaving_) s.push_back(l.first);
    s.insert(s.end(), gone_.begin(), gone_.end());
    return s;
}

void FakeUploader::clear() {
    seq_ = 0;
    pages_.clear();
    tables_.clear();
    blocks_.clear();
    malformed_ = 0;
    leaving_.clear();
    cancelled_.clear();
    gone_.clear();
    cancelled_gone_ = 0;
    fade_out_calls_ = written_while_leaving_ = fade_out_cancels_ = stray_cancels_ = 0;
}

}  // namespace tessera::client
