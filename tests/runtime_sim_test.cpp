// Deterministic simulation of the client runtime: scripted feedback frames of a camera over a
// terrain store, a source with injected latency (in frames), synchronous decoding, a fake
// uploader. Shows residency converging, the LoD bias rising and settling when the pool is too
// small, churn bounded, and the bias returning to 0 when the pressure goes away.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <deque>
#include <map>
#include <set>
#include <thread>
#include <vector>

#include "tessera/client/fakes/uploaders.hpp"
#include "tessera/client/runtime.hpp"
#include "tessera/storage/store_writer.hpp"
#include "page_loader.hpp"
#include "runtime_internal.hpp"
#include "tessera/storage/store_reader.hpp"
#include "test_util.hpp"

namespace {

using namespace tessera::client;

// Serves a local store with a fixed latency in frames; replace semantics like the real sources.
class DelayedSource final : public TileSource {
public:
    DelayedSource(std::string path, unsigned latency_frames, bool ignore_cancel = false)
        : path_(std::move(path)), latency_(latency_frames), ignore_cancel_(ignore_cancel) {}
    tessera::Result<tessera::storage::StoreInfo> bind(TextureId texture, const std::string&) override {
        auto r = tessera::storage::StoreReader::open(path_);
        if (!r) return r.error();
        reader_ = *r;
        texture_ = texture;
        return reader_->info();
    }
    void set_requests(std::uint64_t, std::span<const SourceRequest> requests) override {
        std::map<std::uint64_t, bool> now;
        for (const auto& r : requests) now[page_hash_key(r.page)] = true;
        // Pending requests not in the new set are cancelled; new ones start their latency now.
        if (!ignore_cancel_) std::erase_if(pending_, [&](const auto& p) { return !now.contains(page_hash_key(p.page)); });
        for (const auto& r : requests) {
            const bool known = std::any_of(pending_.begin(), pending_.end(), [&](const auto& p) { return p.page == r.page; });
            if (known) continue;
            const auto slow = fail_next_.find(page_hash_key(r.page));
            pending_.push_back({r.page, frame_ + latency_ + (slow == fail_next_.end() ? 0 : slow->second)});
        }
        ++sets_;
    }
    std::size_t poll(std::vector<SourceTile>& out, std::size_t max) override {
        std::size_t n = 0;
        for (auto it = pending_.begin(); it != pending_.end() && n < max;) {
            if (it->due > frame_) {
                ++it;
                continue;
            }
            auto tile = reader_->read_tile({it->page.level, it->page.x, it->page.y});
            SourceTile t;
            t.page = it->page;
            t.store_version = reader_->info().store_id + version_offset_;
            if (fail_next_.erase(page_hash_key(it->page)) > 0) {
                t.status = tessera::TileStatus::unavailable;
                t.message = "queue full; retry later";
            } else {
                t.data.kind = tile->kind;
                t.data.codec = reader_->info().codec;
                t.data.checksum = tile->checksum;
                t.data.payload = std::move(tile->bytes);
                // A payload that passed every check on its way and still does not decode.
                if (undecodable_.contains(page_hash_key(it->page))) t.data.payload.assign(16, 0x42);
            }
            out.push_back(std::move(t));
            ++served_;
            ++served_pages_[page_hash_key(it->page)];
            it = pending_.erase(it);
            ++n;
        }
        return n;
    }
    bool available() const override { return true; }
    std::string describe() const override { return "delayed"; }
    void tick() { ++frame_; }
    // From now on tiles come as another version of the store (rebuilt and reloaded on a server),
    // or as the bound one again (a rollback).
    void replace_store() { version_offset_ = 1; }
    void restore_store() { version_offset_ = 0; }
    std::uint64_t served() const { return served_; }
    // This page is served, from now on, as bytes its codec refuses.
    void undecodable(const PageKey& page) { undecodable_.insert(page_hash_key(page)); }
    // This page's next delivery is an error (a server's "queue full; retry later"), `later` frames
    // after the source's usual latency.
    void fail_next(const PageKey& page, unsigned later) { fail_next_[page_hash_key(page)] = later; }
    std::uint64_t served(const PageKey& page) const {
        auto it = served_pages_.find(page_hash_key(page));
        return it == served_pages_.end() ? 0 : it->second;
    }

private:
    struct Pending {
        PageKey page;
        std::uint64_t due;
    };
    std::string path_;
    unsigned latency_;
    bool ignore_cancel_;  // a source that serves what it was asked once, even when withdrawn
    std::shared_ptr<tessera::storage::StoreReader> reader_;
    TextureId texture_ = 0;
    std::deque<Pending> pending_;
    std::uint64_t frame_ = 0;
    std::uint64_t sets_ = 0, served_ = 0;
    std::uint64_t version_offset_ = 0;
    std::set<std::uint64_t> undecodable_;
    std::map<std::uint64_t, unsigned> fail_next_;  // page -> extra frames before its error
    std::map<std::uint64_t, std::uint64_t> served_pages_;
};

// A camera over the ground plane: a 1280x720 view with feedback at 1/8 resolution (160x90). Row r
// sees texels at a density growing with distance (a perspective view), so one frame wants several
// levels. tpp: level-0 texels per screen pixel at the bottom row; centre: level-0 texel
// coordinates of the view centre. Each feedback pixel stands for 8x8 screen pixels.
std::vector<FeedbackId> feedback(const tessera::storage::StoreInfo& info, std::uint32_t w, std::uint32_t h, double cx,
                                 double cy, double tpp, float bias) {
    std::vector<FeedbackId> ids(std::size_t(w) * h, kNoPage);
    const auto levels = info.level_count();
    for (std::uint32_t r = 0; r < h; ++r) {
        const double density = tpp * (1.0 + 3.0 * (h - 1 - r) / double(h));  // farther rows: more texels per pixel
        for (std::uint32_t c = 0; c < w; ++c) {
            const double u = cx + (c - w / 2.0) * 8 * density, v = cy + (r - h / 2.0) * 8 * tpp * 2;
            if (u < 0 || v < 0 || u >= info.width || v >= info.height) continue;
            const double lod = std::log2(std::max(density, 1e-9)) + bias;
            const auto level = static_cast<std::uint32_t>(std::clamp(std::floor(lod), 0.0, double(levels - 1)));
            const double span = double(info.tile_payload) * std::ldexp(1.0, int(level));
            ids[std::size_t(r) * w + c] = pack_feedback(PageKey{0, static_cast<std::uint8_t>(level),
                                                                static_cast<std::uint32_t>(u / span),
                                                                static_cast<std::uint32_t>(v / span)});
        }
    }
    return ids;
}

class RuntimeSim : public ::testing::Test {
protected:
    // Built once per build tree and shared by the test processes (read only).
    static void SetUpTestSuite() { path_ = tessera::test::cached_store("procedural:terrain:8192", "terrain.tsr"); }

