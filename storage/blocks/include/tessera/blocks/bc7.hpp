#pragma once
// BC7 blocks (BPTC: GL_COMPRESSED_RGBA_BPTC_UNORM, and GL_COMPRESSED_SRGB_ALPHA_BPTC_UNORM, which
// decodes the same bits). The encoder is for building stores, where quality comes first and time
// may be spent; the decoder gives exactly the texels a GPU samples (all eight modes, as the Khronos
// Data Format Specification defines them), so tests can make reference images from blocks.
//
// A block is 4 x 4 texels in 16 bytes. Pages are size x size texels, size a multiple of 4, RGBA8
// row-major; their blocks go row of blocks by row of blocks, each block's bytes as the GPU reads
// them (the layout glCompressedTexSubImage2D takes): size * size bytes per page.
//
// The encoder tries mode 6 (one RGBA endpoint pair, 4-bit indices), modes 4 and 5 (colour and
// alpha apart) and modes 1 and 3 (two subsets, the partitions a cheap estimate ranks best); from
// effort 1 also modes 0 and 2 (three subsets) on opaque blocks and mode 7 (two RGBA subsets) on
// the others; from effort 2 modes 4 and 5 with each channel as the separate one. The best few are
// then refined, and the block of least squared error wins. Guarantees, at every effort: a uniform
// block decodes exactly; a block whose 16 alphas are 255 decodes with alpha 255. Deterministic and
// single-threaded: callers encode pages in parallel.
#include <cstdint>

namespace tessera::blocks {

struct Bc7Options {
    // Search effort, 0 (fastest) .. 3 (slowest); values outside are clamped. Measured per thread
    // on smooth terrain-like content: effort 0 ~80 000 blocks/s, 1 ~35 000, 2 ~14 000, 3 ~5 500
    // (a 4096^2 page at effort 2: ~75 s), each level 0.05-0.8 dB better than the one below.
    int effort = 2;
    // Weight the error of R, G and B by their share of luma (0.30, 0.59, 0.11) rather than equally:
    // for colour that people look at. Off for data (normals, masks) and to maximise RGB PSNR.
    bool perceptual = false;
};

// One block: `rgba` 16 texels RGBA8, row-major; `out` 16 bytes.
void encode_bc7_block(const std::uint8_t rgba[64], std::uint8_t out[16], const Bc7Options& opt = {});
// A page of size x size texels (size a multiple of 4) into size * size bytes of blocks.
void encode_bc7(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out, const Bc7Options& opt = {});

// One block into 16 RGBA8 texels, row-major. Mode 8 (a first byte of 0, reserved) decodes to
// transparent black, as the specification says.
void decode_bc7_block(const std::uint8_t in[16], std::uint8_t rgba[64]);
// A page of size x size texels (size a multiple of 4) from size * size bytes of blocks.
void decode_bc7(const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba);

}  // namespace tessera::blocks
