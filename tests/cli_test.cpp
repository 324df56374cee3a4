// The `tessera` binary on bad input (one clear error line, non-zero exit, nothing left behind) and
// its inspect and verify commands (the level table, JSON totals, every corrupted byte detected).
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <csignal>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "tessera/storage/store_reader.hpp"
#include "tessera/storage/verify.hpp"
#include "test_util.hpp"

namespace {

namespace fs = std::filesystem;
using tessera::test::read_file;
using tessera::test::run_tessera;
using tessera::test::RunResult;
using tessera::test::ScratchDir;
using tessera::test::write_file;
namespace storage = tessera::storage;

// Single-quoted for the shell.
std::string q(const std::string& s) {
    std::string out = "'";
    for (char c : s) {
        if (c == '\'') out += "'\\''";
        else out += c;
    }
    return out + "'";
}

std::set<std::string> entries(const ScratchDir& dir) {
    const auto v = dir.entries();
    return {v.begin(), v.end()};
}

bool has(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

std::size_t line_count(const std::string& s) { return static_cast<std::size_t>(std::count(s.begin(), s.end(), '\n')); }

// A failed command: non-zero exit (not a crash), exactly one line "tessera: error: ...".
void expect_one_line_error(const RunResult& r) {
    EXPECT_NE(r.exit_code, 0) << r.out;
    EXPECT_LT(r.exit_code, 128) << "killed by a signal:\n" << r.out;
    EXPECT_EQ(r.out.rfind("tessera: error: ", 0), 0u) << r.out;
    EXPECT_EQ(line_count(r.out), 1u) << r.out;
    EXPECT_FALSE(r.out.empty() || r.out.back() != '\n') << r.out;
    EXPECT_GT(r.out.size(), std::string("tessera: error: \n").size() + 5) << "an error that says nothing: " << r.out;
}

// `tessera build ARGS` must fail cleanly and leave exactly `keep` in the scratch directory.
RunResult expect_build_fails(const ScratchDir& dir, const std::string& args, const std::set<std::string>& keep) {
    RunResult r = run_tessera("build " + args);
    expect_one_line_error(r);
    EXPECT_EQ(entries(dir), keep) << "left behind after: tessera build " << args << "\n" << r.out;
    return r;
}

// An image written through OpenImageIO: a deterministic pattern, optionally noisy (so it does not
// compress and its pixel data dominates the file).
void write_image(const std::string& path, int w, int h, int channels, OIIO::TypeDesc type, bool noisy = false,
                 bool uncompressed = false) {
    auto out = OIIO::ImageOutput::create(path);
    ASSERT_TRUE(out) << OIIO::geterror();
    OIIO::ImageSpec spec(w, h, channels, type);
    if (uncompressed) spec.attribute("compression", "none");
    std::vector<float> px(std::size_t(w) * h * channels);
    std::mt19937 rng(42);
    std::uniform_real_distribution<float> noise(0.0f, 1.0f);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < channels; ++c)
                px[(std::size_t(y) * w + x) * channels + c] =
                    noisy ? noise(rng) : float(((x / 8) ^ (y / 8) ^ c) & 1) * 0.8f + 0.1f;
    ASSERT_TRUE(out->open(path, spec)) << out->geterror();
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data())) << out->geterror();
    ASSERT_TRUE(out->close()) << out->geterror();
}

void truncate_file(const std::string& path, std::size_t keep) {
    auto bytes = read_file(path);
    ASSERT_GT(bytes.size(), keep);
    bytes.resize(keep);
    write_file(path, bytes);
}

std::uint32_t crc32(const std::uint8_t* p, std::size_t n) {
    std::uint32_t c = 0xffffffffu;
    for (std::size_t i = 0; i < n; ++i) {
        c ^= p[i];
        for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
    }
    return ~c;
}

void put_be32(std::vector<std::uint8_t>& b, std::size_t off, std::uint32_t v) {
    for (int i = 0; i < 4; ++i) b[off + i] = static_cast<std::uint8_t>(v >> (24 - 8 * i));
}

// A valid PNG whose IHDR (checksum fixed up) claims width x height.
void write_png_claiming(const std::string& path, std::uint32_t width, std::uint32_t height) {
    write_image(path, 16, 16, 3, OIIO::TypeDesc::UINT8);
    auto b = read_file(path);
    ASSERT_GT(b.size(), 33u);
    ASSERT_EQ(std::string(b.begin() + 12, b.begin() + 16), "IHDR");
    put_be32(b, 16, width);
    put_be32(b, 20, height);
    put_be32(b, 29, crc32(b.data() + 12, 17));
    write_file(path, b);
}

// ---- build: bad inputs ----------------------------------------------------------------------------

TEST(CliBuildInput, MissingFile) {
    ScratchDir d;
    const auto r = expect_build_fails(d, q(d.file("nosuch.png")) + " -o " + q(d.file("out.tsr")), {});
    EXPECT_NE(r.out.find("nosuch.png"), std::string::npos) << "the error should name the input: " << r.out;
}

// The store would replace its own input: refused before anything is read, the input untouched.
TEST(CliBuildInput, OutputIsTheInput) {
    ScratchDir d;
    write_image(d.file("in.png"), 64, 48, 3, OIIO::TypeDesc::UINT8);
    const auto before = read_file(d.file("in.png"));
    const auto r = expect_build_fails(d, q(d.file("in.png")) + " -o " + q(d.file("in.png")), {"in.png"});
    EXPECT_EQ(r.exit_code, 2);
    EXPECT_NE(r.out.find("is the input"), std::string::npos) << r.out;
    EXPECT_EQ(read_file(d.file("in.png")), before);
    const auto layered = expect_build_fails(d, "--layer a=" + q(d.file("in.png")) + " --layer b=" + q(d.file("in.png")) + " -o " + q(d.file("in.png")), {"in.png"});
    EXPECT_NE(layered.out.find("is the input"), std::string::npos) << layered.out;
    EXPECT_EQ(read_file(d.file("in.png")), before);
}

// A FIFO blocked build, source, inspect and verify until a writer came: refused at once.
TEST(CliBuildInput, AFifoIsNoInput) {
    ScratchDir d;
    const std::string fifo = d.file("in.png");
    ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
    const std::string bounded = "timeout -s KILL 20 " + std::string(TESSERA_BINARY);
    for (const std::string& args : {"build " + q(fifo) + " -o " + q(d.file("o.tsr")), "source " + q(fifo) + " -o " + q(d.file("o.png")),
                                    "inspect " + q(fifo), "verify " + q(fifo)}) {
        SCOPED_TRACE(args);
        const RunResult r = tessera::test::run_program(bounded, args);
        EXPECT_EQ(r.exit_code, 1) << r.out;
        EXPECT_TRUE(has(r.out, "not a regular file")) << r.out;
    }
    EXPECT_FALSE(std::filesystem::exists(d.file("o.tsr")));
    EXPECT_FALSE(std::filesystem::exists(d.file("o.png")));
}

TEST(CliBuildInput, DirectoryAsInput) {
    ScratchDir d;
    fs::create_directory(d.file("images"));
    expect_build_fails(d, q(d.file("images")) + " -o " + q(d.file("out.tsr")), {"images"});
    EXPECT_TRUE(fs::is_empty(d.file("images")));
}

TEST(CliBuildInput, TruncatedPng) {
    // Cut inside the pixel data (noisy image: IDAT is most of the file) and inside the header chunks.
    for (const bool in_header : {false, true}) {
        SCOPED_TRACE(in_header ? "cut in the header" : "cut in the pixel data");
        ScratchDir d;
        write_image(d.file("in.png"), 128, 128, 3, OIIO::TypeDesc::UINT8, /*noisy=*/true);
        const std::size_t size = fs::file_size(d.file("in.png"));
        truncate_file(d.file("in.png"), in_header ? 60 : size / 2);
        expect_build_fails(d, q(d.file("in.png")) + " -o " + q(d.file("out.tsr")), {"in.png"});
    }
}

TEST(CliBuildInput, TruncatedUncompressedTiff) {
    ScratchDir d;
    write_image(d.file("in.tif"), 128, 128, 3, OIIO::TypeDesc::UINT8, /*noisy=*/true, /*uncompressed=*/true);
    truncate_file(d.file("in.tif"), fs::file_size(d.file("in.tif")) / 2);
    expect_build_fails(d, q(d.file("in.tif")) + " -o " + q(d.file("out.tsr")), {"in.tif"});
}

TEST(CliBuildInput, CorruptJpegBody) {
    ScratchDir d;
    write_image(d.file("in.jpg"), 128, 128, 3, OIIO::TypeDesc::UINT8, /*noisy=*/true);
    auto b = read_file(d.file("in.jpg"));
    // Keep everything up to and including the start-of-scan segment; the entropy-coded body
    // becomes garbage, then the end-of-image marker.
    std::size_t sos = 0;
    for (std::size_t i = 2; i + 3 < b.size(); ++i)
        if (b[i] == 0xff && b[i + 1] == 0xda) {
            sos = i;
            break;
        }
    ASSERT_GT(sos, 0u) << "no SOS marker";
    const std::size_t body = sos + 2 + (std::size_t(b[sos + 2]) << 8 | b[sos + 3]);
    ASSERT_LT(body + 100, b.size());
    std::mt19937 rng(7);
    for (std::size_t i = body; i + 2 < b.size(); ++i) b[i] = static_cast<std::uint8_t>(rng());
    b[b.size() - 2] = 0xff;
    b[b.size() - 1] = 0xd9;
    write_file(d.file("in.jpg"), b);
    expect_build_fails(d, q(d.file("in.jpg")) + " -o " + q(d.file("out.tsr")), {"in.jpg"});
}