    struct Run {
        std::vector<float> bias;
        std::vector<std::uint32_t> evicted, uploaded, wanted;
        std::vector<float> fallback;
    };

    // Runs `frames` frames of a camera path; the feedback of frame N is rendered with the bias the
    // runtime reported after frame N-1 (tagged, so the controller knows).
    static Run run(Runtime& rt, DelayedSource& src, unsigned frames,
                   const std::function<void(unsigned, double&, double&, double&)>& path) {
        Run out;
        const auto& info = *rt.texture_info(0);
        for (unsigned f = 0; f < frames; ++f) {
            double cx = 0, cy = 0, tpp = 1;
            path(f, cx, cy, tpp);
            const float b = rt.lod_bias();
            const auto ids = feedback(info, 160, 90, cx, cy, tpp, b);
            src.tick();
            const auto& s = rt.frame(ids, 160, 90, b);
            out.bias.push_back(s.lod_bias);
            out.evicted.push_back(s.pages_evicted);
            out.uploaded.push_back(s.pages_uploaded);
            out.wanted.push_back(s.pages_wanted);
            out.fallback.push_back(s.fallback_estimate);
        }
        return out;
    }

    static std::unique_ptr<Runtime> make(std::uint32_t pool, FakeUploader& up, DelayedSource& src,
                                         std::uint32_t keep_unwanted_frames = 8, float fade_ms = 0) {
        RuntimeConfig c;
        c.fade_ms = fade_ms;
        c.residency.pool_slots = pool;
        c.transcode_threads = 0;  // deterministic
        c.ram_cache_bytes = 0;    // every page comes from the source
        c.upload_pages_per_frame = 8;
        c.keep_unwanted_frames = keep_unwanted_frames;
        auto rt = Runtime::create(c, up);
        EXPECT_TRUE(rt.ok());
        auto id = (*rt)->add_texture(src, "terrain");
        EXPECT_TRUE(id.ok()) << id.error().message;
        return std::move(*rt);
    }

