// End to end: the client runtime against a real `tessera serve` process. The runtime fetches the
// pages a scripted feedback stream asks for; the server is killed and restarted midway, and the
// client neither crashes nor loses its resident set, then carries on.
#include <gtest/gtest.h>
#include <signal.h>

#include <cmath>
#include <set>
#include <sstream>

#include "server_process.hpp"
#include "tessera/client/fakes/uploaders.hpp"
#include "tessera/client/runtime.hpp"
#include "runtime_internal.hpp"

namespace {

using namespace std::chrono_literals;
using namespace tessera::client;
using tessera::test::ScratchDir;
using tessera::test::ServerProcess;

// Every page of levels [from, levels) of a texture: what a zoomed-out view of the whole texture wants.
std::vector<FeedbackId> whole_texture(const tessera::storage::StoreInfo& info, std::uint32_t level) {
    std::vector<FeedbackId> ids;
    const auto& l = info.levels[level];
    for (std::uint32_t y = 0; y < l.tiles_y; ++y)
        for (std::uint32_t x = 0; x < l.tiles_x; ++x)
            ids.push_back(pack_feedback(PageKey{0, static_cast<std::uint8_t>(level), x, y}));
    return ids;
}

// `tessera build BUILD_ARGS -o DIR/NAME`, then a `tessera serve` of it; null (a test failure
// added) when either fails.
std::unique_ptr<ServerProcess> built_and_served(const ScratchDir& dir, const std::string& name, const std::string& build_args) {
    const std::string store = dir.file(name);
    auto built = tessera::test::run_tessera("build " + build_args + " --quiet -o " + store);
    if (built.exit_code != 0) {
        ADD_FAILURE() << built.out;
        return nullptr;
    }
    auto srv = std::make_unique<ServerProcess>(std::vector<std::string>{"--store", store}, dir.file("log"));
    if (!srv->running()) {
        ADD_FAILURE() << srv->log();
        return nullptr;
    }
    return srv;
}

// Runs frames until pred() or the timeout; returns whether pred() held.
template <class Pred>
bool frames_until(Runtime& rt, const std::vector<FeedbackId>& ids, Pred pred, std::chrono::seconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
        rt.frame(ids, static_cast<std::uint32_t>(ids.size()), 1);
        if (pred()) return true;
        std::this_thread::sleep_for(5ms);
    }
    return false;
}

TEST(RuntimeEndToEnd, FetchesFromARealServerAndSurvivesItsRestart) {
    ScratchDir dir;
    const std::string store = dir.file("terrain.tsr");
    auto built = tessera::test::run_tessera("build procedural:terrain:4096 --quiet -o " + store);
    ASSERT_EQ(built.exit_code, 0) << built.out;
    auto srv = std::make_unique<ServerProcess>(std::vector<std::string>{"--store", store}, dir.file("log1"));
    ASSERT_TRUE(srv->running()) << srv->log();
    const std::string address = srv->grpc_address();

    TileStreamOptions net;
    net.target = address;
    net.backoff_initial = 50ms;
    net.backoff_max = 400ms;
    auto source = make_grpc_source(net);
    FakeUploader uploader;
    RuntimeConfig config;
    config.residency.pool_slots = 512;  // level 0 (17 x 17) + level 1 + ancestors fit
    config.transcode_threads = 1;
    config.disk_cache_dir = dir.file("cache");
    auto created = Runtime::create(config, uploader);
    ASSERT_TRUE(created.ok()) << created.error().message;
    auto& rt = **created;
    auto tex = rt.add_texture(*source, "terrain");
    ASSERT_TRUE(tex.ok()) << tex.error().message;
    const auto& info = *rt.texture_info(*tex);

    // Phase 1: level 1 of the whole texture (9 x 9 pages) plus ancestors arrive and are mapped.
    const auto level1 = whole_texture(info, 1);
    ASSERT_TRUE(frames_until(rt, level1, [&] { return rt.frame(level1, std::uint32_t(level1.size()), 1).fallback_estimate == 0.0f; }, 60s))
        << "resident: " << residency_of(rt).stats().resident_pages;
    const auto resident_before = residency_of(rt).stats().resident_pages;
    EXPECT_GE(resident_before, level1.size());
    for (const auto id : level1) EXPECT_TRUE(residency_of(rt).is_resident(unpack_feedback(id)));

    // Phase 2: the server dies (SIGKILL, no drain). The view moves to level 0: nothing can
    // arrive, frames go on, and what is resident stays resident (level 1 serves as fallback).
    srv.reset();  // SIGKILL in the destructor
    const auto level0 = whole_texture(info, 0);
    for (int f = 0; f < 100; ++f) {
        const auto& s = rt.frame(level0, std::uint32_t(level0.size()), 1);
        EXPECT_GT(s.fallback_estimate, 0.0f);
        std::this_thread::sleep_for(5ms);
    }
    EXPECT_FALSE(source->available());
    for (const auto id : level1) EXPECT_TRUE(residency_of(rt).is_resident(unpack_feedback(id)));

    // Phase 3: a new server on the same port; the client reconnects by itself and level 0 arrives.
    ServerProcess again({"--store", store}, dir.file("log2"), address);
    ASSERT_TRUE(again.running()) << again.log();
    ASSERT_TRUE(frames_until(rt, level0, [&] { return rt.frame(level0, std::uint32_t(level0.size()), 1).fallback_estimate == 0.0f; }, 60s))
        << "resident: " << residency_of(rt).stats().resident_pages;
    for (const auto id : level0) EXPECT_TRUE(residency_of(rt).is_resident(unpack_feedback(id)));
    EXPECT_TRUE(source->available());
    EXPECT_EQ(uploader.malformed(), 0u);
    EXPECT_GT(rt.summary().latency().count(), level0.size());
}