TEST(CliBuildInput, TextFileWithPngExtension) {
    ScratchDir d;
    const std::string text = "this is not a PNG file\nreally not\n";
    write_file(d.file("in.png"), std::vector<std::uint8_t>(text.begin(), text.end()));
    expect_build_fails(d, q(d.file("in.png")) + " -o " + q(d.file("out.tsr")), {"in.png"});
}

TEST(CliBuildInput, EmptyFile) {
    ScratchDir d;
    write_file(d.file("in.tif"), {});
    expect_build_fails(d, q(d.file("in.tif")) + " -o " + q(d.file("out.tsr")), {"in.tif"});
}

TEST(CliBuildInput, UnsupportedChannelCount) {
    ScratchDir d;
    write_image(d.file("five.tif"), 32, 32, 5, OIIO::TypeDesc::UINT8);
    write_image(d.file("six.exr"), 32, 32, 6, OIIO::TypeDesc::HALF);
    const auto r = expect_build_fails(d, q(d.file("five.tif")) + " -o " + q(d.file("out.tsr")), {"five.tif", "six.exr"});
    EXPECT_NE(r.out.find("5 channels"), std::string::npos) << r.out;
    expect_build_fails(d, q(d.file("six.exr")) + " -o " + q(d.file("out.tsr")), {"five.tif", "six.exr"});
}

TEST(CliBuildInput, ImageHeaderWithZeroOrAbsurdSize) {
    ScratchDir d;
    write_png_claiming(d.file("zero.png"), 0, 16);
    write_png_claiming(d.file("huge.png"), 0x7fffffffu, 0x7fffffffu);
    const std::set<std::string> inputs = {"zero.png", "huge.png"};
    expect_build_fails(d, q(d.file("zero.png")) + " -o " + q(d.file("out.tsr")), inputs);
    expect_build_fails(d, q(d.file("huge.png")) + " -o " + q(d.file("out.tsr")), inputs);
}

// Block codecs that do not fit the source, or a BC7 effort out of range: one clear line, no file.
TEST(CliBuildInput, BlockCodecsThatDoNotFit) {
    ScratchDir d;
    write_image(d.file("rgba.png"), 32, 32, 4, OIIO::TypeDesc::UINT8);
    write_image(d.file("grey16.png"), 32, 32, 1, OIIO::TypeDesc::UINT16);
    const std::set<std::string> inputs = {"rgba.png", "grey16.png"};
    auto r = expect_build_fails(d, q(d.file("rgba.png")) + " --codec bc1 -o " + q(d.file("out.tsr")), inputs);
    EXPECT_NE(r.out.find("bc1 holds 3 channels (RGB, no alpha), not 4"), std::string::npos) << r.out;
    r = expect_build_fails(d, q(d.file("grey16.png")) + " --codec bc4 -o " + q(d.file("out.tsr")), inputs);
    EXPECT_NE(r.out.find("bc4 needs 8-bit samples"), std::string::npos) << r.out;
    r = expect_build_fails(d, "procedural:terrain:256 --codec bc7 --tile-size 260 --border 2 -o " + q(d.file("out.tsr")), inputs);
    r = expect_build_fails(d, "procedural:terrain:256 --codec bc7 --bc7-effort 4 -o " + q(d.file("out.tsr")), inputs);
    EXPECT_NE(r.out.find("--bc7-effort must be 0 to 3"), std::string::npos) << r.out;
    // And one that fits: an RGBA image as BC7 keeps its alpha channel.
    const auto ok = run_tessera("build " + q(d.file("rgba.png")) + " --codec bc7 --bc7-effort 0 --quiet -o " + q(d.file("ok.tsr")));
    EXPECT_EQ(ok.exit_code, 0) << ok.out;
}

TEST(CliBuildInput, BadProceduralSpecs) {
    ScratchDir d;
    for (const char* spec : {"procedural:terrain:0", "procedural:terrain:99999999999", "procedural:terrain:abc",
                             "procedural:terrain:", "procedural:terrain:-5", "procedural:nosuch:64", "procedural:"}) {
        SCOPED_TRACE(spec);
        expect_build_fails(d, q(spec) + " -o " + q(d.file("out.tsr")), {});
    }
}

// ---- build: outputs that cannot be written -------------------------------------------------------------

TEST(CliBuildOutput, DirectoryDoesNotExist) {
    ScratchDir d;
    expect_build_fails(d, "procedural:terrain:64 -o " + q(d.file("nosuch/out.tsr")), {});
}

TEST(CliBuildOutput, OutputIsAnExistingDirectory) {
    ScratchDir d;
    fs::create_directory(d.file("out.tsr"));
    expect_build_fails(d, "procedural:terrain:64 -o " + q(d.file("out.tsr")), {"out.tsr"});
    EXPECT_TRUE(fs::is_directory(d.file("out.tsr")));
    EXPECT_TRUE(fs::is_empty(d.file("out.tsr")));
}

TEST(CliBuildOutput, ParentIsARegularFile) {
    ScratchDir d;
    write_file(d.file("file"), {1, 2, 3});
    expect_build_fails(d, "procedural:terrain:64 -o " + q(d.file("file/out.tsr")), {"file"});
    EXPECT_EQ(read_file(d.file("file")), (std::vector<std::uint8_t>{1, 2, 3}));
}

TEST(CliBuildOutput, EmptyOutputPath) {
    ScratchDir d;
    expect_build_fails(d, "procedural:terrain:64 -o ''", {});
}

TEST(CliBuildOutput, ExistingFileUntouchedWhenBuildFails) {
    ScratchDir d;
    const std::string text = "an older store, to be kept when a build fails\n";
    const std::vector<std::uint8_t> old(text.begin(), text.end());
    write_image(d.file("in.tif"), 128, 128, 3, OIIO::TypeDesc::UINT8, /*noisy=*/true, /*uncompressed=*/true);
    truncate_file(d.file("in.tif"), fs::file_size(d.file("in.tif")) / 2);
    write_file(d.file("out.tsr"), old);
    const std::set<std::string> keep = {"in.tif", "out.tsr"};
    // Failing before any input is read, on opening the input, and in the middle of reading it.
    for (const std::string& args : {std::string("procedural:terrain:64 --tile-size 100"), q(d.file("nosuch.png")),
                                    std::string("procedural:terrain:0"), q(d.file("in.tif"))}) {
        SCOPED_TRACE(args);
        expect_build_fails(d, args + " -o " + q(d.file("out.tsr")), keep);
        EXPECT_EQ(read_file(d.file("out.tsr")), old);
    }
}

// Outputs are renamed into place, which replaces whatever is at the path: a device, a FIFO or a
// symbolic link there is refused before any work, for every command that writes a file, and is
// left as it was. (.png: a name `source` can write.)
TEST(CliOutput, OnlyARegularFileIsReplaced) {
    ScratchDir d;
    write_file(d.file("target"), {7, 7, 7});
    ASSERT_EQ(::mkfifo(d.file("fifo.png").c_str(), 0644), 0);
    fs::create_symlink(d.file("target"), d.file("link.png"));
    std::vector<std::pair<std::string, std::string>> paths = {{"fifo.png", "a FIFO"}, {"link.png", "symbolic link"}};
    if (::geteuid() == 0) {  // a character device like /dev/null (1, 3), made here so that a failure destroys nothing
        ASSERT_EQ(::mknod(d.file("null.png").c_str(), S_IFCHR | 0666, ::makedev(1, 3)), 0) << std::strerror(errno);
        paths.emplace_back("null.png", "a device");
    }
    const std::set<std::string> keep = [&] {
        std::set<std::string> k = {"target"};
        for (const auto& p : paths) k.insert(p.first);
        return k;
    }();
    for (const auto& [name, what] : paths) {
        const std::string out = q(d.file(name));
        for (const std::string& args :
             {"build procedural:terrain:64 --quiet -o " + out, "source procedural:terrain:64 --quiet -o " + out,
              "build --atlas " + q(d.file("nosuch.obj")) + " -o " + q(d.file("atlas.tsr")) + " --obj-out " + out,
              "loadtest --server 127.0.0.1:1 --connect-timeout 0.2 --store terrain --json " + out,
              "loadtest --server 127.0.0.1:1 --connect-timeout 0.2 --store terrain --plot " + out,
              "view --headless --store " + q(d.file("nosuch.tsr")) + " --stats " + out,
              "view --headless --store " + q(d.file("nosuch.tsr")) + " --trace " + out}) {
            SCOPED_TRACE(args);
            const RunResult r = run_tessera(args);
            expect_one_line_error(r);
            EXPECT_EQ(r.exit_code, 2) << r.out;
            EXPECT_TRUE(has(r.out, name) && has(r.out, what)) << r.out;
            if (name == "link.png") {
                EXPECT_TRUE(has(r.out, "name the file itself")) << r.out;
            }
            EXPECT_EQ(entries(d), keep) << r.out;
        }
    }
    EXPECT_TRUE(fs::is_fifo(fs::symlink_status(d.file("fifo.png"))));
    EXPECT_TRUE(fs::is_symlink(fs::symlink_status(d.file("link.png"))));
    if (fs::exists(fs::symlink_status(d.file("null.png")))) {
        EXPECT_TRUE(fs::is_character_file(fs::symlink_status(d.file("null.png"))));
    }
    EXPECT_EQ(read_file(d.file("target")), (std::vector<std::uint8_t>{7, 7, 7}));
}

