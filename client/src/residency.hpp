#pragma once
// Residency: the physical page pool (N slots of the GPU page atlas) shared by several virtual
// textures, which pages live in it, which one to replace, and each texture's PageTable
// (docs/client.md, "One frame, end to end", steps 4 and 7).
//
// Protocol (render thread):
//   begin_frame(f)                 once per frame, f never decreasing
//   touch(page)                    for every page the feedback saw this frame (ancestors included);
//                                  a resident page's last-seen frame becomes f; a leaving one stays
//                                  (take_rescued)
//   acquire_slot(page)             a slot to upload `page` into: a free one, else the victim's,
//                                  which is unmapped from its table right away ("unmap before
//                                  overwrite": from here on the shader never samples that slot
//                                  for the victim, even while the upload overwrites it)
//   ... upload into the slot ...
//   complete(page, slot)           maps the page ("map after complete"); last seen = f
//   cancel(slot)                   instead of complete: the upload was abandoned, the slot is free
//   finish_leaving(slot)           a page that acquire_slot set leaving has faded out: unmapped,
//                                  its slot free (pages left over kLeaveDeadlineFrames frames are
//                                  finished by begin_frame, whatever the uploader says: a renderer
//                                  whose clock stands still; take_expired() counts them)
//
// Leaving (fade out): with fade_out_frames > 0, a victim seen within fade_out_frames frames
// before the kept ones (last seen after frame - kept_frames - fade_out_frames) is not taken at
// once: acquire_slot answers kNoSlot and names it in SlotGrant::leaving; it stays mapped (drawn,
// fading out) but is no longer a candidate, and its slot is free once finish_leaving(slot) is
// called. At most max_leaving pages leave at once; past that, victims go at once as without.
// A leaving page the feedback sees again (touch) is rescued: resident again, a candidate like any
// page last seen now, its slot never freed; take_rescued() names it, so that the uploader fades it
// back in (PageUploader::cancel_fade_out) instead of the runtime loading it again once it has gone.
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
    std::uint64_t evictions = 0;       // since creation, leaving pages once they have left
    std::uint64_t rescued = 0;         // since creation, leaving pages seen again and kept
};

// What acquire_slot() gives.
struct SlotGrant {
    SlotId slot = kNoSlot;  // kNoSlot: nothing may be evicted now (see above); try a later frame
    bool evicted = false;   // the slot was taken from `victim` (already unmapped)
    PageKey victim{};
    // kNoSlot now, but this slot's page (seen recently: maybe on screen) starts leaving; the slot
    // is free once finish_leaving(leaving) is called.
    SlotId leaving = kNoSlot;
};

class Residency {
public:
    // Errors (invalid_argument): pool_slots 0 or over PageTable::kMaxSlots, kept_frames not 1..64.
    static Result<Residency> create(const ResidencyConfig& config);

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

    // Starts frame `frame`. Errors (invalid_argument): frame older than the current one.
    Status begin_frame(std::uint64_t frame);
    std::uint64_t frame() const { return frame_; }
    // Marks `page` seen this frame. Returns whether it is resident (mapped). Unknown textures and
    // pages outside the geometry are not resident. A leaving page is rescued (see "Leaving").
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
    // The page leaving `slot` has faded out: unmaps it, frees the slot and returns the page.
    // Errors (invalid_argument): the slot is not leaving (never was, finished at the deadline, or
    // rescued since).
    Result<PageKey> finish_leaving(SlotId slot);
    // Appends the slots whose leaving page touch() rescued since the last call.
    void take_rescued(std::vector<SlotId>& out) {
        out.insert(out.end(), rescued_.begin(), rescued_.end());
        rescued_.clear();
    }
    // Pages begin_frame finished at the deadline since the last call (their uploader never said).
    std::uint32_t take_expired() { return std::exchange(expired_, 0u); }
    // Frames a page may leave for before begin_frame finishes it: far longer than any fade
    // (10 s at 240 frames a second), so only a renderer whose clock stands still meets it.
    static constexpr std::uint64_t kLeaveDeadlineFrames = 2400;

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

    explicit Residency(const ResidencyConfig& config);
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
    std::vector<SlotId> rescued_;  // rescued, not yet taken; at most max_leaving per frame
    std::uint32_t expired_ = 0;    // finished at the deadline, not yet taken
    std::uint64_t frame_ = 0;
    std::uint64_t pinned_pages_total_ = 0;  // pinned pages of all registered textures
    std::uint32_t resident_ = 0;
    std::uint32_t pinned_resident_ = 0;
    std::uint64_t evictions_ = 0;
    std::uint64_t rescues_ = 0;
};

}  // namespace tessera::client
