#include "feedback_analysis.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <utility>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace tessera::client {
namespace {

constexpr std::uint64_t kFarAway = std::numeric_limits<std::uint64_t>::max();
constexpr std::uint32_t kFirstTableSize = 256;  // slots in use at the start of a frame (4 KiB)
constexpr std::uint32_t kRadixFrom = 512;       // pages; fewer are sorted by comparison

// The packed id of a page's parent (same layout as pack_feedback, without unpacking).
inline FeedbackId parent_id(FeedbackId id) {
    const FeedbackId x = id & 0xFFFFFu;
    const FeedbackId y = (id >> 20) & 0xFFFFFu;
    const FeedbackId level = (id >> 40) & 31u;
    return (x >> 1) | ((y >> 1) << 20) | ((level + 1) << 40) | (id & (FeedbackId{0xFFFF} << 45));
}

inline std::uint32_t hash_slot(FeedbackId id, std::uint32_t shift) {
    return static_cast<std::uint32_t>((id * 0x9E3779B97F4A7C15ull) >> shift);
}

// The end of the run of ids equal to *p that starts at p (p < end).
inline const FeedbackId* run_end(const FeedbackId* p, const FeedbackId* end) {
    const FeedbackId id = *p;
    const FeedbackId* q = p + 1;
#if defined(__SSE2__)
    // 8 ids (a cache line) a step: 64-bit equality as two 32-bit equalities. (Locating the end
    // from the compare masks measured slower than finishing with the scalar steps below.)
    const __m128i v = _mm_set1_epi64x(static_cast<long long>(id));
    while (end - q >= 8) {
        const __m128i* m = reinterpret_cast<const __m128i*>(q);
        const __m128i e = _mm_and_si128(
            _mm_and_si128(_mm_cmpeq_epi32(_mm_loadu_si128(m), v), _mm_cmpeq_epi32(_mm_loadu_si128(m + 1), v)),
            _mm_and_si128(_mm_cmpeq_epi32(_mm_loadu_si128(m + 2), v), _mm_cmpeq_epi32(_mm_loadu_si128(m + 3), v)));
        if (_mm_movemask_epi8(e) != 0xFFFF) break;
        q += 8;
    }
#endif
    while (end - q >= 4 && ((q[0] ^ id) | (q[1] ^ id) | (q[2] ^ id) | (q[3] ^ id)) == 0) q += 4;
    while (q < end && *q == id) ++q;
    return q;
}

// min |2x + 1 - w| over x0 <= x <= x1: the doubled distance from a run to the centre column. The
// pixel nearest the centre, (w - 1) / 2 (either of the two middle ones when w is even), clamped.
inline std::int64_t run_dx(std::int64_t x0, std::int64_t x1, std::int64_t w) {
    const std::int64_t d = 2 * std::clamp((w - 1) / 2, x0, x1) + 1 - w;
    return d < 0 ? -d : d;
}

}  // namespace

FeedbackAnalyzer::FeedbackAnalyzer(std::size_t max_pages, std::size_t max_work_pages)
    : max_pages_(std::max<std::size_t>(max_pages, 1)),
      max_work_(max_work_pages ? max_work_pages : 2 * max_pages_) {
    max_work_ = std::min<std::size_t>(std::max(max_work_, max_pages_), std::size_t{1} << 30);
    table_.assign(std::bit_ceil(std::max<std::size_t>(2 * max_work_, kFirstTableSize)), Slot{0, 0, 0});
    nodes_.resize(max_work_);
    by_level_.resize(max_work_);
    sort_.resize(max_work_);
    sort_tmp_.resize(max_work_);
    out_.resize(max_pages_);
}

FeedbackAnalyzer::TextureInfo* FeedbackAnalyzer::texture_slot(TextureId texture) {
    if (textures_.size() <= texture) textures_.resize(std::size_t{texture} + 1);
    return &textures_[texture];
}

void FeedbackAnalyzer::set_texture_levels(TextureId texture, std::uint8_t levels) {
    texture_slot(texture)->levels = static_cast<std::uint8_t>(std::min<std::uint32_t>(levels, kMaxLevels));
}

void FeedbackAnalyzer::set_texture_extent(TextureId texture, std::uint32_t pages_x, std::uint32_t pages_y) {
    TextureInfo* t = texture_slot(texture);
    t->pages_x = pages_x;
    t->pages_y = pages_y;
}

std::uint8_t FeedbackAnalyzer::valid_levels(FeedbackId id) const {
    if (id >> 61) return 0;
    const std::size_t texture = (id >> 45) & 0xFFFFu;
    if (texture >= textures_.size()) return 0;
    const TextureInfo& t = textures_[texture];
    const std::uint32_t level = (id >> 40) & 31u;
    if (level >= t.levels) return 0;
    if (t.pages_x != 0 || t.pages_y != 0) {
        const std::uint64_t round = (std::uint64_t{1} << level) - 1;
        const std::uint64_t w = (std::uint64_t{t.pages_x} + round) >> level;
        const std::uint64_t h = (std::uint64_t{t.pages_y} + round) >> level;
        if ((id & 0xFFFFFu) >= w || ((id >> 20) & 0xFFFFFu) >= h) return 0;
    }
    return t.levels;
}

