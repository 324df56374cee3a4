#include "page_mips.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace tessera::client::gl::detail {

Status PageMipPass::init(GLuint atlas, GLenum format, std::uint32_t columns, std::uint32_t rows, std::uint32_t tile_size,
                         bool srgb) {
    if (tile_size % 2 != 0) return Error{Errc::invalid_argument, fmt::format("page mips: tile size {} is odd", tile_size)};
    auto p = build_program("page_mip.vert", "page_mip.frag", "");
    if (!p) return p.error();
    program_ = std::move(*p);
    glProgramUniform1i(program_.get(), glGetUniformLocation(program_.get(), "pm_pages"), 0);
    glProgramUniform2f(program_.get(), glGetUniformLocation(program_.get(), "pm_cell_ndc"), 2.0f / float(columns),
                       2.0f / float(rows));
    glProgramUniform1i(program_.get(), glGetUniformLocation(program_.get(), "pm_tile_size"), GLint(tile_size));
    columns_ = columns;
    rows_ = rows;
    atlas_ = atlas;
    tile_size_ = tile_size;
    width_ = columns * tile_size / 2;
    height_ = rows * tile_size / 2;
    srgb_ = srgb;
    GLuint view = 0;
    glGenTextures(1, &view);  // glTextureView needs a name never bound
    glTextureView(view, GL_TEXTURE_2D, atlas, format, 0, 1, 0, 1);
    level0_ = Texture(view);
    glTextureParameteri(view, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTextureParameteri(view, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glTextureParameteri(view, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTextureParameteri(view, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    fbo_ = make_framebuffer();
    glNamedFramebufferTexture(fbo_.get(), GL_COLOR_ATTACHMENT0, atlas, 1);
    if (glCheckNamedFramebufferStatus(fbo_.get(), GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
        return Error{Errc::unsupported, "page mips: the atlas's second level is not renderable"};
    vao_ = make_vertex_array();
    cells_ = make_buffer();
    const std::size_t cells = std::size_t(columns) * rows;
    glNamedBufferStorage(cells_.get(), GLsizeiptr(cells * sizeof(Cell)), nullptr, GL_DYNAMIC_STORAGE_BIT);
    pending_index_.assign(cells, -1);
    pending_.reserve(64);
    if (auto e = take_gl_errors("page mips"); !e.empty()) return Error{Errc::resource_exhausted, e};
    return Status();
}

void PageMipPass::mark(std::uint32_t column, std::uint32_t row, std::int32_t origin_x, std::int32_t origin_y,
                       std::uint32_t level_width, std::uint32_t level_height) {
    if (column >= columns_ || row >= rows_) return;
    constexpr std::uint32_t kMax = 1u << 30;
    const Cell c{std::int32_t(column), std::int32_t(row), origin_x, origin_y,
                 std::int32_t(std::min(level_width, kMax)), std::int32_t(std::min(level_height, kMax)), {0, 0}};
    std::int32_t& index = pending_index_[std::size_t(row) * columns_ + column];
    if (index >= 0) {
        pending_[std::size_t(index)] = c;
        return;
    }
    index = std::int32_t(pending_.size());
    pending_.push_back(c);
}

void PageMipPass::copy_from_parent(std::uint32_t column, std::uint32_t row, std::uint32_t parent_x, std::uint32_t parent_y) {
    if (column >= columns_ || row >= rows_) return;
    std::int32_t& index = pending_index_[std::size_t(row) * columns_ + column];
    if (index >= 0) {  // swap-remove its pending box
        const std::size_t i = std::size_t(index);
        if (i + 1 != pending_.size()) {
            pending_[i] = pending_.back();
            pending_index_[std::size_t(pending_[i].row) * columns_ + std::size_t(pending_[i].column)] = std::int32_t(i);
        }
        pending_.pop_back();
        index = -1;
    }
    const auto half = GLsizei(tile_size_ / 2);
    glCopyImageSubData(atlas_, GL_TEXTURE_2D, 0, GLint(parent_x), GLint(parent_y), 0, atlas_, GL_TEXTURE_2D, 1,
                       GLint(column * tile_size_ / 2), GLint(row * tile_size_ / 2), 0, half, half, 1);
    ++copied_;
}

void PageMipPass::run() {
    if (pending_.empty()) return;
    const auto n = GLsizei(pending_.size());
    glNamedBufferSubData(cells_.get(), 0, GLsizeiptr(pending_.size() * sizeof(Cell)), pending_.data());
    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, fbo_.get());
    glViewport(0, 0, GLsizei(width_), GLsizei(height_));
    glDisable(GL_DEPTH_TEST);
    glDisable(GL_CULL_FACE);
    glDisable(GL_BLEND);
    glDisable(GL_SCISSOR_TEST);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    if (srgb_) glEnable(GL_FRAMEBUFFER_SRGB);
    else glDisable(GL_FRAMEBUFFER_SRGB);
    glUseProgram(program_.get());
    glBindTextureUnit(0, level0_.get());
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, cells_.get());
    glBindVertexArray(vao_.get());
    glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, n);
    glBindVertexArray(0);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, 0);
    glUseProgram(0);
    glDisable(GL_FRAMEBUFFER_SRGB);
    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
    for (const Cell& c : pending_) pending_index_[std::size_t(c.row) * columns_ + std::size_t(c.column)] = -1;
    made_ += std::uint64_t(n);
    pending_.clear();
}

}  // namespace tessera::client::gl::detail
