#pragma once
// Residency: the page cache. It owns the physical page pool (N slots of the GPU page atlas)
// shared by several virtual textures, every slot's state and every transition between states
// (docs/client.md, "A slot's life"), which page to replace, each texture's PageTable, and each
// slot's blend weight over the fade time. The uploader only writes what it decided.
//
// Protocol (render thread, once per runtime frame):
//   begin_frame(f, now)            f never decreasing; now: the runtime clock (seconds). Moves every
//                                  fade to `now`: pages that have faded out leave (unmapped, slot
//                                  free); pages leaving for kLeaveDeadlineFrames leave too
//   touch(page)                    for every page the feedback saw this frame (ancestors included);
//                                  a resident page's last-seen frame becomes f; a leaving one is
//                                  kept (it fades back in)
//   acquire_slot(page)             a slot to upload `page` into: a free one, else the victim's,
//                                  which is unmapped from its table right away ("unmap before
//                                  overwrite": from here on the shader never samples that slot
//                                  for the victim, even while the upload overwrites it)
//   ... upload into the slot ...
//   complete(page, slot)           maps the page ("map after complete"); last seen = f; it fades in
//   cancel(slot)                   instead of complete: the upload was abandoned, the slot is free
//   take_weight_changes(out)       the slots whose blend weight changed, for the uploader
//
// Leaving (fade out): with a fade time and fade_out_frames > 0, a victim seen within
// fade_out_frames frames before the kept ones (last seen after frame - kept_frames -
// fade_out_frames) is not taken at once: acquire_slot answers kNoSlot and names it in
// SlotGrant::leaving; it stays mapped (drawn, its weight falling) but is no longer a candidate,
// and its slot is free once its weight has reached 0 (a later begin_frame). At most max_leaving
// pages leave at once; past that, victims go at once as without.
// A leaving page the feedback sees again (touch) is kept: resident again, a candidate like any
// page last seen now, its weight rising from where it is, its slot never freed.
// Replacement order (not seen recently first, finer levels before coarser, LRU among equals;
// docs/client.md, "Replacement"), read as one sort key, smallest evicted first:
//   1. last-seen frame, older first (exact frame numbers, not buckets);
//   2. among pages last seen in the same frame: finer level first (level 0 before level 1);
//   3. among those: least recently touched (or completed) first.
// Pages last seen in the current frame (or the last ResidencyConfig::kept_frames frames) are never
// evicted for an ordinary page: when only those (and pinned or in-flight pages) are left,
// acquire_slot answers kNoSlot and the request waits for a later frame; evicting a page the view
// is using right now to load another one would thrash.
// The one exception is a page of a pinned level (below): it may evict a page seen this frame,
// since the pinned levels are what every fallback ends at.
//
// Pinning: the coarsest pinned levels of every texture are never evicted once resident. They
// are loaded like other pages (the runtime requests them first); add_texture() refuses a texture
// whose pinned pages, with those of the textures already registered, would not fit in the pool.
//
// Data structure: per level one intrusive LRU list (over slots) of the evictable resident pages of
// every texture, ordered by (last seen, touch order), since touching moves a page to its tail.
// The victim is the oldest of the (at most 32) list heads, finer level on ties: acquire, touch and
// complete are O(1) (plus the page-table update). Page -> slot lookups go through the page table.
//
// Not thread-safe; owned by the render thread.
#include <array>
#include <cstddef>
#include <cstdint>
#include <unordered_map>
#include <utility>
#include <vector>

#include "tessera/client/page.hpp"
#include "tessera/client/runtime.hpp"  // ResidencyConfig
#include "fades.hpp"
#include "page_table.hpp"
#include "tessera/result.hpp"

namespace tessera::client {

struct ResidencyStats {
    std::uint32_t pool_slots = 0;
    std::uint32_t free_slots = 0;
    std::uint32_t resident_pages = 0;  // mapped, all textures, pinned included
    std::uint32_t pinned_pages = 0;    // resident pages of pinned levels
    std::uint32_t in_flight = 0;       // acquired, not yet completed or cancelled
    std::uint32_t leaving = 0;         // resident, fading out (see "Leaving")
    std::uint32_t fading = 0;          // weights moving: pages fading in, leaving or kept
    std::uint64_t evictions = 0;       // since creation, leaving pages once they have left
    std::uint64_t rescued = 0;         // since creation, leaving pages seen again and kept
};

// What acquire_slot() gives.
struct SlotGrant {
    SlotId slot = kNoSlot;  // kNoSlot: nothing may be evicted now (see above); try a later frame
    bool evicted = false;   // the slot was taken from `victim` (already unmapped)
    PageKey victim{};
    // kNoSlot now, but this slot's page (seen recently: maybe on screen) starts leaving; the slot
    // is free once it has faded out.
    SlotId leaving = kNoSlot;
};

class Residency {
public:
    // fade_s: the fade time, seconds (0: no fades; then nothing leaves over a fade either).
    // Errors (invalid_argument): pool_slots 0 or over PageTable::kMaxSlots, kept_frames not 1..64,
    // fade_s not 0..10.
    static Result<Residency> create(const ResidencyConfig& config, double fade_s = 0);