// An image write that fails part way (here the file-size limit, as a full disk would: the writes
// fail, EFBIG instead of ENOSPC) is an error naming the output, and leaves neither the output nor
// its temporary file. Every format: some writers ignore failed writes, libjpeg exits.
TEST(CliSourceOutput, FailedWriteLeavesNothing) {
    ScratchDir d;
    // 64 blocks (32 or 64 KiB, as the shell counts) against images of a few hundred KiB or more;
    // SIGXFSZ ignored so that a write past the limit fails rather than killing the process.
    const std::string limited = "ulimit -f 64 && trap '' XFSZ && " + std::string(TESSERA_BINARY);
    for (const char* ext : {"png", "jpg", "tif", "exr", "bmp", "tga", "hdr"}) {
        SCOPED_TRACE(ext);
        const std::string out = std::string("s.") + ext;
        const RunResult r = tessera::test::run_program(limited, "source procedural:terrain:1024 --quiet -o " + q(d.file(out)));
        expect_one_line_error(r);
        EXPECT_TRUE(has(r.out, "cannot write") && has(r.out, out)) << r.out;
        EXPECT_EQ(entries(d), std::set<std::string>{}) << r.out;
    }
    // The same command without the limit writes the file.
    const RunResult ok = run_tessera("source procedural:terrain:256 --quiet -o " + q(d.file("s.png")));
    ASSERT_EQ(ok.exit_code, 0) << ok.out;
    EXPECT_EQ(entries(d), std::set<std::string>{"s.png"});
    // Float samples (heights from -500 to 2000) into a format of integers would be clamped to
    // 0..1: refused, and nothing written; a TIFF keeps them.
    ASSERT_EQ(std::system(("oiiotool --pattern fill:top=-500:bottom=2000 16x8 1 -d float -o " + q(d.file("dem.tif"))).c_str()), 0);
    for (const char* ext : {"png", "jpg"}) {
        const RunResult r = run_tessera("source " + q(d.file("dem.tif")) + " --quiet -o " + q(d.file(std::string("dem.") + ext)));
        expect_one_line_error(r);
        EXPECT_TRUE(has(r.out, "holds no floating-point samples")) << r.out;
    }
    EXPECT_EQ(entries(d), (std::set<std::string>{"s.png", "dem.tif"}));
    EXPECT_EQ(run_tessera("source " + q(d.file("dem.tif")) + " --quiet -o " + q(d.file("copy.tif"))).exit_code, 0);
}

// ---- build --atlas: inputs ---------------------------------------------------------------------------

// A one-triangle OBJ scene in `d`: s.obj using material 'paint' of s.mtl, whose map_Kd is `texture`.
void write_atlas_scene(const ScratchDir& d, const std::string& texture) {
    const std::string obj = "mtllib s.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nusemtl paint\nf 1/1 2/2 3/3\n";
    const std::string mtl = "newmtl paint\nKd 0.5 0.2 0.1\nmap_Kd " + texture + "\n";
    write_file(d.file("s.obj"), std::vector<std::uint8_t>(obj.begin(), obj.end()));
    write_file(d.file("s.mtl"), std::vector<std::uint8_t>(mtl.begin(), mtl.end()));
}

// A texture a material names that cannot be read is an error naming the material, the file and
// why (never a solid colour in its place), and nothing is written.
TEST(CliAtlasInput, ATextureThatCannotBeReadIsAnError) {
    ScratchDir d;
    fs::create_directory(d.file("folder.png"));
    const std::string text = "not an image\n";
    write_file(d.file("text.png"), std::vector<std::uint8_t>(text.begin(), text.end()));
    write_image(d.file("good.png"), 32, 32, 3, OIIO::TypeDesc::UINT8);
    const std::set<std::string> inputs = {"s.obj", "s.mtl", "folder.png", "text.png", "good.png"};
    const std::string args = "--atlas " + q(d.file("s.obj")) + " -o " + q(d.file("o.tsr"));
    for (const auto& [texture, why] : std::vector<std::pair<std::string, std::string>>{
             {"missing.png", "does not exist"}, {"folder.png", "is a directory"}, {"text.png", "as an image"}}) {
        SCOPED_TRACE(texture);
        write_atlas_scene(d, texture);
        const RunResult r = expect_build_fails(d, args, inputs);
        EXPECT_TRUE(has(r.out, "'paint'") && has(r.out, texture) && has(r.out, why)) << r.out;
    }
    // The control: the same scene with a readable texture builds.
    write_atlas_scene(d, "good.png");
    const RunResult ok = run_tessera("build -q " + args);
    ASSERT_EQ(ok.exit_code, 0) << ok.out;
    EXPECT_TRUE(fs::exists(d.file("o.tsr")) && fs::exists(d.file("o.obj"))) << ok.out;
}

// No output of an atlas build may replace a file the scene is read from: the OBJ, its material
// library, a texture (under any spelling of the path, or a hard link to it), nor may the store and
// the OBJ be one file. Refused before anything is written, every input left as it was.
TEST(CliAtlasInput, OutputsNeverReplaceTheInputs) {
    ScratchDir d;
    write_image(d.file("tex.png"), 32, 32, 3, OIIO::TypeDesc::UINT8);
    write_atlas_scene(d, "tex.png");
    fs::create_hard_link(d.file("tex.png"), d.file("link.png"));
    const std::set<std::string> inputs = {"s.obj", "s.mtl", "tex.png", "link.png"};
    const std::map<std::string, std::vector<std::uint8_t>> before = {
        {"s.obj", read_file(d.file("s.obj"))}, {"s.mtl", read_file(d.file("s.mtl"))}, {"tex.png", read_file(d.file("tex.png"))}};
    const std::string scene = "--atlas " + q(d.file("s.obj"));
    const std::string dot = d.path().string() + "/./";
    for (const auto& [args, mention] : std::vector<std::pair<std::string, std::string>>{
             {"-o " + q(d.file("tex.png")), "is the input texture"},
             {"-o " + q(dot + "tex.png") + " --obj-out " + q(d.file("o.obj")), "is the input texture"},
             {"-o " + q(d.file("o.tsr")) + " --obj-out " + q(d.file("tex.png")), "is the input texture"},
             {"-o " + q(d.file("o.tsr")) + " --obj-out " + q(d.file("link.png")), "is the input texture"},
             {"-o " + q(d.file("o.tsr")) + " --obj-out " + q(d.file("s.mtl")), "is the input material library"},
             {"-o " + q(d.file("s.mtl")) + " --obj-out " + q(d.file("o.obj")), "is the input material library"},
             {"-o " + q(d.file("s.obj")) + " --obj-out " + q(d.file("o.obj")), "is the input scene"},
             {"-o " + q(d.file("s.tsr")), "is the input scene"},  // --obj-out defaults to s.obj
             {"-o " + q(d.file("o.tsr")) + " --obj-out " + q(dot + "o.tsr"), "the same file"}}) {
        SCOPED_TRACE(args);
        const RunResult r = expect_build_fails(d, scene + " " + args, inputs);
        EXPECT_TRUE(has(r.out, mention)) << r.out;
        for (const auto& [name, bytes] : before) EXPECT_EQ(read_file(d.file(name)), bytes) << name;
    }
}

// ---- interrupted ---------------------------------------------------------------------------------

// Interrupted while it writes (Ctrl-C's SIGINT, SIGTERM, SIGHUP), a command that writes files
// removes its temporary files and ends by that signal (status 128 + signal): the output folder is
// left empty, with neither the output nor a hidden temporary file in it.
TEST(CliInterrupt, TemporaryFilesAreRemoved) {
    struct Case {
        std::vector<std::string> args;  // after the binary; OUT is replaced by the output path
        int sig;
    };
    const std::vector<Case> cases = {
        {{"build", "procedural:terrain:16384", "--threads", "1", "-q", "-o", "OUT/new.tsr"}, SIGINT},
        {{"build", "procedural:terrain:16384", "--threads", "1", "-q", "-o", "OUT/new.tsr"}, SIGTERM},
        {{"build", "procedural:terrain:16384", "--threads", "1", "-q", "-o", "OUT/new.tsr"}, SIGHUP},
        {{"source", "procedural:terrain:16384", "-q", "-o", "OUT/s.tif"}, SIGINT},
        // The viewer writes its feedback trace for the whole run, paced to 60 Hz over a path of
        // thousands of frames: it is still writing when signalled.
        {{"view", "--store", "STORE", "--headless", "--size", "64x64", "--pace", "--no-warmup", "-q", "--trace",
          "OUT/t.trace", "--stats", "OUT/s.csv"},
         SIGTERM},
    };
    ScratchDir stores;  // the viewer's input, outside the folder that must be left empty
    const std::string store = stores.file("view.tsr");
    ASSERT_EQ(run_tessera("build -q procedural:terrain:1024 -o " + q(store)).exit_code, 0);
    for (const Case& c : cases) {
        ScratchDir d;
        std::vector<std::string> args = {TESSERA_BINARY};
        for (std::string a : c.args) {
            if (a.rfind("OUT/", 0) == 0) a = d.file(a.substr(4));
            if (a == "STORE") a = store;
            args.push_back(a);
        }
        SCOPED_TRACE(args[1] + " " + args.back() + ", signal " + std::to_string(c.sig));
        std::vector<char*> argv;
        for (std::string& a : args) argv.push_back(a.data());
        argv.push_back(nullptr);
        const pid_t pid = ::fork();
        ASSERT_GE(pid, 0);
        if (pid == 0) {
            std::freopen("/dev/null", "w", stdout);
            std::freopen("/dev/null", "w", stderr);
            // As from a terminal, whatever this test inherited (a background job ignores SIGINT).
            sigset_t none;
            sigemptyset(&none);
            ::sigprocmask(SIG_SETMASK, &none, nullptr);
            for (int sig : {SIGINT, SIGTERM, SIGHUP}) std::signal(sig, SIG_DFL);
            ::execv(argv[0], argv.data());
            ::_exit(127);
        }
        // Signalled once it writes: as soon as a temporary (hidden) file appears beside the output.
        bool writing = false;
        for (auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60); !writing && std::chrono::steady_clock::now() < until;) {
            for (const std::string& e : d.entries()) writing = writing || e.rfind('.', 0) == 0;
            if (!writing) std::this_thread::sleep_for(std::chrono::milliseconds(2));
        }
        EXPECT_TRUE(writing) << "no temporary file appeared";
        ::kill(pid, c.sig);
        int status = 0;
        ASSERT_EQ(::waitpid(pid, &status, 0), pid);
        const int code = WIFEXITED(status) ? WEXITSTATUS(status) : WIFSIGNALED(status) ? 128 + WTERMSIG(status) : -1;
        EXPECT_EQ(code, 128 + c.sig);
        EXPECT_EQ(entries(d), std::set<std::string>{}) << "left behind";
    }
}

