// `tessera view --page-format`: the GPU pool's format, bytes per page and texels in the summary
// and the JSON stats; a format the store cannot take, an unknown one, or one the GL lacks is a clear error and a
// non-zero exit (headless, llvmpipe, tiny images).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <cstdlib>
#include <string>

#include "server_process.hpp"  // slurp
#include "test_util.hpp"

using tessera::test::run_tessera;
using tessera::test::RunResult;
using tessera::test::ScratchDir;
using tessera::test::slurp;

namespace {

class PageFormatView : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        dir_ = new ScratchDir();
        store_ = dir_->file("terrain.tsr");
        auto r = run_tessera("build procedural:terrain:2048 --quiet -o " + store_);
        ASSERT_EQ(r.exit_code, 0) << r.out;
    }
    static void TearDownTestSuite() { delete dir_; }
    static std::string view(const std::string& extra) {
        return "view --store " + store_ + " --headless --size 160x90 --frames 30 --pool 256 " + extra;
    }
    static ScratchDir* dir_;
    static std::string store_;
};
ScratchDir* PageFormatView::dir_ = nullptr;
std::string PageFormatView::store_;

TEST_F(PageFormatView, Bc1PoolIsReportedInTheSummaryAndTheStats) {
    const std::string stats = dir_->file("bc1.json");
    auto r = run_tessera(view("--page-format bc1 --stats " + stats));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    // 256 pages of 256^2 texels: BC1 is 32 KiB per page, 8 KiB more for the trilinear second level.
    EXPECT_NE(r.out.find("GPU pool      256 pages of bc1, 40.0 KiB per page, 10.0 MiB in all; 16.8 M texels"), std::string::npos)
        << r.out;
    // The BC1 pool brings the view to full detail (how fast the path then keeps up is speed, which
    // a sanitizer build does not have).
    EXPECT_NE(r.out.find("first view    full detail in"), std::string::npos) << r.out;
    const auto j = nlohmann::json::parse(slurp(stats));
    EXPECT_EQ(j["gpu_pool"]["page_format"], "bc1");
    EXPECT_EQ(j["gpu_pool"]["page_bytes"], 40960);
    EXPECT_EQ(j["gpu_pool"]["pages"], 256);
    EXPECT_EQ(j["gpu_pool"]["texels"], 256ull * 256 * 256);

    auto rgba = run_tessera(view("--page-format rgba8 --filter bilinear"));
    ASSERT_EQ(rgba.exit_code, 0) << rgba.out;
    EXPECT_NE(rgba.out.find("256 pages of rgba8, 256.0 KiB per page, 64.0 MiB in all"), std::string::npos) << rgba.out;
}

TEST_F(PageFormatView, AFormatTheStoreCannotTakeIsAClearError) {
    auto grey = run_tessera(view("--page-format bc4"));
    EXPECT_NE(grey.exit_code, 0);
    EXPECT_NE(grey.out.find("page format bc4 does not fit this store"), std::string::npos) << grey.out;
    auto unknown = run_tessera(view("--page-format bc9"));
    EXPECT_NE(unknown.exit_code, 0);
    EXPECT_NE(unknown.out.find("--page-format 'bc9': expected auto, rgba8, bc1, bc4, bc5, bc7, r16, r16f or r32f"), std::string::npos) << unknown.out;
}

// A store built as BC7 blocks: `auto` gives a BC7 pool (the builder's blocks, uploaded as stored),
// which the summary reports; asking for rgba8 decodes the blocks instead.
// The lowest PSNR the view's summary reports against the reference ("PSNR  mean M dB, min N
// dB"); -1 when there is no such line.
double min_psnr(const std::string& out) {
    const auto line = out.find("\nPSNR ");
    if (line == std::string::npos) return -1;
    const auto min = out.find("min ", line);
    if (min == std::string::npos) return -1;
    return std::strtod(out.c_str() + min + 4, nullptr);
}