// One store behind two textures of one gRPC source (an engine that adds the same texture twice):
// the server's replies name the store, so each texture bound to it must get them. Before, the
// second binding took the store over and the first texture's pages never arrived.
TEST(RuntimeEndToEnd, OneStoreBehindTwoTexturesLoadsBoth) {
    ScratchDir dir;
    const auto srv = built_and_served(dir, "terrain.tsr", "procedural:terrain:1024");
    ASSERT_TRUE(srv);
    TileStreamOptions net;
    net.target = srv->grpc_address();
    auto source = make_grpc_source(net);
    FakeUploader uploader;
    RuntimeConfig config;
    config.residency.pool_slots = 128;
    config.transcode_threads = 1;
    auto created = Runtime::create(config, uploader);
    ASSERT_TRUE(created.ok()) << created.error().message;
    auto& rt = **created;
    auto a = rt.add_texture(*source, "terrain");
    auto b = rt.add_texture(*source, "terrain");
    ASSERT_TRUE(a.ok() && b.ok());
    ASSERT_NE(*a, *b);
    const auto& info = *rt.texture_info(*a);
    std::vector<FeedbackId> both = whole_texture(info, 1);  // texture 0's level 1
    for (const auto id : whole_texture(info, 1)) {
        PageKey k = unpack_feedback(id);
        k.texture = *b;
        both.push_back(pack_feedback(k));
    }
    ASSERT_TRUE(frames_until(rt, both, [&] { return rt.frame(both, std::uint32_t(both.size()), 1).fallback_estimate == 0.0f; }, 60s))
        << "resident: " << residency_of(rt).stats().resident_pages;
    for (const auto id : both) EXPECT_TRUE(residency_of(rt).is_resident(unpack_feedback(id)));
    EXPECT_EQ(uploader.malformed(), 0u);
}

// The sum of a Prometheus counter's samples (every label set) in a /metrics body.
double metric_sum(const std::string& body, const std::string& name) {
    std::istringstream in(body);
    std::string line;
    double sum = 0;
    while (std::getline(in, line))
        if (line.rfind(name, 0) == 0 && (line.size() > name.size() && (line[name.size()] == ' ' || line[name.size()] == '{')))
            sum += std::stod(line.substr(line.rfind(' ') + 1));
    return sum;
}

// A multi-layer store over gRPC: each page's three layers (colour, BC5 normals, 16-bit heights)
// come in one request and one reply, and reach the pool together in one upload holding every
// layer in its format. The server's counter of tiles sent equals the pages the client uploaded
// (per-layer requests would triple it).
TEST(RuntimeEndToEnd, ALayeredStoreComesInOneRequestPerPage) {
    ScratchDir dir;
    const auto srv = built_and_served(dir, "layers.tsr",
                                      "--layer colour=procedural:terrain:1024 --layer normal:bc5=procedural:terrain-normal:1024 "
                                      "--layer height=procedural:terrain-height:1024 --tile-size 128");
    ASSERT_TRUE(srv);
    TileStreamOptions net;
    net.target = srv->grpc_address();
    auto source = make_grpc_source(net);
    PagePoolFormat pool;
    pool.format = PageFormat::rgba8;
    pool.more_layers = {PageFormat::bc5, PageFormat::r16};
    FakeUploader uploader(pool);
    RuntimeConfig config;
    config.residency.pool_slots = 256;
    config.transcode_threads = 1;
    auto created = Runtime::create(config, uploader);
    ASSERT_TRUE(created.ok()) << created.error().message;
    auto& rt = **created;
    auto tex = rt.add_texture(*source, "layers");
    ASSERT_TRUE(tex.ok()) << tex.error().message;
    const auto& info = *rt.texture_info(*tex);
    ASSERT_EQ(info.layers.size(), 3u);
    EXPECT_EQ(info.layers[1].codec, tessera::Codec::bc5);
    EXPECT_EQ(info.layers[2].sample_type, tessera::storage::SampleType::u16);

    const auto level0 = whole_texture(info, 0);
    ASSERT_TRUE(frames_until(rt, level0, [&] { return rt.frame(level0, std::uint32_t(level0.size()), 1).fallback_estimate == 0.0f; }, 60s))
        << "resident: " << residency_of(rt).stats().resident_pages;
    EXPECT_EQ(uploader.malformed(), 0u);
    const std::size_t bytes = pool.upload_bytes(info.tile_size());
    EXPECT_EQ(bytes, std::size_t(128) * 128 * (4 + 1 + 2));
    for (const auto& p : uploader.pages()) ASSERT_EQ(p.data.size(), bytes);
    const std::size_t uploaded = uploader.pages().size();
    ASSERT_GE(uploaded, level0.size());

    tessera::test::HttpConnection http(srv->http_port());
    const auto metrics = http.get("/metrics");
    ASSERT_EQ(metrics.status, 200);
    const double sent = metric_sum(metrics.body, "tessera_tiles_sent_total");
    EXPECT_GE(sent, double(uploaded)) << metrics.body.substr(0, 2000);
    EXPECT_LT(sent, 1.5 * double(uploaded)) << "more tiles sent than pages: one request per layer?";
    std::printf("  %zu pages uploaded (3 layers each, %zu bytes), %.0f tiles sent by the server\n", uploaded, bytes, sent);
}

}  // namespace