    // Registers a texture and creates its page table (level-0 page counts and level count as in
    // PageTable::create). Errors: a texture id already registered, PageTable::create's errors,
    // (resource_exhausted) pinned pages of all textures over the pool.
    Status add_texture(TextureId texture, std::uint32_t pages_x, std::uint32_t pages_y, std::uint32_t levels);
    // The texture's page table (read-only: Residency maps and unmaps), or nullptr if unknown.
    const PageTable* table(TextureId texture) const;
    // Mutable only for the uploader's take_dirty() / mark_all_dirty(); never map/unmap through it.
    PageTable* table_for_upload(TextureId texture);
    std::uint32_t pinned_levels(TextureId texture) const;  // 0 when unknown
    bool is_pinned(const PageKey& page) const;              // the page is in a pinned level

    // Starts frame `frame` at `now` (seconds; a clock older than the last is taken as the last:
    // without `now`, the clock stands still). Errors (invalid_argument): frame older than the
    // current one.
    Status begin_frame(std::uint64_t frame, double now = 0);
    std::uint64_t frame() const { return frame_; }
    // Marks `page` seen this frame. Returns whether it is resident (mapped). Unknown textures and
    // pages outside the geometry are not resident. A leaving page is kept (see "Leaving").
    bool touch(const PageKey& page);

    // See the protocol above. Errors (invalid_argument): unknown texture, page outside the
    // geometry, page already resident or already in flight. A pool with nothing evictable is not
    // an error: the grant's slot is kNoSlot.
    Result<SlotGrant> acquire_slot(const PageKey& page);
    // Maps `page` into `slot`, which acquire_slot(page) gave. Errors (invalid_argument): the slot
    // is not in flight for that page.
    Status complete(const PageKey& page, SlotId slot);
    // Frees a slot that acquire_slot gave and that was never completed. Errors: not in flight.
    Status cancel(SlotId slot);
    // Appends the slots whose blend weight changed since the last call (SlotWeight: 255 full).
    void take_weight_changes(std::vector<SlotWeight>& out) { fades_.take_changes(out); }
    // Pages that left since the last call (faded out, or at the deadline), and leaving pages kept.
    std::uint32_t take_left() { return std::exchange(left_, 0u); }
    std::uint32_t take_kept() { return std::exchange(kept_, 0u); }
    // Of take_left()'s, those the deadline finished (their fade never ended: a clock standing still).
    std::uint32_t take_expired() { return std::exchange(expired_, 0u); }
    // Frames a page may leave for before begin_frame finishes it: far longer than any fade
    // (10 s at 240 frames a second), so only a clock that stands still meets it.
    static constexpr std::uint64_t kLeaveDeadlineFrames = 2400;
    std::uint8_t weight(SlotId slot) const { return fades_.weight(slot); }

    // Nearest resident level of `page` (itself or an ancestor), PageTable::kNotResident (255) when
    // none or when the page is unknown. (The ResidencyView query.)
    std::uint8_t resident_level(const PageKey& page) const;
    bool is_resident(const PageKey& page) const;

    ResidencyStats stats() const;

private:
    enum class SlotState : std::uint8_t { free, in_flight, resident, pinned, leaving };
    struct Slot {
        PageKey page{};
        std::uint64_t last_seen = 0;
        std::uint64_t leave_start = 0;  // leaving: the frame it started leaving
        SlotId prev = kNoSlot;
        SlotId next = kNoSlot;
        SlotState state = SlotState::free;
    };
    struct List {
        SlotId head = kNoSlot;
        SlotId tail = kNoSlot;
    };
    struct Texture {
        PageTable table;
        std::uint32_t pinned_levels = 0;  // levels >= table.levels() - pinned_levels are pinned
        std::uint64_t pinned_pages = 0;   // pages in those levels
    };

    Residency(const ResidencyConfig& config, double fade_s);
    void finish_leaving(SlotId s);
    void link_tail(SlotId s);
    void unlink(SlotId s);
    SlotId pick_victim(bool allow_current_frame) const;
    bool pinned_in(const Texture& t, std::uint32_t level) const { return level + t.pinned_levels >= t.table.levels(); }
    const Texture* find(TextureId texture) const;
    Texture* find(TextureId texture);

    ResidencyConfig config_;
    std::vector<Slot> slots_;
    std::vector<SlotId> free_;  // stack of free slots (lowest id on top at start)
    std::array<List, kMaxLevels> lru_{};
    std::unordered_map<TextureId, Texture> textures_;
    std::unordered_map<PageKey, SlotId, PageKeyHash> in_flight_;
    std::vector<SlotId> leaving_;  // at most config_.max_leaving
    SlotFades fades_;
    std::vector<SlotId> gone_;     // begin_frame's: faded out
    std::uint32_t left_ = 0, kept_ = 0, expired_ = 0;  // since the last take
    std::uint64_t frame_ = 0;
    std::uint64_t pinned_pages_total_ = 0;  // pinned pages of all registered textures
    std::uint32_t resident_ = 0;
    std::uint32_t pinned_resident_ = 0;
    std::uint64_t evictions_ = 0;
    std::uint64_t rescues_ = 0;
};

}  // namespace tessera::client