    static std::string path_;
};
std::string RuntimeSim::path_;

TEST_F(RuntimeSim, StaticViewConvergesWithALargePool) {
    FakeUploader up;
    DelayedSource src(path_, 3);
    auto rt = make(1024, up, src);
    auto r = run(*rt, src, 120, [](unsigned, double& cx, double& cy, double& tpp) { cx = 4000, cy = 4000, tpp = 2; });
    // Converged: nothing missing, nothing in flight, no bias, no churn.
    EXPECT_EQ(r.fallback.back(), 0.0f);
    EXPECT_EQ(rt->in_flight(), 0u);
    for (float b : r.bias) EXPECT_EQ(b, 0.0f);
    std::uint32_t evicted = 0;
    for (auto e : r.evicted) evicted += e;
    EXPECT_EQ(evicted, 0u);
    // Every upload mapped a page; the page table followed.
    EXPECT_EQ(up.malformed(), 0u);
    EXPECT_GT(up.tables().size(), 0u);
    EXPECT_EQ(residency_of(*rt).stats().resident_pages, up.pages().size());
    // Frames to converge: bounded by latency + wanted / upload budget.
    unsigned converged = 0;
    while (converged < r.fallback.size() && r.fallback[converged] > 0) ++converged;
    EXPECT_LT(converged, 3 + r.wanted.back() / 8 + 10u);
}

TEST_F(RuntimeSim, TooSmallAPoolRaisesTheBiasWhichSettlesWithoutThrashing) {
    FakeUploader up;
    DelayedSource src(path_, 2);
    auto rt = make(24, up, src);  // the view wants far more than 24 pages at bias 0
    auto r = run(*rt, src, 400, [](unsigned, double& cx, double& cy, double& tpp) { cx = 4000, cy = 4000, tpp = 1; });
    EXPECT_GT(r.wanted.front(), 24u);
    EXPECT_GT(r.bias.back(), 0.0f) << "the bias rose";
    // Settled: no bias change in the last 200 frames, and at most one reversal overall.
    for (std::size_t f = 200; f < r.bias.size(); ++f) EXPECT_EQ(r.bias[f], r.bias.back()) << "frame " << f;
    int reversals = 0, last_dir = 0;
    for (std::size_t f = 1; f < r.bias.size(); ++f) {
        const int dir = r.bias[f] > r.bias[f - 1] ? 1 : r.bias[f] < r.bias[f - 1] ? -1 : 0;
        if (dir && last_dir && dir != last_dir) ++reversals;
        if (dir) last_dir = dir;
    }
    EXPECT_LE(reversals, 1);
    // Churn: once settled, pages are no longer evicted frame after frame.
    std::uint32_t late_evictions = 0;
    for (std::size_t f = 300; f < r.evicted.size(); ++f) late_evictions += r.evicted[f];
    EXPECT_LE(late_evictions, 10u);
    EXPECT_LE(r.wanted.back(), 24u) << "at the settled bias the view fits the pool";
}

TEST_F(RuntimeSim, MovingCameraKeepsUpAndTheBiasReturnsWhenPressureGoes) {
    FakeUploader up;
    DelayedSource src(path_, 2);
    auto rt = make(40, up, src);
    // 0-299: a wide, close view sweeping sideways (too much for the pool); 300-699: zoomed out and
    // still (little is wanted): the bias must come back down to 0.
    auto r = run(*rt, src, 700, [](unsigned f, double& cx, double& cy, double& tpp) {
        if (f < 300) {
            cx = 1500 + 8.0 * f, cy = 4000, tpp = 0.75;
        } else {
            cx = 4000, cy = 4000, tpp = 24;
        }
    });
    float peak = 0;
    for (std::size_t f = 0; f < 300; ++f) peak = std::max(peak, r.bias[f]);
    EXPECT_GT(peak, 0.0f) << "wanted at first: " << r.wanted.front();
    EXPECT_EQ(r.bias.back(), 0.0f);
    // Churn stays bounded while moving: evictions per frame never exceed the upload budget.
    for (std::size_t f = 0; f < r.evicted.size(); ++f) EXPECT_LE(r.evicted[f], 8u) << "frame " << f;
    // Detail comes back: the still view ends fully resident.
    EXPECT_EQ(r.fallback.back(), 0.0f);
}

// The slots' blend weights as the uploader sees them (FakeUploader::weight), against the page
// cache: every slot drawn below full weight holds a mapped page (the last written into it), and
// no page is written into a slot whose page is still drawn fading out.
struct WeightAudit {
    std::size_t blended_but_unmapped = 0, most_fading_out = 0;
    // kept: pages the frame kept (still drawn falling: their weight turns in the next frame).
    void check(const FakeUploader& up, const Runtime& rt, std::uint32_t kept) {
        for (const SlotId slot : up.below_full()) {
            const auto& calls = up.pages();
            const auto last = std::find_if(calls.rbegin(), calls.rend(), [&](const auto& c) { return c.slot == slot; });
            if (last == calls.rend() || !residency_of(rt).is_resident(last->page)) ++blended_but_unmapped;
        }
        const std::size_t out = up.fading_out().size();
        most_fading_out = std::max(most_fading_out, out);
        EXPECT_LE(out, residency_of(rt).stats().leaving + kept) << "a slot fading out that the page cache does not call leaving";
    }
};

// Fading out (docs/client.md, "A slot's life"): with a fade time, a victim the feedback saw in
// the last fade_out_frames frames leaves over the fade: it stays mapped while its weight falls,
// nothing is written into its slot before it has faded out, and detail still comes back.
// Without a fade time victims go at once and no weight is ever sent.
TEST_F(RuntimeSim, RecentlySeenVictimsFadeOutBeforeTheirSlotsAreReused) {
    for (const float fade_ms : {0.0f, 150.0f}) {  // 150 ms: 9 frames of the runtime's default 60 Hz clock
        FakeUploader up;
        DelayedSource src(path_, 2);
        auto rt = make(40, up, src, 8, fade_ms);
        const auto& info = *rt->texture_info(0);
        WeightAudit audit;
        std::uint32_t most_leaving = 0;
        float last_fallback = 1, peak_bias = 0;
        for (unsigned f = 0; f < 700; ++f) {
            // As MovingCameraKeepsUpAndTheBiasReturnsWhenPressureGoes: a sweep too wide for the
            // pool, then a still view from far.
            const double cx = f < 300 ? 1500 + 8.0 * f : 4000, tpp = f < 300 ? 0.75 : 24;
            const float b = rt->lod_bias();
            src.tick();
            const auto& st = rt->frame(feedback(info, 160, 90, cx, 4000, tpp, b), 160, 90, b);
            last_fallback = st.fallback_estimate;
            peak_bias = std::max(peak_bias, st.lod_bias);
            most_leaving = std::max(most_leaving, residency_of(*rt).stats().leaving);
            audit.check(up, *rt, st.pages_rescued);
        }
        EXPECT_EQ(up.written_while_leaving(), 0u);
        EXPECT_EQ(audit.blended_but_unmapped, 0u);
        EXPECT_GT(peak_bias, 0.0f) << "the sweep must put the pool under pressure";
        EXPECT_EQ(last_fallback, 0.0f) << "detail comes back";
        if (fade_ms == 0) {
            EXPECT_EQ(up.weight_calls(), 0u);
            EXPECT_EQ(most_leaving, 0u);
        } else {
            EXPECT_GT(up.fade_outs(), 0u) << "the sweep evicts pages it has just seen";
            EXPECT_GT(audit.most_fading_out, 0u);
            EXPECT_LE(most_leaving, 32u) << "ResidencyConfig::max_leaving";
            EXPECT_TRUE(up.below_full().empty()) << "the still view ends with every page at full weight";
        }
        std::printf("  fade %.0f ms: %zu pages faded out, at most %u leaving at once, %llu evictions\n", fade_ms, up.fade_outs(),
                    most_leaving, static_cast<unsigned long long>(residency_of(*rt).stats().evictions));
    }
}

TEST_F(RuntimeSim, PagesFadingOutThatTheViewWantsAgainAreKept) {
    // The camera swings back and forth over more than the pool holds: pages behind it start
    // leaving, and the swing back wants them again before they have gone.
    FakeUploader up;
    DelayedSource src(path_, 2);
    auto rt = make(40, up, src, 8, 300.0f);  // 18 frames: the swing back comes within a fade
    const auto& info = *rt->texture_info(0);
    WeightAudit audit;
    std::uint64_t rescued = 0;
    for (unsigned f = 0; f < 400; ++f) {
        const double cx = 2500 + 700 * std::sin(f * 0.15);
        const float b = rt->lod_bias();
        src.tick();
        const auto& st = rt->frame(feedback(info, 160, 90, cx, 4000, 0.75, b), 160, 90, b);
        rescued += st.pages_rescued;
        audit.check(up, *rt, st.pages_rescued);
    }
    EXPECT_GT(up.fade_outs(), 0u) << "the swings must evict pages just seen";
    EXPECT_GT(rescued, 0u) << "the swing back wants leaving pages again";
    // A kept page rises from where its weight was, without a page written: the uploader sees it.
    EXPECT_GT(up.fade_backs(), 0u);
    EXPECT_LE(up.fade_backs(), rescued);
    EXPECT_EQ(up.written_while_leaving(), 0u);
    EXPECT_EQ(residency_of(*rt).stats().rescued, rescued);
    EXPECT_EQ(rt->summary().pages_rescued(), rescued);
    EXPECT_EQ(audit.blended_but_unmapped, 0u);
    std::printf("  %zu pages started fading out, %llu were wanted again and kept (%zu seen rising by the uploader), %llu "
                "evictions\n",
                up.fade_outs(), static_cast<unsigned long long>(rescued), up.fade_backs(),
                static_cast<unsigned long long>(residency_of(*rt).stats().evictions));
}

TEST_F(RuntimeSim, StaleRequestsAreCancelledAtTheSource) {
    // Frame 1 looks at one corner, then the camera cuts to the opposite corner for good: the first
    // corner's requests are cancelled at the source before they are served, and never uploaded.
    FakeUploader up;
    DelayedSource src(path_, 10);
    auto rt = make(1024, up, src);
    auto r = run(*rt, src, 60, [](unsigned f, double& cx, double& cy, double& tpp) {
        tpp = 0.5;
        cx = cy = f == 0 ? 700 : 7400;
    });
    const auto& info = *rt->texture_info(0);
    const auto first = feedback(info, 160, 90, 700, 700, 0.5, 0);
    std::set<std::uint64_t> first_pages, later_pages;
    for (auto id : first)
        if (id != kNoPage && unpack_feedback(id).level == 0) first_pages.insert(id);
    for (auto id : feedback(info, 160, 90, 7400, 7400, 0.5, 0))
        if (id != kNoPage) later_pages.insert(id);
    ASSERT_FALSE(first_pages.empty());
    for (const auto id : first_pages) {
        EXPECT_FALSE(later_pages.contains(id));
        EXPECT_FALSE(residency_of(*rt).is_resident(unpack_feedback(id))) << "a stale page was mapped";
    }
    // Served = what the later view wanted (and the shared coarse ancestors), not the stale ones.
    EXPECT_EQ(r.fallback.back(), 0.0f);
    EXPECT_EQ(src.served(), up.pages().size());
}

TEST_F(RuntimeSim, FramesWithoutFeedbackKeepLoadingAndCancelNothing) {
    // A GPU renderer's feedback arrives frames late: frames without it keep the last wanted set.
    FakeUploader up;
    DelayedSource src(path_, 3);
    auto rt = make(1024, up, src);
    const auto& info = *rt->texture_info(0);
    const auto ids = feedback(info, 160, 90, 4000, 4000, 2, 0);
    src.tick();
    const auto wanted = rt->frame(ids, 160, 90, 0.0f).pages_wanted;
    const auto requested = rt->in_flight();
    ASSERT_GT(requested, 8u);
    std::uint64_t uploaded = 0;
    for (int f = 0; f < 200 && rt->in_flight() > 0; ++f) {
        src.tick();
        const auto& s = rt->frame_without_feedback();
        EXPECT_EQ(s.pages_wanted, wanted);
        EXPECT_LE(s.pages_uploaded, 8u);
        uploaded += s.pages_uploaded;
    }
    EXPECT_EQ(rt->in_flight(), 0u);
    EXPECT_EQ(uploaded, src.served()) << "every request was served and uploaded, none cancelled";
    EXPECT_GE(uploaded, requested);
    // The next real feedback finds everything resident.
    src.tick();
    EXPECT_EQ(rt->frame(ids, 160, 90, 0.0f).fallback_estimate, 0.0f);
}

TEST_F(RuntimeSim, DeterministicForTheSameScript) {
    auto once = [&] {
        FakeUploader up;
        DelayedSource src(path_, 2);
        auto rt = make(48, up, src);
        auto r = run(*rt, src, 150, [](unsigned f, double& cx, double& cy, double& tpp) { cx = 3000 + 5.0 * f, cy = 4000, tpp = 1; });
        return std::make_tuple(r.bias, r.evicted, r.uploaded);
    };
    EXPECT_EQ(once(), once());
}

}  // namespace

