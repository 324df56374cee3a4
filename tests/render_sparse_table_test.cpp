// The two-level page table end to end (docs/stability.md, "Reaching 2^24 end to end"), on Mesa
// llvmpipe or a GPU: textures whose dense table does not fit (2^24, 2^24 - 1 and a non-power-of-two
// size at 1024-texel tiles) get a sparse CPU PageTable and the renderer's two-level table; pages at
// the far corner are mapped in the CPU table, its dirty blocks uploaded with
// upload_page_table_block exactly as the runtime does, and the image read back at level-L texel
// centres.
//
//   RenderSparseTable.FarCornerIsExactAtEveryLevel  levels 0, 1, 4, 9 and the last two: every
//       pixel on a texel centre is the stored texel, no fallback.
//   RenderSparseTable.AnisotropicFarCornerIsExact  the same at 2^24 with the anisotropic filter,
//       whose 2x2 block of entries reaches one page past the far edge.
//   RenderSparseTable.FallbackThroughUnallocatedBlocks  only a level-6 page and the root resident,
//       viewed at level 0: level 0 .. 4 blocks are unallocated and the walk finds the level-6 page
//       inside it and the root outside it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "ground_ray.hpp"
#include "render_util.hpp"
#include "tessera/client/gl/context.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "page_table.hpp"
#include "tessera/scene/camera.hpp"
#include "tessera/scene/scene.hpp"
#include "tessera/storage/types.hpp"

