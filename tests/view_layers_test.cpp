// `tessera view` on a multi-layer store: the terrain displaced by the store's height layer, read
// through the viewer's own tile source (a file, or a server over gRPC), and each layer's page
// format (headless, llvmpipe, tiny images).
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

// Each layer's page format can be chosen: BC5 normals decoded to RGBA8, the colour encoded to BC1
// on the transcode threads; a format a layer cannot take, or a layer the store lacks, is an error
// naming it.
TEST(ViewLayers, EachLayersPageFormatCanBeChosen) {
    const std::string store = cached_store(kLayers, "layers.tsr");
    auto r = run_tessera(view(store, "--layer-format normal=rgba8 --layer-format colour=bc1"));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("layers        3 per page: colour bc1, normal rgba8, height r16"), std::string::npos) << r.out;

    auto misfit = run_tessera(view(store, "--layer-format normal=bc4"));
    EXPECT_NE(misfit.exit_code, 0);
    EXPECT_NE(misfit.out.find("layer normal: page format bc4 does not fit this store"), std::string::npos) << misfit.out;
    auto unknown = run_tessera(view(store, "--layer-format relief=bc4"));
    EXPECT_NE(unknown.exit_code, 0);
    EXPECT_NE(unknown.out.find("NAME one of colour, normal, height"), std::string::npos) << unknown.out;
    auto single = run_tessera(view(cached_store("procedural:terrain:512 --tile-size 128", "terrain.tsr"), "--layer-format colour=bc1"));
    EXPECT_NE(single.exit_code, 0);
    EXPECT_NE(single.out.find("the store has one layer"), std::string::npos) << single.out;
}

TEST(ViewLayers, AStoreWithoutAHeightLayerKeepsTheHeightFunction) {
    const std::string store = cached_store("procedural:terrain:512 --tile-size 128", "terrain.tsr");
    auto r = run_tessera(view(store, "--displacement 64"));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_EQ(displaced_line(r.out), "") << r.out;
}

}  // namespace