TEST_F(PageFormatView, ABlockStoreGivesItsOwnFormatByDefault) {
    const std::string bc7 = dir_->file("terrain_bc7.tsr");
    auto built = run_tessera("build procedural:terrain:512 --codec bc7 --quiet -o " + bc7);
    ASSERT_EQ(built.exit_code, 0) << built.out;
    const std::string args = "view --store " + bc7 + " --headless --size 160x90 --frames 30 --pool 64 ";
    auto r = run_tessera(args + "--psnr-every 10");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    // BC7 is 64 KiB per 256^2 page, 16 KiB more for the trilinear second level.
    EXPECT_NE(r.out.find("GPU pool      64 pages of bc7, 80.0 KiB per page, 5.0 MiB in all"), std::string::npos) << r.out;
    // The BC1 pool brings the view to full detail (how fast the path then keeps up is speed, which
    // a sanitizer build does not have).
    EXPECT_NE(r.out.find("first view    full detail in"), std::string::npos) << r.out;
    // Against the reference (the store's texels as decoded on the CPU): the GL's own BC7 decode
    // and the re-encoded trilinear level measured 52.2 dB at the worst frame; RGBA8 pages of the
    // same texels are near exact (measured 91.5 dB).
    EXPECT_GE(min_psnr(r.out), 50.0) << r.out;
    auto rgba = run_tessera(args + "--page-format rgba8 --psnr-every 10");
    ASSERT_EQ(rgba.exit_code, 0) << rgba.out;
    EXPECT_NE(rgba.out.find("64 pages of rgba8"), std::string::npos) << rgba.out;
    EXPECT_GE(min_psnr(rgba.out), 85.0) << rgba.out;
}

// A grey photo (sRGB colour, from ImageMagick) built as BC4 blocks: `auto` draws it through RGBA8
// (sRGB), since BC4 pages are sampled as stored and its colour would be encoded twice (a ramp's
// 134 shown as 192: 16.6 dB against the reference); asking for bc4, or r16 for 16-bit grey, is
// an error that says why.
TEST_F(PageFormatView, SrgbGreyIsNeverDrawnThroughADataFormat) {
    const std::string png = dir_->file("grey.png"), png16 = dir_->file("grey16.png");
    const RunResult im = tessera::test::run_program(
        "convert-im6.q16", "-size 512x512 gradient:white-black -colorspace Gray -depth 8 " + png +
                               " && convert-im6.q16 -size 512x512 gradient:white-black -colorspace Gray -depth 16 " + png16);
    ASSERT_EQ(im.exit_code, 0) << im.out;
    const std::string bc4 = dir_->file("grey_bc4.tsr"), g16 = dir_->file("grey16.tsr");
    auto built = run_tessera("build " + png + " --codec bc4 --quiet -o " + bc4);
    ASSERT_EQ(built.exit_code, 0) << built.out;
    built = run_tessera("build " + png16 + " --quiet -o " + g16);
    ASSERT_EQ(built.exit_code, 0) << built.out;
    const std::string args = " --headless --size 160x90 --frames 10 --pool 64 ";
    auto r = run_tessera("view --store " + bc4 + args + "--psnr-every 5");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("64 pages of rgba8"), std::string::npos) << r.out;
    EXPECT_TRUE(r.out.find("\nPSNR          lossless") != std::string::npos || min_psnr(r.out) >= 40.0) << r.out;
    for (const auto& [store, format] : {std::pair{bc4, "bc4"}, std::pair{g16, "r16"}}) {
        auto refused = run_tessera("view --store " + store + args + "--page-format " + format);
        EXPECT_NE(refused.exit_code, 0) << refused.out;
        EXPECT_NE(refused.out.find(std::string("page format ") + format + " does not fit this store"), std::string::npos) << refused.out;
        EXPECT_NE(refused.out.find("sRGB colour"), std::string::npos) << refused.out;
    }
}

// A GL without the format (Mesa told to hide S3TC) is an error naming the format and the
// extension, never a black image.
TEST_F(PageFormatView, AFormatTheGlLacksIsAClearError) {
    ::setenv("MESA_EXTENSION_OVERRIDE", "-GL_EXT_texture_compression_s3tc", 1);
    auto r = run_tessera(view("--page-format bc1"));
    ::unsetenv("MESA_EXTENSION_OVERRIDE");
    EXPECT_NE(r.exit_code, 0);
    EXPECT_NE(r.out.find("page format bc1: this GL lacks GL_EXT_texture_compression_s3tc"), std::string::npos) << r.out;
    // The other formats do not need it.
    ::setenv("MESA_EXTENSION_OVERRIDE", "-GL_EXT_texture_compression_s3tc", 1);
    auto rgba = run_tessera(view("--page-format rgba8"));
    ::unsetenv("MESA_EXTENSION_OVERRIDE");
    EXPECT_EQ(rgba.exit_code, 0) << rgba.out;
}

}  // namespace
