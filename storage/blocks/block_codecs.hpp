#pragma once
// The block encoders and decoders behind blocks.hpp's encode_page / decode_page.
#include <cstdint>

#include "tessera/blocks/blocks.hpp"

namespace tessera::blocks {

// `rgba`: size x size RGBA8 texels (size a multiple of 4). BC1 and BC4 write size*size/2 bytes,
// BC5 size*size.
void encode_bc1(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out, Effort effort);
void encode_bc4(const std::uint8_t* rgba, std::uint32_t size, unsigned channel, std::uint8_t* out);
void encode_bc5(const std::uint8_t* rgba, std::uint32_t size, unsigned c0, unsigned c1, std::uint8_t* out);

void decode_bc1(const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba);
void decode_bc4(const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba);
void decode_bc5(const std::uint8_t* blocks, std::uint32_t size, std::uint8_t* rgba);

}  // namespace tessera::blocks
