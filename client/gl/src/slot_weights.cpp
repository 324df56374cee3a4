#include "slot_weights.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace tessera::client::gl::detail {

Status SlotWeights::init(std::uint32_t columns, std::uint32_t rows) {
    columns_ = std::max<std::uint32_t>(columns, 1);
    rows_ = std::max<std::uint32_t>(rows, 1);
    weights_.assign(std::size_t(columns_) * rows_, 255);
    texture_ = make_texture(GL_TEXTURE_2D);
    glTextureStorage2D(texture_.get(), 1, GL_R8, GLsizei(columns_), GLsizei(rows_));
    glTextureParameteri(texture_.get(), GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTextureParameteri(texture_.get(), GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    const std::uint8_t full = 255;
    glClearTexImage(texture_.get(), 0, GL_RED, GL_UNSIGNED_BYTE, &full);
    if (auto e = take_gl_errors("blend weights"); !e.empty())
        return Error{Errc::resource_exhausted, fmt::format("renderer: {}x{} blend weights: {}", columns_, rows_, e)};
    return Status();
}

std::size_t SlotWeights::set(std::span<const SlotWeight> weights) {
    std::size_t ignored = 0;
    for (const SlotWeight& w : weights) {
        if (std::size_t(w.slot) >= weights_.size()) {
            ++ignored;
            continue;
        }
        std::uint8_t& cell = weights_[w.slot];
        if (cell == w.weight) continue;
        below_full_ += (w.weight < 255) - (cell < 255);
        cell = w.weight;
        first_row_ = std::min(first_row_, w.slot / columns_);
        last_row_ = std::max(last_row_, w.slot / columns_);
    }
    return ignored;
}

void SlotWeights::upload() {
    if (first_row_ > last_row_) return;
    // From client memory (a few rows of one byte per cell): no staging needed.
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
    glTextureSubImage2D(texture_.get(), 0, 0, GLint(first_row_), GLsizei(columns_), GLsizei(last_row_ - first_row_ + 1), GL_RED,
                        GL_UNSIGNED_BYTE, weights_.data() + std::size_t(first_row_) * columns_);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    first_row_ = ~0u;
    last_row_ = 0;
}

}  // namespace tessera::client::gl::detail
