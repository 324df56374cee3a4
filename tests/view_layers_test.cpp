// `tessera view` on a multi-layer store: the terrain displaced by the store's height layer, read
// through the viewer's own tile source (a file, or a server over gRPC), and the geometry it makes
// (headless, llvmpipe, tiny images).
#include <gtest/gtest.h>

#include <regex>
#include <string>

#include "server_process.hpp"
#include "test_util.hpp"

using tessera::test::cached_store;
using tessera::test::run_tessera;
using tessera::test::ServerProcess;
using tessera::test::ScratchDir;

namespace {

const char* kLayers =
    "--layer colour=procedural:terrain:512 --layer normal:bc5=procedural:terrain-normal:512 "
    "--layer height=procedural:terrain-height:512 --tile-size 128";

std::string view(const std::string& store, const std::string& extra) {
    return "view --store " + store + " --headless --size 96x64 --frames 12 --pool 128 --no-warmup " + extra;
}

// The summary's "terrain displaced by ..." line, or "" when there is none.
std::string displaced_line(const std::string& out) {
    std::smatch m;
    return std::regex_search(out, m, std::regex("terrain +displaced by ([^\n]*)")) ? m[1].str() : std::string();
}

TEST(ViewLayers, AHeightLayerDisplacesTheTerrainFromAFile) {
    const std::string store = cached_store(kLayers, "layers.tsr");
    // 512^2, 128-texel tiles of 120: level 2 (128^2, 2x2 tiles) is the coarsest at least 128 wide.
    auto r = run_tessera(view(store, "--displacement 64"));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(displaced_line(r.out), "layer height (level 2, 128x128 samples, 4 tiles)") << r.out;
    EXPECT_NE(r.out.find("layers        3 per page: colour rgba8, normal bc5, height r16"), std::string::npos) << r.out;

    // Flat without a displacement: the layer is not read.
    auto flat = run_tessera(view(store, ""));
    ASSERT_EQ(flat.exit_code, 0) << flat.out;
    EXPECT_EQ(displaced_line(flat.out), "") << flat.out;
}

TEST(ViewLayers, AHeightLayerDisplacesTheTerrainOverGrpc) {
    ScratchDir dir;
    const std::string store = cached_store(kLayers, "layers.tsr");
    ServerProcess server({"--store", store}, dir.file("server.log"));
    ASSERT_TRUE(server.running()) << server.log();
    auto r = run_tessera(view("grpc://" + server.grpc_address() + "/layers", "--displacement 64"));
    ASSERT_EQ(r.exit_code, 0) << r.out << server.log();
    EXPECT_EQ(displaced_line(r.out), "layer height (level 2, 128x128 samples, 4 tiles)") << r.out;
}

TEST(ViewLayers, AStoreWithoutAHeightLayerKeepsTheHeightFunction) {
    const std::string store = cached_store("procedural:terrain:512 --tile-size 128", "terrain.tsr");
    auto r = run_tessera(view(store, "--displacement 64"));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(displaced_line(r.out), "") << r.out;
}

}  // namespace