namespace {

// What the runtime skips when a request stops being wanted, counted by stage (docs/visibility.md).
// No grace window here: a page is unwanted in the first frame that does not see it.
TEST_F(RuntimeSim, CountsCancellationsByStage) {
    const auto empty = std::vector<FeedbackId>(160 * 90, kNoPage);
    auto view = [&](Runtime& rt) { return feedback(*rt.texture_info(0), 160, 90, 4000, 4000, 2, 0); };
    {  // Withdrawn while waiting on the source (latency 5 frames): all cancelled before arrival.
        FakeUploader up;
        DelayedSource src(path_, 5);
        auto rt = make(1024, up, src, /*keep_unwanted_frames=*/0);
        src.tick();
        const std::uint32_t requested = rt->frame(view(*rt), 160, 90, 0).pages_requested;
        ASSERT_GT(requested, 0u);
        src.tick();
        const auto& s = rt->frame(empty, 160, 90, 0);
        EXPECT_EQ(s.cancelled_waiting, requested);
        EXPECT_EQ(s.cancelled_arrived, 0u);
        for (int f = 0; f < 10; ++f) {
            src.tick();
            rt->frame(empty, 160, 90, 0);
        }
        EXPECT_EQ(rt->summary().stale_arrivals(), 0u) << "the source dropped them: no I/O";
        EXPECT_EQ(src.served(), 0u);
        EXPECT_EQ(rt->summary().cancelled_waiting(), requested);
        EXPECT_EQ(rt->in_flight(), 0u);
        EXPECT_NE(rt->summary().to_json().find("\"skipped\":{\"cancelled_waiting\":" + std::to_string(requested)),
                  std::string::npos);
    }
    {  // The same with a source that serves withdrawn requests anyway: the I/O was not saved.
        FakeUploader up;
        DelayedSource src(path_, 5, /*ignore_cancel=*/true);
        auto rt = make(1024, up, src, /*keep_unwanted_frames=*/0);
        src.tick();
        const std::uint32_t requested = rt->frame(view(*rt), 160, 90, 0).pages_requested;
        for (int f = 0; f < 10; ++f) {
            src.tick();
            rt->frame(empty, 160, 90, 0);
        }
        EXPECT_EQ(rt->summary().cancelled_waiting(), requested);
        EXPECT_EQ(rt->summary().stale_arrivals(), requested);
        EXPECT_EQ(rt->summary().pages_arrived(), 0u);
    }
    {  // Withdrawn in the frame the data arrived (latency 1): never decoded.
        FakeUploader up;
        DelayedSource src(path_, 1);
        auto rt = make(1024, up, src, /*keep_unwanted_frames=*/0);
        src.tick();
        const std::uint32_t requested = rt->frame(view(*rt), 160, 90, 0).pages_requested;
        src.tick();
        const auto& s = rt->frame(empty, 160, 90, 0);
        EXPECT_EQ(s.pages_arrived, requested);
        EXPECT_EQ(s.cancelled_waiting, 0u);
        EXPECT_EQ(s.cancelled_arrived, requested);
        EXPECT_EQ(s.pages_uploaded, 0u);
        EXPECT_EQ(rt->summary().decodes_dropped(), 0u);  // synchronous decoding: no pool to drop in
    }
}

}  // namespace

namespace {

// Jittered feedback sees a small page only now and then, and a GPU renders many frames while one
// request is in flight: a page seen every fourth frame must still arrive, not be cancelled in
// each frame that misses it (which starved a fast GPU of small pages).
TEST_F(RuntimeSim, PagesSeenNowAndThenAreNotCancelledWithinTheGraceWindow) {
    const auto empty = std::vector<FeedbackId>(160 * 90, kNoPage);
    auto intermittent = [&](std::uint32_t keep_frames) {
        FakeUploader up;
        DelayedSource src(path_, 6);  // served six frames after the request
        auto rt = make(1024, up, src, keep_frames);
        const auto ids = feedback(*rt->texture_info(0), 160, 90, 4000, 4000, 2, 0);
        std::uint32_t requested = 0;
        for (unsigned f = 0; f < 60; ++f) {
            src.tick();
            requested += rt->frame(f % 4 == 0 ? ids : empty, 160, 90, 0).pages_requested;
        }
        return std::make_tuple(requested, rt->summary().cancelled_waiting(), up.pages().size());
    };
    const auto [requested, cancelled, uploaded] = intermittent(8);
    ASSERT_GT(requested, 8u);
    EXPECT_EQ(cancelled, 0u);
    EXPECT_EQ(uploaded, requested) << "every page requested was delivered";

    // Without the window every request is withdrawn the frame after it was made, again and again.
    const auto [requested0, cancelled0, uploaded0] = intermittent(0);
    EXPECT_GT(requested0, 8u);
    EXPECT_EQ(cancelled0, requested0);
    EXPECT_EQ(uploaded0, 0u);
}

// The window ends: a page unseen for more than its frames is given up.
TEST_F(RuntimeSim, PagesUnseenForLongerThanTheGraceWindowAreCancelled) {
    const auto empty = std::vector<FeedbackId>(160 * 90, kNoPage);
    FakeUploader up;
    DelayedSource src(path_, 1000);  // never served within this test
    auto rt = make(1024, up, src, /*keep_unwanted_frames=*/8);
    src.tick();
    const std::uint32_t requested = rt->frame(feedback(*rt->texture_info(0), 160, 90, 4000, 4000, 2, 0), 160, 90, 0).pages_requested;
    ASSERT_GT(requested, 0u);
    for (int f = 0; f < 8; ++f) {
        src.tick();
        rt->frame(empty, 160, 90, 0);
    }
    EXPECT_EQ(rt->summary().cancelled_waiting(), 0u) << "unseen for 8 frames: still wanted";
    EXPECT_EQ(rt->in_flight(), requested);
    src.tick();
    rt->frame(empty, 160, 90, 0);
    EXPECT_EQ(rt->summary().cancelled_waiting(), requested) << "unseen for 9 frames: given up";
    EXPECT_EQ(rt->in_flight(), 0u);
}

}  // namespace

