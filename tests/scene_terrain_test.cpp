// The `terrain` scene: chunk layout, integer texel origins, bounds, winding, texel = world xy, and
// the displaced variant.
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "tessera/scene/scene.hpp"

namespace {

using namespace tessera::scene;

TEST(Terrain, ChunksTexelOriginsAndBounds) {
    TerrainOptions o;
    o.vt_width = 10000;
    o.vt_height = 5000;
    o.chunk_texels = 4096;
    o.quads_per_chunk = 16;
    auto s = make_terrain(o);
    ASSERT_TRUE(s.ok()) << s.error().message;
    EXPECT_EQ(s->name, "terrain");
    EXPECT_EQ(s->vt_width, 10000u);
    EXPECT_EQ(s->vt_height, 5000u);
    ASSERT_EQ(s->chunks.size(), 6u);  // 3 x 2
    std::set<std::pair<std::uint32_t, std::uint32_t>> origins;
    for (const Chunk& c : s->chunks) {
        origins.insert({c.texel_origin[0], c.texel_origin[1]});
        EXPECT_EQ(c.origin[0], double(c.texel_origin[0]));
        EXPECT_EQ(c.origin[1], double(c.texel_origin[1]));
        EXPECT_EQ(c.origin[2], 0.0);
        EXPECT_EQ(c.vertices.size(), 17u * 17u);
        EXPECT_EQ(c.indices.size(), 16u * 16u * 6u);
        const double w = std::min<double>(4096, 10000 - c.texel_origin[0]), h = std::min<double>(4096, 5000 - c.texel_origin[1]);
        EXPECT_EQ(c.bounds_min[0], c.origin[0]);
        EXPECT_EQ(c.bounds_min[1], c.origin[1]);
        EXPECT_EQ(c.bounds_max[0], c.origin[0] + w);
        EXPECT_EQ(c.bounds_max[1], c.origin[1] + h);
        EXPECT_EQ(c.bounds_min[2], 0.0);
        EXPECT_EQ(c.bounds_max[2], 0.0);
        for (const Vertex& v : c.vertices) {
            // Flat terrain: the texel of world (x, y) is (x, y); positions are chunk-relative.
            EXPECT_EQ(v.texel[0], v.position[0]);
            EXPECT_EQ(v.texel[1], v.position[1]);
            EXPECT_EQ(v.position[2], 0.0f);
            EXPECT_GE(v.position[0], 0.0f);
            EXPECT_LE(v.position[0], float(w));
            EXPECT_LE(v.position[1], float(h));
        }
        // Counter-clockwise seen from +Z.
        for (std::size_t i = 0; i < c.indices.size(); i += 3) {
            const Vertex &a = c.vertices[c.indices[i]], &b = c.vertices[c.indices[i + 1]], &d = c.vertices[c.indices[i + 2]];
            const double cz = double(b.position[0] - a.position[0]) * (d.position[1] - a.position[1]) -
                              double(b.position[1] - a.position[1]) * (d.position[0] - a.position[0]);
            EXPECT_GT(cz, 0) << "triangle " << i / 3;
        }
    }
    const std::set<std::pair<std::uint32_t, std::uint32_t>> want = {{0, 0}, {4096, 0}, {8192, 0}, {0, 4096}, {4096, 4096}, {8192, 4096}};
    EXPECT_EQ(origins, want);
    EXPECT_EQ(s->bounds_min[0], 0.0);
    EXPECT_EQ(s->bounds_min[1], 0.0);
    EXPECT_EQ(s->bounds_max[0], 10000.0);
    EXPECT_EQ(s->bounds_max[1], 5000.0);
    EXPECT_EQ(s->bounds_max[2], 0.0);
}

TEST(Terrain, HugeTerrainsKeepTexelsExact) {
    TerrainOptions o;
    o.vt_width = o.vt_height = 1u << 24;
    o.chunk_texels = 1u << 20;
    o.quads_per_chunk = 8;
    auto s = make_terrain(o);
    ASSERT_TRUE(s.ok()) << s.error().message;
    ASSERT_EQ(s->chunks.size(), 256u);
    const Chunk& last = s->chunks.back();
    EXPECT_EQ(last.texel_origin[0], 15u << 20);
    EXPECT_EQ(last.texel_origin[1], 15u << 20);
    // Every vertex sits on an exact texel: origin (integer) + offset (exact in float).
    for (const Vertex& v : last.vertices) {
        EXPECT_EQ(v.texel[0], std::floor(v.texel[0]));
        EXPECT_EQ(double(last.texel_origin[0]) + v.texel[0], last.origin[0] + v.position[0]);
    }
    EXPECT_EQ(s->bounds_max[0], 16777216.0);
    // The default chunk size would make 2^24 chunks' worth of vertices: refused with a clear message.
    o.chunk_texels = 4096;
    auto too_many = make_terrain(o);
    ASSERT_FALSE(too_many.ok());
    EXPECT_NE(too_many.error().message.find("chunk_texels"), std::string::npos) << too_many.error().message;
}

TEST(Terrain, NeighbouringChunksShareTheirEdges) {
    TerrainOptions o;
    o.vt_width = 3000;
    o.vt_height = 1000;
    o.chunk_texels = 1024;
    o.quads_per_chunk = 4;
    o.displacement = 200;
    auto s = make_terrain(o);
    ASSERT_TRUE(s.ok());
    const Chunk &a = s->chunks[0], &b = s->chunks[1];
    ASSERT_EQ(b.texel_origin[0], 1024u);
    for (std::uint32_t j = 0; j <= 4; ++j) {
        const Vertex& ea = a.vertices[j * 5 + 4];  // right edge of a
        const Vertex& eb = b.vertices[j * 5 + 0];  // left edge of b
        EXPECT_EQ(a.origin[0] + ea.position[0], b.origin[0] + eb.position[0]);
        EXPECT_EQ(a.origin[1] + ea.position[1], b.origin[1] + eb.position[1]);
        EXPECT_EQ(ea.position[2], eb.position[2]);  // same height: no cracks
    }
}

TEST(Terrain, DisplacementIsSmoothDeterministicAndBounded) {
    TerrainOptions o;
    o.vt_width = o.vt_height = 16384;
    o.chunk_texels = 4096;
    o.quads_per_chunk = 32;
    o.displacement = 300;
    auto s = make_terrain(o);
    ASSERT_TRUE(s.ok());
    double lo = 1e9, hi = -1e9;
    for (const Chunk& c : s->chunks) {
        for (const Vertex& v : c.vertices) {
            const double z = terrain_height(o, c.origin[0] + v.position[0], c.origin[1] + v.position[1]);
            EXPECT_FLOAT_EQ(v.position[2], static_cast<float>(z));
            EXPECT_GE(z, 0.0);
            EXPECT_LE(z, 300.0);
            lo = std::min(lo, z);
            hi = std::max(hi, z);
            EXPECT_GE(z, c.bounds_min[2]);
            EXPECT_LE(z, c.bounds_max[2]);
        }
    }
    EXPECT_GT(hi - lo, 100.0);  // it is not flat
    EXPECT_EQ(terrain_height(o, 1234.5, 777.25), terrain_height(o, 1234.5, 777.25));
    // Smooth: one texel apart, the height changes by a small fraction of a unit.
    EXPECT_LT(std::abs(terrain_height(o, 5000, 5000) - terrain_height(o, 5001, 5000)), 2.0);
    o.displacement = 0;
    EXPECT_EQ(terrain_height(o, 5000, 5000), 0.0);
}

// A height field (a store's height layer) displaces the terrain instead of the height function:
// its samples at their cell centres exactly, bilinear between them, clamped beyond the edges.
TEST(Terrain, AHeightFieldDisplacesTheGroundBilinearly) {
    TerrainOptions o;
    o.vt_width = o.vt_height = 1024;
    o.chunk_texels = 512;
    o.quads_per_chunk = 8;
    o.displacement = 200;
    auto f = std::make_shared<HeightField>();
    f->width = 4;
    f->height = 2;  // cells of 256 x 512 texels: centres at x = 128, 384, 640, 896 and y = 256, 768
    f->samples = {0.0f, 0.25f, 0.5f, 1.0f,  //
                  1.0f, 0.75f, 0.5f, 0.0f};
    o.heights = f;
    auto s = make_terrain(o);
    ASSERT_TRUE(s.ok()) << s.error().message;
    EXPECT_DOUBLE_EQ(terrain_height(o, 128, 256), 0.0);
    EXPECT_DOUBLE_EQ(terrain_height(o, 896, 256), 200.0);
    EXPECT_DOUBLE_EQ(terrain_height(o, 128, 768), 200.0);
    EXPECT_DOUBLE_EQ(terrain_height(o, 256, 256), 25.0);   // halfway between 0 and 0.25
    EXPECT_DOUBLE_EQ(terrain_height(o, 128, 512), 100.0);  // halfway between 0 and 1
    EXPECT_DOUBLE_EQ(terrain_height(o, 0, 0), 0.0);        // clamped to the corner sample
    EXPECT_DOUBLE_EQ(terrain_height(o, 1024, 0), 200.0);
    double lo = 1e9, hi = -1e9;
    for (const Chunk& c : s->chunks)
        for (const Vertex& v : c.vertices) {
            const double z = terrain_height(o, c.origin[0] + v.position[0], c.origin[1] + v.position[1]);
            EXPECT_FLOAT_EQ(v.position[2], static_cast<float>(z));
            EXPECT_GE(z, c.bounds_min[2]);
            EXPECT_LE(z, c.bounds_max[2]);
            lo = std::min(lo, z);
            hi = std::max(hi, z);
        }
    EXPECT_DOUBLE_EQ(lo, 0.0);
    EXPECT_DOUBLE_EQ(hi, 200.0);

    // A store level's samples cover 2^L texels each, the last overhanging a texture whose size is
    // not a multiple: the centres stay where the level puts them.
    TerrainOptions odd = o;
    odd.vt_width = odd.vt_height = 1000;
    auto g = std::make_shared<HeightField>(*f);
    g->texels_per_sample = 256;  // 4 x 2 samples of 256: centres at x = 128, 384, 640, 896
    odd.heights = g;
    EXPECT_DOUBLE_EQ(terrain_height(odd, 896, 128), 200.0);
    EXPECT_DOUBLE_EQ(terrain_height(odd, 256, 128), 25.0);

    f->samples.pop_back();  // not width x height samples
    EXPECT_FALSE(make_terrain(o).ok());
    f->samples.push_back(std::nanf(""));
    EXPECT_FALSE(make_terrain(o).ok());
}

TEST(Terrain, BadOptions) {
    TerrainOptions o;
    EXPECT_FALSE(make_terrain(o).ok());  // zero size
    o.vt_width = o.vt_height = 1024;
    o.chunk_texels = 0;
    EXPECT_FALSE(make_terrain(o).ok());
    o.chunk_texels = 256;
    o.quads_per_chunk = 0;
    EXPECT_FALSE(make_terrain(o).ok());
    o.quads_per_chunk = 4;
    o.displacement = -1;
    EXPECT_FALSE(make_terrain(o).ok());
    o.displacement = 0;
    EXPECT_TRUE(make_terrain(o).ok());
    // A texture smaller than one chunk: one chunk of the texture's size.
    o.vt_width = 100;
    o.vt_height = 7;
    auto s = make_terrain(o);
    ASSERT_TRUE(s.ok());
    ASSERT_EQ(s->chunks.size(), 1u);
    EXPECT_EQ(s->chunks[0].bounds_max[0], 100.0);
    EXPECT_EQ(s->chunks[0].bounds_max[1], 7.0);
}

// The VT renderer skips its depth pre-pass exactly for scenes where no triangle can hide another.
TEST(Overdraw, OnlyOnePlaneFacingOneWayIsOverdrawFree) {
    TerrainOptions o;
    o.vt_width = 9000;
    o.vt_height = 5000;
    o.chunk_texels = 2048;
    auto flat = make_terrain(o);
    ASSERT_TRUE(flat.ok());
    ASSERT_GT(flat->chunks.size(), 4u);
    EXPECT_TRUE(overdraw_free(*flat));

    o.displacement = 300;
    auto hills = make_terrain(o);
    ASSERT_TRUE(hills.ok());
    EXPECT_FALSE(overdraw_free(*hills));

    // One chunk lifted by a unit: two parallel planes, one can hide the other.
    Scene lifted = *flat;
    lifted.chunks[1].origin[2] += 1.0;
    EXPECT_FALSE(overdraw_free(lifted));

    // One triangle wound the other way: it faces down, and seen from below it is drawn alone,
    // but the scene as a whole is not one plane facing one way.
    Scene flipped = *flat;
    std::swap(flipped.chunks[2].indices[0], flipped.chunks[2].indices[1]);
    EXPECT_FALSE(overdraw_free(flipped));

    // Degenerate triangles cover nothing and do not count; an empty scene is trivially free.
    Scene empty;
    EXPECT_TRUE(overdraw_free(empty));
    Scene degenerate = *flat;
    degenerate.chunks[0].indices.insert(degenerate.chunks[0].indices.end(), {0, 0, 0});
    EXPECT_TRUE(overdraw_free(degenerate));
    // A bad index is never read past: the scene is simply not declared free.
    Scene broken = *flat;
    broken.chunks[0].indices.insert(broken.chunks[0].indices.end(), {0, 1, 1000000});
    EXPECT_FALSE(overdraw_free(broken));
}

}  // namespace
