#include "tessera/client/fakes/uploaders.hpp"

#include <algorithm>

#include "page_table.hpp"

namespace tessera::client {

void FakeUploader::upload_page(SlotId slot, const PageKey& page, std::span<const std::uint8_t> page_data, std::uint32_t tile_size) {
    if (page_data.size() != format_.upload_bytes(tile_size)) ++malformed_;
    if (slot < weights_.size()) {
        if (falling_[slot] && weights_[slot] > 0) ++written_while_leaving_;
        falling_[slot] = 0;
    }
    written_.push_back(slot);
    pages_.push_back(PageCall{seq_++, slot, page, tile_size, std::vector<std::uint8_t>(page_data.begin(), page_data.end())});
}

void FakeUploader::write_page_table(const PageTableWrite& w) {
    if (w.sparse_block) {
        if (!w.entries.empty() && w.entries.size() != PageTable::kBlockEntries) ++malformed_;
        blocks_.push_back(BlockCall{seq_++, w.texture, w.level, w.x0, w.y0, std::vector<std::uint32_t>(w.entries.begin(), w.entries.end())});
        return;
    }
    if (w.entries.size() != std::size_t(w.w) * w.h) ++malformed_;
    tables_.push_back(
        TableCall{seq_++, w.texture, w.level, w.x0, w.y0, w.w, w.h, std::vector<std::uint32_t>(w.entries.begin(), w.entries.end())});
}

void FakeUploader::set_slot_weights(std::span<const SlotWeight> weights) {
    ++weight_calls_;
    for (const SlotWeight& w : weights) {
        if (w.slot >= weights_.size()) {
            weights_.resize(std::size_t(w.slot) + 1, 255);
            falling_.resize(weights_.size(), 0);
        }
        const std::uint8_t before = weights_[w.slot];
        if (std::find(written_.begin(), written_.end(), w.slot) != written_.end()) {
            falling_[w.slot] = 0;  // a page written since the last weights: it arrives
        } else if (w.weight < before && !falling_[w.slot] && before != 0) {
            ++fade_outs_;
            falling_[w.slot] = 1;
        } else if (w.weight > before && falling_[w.slot]) {
            if (w.weight < 255) ++fade_backs_;
            falling_[w.slot] = 0;
        }
        weights_[w.slot] = w.weight;
    }
    written_.clear();
}

std::vector<SlotId> FakeUploader::below_full() const {
    std::vector<SlotId> s;
    for (SlotId i = 0; i < weights_.size(); ++i)
        if (weights_[i] < 255) s.push_back(i);
    return s;
}

std::vector<SlotId> FakeUploader::fading_out() const {
    std::vector<SlotId> s;
    for (SlotId i = 0; i < weights_.size(); ++i)
        if (falling_[i] && weights_[i] > 0) s.push_back(i);
    return s;
}

void FakeUploader::clear() {
    seq_ = 0;
    pages_.clear();
    tables_.clear();
    blocks_.clear();
    malformed_ = 0;
    weights_.clear();
    falling_.clear();
    written_.clear();
    weight_calls_ = fade_outs_ = fade_backs_ = written_while_leaving_ = 0;
}

}  // namespace tessera::client