namespace {

namespace gl = tessera::client::gl;
namespace sc = tessera::scene;
namespace st = tessera::storage;
using tessera::client::DirtyBlock;
using tessera::client::PageTable;
using tessera::test::corner_chunk;
using tessera::test::straight_down;

constexpr std::uint32_t kTile = 1024, kBorder = 4, kP = kTile - 2 * kBorder;
constexpr std::uint32_t kW = 128, kH = 96;

st::StoreInfo geometry(std::uint32_t size) { return tessera::test::store_geometry(size, size, kTile, kBorder); }

gl::RendererConfig config(gl::Filter filter = gl::Filter::bilinear) {
    auto c = tessera::test::exact_config(kW, kH, kTile, kBorder, 4);
    c.filter = filter;
    c.max_anisotropy = 1;  // one tap per pixel: texel centres read back exactly (see below)
    return c;
}

// What Runtime::frame does with a sparse table's changes.
std::size_t upload_blocks(PageTable& t, gl::VtRenderer& r) {
    std::vector<DirtyBlock> dirty;
    t.take_dirty_blocks(dirty);
    for (const DirtyBlock& b : dirty)
        r.upload_page_table_block(t.texture(), std::uint8_t(b.level), b.bx, b.by,
                                  b.allocated ? t.block_entries(b.level, b.bx, b.by) : std::span<const std::uint32_t>());
    return dirty.size();
}

struct Setup {
    std::unique_ptr<gl::VtRenderer> renderer;
    PageTable table;
    st::StoreInfo info;
};

std::optional<Setup> make(std::uint32_t size, gl::Filter filter = gl::Filter::bilinear) {
    auto made = gl::VtRenderer::create(config(filter));
    EXPECT_TRUE(made.ok()) << made.error().message;
    if (!made) return std::nullopt;
    const st::StoreInfo info = geometry(size);
    const std::uint32_t n = info.levels[0].tiles_x;
    EXPECT_FALSE(PageTable::dense_packing_fits(n, n)) << size << ": should need the two-level table";
    const auto added = (*made)->add_texture(0, info);
    EXPECT_TRUE(added.ok()) << added.error().message;
    auto table = PageTable::create(0, n, n, info.level_count(), PageTable::kDefaultMaxBytes, true);
    EXPECT_TRUE(table.ok()) << table.error().message;
    if (!added || !table) return std::nullopt;
    EXPECT_TRUE(table->sparse());
    return Setup{std::move(*made), std::move(*table), info};
}

void far_corner_exact(std::uint32_t size, gl::Filter filter = gl::Filter::bilinear) {
    SCOPED_TRACE(testing::Message() << "size " << size << ", filter " << int(filter));
    auto s = make(size, filter);
    ASSERT_TRUE(s);
    gl::VtRenderer& r = *s->renderer;
    const st::StoreInfo& info = s->info;
    const std::uint32_t levels = info.level_count();
    std::vector<std::uint8_t> page(std::size_t(kTile) * kTile * 4);
    for (const std::uint32_t level : {0u, 1u, 4u, 9u, levels - 2, levels - 1}) {
        const auto [texels, pages, k, first_page, count] = tessera::test::corner_pages(info, level);
        std::vector<std::pair<std::uint32_t, std::uint32_t>> mapped;
        for (std::uint32_t py = 0; py < count; ++py)
            for (std::uint32_t px = 0; px < count; ++px) {
                const std::uint32_t slot = py * 2 + px;
                tessera::test::encode_page(page, kTile, kBorder, first_page + px, first_page + py, texels);
                r.upload_page(slot, {0, std::uint8_t(level), first_page + px, first_page + py}, page, kTile);
                ASSERT_TRUE(s->table.map(level, first_page + px, first_page + py, slot).ok());
                mapped.emplace_back(first_page + px, first_page + py);
            }
        const std::size_t blocks = upload_blocks(s->table, r);

        // Anisotropic wants floor(lod), and at exactly 2^L texels per pixel the lod rounds to either
        // side of L: the finer level wanted is not mapped, and its pixels count as fallback (while
        // sampling level L's texels exactly, which is what is checked).
        const auto [checked, wrong] =
            tessera::test::render_corner_exactly(r, size, k, level, kW, kH, filter != gl::Filter::anisotropic);
        std::printf("  %u texels (2^%.4f): level %u (%u pages per side), %zu blocks uploaded, %zu pixels on texel centres, "
                    "%zu wrong\n",
                    size, std::log2(double(size)), level, pages, blocks, checked, wrong);
        for (const auto& [x, y] : mapped) ASSERT_TRUE(s->table.unmap(level, x, y).ok());
    }
    // Everything unmapped: only the coarse blocks are left, and the renderer was told.
    upload_blocks(s->table, r);
    std::size_t coarse = 0;
    for (std::uint32_t l = 0; l < levels; ++l)
        coarse += info.levels[l].tiles_x <= PageTable::kBlockSide && info.levels[l].tiles_y <= PageTable::kBlockSide;
    EXPECT_EQ(s->table.allocated_blocks(), coarse);
    EXPECT_EQ(r.stats().malformed_uploads, 0u);
}

TEST(RenderSparseTable, FarCornerIsExactAtEveryLevel) {
    REQUIRE_GL(ctx);
    far_corner_exact(1u << 24);
    far_corner_exact((1u << 24) - 1);
    far_corner_exact(12'345'679);  // not a power of two: 12,151 pages per side
}

// Anisotropic, at most one tap (with more, a footprint of exactly 2^L texels per pixel may round
// to two taps a quarter texel either side of the centre): the shader still reads the 2x2 pages
// around each centre, which at the far corner reach past the texture's last page, where the
// two-level table has no directory entries and must read the edge page instead.
TEST(RenderSparseTable, AnisotropicFarCornerIsExact) {
    REQUIRE_GL(ctx);
    far_corner_exact(1u << 24, gl::Filter::anisotropic);
}

TEST(RenderSparseTable, FallbackThroughUnallocatedBlocks) {
    REQUIRE_GL(ctx);
    const std::uint32_t size = 1u << 24;
    auto s = make(size);
    ASSERT_TRUE(s);
    gl::VtRenderer& r = *s->renderer;
    const std::uint32_t levels = s->info.level_count(), fine = 6;
    // Uniform pages: any bilinear sample of one is its colour exactly.
    const std::uint8_t inside[4] = {10, 200, 30, 255}, outside[4] = {250, 20, 90, 255};
    std::vector<std::uint8_t> page(std::size_t(kTile) * kTile * 4);
    // The level-6 page at the far corner (slot 0), and the root (slot 1).
    const std::uint32_t px = s->info.levels[fine].tiles_x - 1;
    const tessera::client::PageKey keys[2] = {{0, std::uint8_t(fine), px, px}, {0, std::uint8_t(levels - 1), 0, 0}};
    for (const auto& [slot, colour] : {std::pair{0u, inside}, {1u, outside}}) {
        for (std::size_t i = 0; i < page.size(); i += 4) std::copy(colour, colour + 4, page.begin() + std::ptrdiff_t(i));
        r.upload_page(slot, keys[slot], page, kTile);
    }
    ASSERT_TRUE(s->table.map(fine, px, px, 0).ok());
    ASSERT_TRUE(s->table.map(levels - 1, 0, 0, 1).ok());
    upload_blocks(s->table, r);
    // Level 0 at the page's left / top edge: nothing resident at levels 0 .. 4 there.
    const std::uint32_t edge = px * kP << fine;  // level-0 texel of the level-6 page's corner
    EXPECT_EQ(s->table.block_entries(0, (edge / kP) >> PageTable::kBlockShift, (edge / kP) >> PageTable::kBlockShift).size(), 0u);
    const std::uint32_t o = (edge - 4000) | 1u;
    ASSERT_TRUE(r.set_scene(corner_chunk(size, o), 0).ok());
    const double height = kH / (2.0 * std::tan(sc::Camera{}.fov_y / 2.0));
    const sc::Camera cam = straight_down(edge + 0.25, edge + 0.25, height);
    const auto frame = r.render(cam, 0);
    std::vector<gl::FrameCounters> counters;
    r.finish(&counters, nullptr);
    const auto rgba = r.read_color();
    EXPECT_EQ(r.stats().gl_errors, 0u);
    EXPECT_EQ(r.stats().malformed_uploads, 0u);
    std::size_t in = 0, out = 0, wrong = 0;
    for (std::uint32_t j = 0; j < kH; ++j)
        for (std::uint32_t i = 0; i < kW; ++i) {
            double x, y;
            ASSERT_TRUE(tessera::test::pixel_to_ground(cam, kW, kH, i, j, x, y));
            if (std::abs(x - edge) < 1.0 || std::abs(y - edge) < 1.0) continue;  // on the page edge
            const bool is_in = x > edge && y > edge;
            const std::uint8_t* want = is_in ? inside : outside;
            const std::uint8_t* got = rgba.data() + (std::size_t(j) * kW + i) * 4;
            (is_in ? in : out)++;
            if (!std::equal(want, want + 4, got) && ++wrong <= 5)
                ADD_FAILURE() << "pixel (" << i << ", " << j << ") at (" << x << ", " << y << "): got " << int(got[0]) << " "
                              << int(got[1]) << " " << int(got[2]) << ", want " << int(want[0]) << " " << int(want[1]) << " "
                              << int(want[2]);
        }
    EXPECT_EQ(wrong, 0u);
    EXPECT_GT(in, std::size_t(kW * kH / 8));
    EXPECT_GT(out, std::size_t(kW * kH / 8));
    for (const auto& c : counters) {
        if (c.frame == frame) {
            EXPECT_EQ(c.fallback_unbiased, c.textured_pixels) << "every pixel wants level 0 and gets 6 or the root";
        }
    }
    std::printf("  2^24: level-6 page and root resident, level 0 viewed: %zu pixels from the level-6 page, %zu from the root, "
                "%zu wrong; %zu blocks allocated\n",
                in, out, wrong, s->table.allocated_blocks());
}

}  // namespace