// ---- build: invalid flags ----------------------------------------------------------------------------

TEST(CliBuildFlags, InvalidValues) {
    ScratchDir d;
    const std::string out = " -o " + q(d.file("out.tsr"));
    for (const char* flags : {"--tile-size 100", "--tile-size 32", "--tile-size 2048", "--tile-size 0", "--tile-size abc",
                              "--tile-size -256", "--tile-size 99999999999", "--border 3", "--border 200",
                              "--tile-size 256 --border 200", "--tile-size 64 --border 18", "--border -2", "--quality 0",
                              "--quality 101", "--quality x", "--codec foo", "--codec", "--chroma 422", "--threads -1",
                              "--threads 100000", "--zstd-level 0", "--zstd-level 20", "--colour-space cmyk",
                              "--nosuch-flag", "-z", "--sparse=maybe"}) {
        SCOPED_TRACE(flags);
        expect_build_fails(d, std::string("procedural:terrain:64 ") + flags + out, {});
    }
}

TEST(CliBuildFlags, MissingArguments) {
    ScratchDir d;
    expect_build_fails(d, "", {});
    expect_build_fails(d, "procedural:terrain:64", {});
    expect_build_fails(d, "-o " + q(d.file("out.tsr")), {});
    expect_build_fails(d, "procedural:terrain:64 extra-positional -o " + q(d.file("out.tsr")), {});
}

TEST(CliBuildFlags, JpegNeedsEightBitGreyOrRgb) {
    ScratchDir d;
    write_image(d.file("rgb16.png"), 64, 64, 3, OIIO::TypeDesc::UINT16);
    write_image(d.file("rgba.png"), 64, 64, 4, OIIO::TypeDesc::UINT8);
    write_image(d.file("grey_alpha.png"), 64, 64, 2, OIIO::TypeDesc::UINT8);
    write_image(d.file("float.exr"), 64, 64, 3, OIIO::TypeDesc::HALF);
    const std::set<std::string> inputs = {"rgb16.png", "rgba.png", "grey_alpha.png", "float.exr"};
    for (const auto& in : inputs) {
        SCOPED_TRACE(in);
        expect_build_fails(d, q(d.file(in)) + " --codec jpeg -o " + q(d.file("out.tsr")), inputs);
    }
}

TEST(CliBuildFlags, SparseNeedsAlpha) {
    ScratchDir d;
    write_image(d.file("rgb.png"), 64, 64, 3, OIIO::TypeDesc::UINT8);
    expect_build_fails(d, "procedural:terrain:64 --sparse -o " + q(d.file("out.tsr")), {"rgb.png"});
    expect_build_fails(d, q(d.file("rgb.png")) + " --sparse -o " + q(d.file("out.tsr")), {"rgb.png"});
}

// The same sources and flags that fail above succeed when they are valid: the failures are about
// the values, not about the test setup.
TEST(CliBuildFlags, ValidControlCases) {
    ScratchDir d;
    write_image(d.file("rgba.png"), 64, 64, 4, OIIO::TypeDesc::UINT8);
    for (const std::string& args :
         {std::string("procedural:terrain:64 --tile-size 64 --border 16 --quality 1 --chroma 420 --threads 1"),
          std::string("procedural:terrain:64 --tile-size 1024 --border 0 --codec raw --zstd-level 19"),
          q(d.file("rgba.png")) + " --sparse --codec zstd"}) {
        SCOPED_TRACE(args);
        const RunResult r = run_tessera("build -q " + args + " -o " + q(d.file("out.tsr")));
        EXPECT_EQ(r.exit_code, 0) << r.out;
        EXPECT_EQ(r.out, "");
        EXPECT_EQ(entries(d), (std::set<std::string>{"rgba.png", "out.tsr"}));
        fs::remove(d.file("out.tsr"));
    }
}

// ---- inspect ---------------------------------------------------------------------------------------

// The small store the inspect and verify tests share: 600 x 600 terrain, 64-texel tiles, zstd.
std::string build_small_store(const ScratchDir& d, const std::string& codec = "zstd") {
    const std::string path = d.file("terrain-" + codec + ".tsr");
    const RunResult r = run_tessera("build -q procedural:terrain:600 --tile-size 64 --codec " + codec + " -o " + q(path));
    EXPECT_EQ(r.exit_code, 0) << r.out;
    return path;
}

