#include "residency.hpp"

#include <algorithm>
#include <cassert>
#include <string>
#include <utility>

namespace tessera::client {
namespace {

std::string page_name(const PageKey& p) {
    return "page (texture " + std::to_string(p.texture) + ", level " + std::to_string(p.level) + ", " +
           std::to_string(p.x) + ", " + std::to_string(p.y) + ")";
}

}  // namespace

Result<Residency> Residency::create(const ResidencyConfig& config, double fade_s) {
    if (config.pool_slots == 0 || config.pool_slots > PageTable::kMaxSlots)
        return make_error(Errc::invalid_argument, "residency: pool_slots must be 1.." +
                                                      std::to_string(PageTable::kMaxSlots) + ", got " +
                                                      std::to_string(config.pool_slots));
    if (config.fade_out_frames > 0 && config.max_leaving == 0)
        return make_error(Errc::invalid_argument, "residency: max_leaving must be >= 1 when fade_out_frames > 0");
    if (config.kept_frames == 0 || config.kept_frames > 64)
        return make_error(Errc::invalid_argument,
                          "residency: kept_frames must be 1..64, got " + std::to_string(config.kept_frames));
    if (!(fade_s >= 0 && fade_s <= 10))
        return make_error(Errc::invalid_argument, "residency: the fade time must be 0..10 s, got " + std::to_string(fade_s));
    return Residency(config, fade_s);
}

Residency::Residency(const ResidencyConfig& config, double fade_s)
    : config_(config), slots_(config.pool_slots), fades_(config.pool_slots, fade_s) {
    // Without fades nothing can leave over one.
    if (!fades_.enabled()) config_.fade_out_frames = 0;
    free_.reserve(config.pool_slots);
    for (SlotId s = config.pool_slots; s-- > 0;) free_.push_back(s);
}

const Residency::Texture* Residency::find(TextureId texture) const {
    const auto it = textures_.find(texture);
    return it == textures_.end() ? nullptr : &it->second;
}

Residency::Texture* Residency::find(TextureId texture) {
    const auto it = textures_.find(texture);
    return it == textures_.end() ? nullptr : &it->second;
}

Status Residency::add_texture(TextureId texture, std::uint32_t pages_x, std::uint32_t pages_y, std::uint32_t levels) {
    if (find(texture))
        return make_error(Errc::invalid_argument, "residency: texture " + std::to_string(texture) + " already registered");
    auto table = PageTable::create(texture, pages_x, pages_y, levels, config_.max_table_bytes, config_.sparse_tables);
    if (!table) return table.error();

    // Pinned levels: the coarsest ones, counted from the last (1x1) level.
    std::uint32_t pinned = 0;
    std::uint64_t pinned_pages = 0;
    const auto level_pages = [&](std::uint32_t l) { return std::uint64_t(table->level_width(l)) * table->level_height(l); };
    if (config_.pinned_levels == ResidencyConfig::kAutoPinnedLevels) {
        pinned = 1;
        pinned_pages = 1;
        while (pinned < levels && pinned_pages + level_pages(levels - 1 - pinned) <= config_.auto_pin_max_pages)
            pinned_pages += level_pages(levels - 1 - pinned++);
    } else {
        pinned = std::min(config_.pinned_levels, levels);
        for (std::uint32_t i = 0; i < pinned; ++i) pinned_pages += level_pages(levels - 1 - i);
    }
    if (pinned_pages_total_ + pinned_pages > config_.pool_slots)
        return make_error(Errc::resource_exhausted,
                          "residency: texture " + std::to_string(texture) + " pins " + std::to_string(pinned_pages) +
                              " pages (" + std::to_string(pinned) + " levels); with the " +
                              std::to_string(pinned_pages_total_) + " pinned pages of the other textures that is over the " +
                              std::to_string(config_.pool_slots) + "-slot pool");
    pinned_pages_total_ += pinned_pages;
    textures_.emplace(texture, Texture{std::move(*table), pinned, pinned_pages});
    return {};
}

const PageTable* Residency::table(TextureId texture) const {
    const Texture* t = find(texture);
    return t ? &t->table : nullptr;
}

PageTable* Residency::table_for_upload(TextureId texture) {
    Texture* t = find(texture);
    return t ? &t->table : nullptr;
}

std::uint32_t Residency::pinned_levels(TextureId texture) const {
    const Texture* t = find(texture);
    return t ? t->pinned_levels : 0;
}

bool Residency::is_pinned(const PageKey& page) const {
    const Texture* t = find(page.texture);
    return t && page.level < t->table.levels() && pinned_in(*t, page.level);
}

Status Residency::begin_frame(std::uint64_t frame, double now) {
    if (frame < frame_)
        return make_error(Errc::invalid_argument, "residency: frame " + std::to_string(frame) +
                                                      " is older than the current frame " + std::to_string(frame_));
    frame_ = frame;
    gone_.clear();
    fades_.advance(now, gone_);
    for (const SlotId s : gone_) finish_leaving(s);
    // A leaving page whose fade never ends (a clock standing still) leaves anyway.
    for (std::size_t i = 0; i < leaving_.size();) {
        const SlotId s = leaving_[i];
        if (slots_[s].leave_start + kLeaveDeadlineFrames <= frame_) {
            finish_leaving(s);  // removes it from leaving_
            ++expired_;
        } else {
            ++i;
        }
    }
    return {};
}

bool Residency::touch(const PageKey& page) {
    const Texture* t = find(page.texture);
    if (!t || !t->table.contains(page.level, page.x, page.y)) return false;
    const SlotId s = t->table.mapped_slot(page.level, page.x, page.y);
    if (s == kNoSlot) return false;
    Slot& slot = slots_[s];
    slot.last_seen = frame_;
    if (slot.state == SlotState::resident) {
        unlink(s);
        link_tail(s);
    } else if (slot.state == SlotState::leaving) {
        // Still wanted: it stays, fading back in (see "Leaving"); its slot was promised to no one.
        std::erase(leaving_, s);
        slot.state = SlotState::resident;
        link_tail(s);
        fades_.keep(s);
        ++kept_;
        ++rescues_;
    }
    return true;
}

void Residency::link_tail(SlotId s) {
    Slot& slot = slots_[s];
    List& list = lru_[slot.page.level];
    slot.prev = list.tail;
    slot.next = kNoSlot;
    if (list.tail != kNoSlot)
        slots_[list.tail].next = s;
    else
        list.head = s;
    list.tail = s;
}

void Residency::unlink(SlotId s) {
    Slot& slot = slots_[s];
    List& list = lru_[slot.page.level];
    if (slot.prev != kNoSlot)
        slots_[slot.prev].next = slot.next;
    else
        list.head = slot.next;
    if (slot.next != kNoSlot)
        slots_[slot.next].prev = slot.prev;
    else
        list.tail = slot.prev;
    slot.prev = slot.next = kNoSlot;
}

// The smallest (last seen, level) among the list heads; each list is sorted by (last seen, touch
// order), so its head is its least recently seen page. Strict comparison in level order keeps the
// finer level on ties.
SlotId Residency::pick_victim(bool allow_current_frame) const {
    SlotId best = kNoSlot;
    for (const List& list : lru_) {
        if (list.head == kNoSlot) continue;
        const Slot& s = slots_[list.head];
        if (!allow_current_frame && s.last_seen + config_.kept_frames > frame_) continue;
        if (best == kNoSlot || s.last_seen < slots_[best].last_seen) best = list.head;
    }
    return best;
}

Result<SlotGrant> Residency::acquire_slot(const PageKey& page) {
    Texture* t = find(page.texture);
    if (!t) return make_error(Errc::invalid_argument, "acquire_slot: " + page_name(page) + ": unknown texture");
    if (!t->table.contains(page.level, page.x, page.y))
        return make_error(Errc::invalid_argument, "acquire_slot: " + page_name(page) + " is outside the texture");
    if (t->table.is_mapped(page.level, page.x, page.y))
        return make_error(Errc::invalid_argument, "acquire_slot: " + page_name(page) + " is already resident");
    if (in_flight_.count(page))
        return make_error(Errc::invalid_argument, "acquire_slot: " + page_name(page) + " is already in flight");

    SlotGrant grant;
    if (!free_.empty()) {
        grant.slot = free_.back();
        free_.pop_back();
    } else {
        const bool pinned_page = pinned_in(*t, page.level);
        const SlotId victim = pick_victim(pinned_page);
        if (victim == kNoSlot) return grant;  // everything evictable was seen this frame
        Slot& v = slots_[victim];
        if (config_.fade_out_frames > 0 && !pinned_page && leaving_.size() < config_.max_leaving &&
            v.last_seen + config_.kept_frames + config_.fade_out_frames > frame_) {
            // Seen recently, maybe on screen: it fades out first (see "Leaving").
            unlink(victim);
            v.state = SlotState::leaving;
            v.leave_start = frame_;
            leaving_.push_back(victim);
            fades_.leave(victim);
            grant.leaving = victim;
            grant.victim = v.page;
            return grant;
        }
        unlink(victim);
        // Unmap before overwrite: the victim's table region falls back to its nearest resident
        // ancestor now, before any byte of the new page reaches the slot.
        Texture* vt = find(v.page.texture);
        const Status st = vt->table.unmap(v.page.level, v.page.x, v.page.y);
        assert(st.ok());  // cannot fail: a resident slot's page is mapped to it
        (void)st;
        --resident_;
        ++evictions_;
        fades_.release(victim);
        grant.slot = victim;
        grant.evicted = true;
        grant.victim = v.page;
    }
    Slot& slot = slots_[grant.slot];
    slot.page = page;
    slot.state = SlotState::in_flight;
    slot.last_seen = frame_;
    in_flight_.emplace(page, grant.slot);
    return grant;
}

Status Residency::complete(const PageKey& page, SlotId slot) {
    const auto it = in_flight_.find(page);
    if (it == in_flight_.end() || it->second != slot)
        return make_error(Errc::invalid_argument, "complete: slot " + std::to_string(slot) + " is not in flight for " +
                                                      page_name(page));
    in_flight_.erase(it);
    Texture* t = find(page.texture);
    const Status st = t->table.map(page.level, page.x, page.y, slot);
    assert(st.ok());  // cannot fail: acquire_slot checked the page, and nothing maps it meanwhile
    (void)st;
    Slot& s = slots_[slot];
    s.last_seen = frame_;
    ++resident_;
    if (pinned_in(*t, page.level)) {
        s.state = SlotState::pinned;
        ++pinned_resident_;
    } else {
        s.state = SlotState::resident;
        link_tail(slot);
    }
    fades_.arrive(slot);
    return {};
}

Status Residency::cancel(SlotId slot) {
    if (slot >= slots_.size() || slots_[slot].state != SlotState::in_flight)
        return make_error(Errc::invalid_argument, "cancel: slot " + std::to_string(slot) + " is not in flight");
    in_flight_.erase(slots_[slot].page);
    slots_[slot].state = SlotState::free;
    free_.push_back(slot);
    return {};
}

// The page leaving `slot` has gone (faded out, or at the deadline): unmapped, its slot free.
void Residency::finish_leaving(SlotId slot) {
    const auto it = std::find(leaving_.begin(), leaving_.end(), slot);
    assert(it != leaving_.end() && slots_[slot].state == SlotState::leaving);
    *it = leaving_.back();
    leaving_.pop_back();
    Slot& v = slots_[slot];
    Texture* vt = find(v.page.texture);
    const Status st = vt->table.unmap(v.page.level, v.page.x, v.page.y);
    assert(st.ok());  // cannot fail: a leaving page stays mapped to its slot until here
    (void)st;
    --resident_;
    ++evictions_;
    ++left_;
    fades_.release(slot);
    v.state = SlotState::free;
    free_.push_back(slot);
}

std::uint8_t Residency::resident_level(const PageKey& page) const {
    const Texture* t = find(page.texture);
    return t ? t->table.resident_level(page.level, page.x, page.y) : PageTable::kNotResident;
}

bool Residency::is_resident(const PageKey& page) const {
    const Texture* t = find(page.texture);
    return t && t->table.contains(page.level, page.x, page.y) && t->table.is_mapped(page.level, page.x, page.y);
}

ResidencyStats Residency::stats() const {
    ResidencyStats s;
    s.pool_slots = config_.pool_slots;
    s.free_slots = static_cast<std::uint32_t>(free_.size());
    s.resident_pages = resident_;
    s.pinned_pages = pinned_resident_;
    s.in_flight = static_cast<std::uint32_t>(in_flight_.size());
    s.leaving = static_cast<std::uint32_t>(leaving_.size());
    s.fading = static_cast<std::uint32_t>(fades_.fading());
    s.evictions = evictions_;
    s.rescued = rescues_;
    return s;
}

}  // namespace tessera::client