namespace {

// The runtime transcodes every page to the uploader's pool format, and refuses a store that
// cannot take it when the texture is added, naming the format.
// A layered store whose layers are sparse apart: a tile with one layer absent is a page the
// runtime cannot make (never a page resident in some layers only), so it falls back to the parent
// like an absent tile, and is asked for once, not again on every frame.
TEST_F(RuntimeSim, PagesWithAnAbsentLayerAreAskedForOnce) {
    tessera::test::ScratchDir d;
    const std::uint32_t N = 256;  // 4 x 4 tiles of 64 at level 0
    // Two RGBA layers: a transparent on the left half, b on the left half and the top half, so
    // tiles (2..3, 0..1) hold a but not b.
    for (const bool second : {false, true}) {
        std::vector<std::uint8_t> im(std::size_t(N) * N * 4);
        for (std::uint32_t y = 0; y < N; ++y)
            for (std::uint32_t x = 0; x < N; ++x) {
                std::uint8_t* t = im.data() + (std::size_t(y) * N + x) * 4;
                t[0] = std::uint8_t(x), t[1] = std::uint8_t(y), t[2] = second ? 200 : 7;
                t[3] = x < N / 2 || (second && y < N / 2) ? 0 : 255;
            }
        const std::string raw = d.file(second ? "b.rgba" : "a.rgba");
        std::FILE* f = std::fopen(raw.c_str(), "wb");
        ASSERT_TRUE(f);
        ASSERT_EQ(std::fwrite(im.data(), 1, im.size(), f), im.size());
        std::fclose(f);
        const std::string cmd = "convert-im6.q16 -size 256x256 -depth 8 rgba:" + raw + " " + d.file(second ? "b.png" : "a.png");
        ASSERT_EQ(std::system((cmd + " >/dev/null 2>&1").c_str()), 0) << cmd;
    }
    const std::string store = d.file("s.tsr");
    const auto built = tessera::test::run_tessera("build --quiet --sparse --tile-size 64 --border 0 --layer a=" + d.file("a.png") +
                                                  " --layer b=" + d.file("b.png") + " -o " + store);
    ASSERT_EQ(built.exit_code, 0) << built.out;

    PagePoolFormat pool;
    pool.format = PageFormat::rgba8;
    pool.more_layers = {PageFormat::rgba8};
    FakeUploader up(pool);
    DelayedSource src(store, 1);
    RuntimeConfig c;
    c.residency.pool_slots = 64;
    c.transcode_threads = 0;
    c.ram_cache_bytes = 0;  // every page comes from the source
    auto rt = Runtime::create(c, up);
    ASSERT_TRUE(rt.ok());
    auto id = (*rt)->add_texture(src, "s");
    ASSERT_TRUE(id.ok()) << id.error().message;
    // The view wants every level-0 page.
    std::vector<FeedbackId> ids;
    for (std::uint32_t y = 0; y < 4; ++y)
        for (std::uint32_t x = 0; x < 4; ++x) ids.push_back(pack_feedback(PageKey{0, 0, x, y}));
    auto frames = [&](int n) {
        for (int f = 0; f < n; ++f) {
            src.tick();
            (*rt)->frame(ids, std::uint32_t(ids.size()), 1, 0);
        }
    };
    frames(20);
    const std::uint64_t served = src.served();
    frames(20);
    EXPECT_EQ(src.served(), served) << "pages asked for again after they were found";
    EXPECT_EQ(up.malformed(), 0u);
    for (const auto& p : up.pages())
        EXPECT_FALSE(p.page.level == 0 && p.page.x >= 2 && p.page.y < 2) << "a page without its layer b was uploaded: " << p.page.x << "," << p.page.y;
    // The four level-0 pages with both layers are resident.
    std::size_t both = 0;
    for (const auto& p : up.pages()) both += p.page.level == 0 && p.page.x >= 2 && p.page.y >= 2;
    EXPECT_EQ(both, 4u);
}

// A tile that arrives whole but does not decode: asking again brings the same bytes, so the page
// stands absent (its parent shown), is counted, and is not fetched and decoded frame after frame.
TEST_F(RuntimeSim, ATileThatDoesNotDecodeIsAskedForOnce) {
    FakeUploader up;
    DelayedSource src(path_, 1);
    auto rt = make(256, up, src);
    const auto& info = *rt->texture_info(0);
    const std::uint8_t top = std::uint8_t(info.level_count() - 1);
    const PageKey bad{0, std::uint8_t(top - 2), 1, 1};
    src.undecodable(bad);
    const std::vector<FeedbackId> ids = {pack_feedback(bad)};
    for (int f = 0; f < 60; ++f) {
        src.tick();
        rt->frame(ids, 1, 1, 0);
    }
    EXPECT_EQ(src.served(bad), 1u) << "fetched again after it failed to decode";
    EXPECT_EQ(rt->summary().decode_failures(), 1u);
    EXPECT_FALSE(residency_of(*rt).is_resident(bad));
    EXPECT_TRUE(residency_of(*rt).is_resident(PageKey{0, std::uint8_t(top - 1), 0, 0})) << "its parent stands in";
    EXPECT_EQ(rt->in_flight(), 0u);
    EXPECT_NE(rt->summary().to_json().find("\"decode_failures\":1"), std::string::npos) << rt->summary().to_json();
    EXPECT_EQ(up.malformed(), 0u);
}

// An error reply (a server's "retry later") ends the request at the source: the page is asked
// again PageLoader::kErrorRetryFrames later, not on every frame, and not only at the next
// 30-frame resend of an unchanged request set.
TEST_F(RuntimeSim, AnErrorReplyIsAskedAgainAtOnce) {
    FakeUploader up;
    DelayedSource src(path_, 3);
    auto rt = make(256, up, src);
    const auto& info = *rt->texture_info(0);
    const std::uint8_t top = std::uint8_t(info.level_count() - 1);
    const PageKey page{0, std::uint8_t(top - 2), 1, 1};
    const std::vector<FeedbackId> ids = {pack_feedback(page)};
    // The error comes 5 frames after the page's ancestors have arrived: nothing else changes in
    // the request set when it does.
    src.fail_next(page, 5);
    int frames = 0;
    while (!residency_of(*rt).is_resident(page) && frames < 60) {
        src.tick();
        rt->frame(ids, 1, 1, 0);
        ++frames;
    }
    EXPECT_TRUE(residency_of(*rt).is_resident(page));
    EXPECT_EQ(src.served(page), 2u);  // the error, then the tile
    // Asked at frame 1, the error at 1 + 3 + 5, asked again kErrorRetryFrames later, the tile 3
    // frames after that.
    const int retry = int(PageLoader::kErrorRetryFrames);
    EXPECT_GE(frames, 1 + 3 + 5 + retry) << "asked again before the back-off";
    EXPECT_LE(frames, 1 + 3 + 5 + retry + 3 + 2) << "the retry waited for the periodic resend";
    // Counted, with the first one's page and message, for the viewer's summary to say.
    EXPECT_EQ(rt->summary().source_errors(), 1u);
    EXPECT_EQ(rt->summary().first_source_error(),
              "level " + std::to_string(page.level) + " (1, 1): UNAVAILABLE queue full; retry later");
    EXPECT_NE(rt->summary().to_json().find("\"source_errors\":1"), std::string::npos) << rt->summary().to_json();
}

// The disk cache keys tiles by store name. A texture over a local file (named by its path) skips
// it: its pages take as many frames as without a disk cache, not one more through the disk lookup.
// A server's absent tiles (checksum 0, no payload) are kept like any other, so a second run
// over a sparse store does not ask for them again.
TEST_F(RuntimeSim, TheDiskCacheTakesServerStoresAbsentTilesIncluded) {
    tessera::test::ScratchDir d;
    auto frames_to_detail = [&](bool with_disk) {
        FakeUploader up;
        DelayedSource src(path_, 2);
        RuntimeConfig c;
        c.residency.pool_slots = 64;
        c.transcode_threads = 0;
        c.ram_cache_bytes = 0;
        if (with_disk) c.disk_cache_dir = d.file("local-cache");
        auto rt = Runtime::create(c, up);
        EXPECT_TRUE(rt.ok());
        auto id = (*rt)->add_texture(src, path_);  // a local file: named by its path
        EXPECT_TRUE(id.ok());
        const auto& info = *(*rt)->texture_info(0);
        const PageKey page{0, std::uint8_t(info.level_count() - 3), 1, 1};
        const std::vector<FeedbackId> ids = {pack_feedback(page)};
        int f = 0;
        for (; f < 100 && !residency_of(**rt).is_resident(page); ++f) {
            src.tick();
            (*rt)->frame(ids, 1, 1, 0);
        }
        return f;
    };
    EXPECT_EQ(frames_to_detail(true), frames_to_detail(false));

    // A sparse store, served under a store name: 4 x 4 tiles at level 0, one present.
    tessera::storage::StoreSpec spec;
    spec.width = spec.height = 256;
    spec.tile_payload = 64;
    spec.channels = 1;
    spec.codec = tessera::Codec::raw;
    spec.colour_space = tessera::storage::ColourSpace::linear;
    {
        auto w = tessera::storage::StoreWriter::create(d.file("sparse.tsr"), spec);
        ASSERT_TRUE(w.ok());
        ASSERT_TRUE((*w)->add_present({0, 0, 0}, std::vector<std::uint8_t>(64 * 64, 9)).ok());
        ASSERT_TRUE((*w)->add_present({1, 0, 0}, std::vector<std::uint8_t>(64 * 64, 9)).ok());
        ASSERT_TRUE((*w)->add_present({2, 0, 0}, std::vector<std::uint8_t>(64 * 64, 9)).ok());
        ASSERT_TRUE((*w)->finish().ok());
    }
    std::vector<FeedbackId> level0;
    for (std::uint32_t y = 0; y < 4; ++y)
        for (std::uint32_t x = 0; x < 4; ++x) level0.push_back(pack_feedback(PageKey{0, 0, x, y}));
    std::uint64_t served[2] = {};
    for (int run = 0; run < 2; ++run) {
        FakeUploader up;
        DelayedSource src(d.file("sparse.tsr"), 1);
        RuntimeConfig c;
        c.residency.pool_slots = 32;
        c.transcode_threads = 0;
        c.ram_cache_bytes = 0;
        c.disk_cache_dir = d.file("server-cache");
        auto rt = Runtime::create(c, up);
        ASSERT_TRUE(rt.ok());
        ASSERT_TRUE((*rt)->add_texture(src, "sparse").ok());
        for (int f = 0; f < 200 && (f < 5 || (*rt)->in_flight() > 0); ++f) {
            std::this_thread::sleep_for(std::chrono::milliseconds(2));  // the disk lookups run on their own thread
            src.tick();
            (*rt)->frame(level0, std::uint32_t(level0.size()), 1, 0);
        }
        EXPECT_EQ((*rt)->in_flight(), 0u) << "run " << run;
        served[run] = src.served();
        // The cache's own counts: written in the first run, found in the second.
        const auto disk = (*rt)->disk_cache();
        ASSERT_TRUE(disk.has_value());
        if (run == 0) {
            (*rt).reset();  // closing drains the write queue
        } else {
            EXPECT_GE(disk->hits, 16u);
            EXPECT_GE(disk->entries, 16u);
            EXPECT_GT(disk->bytes, 0u);
            EXPECT_EQ(disk->write_errors + disk->corrupt + disk->write_drops, 0u);
        }
    }
    {
        FakeUploader up;
        RuntimeConfig c;
        c.residency.pool_slots = 32;
        c.transcode_threads = 0;
        auto rt = Runtime::create(c, up);
        ASSERT_TRUE(rt.ok()) << rt.error().message;
        EXPECT_FALSE((*rt)->disk_cache().has_value()) << "no disk cache, no counts";
    }
    EXPECT_GT(served[0], 15u) << "the first run asks for every page";
    EXPECT_EQ(served[1], 0u) << "the second run has them all on disk, the absent ones too";
}

// kept_frames keeps the pages of the last N feedbacks. A frame without feedback (a readback gap)
// saw nothing: it must not age the view's pages. Before, it advanced residency's frame number, so
// with motion prefetch (N = 2: the view, then the view ahead) a gap let the view ahead's tiles
// evict pages on screen.
TEST_F(RuntimeSim, AFrameWithoutFeedbackDoesNotAgeTheView) {
    auto make_rt = [&](std::uint32_t pool, FakeUploader& up, DelayedSource& src) {
        RuntimeConfig c;
        c.residency.pool_slots = pool;
        c.residency.kept_frames = 2;
        c.keep_unwanted_frames = 8;  // the view ahead's requests outlive the frames that see the view
        // Only the 1 x 1 level pinned: a pinned page's upload may evict anything, which is not
        // what this is about.
        c.residency.auto_pin_max_pages = 1;
        c.transcode_threads = 0;
        c.ram_cache_bytes = 0;
        c.upload_pages_per_frame = 64;
        auto rt = Runtime::create(c, up);
        EXPECT_TRUE(rt.ok());
        EXPECT_TRUE((*rt)->add_texture(src, "terrain").ok());
        return std::move(*rt);
    };
    std::vector<FeedbackId> view, ahead;
    std::uint8_t level = 0;
    std::uint32_t tiles_x = 0, tiles_y = 0;
    {
        FakeUploader up;
        DelayedSource src(path_, 3);
        auto probe = make_rt(1024, up, src);
        const auto& info = *probe->texture_info(0);
        level = std::uint8_t(info.level_count() - 5);
        tiles_x = info.levels[level].tiles_x, tiles_y = info.levels[level].tiles_y;
    }
    ASSERT_GE(tiles_x, 8u);
    ASSERT_GE(tiles_y, 4u);
    for (std::uint32_t y = 0; y < 2; ++y)
        for (std::uint32_t x = 0; x < 4; ++x) {
            view.push_back(pack_feedback(PageKey{0, level, x, y}));
            ahead.push_back(pack_feedback(PageKey{0, level, tiles_x - 4 + x, tiles_y - 2 + y}));
        }
    // The pool: exactly what the view needs (its pages and their ancestors).
    std::uint32_t needed = 0;
    {
        FakeUploader up;
        DelayedSource src(path_, 3);
        auto probe = make_rt(1024, up, src);
        for (int f = 0; f < 40; ++f) {
            src.tick();
            probe->frame(view, std::uint32_t(view.size()), 1, 0);
        }
        needed = std::uint32_t(residency_of(*probe).stats().resident_pages);
    }
    FakeUploader up;
    DelayedSource src(path_, 3);
    auto rt = make_rt(needed, up, src);
    for (int f = 0; f < 40; ++f) {
        src.tick();
        rt->frame(view, std::uint32_t(view.size()), 1, 0);
    }
    for (const auto id : view) ASSERT_TRUE(residency_of(*rt).is_resident(unpack_feedback(id)));
    // Motion prefetch: the view ahead asks, the view is seen, a readback gap, the view ahead
    // again as its tiles arrive.
    src.tick();
    ASSERT_GT(rt->frame(ahead, std::uint32_t(ahead.size()), 1, 0).pages_requested, 0u);
    src.tick();
    rt->frame(view, std::uint32_t(view.size()), 1, 0);
    src.tick();
    rt->frame_without_feedback();
    src.tick();
    EXPECT_GT(rt->frame(ahead, std::uint32_t(ahead.size()), 1, 0).pages_arrived, 0u) << "the view ahead's tiles came";
    for (const auto id : view) EXPECT_TRUE(residency_of(*rt).is_resident(unpack_feedback(id))) << "a page on screen was evicted";
}

// A replaced store's missing pages are asked for only every kReplacedRetryFrames, but those the
// RAM cache still holds (tiles of the bound version) come from it at once.
TEST_F(RuntimeSim, AReplacedStoresCachedPagesComeFromRam) {
    auto make_rt = [&](std::uint32_t pool, FakeUploader& up, DelayedSource& src) {
        RuntimeConfig c;
        c.residency.pool_slots = pool;
        c.residency.auto_pin_max_pages = 1;
        c.transcode_threads = 0;
        c.ram_cache_bytes = 64u << 20;
        c.keep_unwanted_frames = 2;
        auto rt = Runtime::create(c, up);
        EXPECT_TRUE(rt.ok());
        EXPECT_TRUE((*rt)->add_texture(src, "terrain").ok());
        return std::move(*rt);
    };
    FakeUploader probe_up;
    DelayedSource probe_src(path_, 2);
    auto probe = make_rt(1024, probe_up, probe_src);
    const auto& info = *probe->texture_info(0);
    const std::uint8_t level = std::uint8_t(info.level_count() - 5);
    const std::uint32_t tx = info.levels[level].tiles_x, ty = info.levels[level].tiles_y;
    ASSERT_GE(tx, 8u);
    ASSERT_GE(ty, 6u);
    auto block = [&](std::uint32_t x0, std::uint32_t y0) {
        std::vector<FeedbackId> ids;
        for (std::uint32_t y = 0; y < 2; ++y)
            for (std::uint32_t x = 0; x < 4; ++x) ids.push_back(pack_feedback(PageKey{0, level, x0 + x, y0 + y}));
        return ids;
    };
    const auto view = block(0, 0), other = block(tx - 4, ty - 2), third = block(tx - 4, 2);
    auto run = [&](Runtime& rt, DelayedSource& src, const std::vector<FeedbackId>& ids, int frames) {
        for (int f = 0; f < frames; ++f) {
            src.tick();
            rt.frame(ids, std::uint32_t(ids.size()), 1, 0);
        }
    };
    run(*probe, probe_src, view, 30);
    const auto pool = std::uint32_t(residency_of(*probe).stats().resident_pages);

    FakeUploader up;
    DelayedSource src(path_, 2);
    auto rt = make_rt(pool, up, src);
    run(*rt, src, view, 30);
    run(*rt, src, other, 30);  // the view's pages leave the pool; the RAM cache keeps them
    ASSERT_FALSE(residency_of(*rt).is_resident(unpack_feedback(view.front())));
    src.replace_store();
    run(*rt, src, third, 10);  // missing pages: the other version arrives, the store is replaced
    ASSERT_NE(rt->texture_replaced(0), 0u);
    const std::uint64_t served = src.served();
    int frames = 0;
    while (frames < 20 && !std::all_of(view.begin(), view.end(), [&](FeedbackId id) {
               return residency_of(*rt).is_resident(unpack_feedback(id));
           })) {
        run(*rt, src, view, 1);
        ++frames;
    }
    EXPECT_LE(frames, 3) << "pages the RAM cache holds waited for the replaced store's retry";
    EXPECT_EQ(src.served(), served) << "they came from the RAM cache";
}

// The store is rebuilt and reloaded on its server while a view runs: its tiles are refused (never
// mixed with the bound version's), counted, the texture says it was replaced, and its missing
// pages are asked for only now and then (PageLoader::kReplacedRetryFrames), not on every frame,
// keeping what is resident. When the bound version is served again (a rollback, a replica), the
// view loads again.
TEST_F(RuntimeSim, AReplacedStoreIsNotAskedForEveryFrame) {
    FakeUploader up;
    DelayedSource src(path_, 2);
    auto rt = make(1024, up, src);
    const auto& info = *rt->texture_info(0);
    const std::uint64_t bound = info.store_id;
    const auto ids = feedback(info, 160, 90, 4000, 4000, 2, 0);
    for (int f = 0; f < 3; ++f) {
        src.tick();
        rt->frame(ids, 160, 90, 0);
    }
    ASSERT_GT(rt->in_flight(), 0u) << "the view should still be loading when the store is replaced";
    EXPECT_EQ(rt->texture_replaced(0), 0u);
    src.replace_store();
    // The camera moves on: the view wants pages it has not asked for yet.
    const auto moved = feedback(info, 160, 90, 1500, 6000, 2, 0);
    for (int f = 0; f < 10; ++f) {
        src.tick();
        rt->frame(moved, 160, 90, 0);
    }
    EXPECT_EQ(rt->texture_replaced(0), bound + 1);
    EXPECT_GT(rt->summary().other_version_arrivals(), 0u);
    const std::size_t uploaded = up.pages().size();
    // 1200 frames: the missing pages are asked for 4 times (every kReplacedRetryFrames), where an
    // unchanged request set is otherwise sent again every 30 frames (40 times).
    int frames_serving = 0;
    for (int f = 0; f < 1200; ++f) {
        const std::uint64_t before = src.served();
        src.tick();
        rt->frame(moved, 160, 90, 0);
        frames_serving += src.served() != before;
    }
    EXPECT_LE(frames_serving, 5) << "pages of the replaced store asked for again and again";
    EXPECT_GT(frames_serving, 0) << "never asked again: a rollback would never be seen";
    EXPECT_EQ(up.pages().size(), uploaded) << "pages of another version uploaded";
    EXPECT_GT(residency_of(*rt).stats().resident_pages, 0u) << "what was resident stays";
    EXPECT_NE(rt->summary().to_json().find("\"other_version_arrivals\""), std::string::npos);

    src.restore_store();
    for (int f = 0; f < 400 && (rt->texture_replaced(0) != 0 || rt->in_flight() > 0); ++f) {
        src.tick();
        rt->frame(moved, 160, 90, 0);
    }
    EXPECT_EQ(rt->texture_replaced(0), 0u) << "the bound version came back";
    EXPECT_GT(up.pages().size(), uploaded) << "the view loads again";
}

// A view roaming a sparse store meets absent pages without end: the loader remembers them (not
// asked for again) up to PageLoader::kMaxAbsentPages, then forgets them, so its memory is bounded
// and a forgotten page is asked for once more.
TEST_F(RuntimeSim, AbsentPagesAreRememberedWithinABound) {
    const std::string store = tessera::test::cached_store("procedural:coords-sparse:1048576", "coords.tsr");
    FakeUploader up;
    DelayedSource src(store, 1);
    RuntimeConfig c;
    c.residency.pool_slots = 64;
    c.transcode_threads = 0;
    c.ram_cache_bytes = 0;
    auto created = Runtime::create(c, up);
    ASSERT_TRUE(created.ok());
    auto& rt = **created;
    ASSERT_TRUE(rt.add_texture(src, "coords").ok());
    // Level-0 pages far from the corners and the centre (the only tiles the pattern writes), 512 a
    // frame; set k holds pages [512 k, 512 k + 512) of a 2000-wide band.
    const std::size_t per_set = 512;
    auto page_set = [&](std::size_t k) {
        std::vector<FeedbackId> ids;
        for (std::size_t i = k * per_set; i < (k + 1) * per_set; ++i)
            ids.push_back(pack_feedback(PageKey{0, 0, std::uint32_t(100 + i % 2000), std::uint32_t(100 + i / 2000)}));
        return ids;
    };
    auto show = [&](const std::vector<FeedbackId>& ids) {
        for (int f = 0; f < 3; ++f) {
            src.tick();
            rt.frame(ids, std::uint32_t(ids.size()), 1, 0);
        }
    };
    // Pages served and not uploaded are the absent ones the loader learned (the view's fallback
    // ancestors among them, some of which are present).
    auto absent_learned = [&] { return src.served() - up.pages().size(); };
    const auto first = page_set(0);
    show(first);
    ASSERT_GE(src.served(), per_set);
    const std::size_t bound = PageLoader::kMaxAbsentPages;
    std::size_t k = 1;
    for (; absent_learned() < bound / 2; ++k) show(page_set(k));
    std::uint64_t before = src.served();
    show(first);
    EXPECT_EQ(src.served(), before) << "remembered within the bound: not asked for again";
    for (; absent_learned() <= bound; ++k) show(page_set(k));  // past the bound: forgotten
    before = src.served();
    show(first);
    EXPECT_GE(src.served(), before + per_set) << "forgotten past the bound: asked for once more";
    before = src.served();
    show(first);
    EXPECT_EQ(src.served(), before) << "and then remembered again";
    std::printf("  %zu sets of %zu pages; %llu pages served\n", k, per_set, static_cast<unsigned long long>(src.served()));
}

TEST_F(RuntimeSim, PagesComeInThePoolsFormat) {
    for (const bool second_level : {false, true}) {
        FakeUploader up(PagePoolFormat{PageFormat::bc1, second_level, {}});
        DelayedSource src(path_, 1);
        auto rt = make(1024, up, src);
        const auto& info = *rt->texture_info(0);
        const auto ids = feedback(info, 160, 90, 4000, 4000, 2, 0);
        for (int f = 0; f < 40 && (f == 0 || rt->in_flight() > 0); ++f) {
            src.tick();
            rt->frame(ids, 160, 90, 0);
        }
        ASSERT_GT(up.pages().size(), 4u);
        EXPECT_EQ(up.malformed(), 0u);
        for (const auto& p : up.pages())
            EXPECT_EQ(p.data.size(), page_upload_bytes(PageFormat::bc1, info.tile_size(), second_level));
        EXPECT_EQ(rt->summary().bytes_uploaded(), up.pages().size() * page_upload_bytes(PageFormat::bc1, info.tile_size(), second_level));
    }
    FakeUploader grey_only(PagePoolFormat{PageFormat::bc4, false, {}});
    DelayedSource src(path_, 1);
    RuntimeConfig c;
    c.residency.pool_slots = 64;
    c.transcode_threads = 0;
    auto rt = Runtime::create(c, grey_only);
    ASSERT_TRUE(rt.ok());
    auto id = (*rt)->add_texture(src, "terrain");
    ASSERT_FALSE(id.ok()) << "a 3-channel store accepted for bc4 pages";
    EXPECT_NE(id.error().message.find("bc4"), std::string::npos) << id.error().message;
}

}  // namespace