TEST(CliInspect, PrintsHeaderAndLevelTable) {
    ScratchDir d;
    const std::string store = build_small_store(d);
    auto reader = storage::StoreReader::open(store);
    ASSERT_TRUE(reader) << reader.error().message;
    const storage::StoreInfo& info = (*reader)->info();
    ASSERT_EQ(info.level_count(), 5u);

    const RunResult r = run_tessera("inspect " + q(store));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("600 x 600"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("codec zstd"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("5 levels"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("bits/texel"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("compression"), std::string::npos) << r.out;
    // One row per level: index, texels, tiles, present, uniform, absent, dedup.
    std::istringstream lines(r.out);
    std::string line;
    std::map<std::uint32_t, std::string> rows;
    std::uint64_t total_tiles = 0;
    while (std::getline(lines, line)) {
        std::istringstream f(line);
        std::string first;
        f >> first;
        if (first.empty() || first.find_first_not_of("0123456789") != std::string::npos) continue;
        rows[static_cast<std::uint32_t>(std::stoul(first))] = line;
    }
    ASSERT_EQ(rows.size(), info.level_count()) << r.out;
    for (std::uint32_t l = 0; l < info.level_count(); ++l) {
        const auto& L = info.levels[l];
        std::istringstream f(rows[l]);
        std::string idx, texels, tiles;
        std::uint64_t present = 0, uniform = 0, absent = 0, dedup = 0;
        f >> idx >> texels >> tiles >> present >> uniform >> absent >> dedup;
        EXPECT_EQ(texels, std::to_string(L.width) + "x" + std::to_string(L.height)) << rows[l];
        EXPECT_EQ(tiles, std::to_string(L.tiles_x) + "x" + std::to_string(L.tiles_y)) << rows[l];
        EXPECT_EQ(present, L.present);
        EXPECT_EQ(uniform, L.uniform);
        EXPECT_EQ(absent, L.absent);
        EXPECT_EQ(dedup, L.deduplicated);
        EXPECT_EQ(present + uniform + absent, std::uint64_t(L.tiles_x) * L.tiles_y);
        total_tiles += std::uint64_t(L.tiles_x) * L.tiles_y;
    }
    EXPECT_EQ(total_tiles, 121u + 36u + 9u + 4u + 1u);
}

TEST(CliInspect, JsonParsesAndAddsUp) {
    ScratchDir d;
    const std::string store = build_small_store(d);
    const RunResult r = run_tessera("inspect --json " + q(store));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    nlohmann::json j;
    ASSERT_NO_THROW(j = nlohmann::json::parse(r.out)) << r.out;
    EXPECT_EQ(j.at("width"), 600);
    EXPECT_EQ(j.at("height"), 600);
    EXPECT_EQ(j.at("codec"), "zstd");
    EXPECT_EQ(j.at("tile_size"), 64);
    EXPECT_EQ(j.at("tile_payload").get<int>() + 2 * j.at("border").get<int>(), 64);
    EXPECT_EQ(j.at("format_version"), "1.0");
    EXPECT_EQ(j.at("file_size").get<std::uint64_t>(), fs::file_size(store));
    const auto& levels = j.at("level_info");
    ASSERT_TRUE(levels.is_array());
    EXPECT_EQ(j.at("levels").get<std::size_t>(), levels.size());
    EXPECT_EQ(levels.size(), 5u);
    std::uint64_t tiles = 0, present = 0, uniform = 0, absent = 0, dedup = 0, payload = 0, raw = 0, texels = 0;
    for (std::size_t i = 0; i < levels.size(); ++i) {
        const auto& l = levels[i];
        EXPECT_EQ(l.at("level").get<std::size_t>(), i);
        const std::uint64_t n = l.at("tiles_x").get<std::uint64_t>() * l.at("tiles_y").get<std::uint64_t>();
        EXPECT_EQ(l.at("present").get<std::uint64_t>() + l.at("uniform").get<std::uint64_t>() + l.at("absent").get<std::uint64_t>(), n)
            << l.dump();
        EXPECT_LE(l.at("deduplicated").get<std::uint64_t>(), l.at("present").get<std::uint64_t>());
        const std::uint64_t t = l.at("width").get<std::uint64_t>() * l.at("height").get<std::uint64_t>();
        EXPECT_NEAR(l.at("bits_per_texel").get<double>(), 8.0 * l.at("payload_bytes").get<double>() / double(t), 1e-6);
        tiles += n;
        present += l.at("present").get<std::uint64_t>();
        uniform += l.at("uniform").get<std::uint64_t>();
        absent += l.at("absent").get<std::uint64_t>();
        dedup += l.at("deduplicated").get<std::uint64_t>();
        payload += l.at("payload_bytes").get<std::uint64_t>();
        texels += t;
        raw += t * 3;
    }
    const auto& t = j.at("totals");
    EXPECT_EQ(t.at("tiles").get<std::uint64_t>(), tiles);
    EXPECT_EQ(t.at("present").get<std::uint64_t>(), present);
    EXPECT_EQ(t.at("uniform").get<std::uint64_t>(), uniform);
    EXPECT_EQ(t.at("absent").get<std::uint64_t>(), absent);
    EXPECT_EQ(t.at("deduplicated").get<std::uint64_t>(), dedup);
    EXPECT_EQ(present + uniform + absent, tiles);
    EXPECT_EQ(tiles, 171u);
    EXPECT_EQ(t.at("payload_bytes").get<std::uint64_t>(), payload);
    EXPECT_LT(payload, j.at("file_size").get<std::uint64_t>());
    EXPECT_EQ(t.at("raw_bytes").get<std::uint64_t>(), raw);
    EXPECT_NEAR(t.at("bits_per_texel").get<double>(), 8.0 * double(payload) / double(texels), 1e-6);
    const double ratio = t.at("compression_ratio").get<double>();
    EXPECT_NEAR(ratio, double(raw) / double(j.at("file_size").get<std::uint64_t>()), 1e-9);
    EXPECT_GT(ratio, 0.0);
}

// zstd barely compresses the noisy terrain at 64-texel tiles (each tile also stores its borders,
// and the index is a fixed 96 KiB per level here), so the > 1 ratio is checked on JPEG.
TEST(CliInspect, JpegCompressionRatioAboveOne) {
    ScratchDir d;
    const std::string store = build_small_store(d, "jpeg");
    const RunResult r = run_tessera("inspect --json " + q(store));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    nlohmann::json j;
    ASSERT_NO_THROW(j = nlohmann::json::parse(r.out)) << r.out;
    EXPECT_EQ(j.at("codec"), "jpeg");
    EXPECT_GT(j.at("totals").at("compression_ratio").get<double>(), 1.0) << j.dump(2);
    EXPECT_LT(j.at("totals").at("bits_per_texel").get<double>(), 24.0) << j.dump(2);
}

// ---- inspect and verify on files that are not sound stores ------------------------------------------

struct BadStore {
    std::string name;
    std::string expect;  // a fragment of the message
};

std::vector<BadStore> make_bad_stores(const ScratchDir& d) {
    const std::string good = build_small_store(d);
    const auto bytes = read_file(good);
    fs::remove(good);
    auto cut = [&](const std::string& name, std::size_t n) {
        write_file(d.file(name), std::vector<std::uint8_t>(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(n)));
    };
    cut("half.tsr", bytes.size() / 2);
    cut("header-only.tsr", 100);
    cut("one-short.tsr", bytes.size() - 1);
    write_file(d.file("zero.tsr"), {});
    const std::string text = "hello, I am a text file pretending to be a store. ";
    std::vector<std::uint8_t> t;
    while (t.size() < 4096) t.insert(t.end(), text.begin(), text.end());
    write_file(d.file("text.tsr"), t);
    write_image(d.file("image.png"), 64, 64, 3, OIIO::TypeDesc::UINT8);
    fs::rename(d.file("image.png"), d.file("image.tsr"));
    fs::create_directory(d.file("dir.tsr"));
    return {{"missing.tsr", "missing.tsr"}, {"half.tsr", "truncated"},   {"header-only.tsr", "too small"},
            {"one-short.tsr", "truncated"}, {"zero.tsr", "too small"},   {"text.tsr", "not a Tessera store"},
            {"image.tsr", "not a Tessera store"}, {"dir.tsr", "not a regular file"}};
}

TEST(CliInspect, BadStoreFiles) {
    ScratchDir d;
    for (const auto& bad : make_bad_stores(d)) {
        for (const char* cmd : {"inspect ", "inspect --json "}) {
            SCOPED_TRACE(cmd + bad.name);
            const RunResult r = run_tessera(cmd + q(d.file(bad.name)));
            expect_one_line_error(r);
            EXPECT_NE(r.out.find(bad.expect), std::string::npos) << r.out;
        }
    }
}

TEST(CliVerify, BadStoreFiles) {
    ScratchDir d;
    for (const auto& bad : make_bad_stores(d)) {
        SCOPED_TRACE(bad.name);
        const RunResult r = run_tessera("verify " + q(d.file(bad.name)));
        EXPECT_NE(r.exit_code, 0) << r.out;
        EXPECT_LT(r.exit_code, 128) << r.out;
        EXPECT_NE(r.out.find("FAILED"), std::string::npos) << r.out;
        EXPECT_NE(r.out.find(bad.expect), std::string::npos) << r.out;
        const RunResult rq = run_tessera("verify -q " + q(d.file(bad.name)));
        EXPECT_EQ(rq.exit_code, r.exit_code);
    }
}

// ---- verify --------------------------------------------------------------------------------------

// Which tiles' payloads cover each byte of the data section, from the reader's own index.
struct PayloadMap {
    struct Span {
        std::uint64_t begin = 0, end = 0;
        std::vector<tessera::TileKey> keys;  // more than one when deduplicated
    };
    std::vector<Span> spans;  // sorted by begin
    std::uint64_t data_begin = UINT64_MAX;

    const Span* find(std::uint64_t off) const {
        auto it = std::upper_bound(spans.begin(), spans.end(), off, [](std::uint64_t o, const Span& s) { return o < s.begin; });
        if (it == spans.begin()) return nullptr;
        --it;
        return off < it->end ? &*it : nullptr;
    }
};

PayloadMap map_payloads(const std::string& store) {
    PayloadMap m;
    auto reader = storage::StoreReader::open(store);
    EXPECT_TRUE(reader) << reader.error().message;
    if (!reader) return m;
    const storage::StoreInfo& info = (*reader)->info();
    std::map<std::uint64_t, PayloadMap::Span> by_offset;
    for (std::uint32_t l = 0; l < info.level_count(); ++l)
        for (std::uint32_t y = 0; y < info.levels[l].tiles_y; ++y)
            for (std::uint32_t x = 0; x < info.levels[l].tiles_x; ++x) {
                auto loc = (*reader)->locate({l, x, y});
                EXPECT_TRUE(loc) << loc.error().message;
                if (!loc || loc->kind != tessera::TileKind::present) continue;
                auto& s = by_offset[loc->offset];
                s.begin = loc->offset;
                s.end = loc->offset + loc->length;
                s.keys.push_back({l, x, y});
            }
    for (auto& [off, s] : by_offset) {
        m.data_begin = std::min(m.data_begin, off);
        m.spans.push_back(std::move(s));
    }
    return m;
}

std::string tile_name(const tessera::TileKey& k) {
    return "level " + std::to_string(k.level) + " tile (" + std::to_string(k.x) + "," + std::to_string(k.y) + ")";
}

TEST(CliVerify, SoundStorePasses) {
    ScratchDir d;
    for (const char* codec : {"zstd", "jpeg"}) {
        SCOPED_TRACE(codec);
        const std::string store = build_small_store(d, codec);
        for (const char* flags : {"", "--decode ", "-q "}) {
            const RunResult r = run_tessera(std::string("verify ") + flags + q(store));
            EXPECT_EQ(r.exit_code, 0) << r.out;
            if (std::string(flags) == "-q ") EXPECT_EQ(r.out, "");
            else EXPECT_NE(r.out.find("OK, 171 tiles"), std::string::npos) << r.out;
        }
    }
}

// Every flipped byte, wherever it is (header, level table, palette, block tables, entry blocks,
// payloads), is caught; a flipped payload byte is reported against its tile. The library is
// checked on a dense set of positions, the command line on a spread of them.
TEST(CliVerify, EveryFlippedByteIsDetected) {
    ScratchDir d;
    const std::string store = build_small_store(d);
    const auto good = read_file(store);
    ASSERT_GT(good.size(), 1000u);
    const PayloadMap map = map_payloads(store);
    ASSERT_FALSE(map.spans.empty());
    ASSERT_GT(map.data_begin, 128u);
    ASSERT_EQ(map.spans.back().end, good.size());

    std::set<std::uint64_t> dense;
    for (std::uint64_t p = 0; p < good.size(); p += 97) dense.insert(p);
    for (std::uint64_t p = 0; p < 200; ++p) {
        dense.insert(p);
        dense.insert(good.size() - 1 - p);
    }
    std::vector<std::uint8_t> bytes;
    std::size_t in_payload = 0;
    for (const std::uint64_t p : dense) {
        bytes = good;
        bytes[p] ^= static_cast<std::uint8_t>(1u << (p % 8));
        auto reader = storage::StoreReader::open_memory(bytes);
        if (!reader) continue;  // the header or index no longer opens: detected
        storage::VerifyOptions opt;
        opt.max_problems = 100000;
        const storage::VerifyReport rep = storage::verify_store(**reader, opt);
        ASSERT_FALSE(rep.ok()) << "flipping byte " << p << " went unnoticed";
        if (const auto* span = map.find(p)) {
            ++in_payload;
            for (const auto& k : span->keys) {
                const bool named = std::any_of(rep.problems.begin(), rep.problems.end(),
                                               [&](const std::string& s) { return s.find(tile_name(k)) != std::string::npos; });
                EXPECT_TRUE(named) << "byte " << p << " of " << tile_name(k) << " flipped, report does not name it";
            }
        }
    }
    EXPECT_GT(in_payload, 1000u);

    // The command line: a spread over the whole file plus the first payload byte of every level.
    std::set<std::uint64_t> spread = {0, 8, 12, 16, 30, 31, 34, 40, 72, 80, 88, 119, 120, 127, 128, 200,
                                      map.data_begin - 1, map.data_begin, good.size() - 1};
    for (int i = 0; i < 48; ++i) spread.insert(good.size() * std::uint64_t(i) / 48 + 13);
    std::set<std::uint32_t> levels_seen;
    for (const auto& s : map.spans)
        if (levels_seen.insert(s.keys.front().level).second) spread.insert(s.begin + (s.end - s.begin) / 2);
    const std::string flipped = d.file("flipped.tsr");
    for (const std::uint64_t p : spread) {
        SCOPED_TRACE("byte " + std::to_string(p));
        bytes = good;
        bytes[p] ^= 0xff;
        write_file(flipped, bytes);
        const RunResult r = run_tessera("verify -q " + q(flipped));
        EXPECT_EQ(r.exit_code, 1) << r.out;
        EXPECT_NE(r.out.find("FAILED"), std::string::npos) << r.out;
        if (const auto* span = map.find(p)) {
            for (const auto& k : span->keys)
                EXPECT_NE(r.out.find(tile_name(k) + ": payload of " + tile_name(k) + " fails its checksum"), std::string::npos)
                    << r.out;
            EXPECT_NE(r.out.find("FAILED, " + std::to_string(span->keys.size()) + " problem"), std::string::npos) << r.out;
        }
    }
    // The original is still sound (the copies never touched it).
    EXPECT_EQ(run_tessera("verify -q " + q(store)).exit_code, 0);
}

// ---- the command line as a new user meets it ----------------------------------------------------

// `tessera-server ARGS`, as run_tessera runs `tessera ARGS`.
RunResult run_server_binary(const std::string& args) { return tessera::test::run_program(TESSERA_SERVER_EXE, args); }


// A help screen's entry for an option or command: from "  NAME" to the next entry (a long one's
// description is on the lines below it).
std::string help_line(const std::string& help, const std::string& name) {
    const std::size_t at = help.find("  " + name + " ");
    if (at == std::string::npos) return {};
    const std::size_t end = std::min(help.find("\n  -", at + 1), help.find("\n\n", at + 1));
    return help.substr(at, end == std::string::npos ? std::string::npos : end - at);
}

// `--size` is the viewer's WIDTHxHEIGHT; the procedural terrain's texels per side are `--texels`.
TEST(CliVocabulary, SizeIsTheImageAndTexelsTheTerrain) {
    const RunResult view = run_tessera("view --help");
    ASSERT_EQ(view.exit_code, 0) << view.out;
    EXPECT_TRUE(has(help_line(view.out, "--size"), "WIDTHxHEIGHT")) << view.out;
    for (const char* command : {"bench", "demo"}) {
        SCOPED_TRACE(command);
        const RunResult r = run_tessera(std::string(command) + " --help");
        ASSERT_EQ(r.exit_code, 0) << r.out;
        EXPECT_TRUE(has(help_line(r.out, "--texels"), "exels per side")) << r.out;
        EXPECT_FALSE(has(r.out, "--size")) << r.out;
        EXPECT_TRUE(has(help_line(r.out, "--resolution"), "WIDTHxHEIGHT")) << r.out;
    }
    // The range is --texels's.
    ScratchDir d;
    RunResult r = run_tessera("bench --quick --texels 17 --out " + q(d.file("b")));
    expect_one_line_error(r);
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_TRUE(has(r.out, "--texels")) << r.out;
    // The former spelling still works, with a notice; an image size given to it says where to go.
    r = run_tessera("bench --quick --size 512 --out /proc/nope");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_TRUE(has(r.out, "note: --size is now --texels")) << r.out;
    EXPECT_TRUE(has(r.out, "--out")) << r.out;
    for (const std::string& command : {"bench --quick --out " + q(d.file("b")), "demo --dir " + q(d.file("demo"))}) {
        SCOPED_TRACE(command);
        r = run_tessera(command + " --size 1280x720");
        expect_one_line_error(r);
        EXPECT_EQ(r.out.rfind("tessera: error: --size '1280x720': ", 0), 0u) << r.out;
        EXPECT_TRUE(has(r.out, "--texels") && has(r.out, "--resolution")) << r.out;
    }
    r = run_tessera("bench --quick --size 17 --out " + q(d.file("b")));
    expect_one_line_error(r);
    EXPECT_EQ(r.out.rfind("tessera: error: --size (now --texels): ", 0), 0u) << r.out;
    r = run_tessera("demo --texels 512 --size 512 --dir " + q(d.file("demo")));
    expect_one_line_error(r);
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_EQ(r.out.rfind("tessera: error: --size: the former name of --texels", 0), 0u) << r.out;
    EXPECT_EQ(entries(d), std::set<std::string>{}) << r.out;
}

// Byte counts take units on every command, through serve's parser, and help shows the defaults
// in units.
TEST(CliVocabulary, ByteCountsTakeUnitsEverywhere) {
    const std::map<std::string, std::vector<std::pair<std::string, std::string>>> defaults = {
        {"view", {{"--ram-cache", "SIZE=256MiB"}, {"--disk-cache-size", "SIZE=1GiB"}}},
        {"loadtest", {{"--ram-cache", "SIZE=0"}}},
        {"serve",
         {{"--cache-size", "SIZE=256MiB"}, {"--max-message", "SIZE=4MiB"}, {"--reply-message", "SIZE=64KiB"},
          {"--viewer-buffer", "SIZE=4MiB"}, {"--total-buffer", "SIZE=512MiB"}, {"--web-cache", "SIZE=64MiB"},
          {"--max-header", "SIZE=8KiB"}}}};
    for (const auto& [command, options] : defaults) {
        const RunResult r = run_tessera(command + " --help");
        ASSERT_EQ(r.exit_code, 0) << r.out;
        for (const auto& [option, shown] : options)
            EXPECT_TRUE(has(help_line(r.out, option), option + " " + shown)) << command << " " << option << "\n" << r.out;
    }
    // Units are read: the run gets past the options and fails on the missing store instead.
    ScratchDir d;
    const std::string missing = q(d.file("missing.tsr"));
    RunResult r = run_tessera("view --headless --store " + missing + " --ram-cache 64MiB --disk-cache-size 2g");
    expect_one_line_error(r);
    EXPECT_TRUE(has(r.out, "missing.tsr")) << r.out;
    r = run_tessera("loadtest --server 127.0.0.1:1 --connect-timeout 0.2 --store terrain --ram-cache 16MiB");
    expect_one_line_error(r);
    EXPECT_FALSE(has(r.out, "--ram-cache")) << r.out;
    r = run_tessera("serve --grpc 127.0.0.1:0 --http 127.0.0.1:0 --store " + missing + " --web-cache 1GiB --max-header 16KiB");
    EXPECT_NE(r.exit_code, 0) << r.out;
    EXPECT_TRUE(has(r.out, "missing.tsr")) << r.out;
    EXPECT_FALSE(has(r.out, "--web-cache") || has(r.out, "--max-header")) << r.out;
    // A unit that is not one is an argument error naming the option.
    r = run_tessera("view --headless --store " + missing + " --ram-cache 64XB");
    expect_one_line_error(r);
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_TRUE(has(r.out, "--ram-cache")) << r.out;
}

// A negative byte count or one past the option's type is an error naming the option, not a huge
// budget (CLI11 alone reads -1 as 2^64-1 and lets a long number overflow).
TEST(CliVocabulary, ByteCountsAreNeitherNegativeNorOverflowing) {
    ScratchDir d;
    ASSERT_EQ(run_tessera("build procedural:terrain:64 --quiet -o " + q(d.file("s.tsr"))).exit_code, 0);
    const std::string serve = "serve --store " + q(d.file("s.tsr")) + " --grpc 127.0.0.1:0 --http 127.0.0.1:0 ";
    // A server that did start is killed after 30 s: the test then fails, it does not hang.
    const std::string bounded = "timeout -s KILL 30 " + std::string(TESSERA_BINARY);
    const std::vector<std::tuple<std::string, std::string, std::string>> cases = {
        {serve, "--cache-size -1", "negative"},
        {serve, "--cache-size 99999999999999999999", "too large"},
        {serve, "--web-cache -5", "negative"},
        {serve, "--max-header -1KiB", "negative"},
        {"view --headless --store " + q(d.file("s.tsr")) + " ", "--ram-cache -1", "negative"},
        {"loadtest --server 127.0.0.1:1 --store s ", "--ram-cache 99999999999999999999", "too large"}};
    for (const auto& [command, option, why] : cases) {
        SCOPED_TRACE(option);
        const RunResult r = tessera::test::run_program(bounded, command + option);
        expect_one_line_error(r);
        EXPECT_EQ(r.exit_code, 2) << r.out;
        EXPECT_TRUE(has(r.out, option.substr(0, option.find(' ')) + ":") && has(r.out, why)) << r.out;
    }
}

// nan and infinities are refused by every floating-point option, naming it (CLI11 reads them, and
// its range checks let nan through: a load test at --fps nan reported a clean, meaningless run).
TEST(CliVocabulary, FloatingPointOptionsAreFinite) {
    ScratchDir d;
    const std::string loadtest = "loadtest --server 127.0.0.1:1 --store s --connect-timeout 0.2 ";
    const std::string view = "view --headless --store " + q(d.file("missing.tsr")) + " ";
    // A run that did start is killed after 30 s: the test then fails, it does not hang.
    const std::string bounded = "timeout -s KILL 30 " + std::string(TESSERA_BINARY);
    const std::vector<std::pair<std::string, std::string>> cases = {
        {loadtest, "--fps nan"},           {loadtest, "--latency nan"},      {loadtest, "--bandwidth nan"},
        {loadtest, "--ramp-p99-ms nan"},   {loadtest, "--ramp-fallback nan"}, {loadtest, "--jitter nan"},
        {loadtest, "--duration nan"},      {loadtest, "--warmup NaN"},       {loadtest, "--ramp-p99-ms inf"},
        {view, "--fps nan"},               {view, "--fps -inf"},             {view, "--fade-ms nan"},
        {view, "--link-latency-ms inf"},   {view, "--guard-band nan"}};
    for (const auto& [command, option] : cases) {
        SCOPED_TRACE(command + option);
        const RunResult r = tessera::test::run_program(bounded, command + option);
        expect_one_line_error(r);
        EXPECT_EQ(r.exit_code, 2) << r.out;
        EXPECT_TRUE(has(r.out, option.substr(0, option.find(' ')) + ": '") && has(r.out, "is not a finite number")) << r.out;
    }
}

// Values that would make a run do nothing, or do it against the wrong server, are refused before
// any work: a page budget of 0, every 0th frame, a port gRPC would take modulo 65536, an output
// the run could not write at its end, an empty output directory, a PSNR reference of another
// image, a demo resolution, path or page format that does not exist.
TEST(CliVocabulary, RunsThatCannotSucceedAreRefusedFirst) {
    ScratchDir d;
    const std::string bounded = "timeout -s KILL 30 " + std::string(TESSERA_BINARY);
    const std::string view = "view --headless --store " + q(d.file("missing.tsr")) + " ";
    const std::vector<std::tuple<std::string, int, std::string>> cases = {
        {view + "--upload-pages 0", 2, "--upload-pages"},
        {view + "--motion-prefetch-every 0", 2, "--motion-prefetch-every"},
        {view + "--transcode-threads 999", 2, "--transcode-threads"},
        {view + "--pool 99999999", 2, "--pool"},  // named as the flag, not as the renderer's field
        {view + "--prefetch-lod 5", 2, "--prefetch-lod"},
        {view + "--guard-band -1", 2, "--guard-band"},
        // Named as the flags, with the help that lists them (not as the runtime's fields).
        {view + "--fade-ms 20000", 2, "--fade-ms"},
        {view + "--pool 15", 2, "--pool"},
        {view + "--anisotropy 9", 2, "--anisotropy"},
        {view + "--feedback-scale 0", 2, "--feedback-scale"},
        {view + "--fps 0", 2, "--fps"},
        {view + "--link-latency-ms -5", 2, "--link-latency-ms"},
        {"demo --dir " + q(d.file("demo")) + " --fade-ms 20000", 2, "--fade-ms"},
        {"view --headless --store grpc://127.0.0.1:112407/t", 1, "with a port from 1 to 65535"},
        {"loadtest --store t --server 127.0.0.1:112407", 2, "with a port from 1 to 65535"},
        {"loadtest --store t --server 127.0.0.1:1, --connect-timeout 0.2", 2, "with a port from 1 to 65535"},
        {"loadtest --store t --server 127.0.0.1:1 --connect-timeout 0.2 --json " + q(d.file("no/such/dir/r.json")), 1,
         "cannot write"},
        {"bench --out ''", 2, "--out"},
        // demo: before it builds its 16384^2 store (seconds), not after.
        {"demo --dir " + q(d.file("demo")) + " --resolution 0x0", 2, "--resolution"},
        {"demo --dir " + q(d.file("demo")) + " --resolution 8x8", 2, "--resolution"},  // the viewer's bounds: 16 to 8192
        {"demo --dir " + q(d.file("demo")) + " --guard-band 5", 2, "--guard-band"},
        {"demo --dir " + q(d.file("demo")) + " --texels 1000 --psnr-every 5", 2, "--texels a power of two"},
        {"serve --store " + q(d.file("missing.tsr")) + " --public-url example.org", 2, "--public-url"},
        {"serve --store " + q(d.file("missing.tsr")) + " --max-connections -1", 2, "--max-connections"},  // was: no limit
        {"serve --store " + q(d.file("missing.tsr")) + " --config " + q(d.path().string()), 2, "is a directory"},  // was: read as empty
        {"serve --store " + q(d.file("missing.tsr")) + " --max-viewers 99999999999999999999999", 2, "--max-viewers"},
        {"demo --dir " + q(d.file("demo")) + " --path nosuch", 2, "--path"},
        {"demo --dir " + q(d.file("demo")) + " --page-format foo", 2, "--page-format"},
        {"demo --dir " + q(d.file("demo")) + " --prefetch-lod 9", 2, "--prefetch-lod"},
        {"view --headless --frames 2 --size 64x36 --psnr-every 1 --store " +
             q(tessera::test::cached_store("procedural:terrain:1024 --codec zstd", "t1024.tsr")) + " --reference-store " +
             q(tessera::test::cached_store("procedural:terrain:512 --codec zstd", "t512.tsr")),
         1, "not a copy of it"},
        // The reference samples GL mips, which halve rounding down: a 257-texel store's levels do not.
        {"view --headless --frames 2 --size 64x36 --psnr-every 1 --store " +
             q(tessera::test::cached_store("procedural:terrain:257 --codec zstd", "t257.tsr")),
         1, "levels that halve exactly"},
    };
    for (const auto& [args, code, says] : cases) {
        SCOPED_TRACE(args);
        const RunResult r = tessera::test::run_program(bounded, args);
        expect_one_line_error(r);
        EXPECT_EQ(r.exit_code, code) << r.out;
        EXPECT_TRUE(has(r.out, says)) << r.out;
    }
    EXPECT_FALSE(std::filesystem::exists(d.file("demo"))) << "demo started its work";
}

// An error in a --config file names the file and the line, and says what is wrong there; CLI11's
// reader said "INI was not able to parse bogus-key" and took an unclosed quote literally.
TEST(CliConfigFile, ErrorsNameTheFileAndLine) {
    ScratchDir d;
    const std::string conf = d.file("tessera.conf");
    const std::vector<std::tuple<std::string, std::string>> cases = {
        {"# a comment\n\nbogus-key\n", ":3: expected `key = value`, got 'bogus-key'"},
        {"[serve]\nbogus = 1\n", ":2: unknown option 'bogus'"},
        {"public-url = \"https://example.org\n", ":1: unclosed quote"},
        {"[client]\nhttp = \"127.0.0.1:0\"\n", ":1: unknown section [client]"},
        {"\n\n\nmax-connections = -1\n", ":4: max-connections:"},
        {"http = [\"127.0.0.1:1\", \"127.0.0.1:2\"]\n", ":1: 'http' takes one value"},
        {"store-dir = [\"a\",\n  \"b\"\n", ":1: the list of 'store-dir' has no closing ']'"},
        {"cache-size = \"1GiB\" extra\n", ":1: text after the closing quote"},
        {"grpc =\n", ":1: no value"},
        {"Http = \"127.0.0.1:0\"\n", ":1: 'Http' is not an option name"},
        {"config = \"other.conf\"\n", ":1: unknown option 'config'"},
        {"grpc = # off\n", ":1: no value"},  // a comment, not the value "# off"
        // A byte order mark is not part of the first key; a repeated key names both lines.
        {"\xEF\xBB\xBFhttp = \"127.0.0.1:1\"\n\nhttp = \"127.0.0.1:2\"\n", ":1: 'http' takes one value, the file gives 2 (again on line 3)"},
    };
    for (const auto& [text, says] : cases) {
        SCOPED_TRACE(text);
        {
            std::ofstream f(conf, std::ios::trunc);
            f << text;
        }
        const RunResult r = run_tessera("serve --store " + q(d.file("missing.tsr")) + " --config " + q(conf));
        expect_one_line_error(r);
        EXPECT_EQ(r.exit_code, 2) << r.out;
        EXPECT_TRUE(has(r.out, conf + says)) << r.out;
    }
}

// Values are read as written: a quoted one keeps its '#' and spaces, a list may go on over lines
// with comments between, and the command line wins over the file.
TEST(CliConfigFile, ValuesAreReadAsWritten) {
    ScratchDir d;
    const std::string store = tessera::test::cached_store("procedural:terrain:512 --codec zstd", "t512.tsr");
    const std::string conf = d.file("tessera.conf");
    auto serve_with = [&](const std::string& text, const std::string& args = "") {
        {
            std::ofstream f(conf, std::ios::trunc);
            f << text;
        }
        return run_tessera("serve --grpc 127.0.0.1:0 --http 127.0.0.1:0 --config " + q(conf) + " " + args);
    };
    // The second store is missing: its whole name, '#' and space included, is in the error.
    RunResult r = serve_with("[serve]\nstore = [\n  \"" + store + "\",  # exists\n  \"" + d.file("b #2.tsr") +
                             "\"   # does not\n]\n");
    EXPECT_NE(r.exit_code, 0) << r.out;
    EXPECT_TRUE(has(r.out, d.file("b #2.tsr"))) << r.out;
    // One value quoted with a '#', then a comment.
    r = serve_with("store = '" + d.file("c #3.tsr") + "'  # missing\n");
    EXPECT_NE(r.exit_code, 0) << r.out;
    EXPECT_TRUE(has(r.out, d.file("c #3.tsr"))) << r.out;
    // A bracket that does not end its line is no list (an IPv6 listen address is written so).
    r = serve_with("store = [x]" + d.file("y.tsr").substr(1) + "\n");
    EXPECT_NE(r.exit_code, 0) << r.out;
    EXPECT_TRUE(has(r.out, "[x]" + d.file("y.tsr").substr(1) + " does not exist")) << r.out;
    // A bare value ends at " #".
    r = serve_with("store = " + d.file("d.tsr") + " # missing\n");
    EXPECT_NE(r.exit_code, 0) << r.out;
    EXPECT_TRUE(has(r.out, d.file("d.tsr") + " does not exist")) << r.out;
    // The command line wins: the file's invalid value for the same key is not applied, so the run
    // gets as far as opening its (missing) store.
    r = serve_with("store = " + d.file("e.tsr") + "\ndrain-timeout = -1\n", "--drain-timeout 10");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_TRUE(has(r.out, d.file("e.tsr"))) << r.out;
    EXPECT_FALSE(has(r.out, "drain-timeout")) << r.out;
}

// A mistyped command is named, not answered "A subcommand is required".
TEST(CliHelp, AnUnknownCommandIsNamed) {
    RunResult r = run_tessera("frobnicate");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_TRUE(has(r.out, "'frobnicate' is not a command")) << r.out;
    r = run_tessera("--bogus");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_TRUE(has(r.out, "--bogus")) << r.out;
}

TEST(CliHelp, ConfigTakesAFile) {
    for (const bool server : {false, true}) {
        SCOPED_TRACE(server ? "tessera-server" : "tessera");
        const RunResult r = server ? run_server_binary("serve --help") : run_tessera("serve --help");
        ASSERT_EQ(r.exit_code, 0) << r.out;
        EXPECT_TRUE(has(r.out, "  --config FILE ")) << r.out;
    }
}

TEST(CliHelp, ServeSaysBothLogFormats) {
    const RunResult r = run_tessera("serve --help");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_FALSE(has(r.out, "Logs are one JSON object per line")) << r.out;
    EXPECT_TRUE(has(r.out, "(--log-format json)") && has(r.out, "(--log-format text)")) << r.out;
}

// loadtest takes the viewer's paths: every built-in (listed by the scene library) and path files.
TEST(CliHelp, LoadtestPathsAreTheViewersPaths) {
    const RunResult view = run_tessera("view --help");
    const RunResult loadtest = run_tessera("loadtest --help");
    ASSERT_EQ(loadtest.exit_code, 0) << loadtest.out;
    for (const char* name : {"auto", "flyover", "dive", "whip", "walk", "orbit", "path file"}) {
        EXPECT_TRUE(has(help_line(view.out, "--path"), name)) << name << "\n" << view.out;
        EXPECT_TRUE(has(help_line(loadtest.out, "--path"), name)) << name << "\n" << loadtest.out;
    }
}

TEST(CliHelp, DemoSaysWhatItDoes) {
    const RunResult r = run_tessera("--help");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    const std::string demo = help_line(r.out, "demo");
    for (const char* part : {"serve", "headless", "fallback", "PSNR", "popping"})
        EXPECT_TRUE(has(demo, part)) << part << "\n" << r.out;
}

// CLI11's errors name the subcommand's help, for both binaries; one line, exit 2.
TEST(CliErrors, PointToTheSubcommandsHelp) {
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"view --no-such-flag", "run 'tessera view --help' for the options"},
        {"view --frames many --store x.tsr", "run 'tessera view --help' for the options"},
        {"build procedural:terrain:64", "run 'tessera build --help' for the options"},
        {"loadtest --viewers 4", "run 'tessera loadtest --help' for the options"},
        {"serve --log-format xml", "run 'tessera serve --help' for the options"},
        {"no-such-command", "run 'tessera --help' for the commands"},
        {"", "run 'tessera --help' for the commands"}};
    for (const auto& [args, hint] : cases) {
        SCOPED_TRACE(args);
        const RunResult r = run_tessera(args);
        expect_one_line_error(r);
        EXPECT_EQ(r.exit_code, 2) << r.out;
        EXPECT_TRUE(has(r.out, hint)) << r.out;
    }
    for (const auto& [args, hint] : std::vector<std::pair<std::string, std::string>>{
             {"serve --no-such-flag", "tessera-server: error: "},
             {"serve --no-such-flag", "run 'tessera-server serve --help' for the options"},
             {"verify", "run 'tessera-server verify --help' for the options"},
             {"no-such-command", "run 'tessera-server --help' for the commands"}}) {
        SCOPED_TRACE("tessera-server " + args);
        const RunResult r = run_server_binary(args);
        EXPECT_EQ(r.exit_code, 2) << r.out;
        EXPECT_EQ(line_count(r.out), 1u) << r.out;
        EXPECT_TRUE(has(r.out, hint)) << r.out;
    }
}

// A view identical to its reference: "lossless", never "inf dB".
TEST(CliView, LosslessPsnrIsSaidInWords) {
    ScratchDir d;
    // One colour everywhere: every level, every fallback and the reference are the same colour.
    {
        auto out = OIIO::ImageOutput::create(d.file("flat.png"));
        ASSERT_TRUE(out);
        OIIO::ImageSpec spec(512, 512, 3, OIIO::TypeDesc::UINT8);
        std::vector<std::uint8_t> px(std::size_t(512) * 512 * 3, 120);
        ASSERT_TRUE(out->open(d.file("flat.png"), spec));
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px.data()));
        ASSERT_TRUE(out->close());
    }
    RunResult r = run_tessera("build " + q(d.file("flat.png")) + " --codec zstd --tile-size 128 -o " + q(d.file("flat.tsr")) +
                              " --quiet");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    r = run_tessera("view --store " + q(d.file("flat.tsr")) + " --headless --size 96x64 --frames 6 --psnr-every 1 --pool 64 "
                    "--stats " + q(d.file("stats.json")));
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_FALSE(has(r.out, "inf")) << r.out;
    EXPECT_TRUE(has(r.out, "PSNR          lossless: the 6 compared frames are identical to the reference")) << r.out;
    EXPECT_TRUE(has(r.out, "settled       lossless (identical to the reference)")) << r.out;
    // The records hold numbers JSON can carry (999 for identical frames, docs/viewer.md).
    const auto stats = nlohmann::json::parse(read_file(d.file("stats.json")));
    EXPECT_EQ(stats["frames"][0]["psnr_db"].get<double>(), 999.0) << stats["frames"][0];
    EXPECT_EQ(stats["settled"]["psnr_db"].get<double>(), 999.0) << stats["settled"];
}

