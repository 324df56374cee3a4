#pragma once
// The demo source image: fractal terrain colours plus a labelled grid, generated one row at a time.
#include <array>
#include <cstdint>
#include <vector>

namespace tessera::storage::build {

// The demo source: fractal terrain colours plus a labelled grid, generated row by row so an image
// of any size (up to 2^24 per side) never has to exist in memory. Deterministic: the same (size, y)
// always gives the same bytes, on any machine, whatever the thread. render_row is const and
// thread-safe (called concurrently for different rows from many threads).
class ProceduralTerrain {
public:
    static constexpr std::uint64_t kMaxSize = std::uint64_t(1) << 24;

    // Square image, size x size texels. Throws std::invalid_argument unless 1 <= size <= kMaxSize.
    explicit ProceduralTerrain(std::uint64_t size);
    std::uint64_t size() const { return size_; }
    // Writes texels [0, size) of row y (y < size) as RGB8 (sRGB), 3*size bytes, into out.
    // Never allocates.
    void render_row(std::uint64_t y, std::uint8_t* out) const;
    // The height field the colours of row y are made from (the fBm sum before the colour ramp:
    // sea below 0, land above, within [-1, 1]), size floats into out. Deterministic like
    // render_row, and as cheap minus the shading. Never allocates.
    void height_row(std::uint64_t y, float* out) const;

private:
    static constexpr int kMaxOctaves = 12;

    // One fBm octave: value noise on a lattice of spacing 2^shift texels, sheared along x.
    struct Octave {
        std::uint32_t shift = 0;       // log2 of the lattice spacing in texels (>= 2)
        std::uint32_t group = 0;       // shading group (see the .cpp)
        float inv_spacing = 0;         // 2^-shift
        float weight = 0;              // amplitude; the weights sum to 1
        float facing_x = 0;            // "facing the light" per unit of x slope coefficient
        float facing_y = 0;            // ... and per unit of d(value)/dy
        std::int64_t x_origin16 = 0;   // x offset of the lattice, in 1/65536 texels (positive)
        std::int64_t x_shear16 = 0;    // extra x offset per row, in 1/65536 texels
        std::uint64_t y_origin = 0;    // y offset of the lattice, in texels
        std::uint64_t seed = 0;        // picks the lattice values of each lattice row
    };

    // Colour ramp entry, indexed by height; 16 bytes so that one entry loads as one vector.
    struct alignas(16) RampEntry {
        float r, g, b;  // sRGB, 0..255
        float relief;   // how strongly hill shading applies (weak under water)
    };

    template <bool kColour>
    void fbm_row(std::uint64_t y, std::uint8_t* rgb, float* heights) const;
    void draw_grid(std::uint64_t y, std::uint8_t* out) const;

    std::uint64_t size_;
    int octave_count_ = 0;
    std::array<Octave, kMaxOctaves> octaves_{};
    std::vector<float> lattice_;  // random lattice values in [-1, 1), indexed modulo its size
    std::vector<RampEntry> ramp_;
};

}  // namespace tessera::storage::build