// Slots of older generations are empty: a new generation clears the table without touching it.
void FeedbackAnalyzer::next_generation() {
    if (++generation_ == 0) {  // after 2^32 generations: forget every slot for real
        for (Slot& s : table_) s.generation = 0;
        generation_ = 1;
    }
}

void FeedbackAnalyzer::use_table_size(std::uint32_t size) {
    table_mask_ = size - 1;
    table_shift_ = static_cast<std::uint32_t>(64 - std::countr_zero(size));
    // At most half full; the whole table holds 2 * max_work_, so the work bound comes first there.
    table_limit_ = size / 2;
}

void FeedbackAnalyzer::grow_table() {
    use_table_size(static_cast<std::uint32_t>(std::min<std::size_t>(std::size_t{table_mask_ + 1} * 4, table_.size())));
    next_generation();
    for (std::uint32_t n = 0; n < node_count_; ++n) table_[probe(nodes_[n].id)] = Slot{nodes_[n].id, generation_, n};
}

std::uint32_t FeedbackAnalyzer::probe(FeedbackId id) const {
    std::uint32_t i = hash_slot(id, table_shift_);
    while (table_[i].generation == generation_ && table_[i].id != id) i = (i + 1) & table_mask_;
    return i;
}

std::uint32_t FeedbackAnalyzer::insert_at(std::uint32_t slot, FeedbackId id, std::uint8_t levels) {
    if (node_count_ == max_work_) return kNone;
    if (node_count_ >= table_limit_) {
        grow_table();
        slot = probe(id);
    }
    table_[slot] = Slot{id, generation_, node_count_};
    nodes_[node_count_] =
        Node{id, kFarAway, 0, 0, kNone, 0.0f, static_cast<std::uint8_t>((id >> 40) & 31u), levels, 0, 0};
    return node_count_++;
}

std::uint32_t FeedbackAnalyzer::find_or_insert(FeedbackId id, std::uint8_t levels) {
    const std::uint32_t slot = probe(id);
    if (table_[slot].generation == generation_) return table_[slot].node;
    return insert_at(slot, id, levels);
}

std::span<const WantedPage> FeedbackAnalyzer::analyse(std::span<const FeedbackId> ids, std::uint32_t width,
                                                      std::uint32_t height, const ResidencyView& residency) {
    stats_ = Stats{};
    node_count_ = 0;
    out_count_ = 0;
    const std::uint64_t pixels = std::uint64_t{width} * height;
    if (ids.size() != pixels || pixels > std::numeric_limits<std::uint32_t>::max()) return {};
    stats_.pixels = static_cast<std::uint32_t>(pixels);
    next_generation();
    use_table_size(static_cast<std::uint32_t>(std::min<std::size_t>(kFirstTableSize, table_.size())));

    // Pass 1: runs of identical ids within each row; one table probe per run. Only valid ids are
    // ever inserted, so a hit needs no validation.
    const std::int64_t w = width;
    const std::int64_t h = height;
    std::uint32_t vt = 0, invalid = 0, untracked = 0;
    for (std::int64_t y = 0; y < h; ++y) {
        const FeedbackId* const row = ids.data() + y * w;
        const FeedbackId* const end = row + w;
        const std::int64_t dy = 2 * y + 1 - h;
        const std::uint64_t dy2 = static_cast<std::uint64_t>(dy * dy);
        const FeedbackId* p = row;
        while (p < end) {
            const FeedbackId id = *p;
            const FeedbackId* const q = run_end(p, end);
            const auto len = static_cast<std::uint32_t>(q - p);
            const FeedbackId* const run = p;
            p = q;
            if (id == kNoPage) continue;
            const std::uint32_t slot = probe(id);
            std::uint32_t node = table_[slot].node;
            if (table_[slot].generation != generation_) {
                const std::uint8_t levels = valid_levels(id);
                if (levels == 0) {
                    invalid += len;
                    continue;
                }
                node = insert_at(slot, id, levels);
                if (node == kNone) {
                    untracked += len;
                    continue;
                }
            }
            Node& n = nodes_[node];
            const std::int64_t dx = run_dx(run - row, q - row - 1, w);
            n.pixels += len;
            n.d2 = std::min(n.d2, static_cast<std::uint64_t>(dx * dx) + dy2);
            vt += len;
        }
    }
    stats_.vt_pixels = vt;
    stats_.invalid_pixels = invalid;
    stats_.untracked_pixels = untracked;
    stats_.unique_pages = node_count_;

    // Pass 2: ancestors. Every node (those appended here too) looks up its parent once, so each
    // chain is walked only until it meets a page already present.
    std::uint32_t level_count[kMaxLevels + 1] = {};
    for (std::uint32_t i = 0; i < node_count_; ++i) {
        Node& n = nodes_[i];
        n.subtree = n.pixels;
        ++level_count[n.level + 1];
        if (n.level + 1 >= n.levels) continue;
        const std::uint32_t parent = find_or_insert(parent_id(n.id), n.levels);
        if (parent == kNone)
            ++stats_.untracked_ancestors;
        else
            n.parent = parent;  // nodes_ is sized once: n stays valid across insertions
    }
    stats_.ancestor_pages = node_count_ - stats_.unique_pages;

    // Pass 3: subtree sums and distances, finest level first, each page into its parent once.
    for (std::uint32_t l = 1; l <= kMaxLevels; ++l) level_count[l] += level_count[l - 1];
    for (std::uint32_t i = 0; i < node_count_; ++i) by_level_[level_count[nodes_[i].level]++] = i;
    for (std::uint32_t k = 0; k < node_count_; ++k) {
        const Node& n = nodes_[by_level_[k]];
        if (n.parent == kNone) continue;
        Node& p = nodes_[n.parent];
        p.subtree += n.subtree;
        p.d2 = std::min(p.d2, n.d2);
    }

    rank(width, height, residency);
    return {out_.data(), out_count_};
}

