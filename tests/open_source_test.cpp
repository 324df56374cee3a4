// client::parse_source_url and client::open_source: what a user types turned into a source, with
// a clear error for what is not one.
#include <gtest/gtest.h>

#include <fstream>
#include <thread>

#include "tessera/client/open_source.hpp"
#include "test_util.hpp"

namespace {

using namespace tessera::client;

TEST(SourceUrl, FilesServersAndTls) {
    tessera::test::ScratchDir dir;
    const std::string file = dir.file("a.tsr");
    { std::ofstream(file) << "x"; }
    auto local = parse_source_url(file);
    ASSERT_TRUE(local.ok()) << local.error().message;
    EXPECT_FALSE(local->remote);
    EXPECT_EQ(local->store, file);

    auto plain = parse_source_url("grpc://tiles.example:50051/earth");
    ASSERT_TRUE(plain.ok()) << plain.error().message;
    EXPECT_TRUE(plain->remote);
    EXPECT_FALSE(plain->tls);
    EXPECT_EQ(plain->target, "tiles.example:50051");
    EXPECT_EQ(plain->store, "earth");

    auto tls = parse_source_url("grpcs://10.0.0.1:1,10.0.0.2:2/moon");
    ASSERT_TRUE(tls.ok()) << tls.error().message;
    EXPECT_TRUE(tls->tls);
    EXPECT_EQ(tls->target, "10.0.0.1:1,10.0.0.2:2") << "a replica list is a target";
    EXPECT_EQ(tls->store, "moon");

    auto bare = parse_source_url("localhost:7000/mars");
    ASSERT_TRUE(bare.ok()) << bare.error().message;
    EXPECT_TRUE(bare->remote) << "HOST:PORT/NAME without a scheme, no such file";
    EXPECT_EQ(bare->target, "localhost:7000");
}

TEST(SourceUrl, ErrorsNameTheSpecAndWhatIsMissing) {
    const auto message = [](const std::string& spec) {
        auto r = parse_source_url(spec);
        EXPECT_FALSE(r.ok()) << spec;
        return r.ok() ? std::string() : r.error().message;
    };
    EXPECT_NE(message("/no/such/store.tsr").find("no such store file"), std::string::npos);
    EXPECT_NE(message("/no/such/store.tsr").find("'/no/such/store.tsr'"), std::string::npos);
    EXPECT_NE(message("grpc://host:1/").find("HOST:PORT/NAME"), std::string::npos);
    EXPECT_NE(message("grpc://host:1").find("HOST:PORT/NAME"), std::string::npos);
    EXPECT_NE(message("grpc:///name").find("HOST:PORT/NAME"), std::string::npos);
    EXPECT_NE(message("grpc://host/name").find("needs a port"), std::string::npos);
    // Ports gRPC would take modulo 65536, or as 0 (112407 is 46871: another server's port).
    for (const char* spec : {"grpc://127.0.0.1:112407/t", "grpc://h:0/t", "grpc://h:-1/t", "grpc://h:abc/t", "grpc://h:1,/t",
                             "grpc://h:1,h:70000/t", "grpc://h:/t"}) {
        EXPECT_NE(message(spec).find("with a port from 1 to 65535"), std::string::npos) << spec;
    }
}

TEST(GrpcTarget, EveryEntryNeedsAPortFrom1To65535) {
    for (const char* ok : {"h:1", "tiles.example:65535", "10.0.0.1:1,10.0.0.2:2", "[::1]:50051", "dns:///tiles.example:443"})
        EXPECT_TRUE(check_grpc_target(ok).ok()) << ok;
    for (const char* bad : {"", "h", "h:", ":1", "h:65536", "h:99999", "h:123456", "h:0", "h:1x", "h:1,", ",h:1", "h:1,,h:2"}) {
        const auto st = check_grpc_target(bad);
        EXPECT_FALSE(st.ok()) << bad;
    }
    EXPECT_NE(check_grpc_target("a:1,b:99999").error().message.find("'b:99999'"), std::string::npos);
}

TEST(OpenSource, ALocalStoreBindsAndServesAndBadOptionsAreErrors) {
    const std::string store = tessera::test::cached_store("procedural:terrain:600 --codec zstd", "t.tsr");
    auto url = parse_source_url(store);
    ASSERT_TRUE(url.ok()) << url.error().message;
    auto opened = open_source(*url, {});
    ASSERT_TRUE(opened.ok()) << opened.error().message;
    ASSERT_NE(opened->source, nullptr);
    auto info = opened->source->bind(0, opened->store);
    ASSERT_TRUE(info.ok()) << info.error().message;
    const PageKey root{0, std::uint8_t(info->level_count() - 1), 0, 0};
    const SourceRequest want{root, 1.0f};
    opened->source->set_requests(1, std::span(&want, 1));
    std::vector<SourceTile> got;
    for (int i = 0; i < 500 && got.empty(); ++i) {
        opened->source->poll(got);
        if (got.empty()) std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    ASSERT_EQ(got.size(), 1u);
    EXPECT_EQ(got[0].page, root);
    EXPECT_FALSE(got[0].data.payload.empty());

    // A link adds its delay to the same source.
    SourceOptions slow;
    slow.link.latency = std::chrono::milliseconds(50);
    auto delayed = open_source(*url, slow);
    ASSERT_TRUE(delayed.ok()) << delayed.error().message;
    ASSERT_TRUE(delayed->source->bind(0, delayed->store).ok());
    const auto t0 = std::chrono::steady_clock::now();
    delayed->source->set_requests(1, std::span(&want, 1));
    got.clear();
    for (int i = 0; i < 1000 && got.empty(); ++i) {
        delayed->source->poll(got);
        if (got.empty()) std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    ASSERT_EQ(got.size(), 1u);
    EXPECT_GE(std::chrono::steady_clock::now() - t0, std::chrono::milliseconds(50));

    SourceOptions bad;
    bad.link.jitter = std::chrono::milliseconds(-1);
    EXPECT_FALSE(open_source(*url, bad).ok());
    auto tls = parse_source_url("grpcs://host:1/name");
    ASSERT_TRUE(tls.ok());
    auto no_roots = open_source(*tls, {});
    ASSERT_FALSE(no_roots.ok());
    EXPECT_NE(no_roots.error().message.find("roots"), std::string::npos);
}

}  // namespace