// A store whose every tile fails to read: the summary says so, and the run is no success (exit 1
// after the summary), where it exited 0 having shown nothing of the store after a 20 s warm-up.
TEST(CliView, AStoreNoTileOfWhichCanBeReadFails) {
    ScratchDir d;
    ASSERT_EQ(run_tessera("build -q procedural:terrain:64 --codec zstd -o " + q(d.file("one.tsr"))).exit_code, 0);
    auto bytes = read_file(d.file("one.tsr"));
    bytes[bytes.size() - 10] ^= 0xFF;  // in its one tile's payload
    write_file(d.file("bad.tsr"), std::vector<std::uint8_t>(bytes.begin(), bytes.end()));
    // The warm-up gives up after 2 s of nothing but errors, not after its 20 s.
    const auto t0 = std::chrono::steady_clock::now();
    const RunResult r = run_tessera("view --store " + q(d.file("bad.tsr")) + " --headless --size 32x32 --frames 5");
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(15)) << r.out;
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_TRUE(has(r.out, "NOT at full detail (stopped: for 2 s every read failed)")) << r.out;
    EXPECT_TRUE(has(r.out, " tile answers were errors (first: level 0 (0, 0): DATA_LOSS")) << r.out;
    EXPECT_TRUE(has(r.out, "no tile of the store could be read")) << r.out;
    // The intact store: exit 0.
    EXPECT_EQ(run_tessera("view --store " + q(d.file("one.tsr")) + " --headless --size 32x32 --frames 5 --no-warmup").exit_code, 0);
}