namespace {

// Stable LSD radix sort by the 64-bit key, 8 bits a pass, skipping bytes every key shares.
template <class Item>
void radix_sort(Item* items, Item* tmp, std::uint32_t n) {
    std::uint32_t count[8][256] = {};
    for (std::uint32_t i = 0; i < n; ++i) {
        const std::uint64_t a = items[i].a;
        for (int d = 0; d < 8; ++d) ++count[d][(a >> (8 * d)) & 0xFF];
    }
    Item* src = items;
    Item* dst = tmp;
    for (int d = 0; d < 8; ++d) {
        if (count[d][(src[0].a >> (8 * d)) & 0xFF] == n) continue;
        std::uint32_t offset[256];
        std::uint32_t sum = 0;
        for (int b = 0; b < 256; ++b) {
            offset[b] = sum;
            sum += count[d][b];
        }
        for (std::uint32_t i = 0; i < n; ++i) dst[offset[(src[i].a >> (8 * d)) & 0xFF]++] = src[i];
        std::swap(src, dst);
    }
    if (src != items) std::copy(src, src + n, items);
}

}  // namespace

void FeedbackAnalyzer::rank(std::uint32_t width, std::uint32_t height, const ResidencyView& residency) {
    const std::uint32_t n = node_count_;
    const double diag = std::sqrt(double(width) * width + double(height) * height);
    // Fast path: (gap, subtree, distance) fit one 64-bit key when subtree sums stay under 2^24;
    // the packed id breaks ties. Otherwise (> 16M pixels) a comparator on every field.
    const bool packed = stats_.vt_pixels < (1u << 24);
    for (std::uint32_t i = 0; i < n; ++i) {
        Node& node = nodes_[i];
        node.resident = residency.resident_level(unpack_feedback(node.id));
        node.gap = node.resident > node.level ? static_cast<std::uint8_t>(node.resident - node.level) : 0;
        node.distance = static_cast<float>(std::sqrt(static_cast<double>(node.d2)) / diag);
        const std::uint64_t a = packed ? (std::uint64_t{255u - node.gap} << 56) |
                                             (std::uint64_t{0xFFFFFFu - node.subtree} << 32) |
                                             std::bit_cast<std::uint32_t>(node.distance)
                                       : 0;
        sort_[i] = SortItem{a, i, 0};
    }
    const Node* nodes = nodes_.data();
    auto less_packed = [nodes](const SortItem& x, const SortItem& y) {
        return x.a != y.a ? x.a < y.a : nodes[x.node].id < nodes[y.node].id;
    };
    auto less_full = [nodes](const SortItem& x, const SortItem& y) {
        const Node& u = nodes[x.node];
        const Node& v = nodes[y.node];
        if (u.gap != v.gap) return u.gap > v.gap;
        if (u.subtree != v.subtree) return u.subtree > v.subtree;
        if (u.distance != v.distance) return u.distance < v.distance;
        return u.id < v.id;
    };
    const std::size_t keep = std::min<std::size_t>(n, max_pages_);
    SortItem* first = sort_.data();
    auto order = [&](auto less) {
        if (keep < n) std::nth_element(first, first + keep, first + n, less);
        std::sort(first, first + keep, less);
    };
    if (packed && n >= kRadixFrom) {
        radix_sort(first, sort_tmp_.data(), n);
        for (std::uint32_t i = 0, j; i < n; i = j) {  // equal keys: packed id order
            for (j = i + 1; j < n && first[j].a == first[i].a;) ++j;
            if (j - i > 1) std::sort(first + i, first + j, less_packed);
        }
    } else if (packed) {
        order(less_packed);
    } else {
        order(less_full);
    }

    for (std::size_t k = 0; k < keep; ++k) {
        const Node& node = nodes_[sort_[k].node];
        out_[k] = WantedPage{unpack_feedback(node.id), node.pixels, node.subtree, node.distance, node.resident, node.gap};
    }
    out_count_ = keep;
    stats_.dropped_pages = static_cast<std::uint32_t>(n - keep);
}

}  // namespace tessera::client
