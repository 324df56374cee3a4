#pragma once
// Feedback analysis (docs/client.md, "One frame, end to end", steps 3 and 4): turns one frame's
// feedback buffer (one packed FeedbackId per pixel) into the set of pages the view wants, with
// their ancestors, ordered by priority. Runs on the thread that calls it (Runtime::frame: the
// render thread); one analyser per thread.
//
// Cost model: one pass over the pixels that skips runs of identical ids (neighbouring pixels
// mostly repeat), one hash lookup per run, one lookup per wanted page for its parent, one
// ResidencyView call per wanted page, one sort of the wanted pages. All memory is allocated by the
// constructor and by set_texture_levels/set_texture_extent (setup); analyse() never allocates.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "tessera/client/page.hpp"

namespace tessera::client {

// What the analysis needs to know about residency: the level of the nearest resident
// ancestor-or-self of a page (the page table answers it); kNothingResident (255) when nothing is.
// Called once per wanted page (leaves and ancestors), from the thread that calls analyse().
class ResidencyView {
public:
    static constexpr std::uint8_t kNothingResident = 255;
    virtual ~ResidencyView() = default;
    virtual std::uint8_t resident_level(const PageKey& page) const = 0;
};

struct WantedPage {
    PageKey key;
    std::uint32_t pixels = 0;          // feedback pixels that asked for exactly this page (0 for ancestors added)
    std::uint32_t subtree_pixels = 0;  // pixels of this page and every wanted descendant
    float centre_distance = 0;         // min over its pixels (and descendants') of the distance from the pixel
                                       // centre to the screen centre, in units of the half-diagonal (0..1)
    std::uint8_t resident_level = 0;   // from ResidencyView
    std::uint8_t level_gap = 0;        // resident_level - key.level (0: resident); 255 - level when nothing is
    friend bool operator==(const WantedPage&, const WantedPage&) = default;
};

class FeedbackAnalyzer {
public:
    struct Stats {
        std::uint32_t pixels = 0;          // width * height
        std::uint32_t vt_pixels = 0;       // pixels with a valid page id (counted in the pages)
        std::uint32_t invalid_pixels = 0;  // pixels with an id that is neither kNoPage nor a valid page
        std::uint32_t unique_pages = 0;    // distinct pages asked for by at least one pixel
        std::uint32_t ancestor_pages = 0;  // pages added only as ancestors (pixels == 0)
        std::uint32_t dropped_pages = 0;   // wanted pages cut by max_pages (lowest priority first)
        // Work set full (more distinct pages and ancestors than max_work_pages): pixels whose page
        // could not be tracked, and ancestors that could not be added. 0 in a sane configuration.
        std::uint32_t untracked_pixels = 0;
        std::uint32_t untracked_ancestors = 0;
    };

    // max_pages bounds the output (pages beyond it are dropped lowest priority first and counted).
    // max_work_pages bounds the pages (with ancestors) one frame may touch before ranking (0:
    // 2 * max_pages); beyond it pages are not tracked (Stats::untracked_*). All memory is
    // allocated here, once: 108 bytes per work page plus 28 per output page (15 MiB with the
    // defaults, 1 MiB for max_pages = 4096). A frame only touches what its pages need.
    explicit FeedbackAnalyzer(std::size_t max_pages = 1 << 16, std::size_t max_work_pages = 0);

    // Number of levels of a texture (so ancestors stop at its coarsest level, levels - 1). Ids of
    // textures never given levels (or given 0) are invalid. Clamped to kMaxLevels. Setup: may allocate.
    void set_texture_levels(TextureId texture, std::uint8_t levels);
    // Optional: the texture's level-0 size in pages. When set, ids whose x/y lie outside
    // ceil(pages / 2^level) at their level are invalid. 0 clears the check. Setup: may allocate.
    void set_texture_extent(TextureId texture, std::uint32_t pages_x, std::uint32_t pages_y);

    // Analyses one frame. ids: width*height ids, row-major (anything else: empty result, all
    // stats 0). kNoPage pixels are skipped; ids whose level >= the texture's levels, whose x/y lie
    // outside the extent, of unknown textures or with bits 61..63 set are counted invalid and
    // ignored. Returns the wanted pages with every ancestor up to each texture's top level, ordered
    // by priority: level_gap desc, subtree_pixels desc, centre_distance asc, then packed id asc
    // (pack_feedback(key)); fully deterministic. Valid until the next call. Never allocates.
    // Note: a page's ancestors have smaller gaps than it has, so they rank after it, and a
    // max_pages cut can keep a page while dropping some of its ancestors.
    std::span<const WantedPage> analyse(std::span<const FeedbackId> ids, std::uint32_t width, std::uint32_t height,
                                        const ResidencyView& residency);

    const Stats& stats() const { return stats_; }
    std::size_t max_pages() const { return max_pages_; }
    std::size_t max_work_pages() const { return max_work_; }

private:
    static constexpr std::uint32_t kNone = ~std::uint32_t{0};
    struct Slot {  // hash table entry: valid in the current frame iff generation == generation_
        std::uint64_t id;
        std::uint32_t generation;
        std::uint32_t node;
    };
    struct Node {  // one wanted page of the current frame
        std::uint64_t id;
        std::uint64_t d2;  // min squared distance to the centre, in doubled pixel units
        std::uint32_t pixels;
        std::uint32_t subtree;
        std::uint32_t parent;
        float distance;  // centre_distance, set when ranking
        std::uint8_t level;
        std::uint8_t levels;  // of its texture
        std::uint8_t resident;
        std::uint8_t gap;
    };
    struct SortItem {
        std::uint64_t a;  // (255 - gap) | (2^24-1 - subtree) | float bits of centre_distance
        std::uint32_t node;
        std::uint32_t unused;
    };
    struct TextureInfo {
        std::uint8_t levels = 0;
        std::uint32_t pages_x = 0;  // level-0 extent in pages; 0: unchecked
        std::uint32_t pages_y = 0;
    };

    TextureInfo* texture_slot(TextureId texture);
    std::uint8_t valid_levels(FeedbackId id) const;  // 0 when invalid, else the texture's levels
    void next_generation();
    void use_table_size(std::uint32_t size);  // the part of table_ in use this frame
    void grow_table();                        // x4, and rehash the nodes so far
    std::uint32_t probe(FeedbackId id) const;  // the slot holding id, or the empty slot where it goes
    // Index of the node for id, inserting it when absent (kNone when the work set is full).
    std::uint32_t find_or_insert(FeedbackId id, std::uint8_t levels);
    std::uint32_t insert_at(std::uint32_t slot, FeedbackId id, std::uint8_t levels);
    void rank(std::uint32_t width, std::uint32_t height, const ResidencyView& residency);

    std::size_t max_pages_;
    std::size_t max_work_;
    // The table holds 2 * max_work_ slots, but a frame uses only as many as its pages need (at most
    // half full), starting small and growing by rehashing, so that few pages stay cache-resident.
    std::uint32_t table_mask_ = 0;
    std::uint32_t table_shift_ = 0;
    std::uint32_t table_limit_ = 0;  // grow when node_count_ reaches it
    std::uint32_t generation_ = 0;
    std::uint32_t node_count_ = 0;
    std::vector<Slot> table_;
    std::vector<Node> nodes_;
    std::vector<std::uint32_t> by_level_;  // node indices, finest level first
    std::vector<SortItem> sort_;
    std::vector<SortItem> sort_tmp_;  // radix sort's second buffer
    std::vector<WantedPage> out_;
    std::size_t out_count_ = 0;
    std::vector<TextureInfo> textures_;
    Stats stats_{};
};

}  // namespace tessera::client