// A first view that shows none of the texture (the camera beside it) wants nothing: the warm-up
// ends at once, where it drew frames as fast as it could for its whole 20 s and said "timed out".
TEST(CliView, AViewOfNoTextureIsSettledAtOnce) {
    ScratchDir d;
    ASSERT_EQ(run_tessera("build -q procedural:terrain:512 --codec zstd -o " + q(d.file("t.tsr"))).exit_code, 0);
    {
        std::ofstream path(d.file("beside.path"));
        path << "0 5000 5000 600 90 -90\n1 5000 5000 600 90 -90\n";
    }
    const auto t0 = std::chrono::steady_clock::now();
    const RunResult r = run_tessera("view --store " + q(d.file("t.tsr")) + " --headless --size 32x32 --frames 3 --path " +
                                    q(d.file("beside.path")));
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(15)) << r.out;
    EXPECT_EQ(r.exit_code, 0) << r.out;
    EXPECT_TRUE(has(r.out, "first view    full detail in")) << r.out;
    EXPECT_TRUE(has(r.out, "fallback      n/a")) << r.out;
}

// ---- serve: options checked before it starts ------------------------------------------------------

// Thread counts past 1024 are refused on the command line; threads that cannot be created at start
// (here a 4 GB address space against 1000 stacks of 8 MiB) are an error, not std::terminate.
TEST(CliServe, ThreadCountsAreBoundedAndAFailedStartIsAnError) {
    ScratchDir d;
    ASSERT_EQ(run_tessera("build procedural:terrain:64 --quiet -o " + q(d.file("s.tsr"))).exit_code, 0);
    const std::string serve = "serve --store " + q(d.file("s.tsr")) + " --grpc 127.0.0.1:0 --http 127.0.0.1:0 --log-format text ";
    // A server that did start is killed after 60 s: the test then fails, it does not hang.
    const std::string bounded = "timeout -s KILL 60 " + std::string(TESSERA_BINARY);
    for (const std::string flag : {"--io-threads", "--http-threads"}) {
        for (const char* n : {"1025", "100000"}) {
            SCOPED_TRACE(flag + " " + n);
            const RunResult r = tessera::test::run_program(bounded, serve + flag + " " + n);
            expect_one_line_error(r);
            EXPECT_EQ(r.exit_code, 2) << r.out;
            EXPECT_TRUE(has(r.out, flag) && has(r.out, "1024")) << r.out;
        }
        const RunResult help = run_tessera("serve --help");
        EXPECT_TRUE(has(help_line(help.out, flag), "at most 1024")) << help.out;
    }
#if !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)  // sanitizers reserve terabytes: no ulimit -v
    const std::string limited = "ulimit -s 8192 && ulimit -v 4000000 && " + bounded;
    for (const char* flags : {"--io-threads 1000", "--http-threads 1000", "--work-threads 1000"}) {
        SCOPED_TRACE(flags);
        const RunResult r = tessera::test::run_program(limited, serve + flags);
        EXPECT_EQ(r.exit_code, 1) << r.out;
        EXPECT_TRUE(has(r.out, "tessera: error: cannot start the server's threads")) << r.out;
        EXPECT_FALSE(has(r.out, "terminate")) << r.out;
    }
#endif
}

}  // namespace
