#include "staging.hpp"

#include <cstring>

namespace tessera::client::gl::detail {

StagingRing::StagingRing(std::size_t bytes) : bytes_(bytes) {
    if (bytes_ == 0) return;
    buffer_ = make_buffer();
    const GLbitfield flags = GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
    glNamedBufferStorage(buffer_.get(), static_cast<GLsizeiptr>(bytes_), nullptr, flags);
    map_ = static_cast<std::uint8_t*>(glMapNamedBufferRange(buffer_.get(), 0, static_cast<GLsizeiptr>(bytes_), flags));
}

StagingRing::~StagingRing() {
    batches_.clear();
    if (map_) glUnmapNamedBuffer(buffer_.get());
}

std::size_t StagingRing::in_use() const {
    if (batches_.empty()) return 0;
    const std::size_t tail = batches_.front().begin;
    return head_ >= tail ? head_ - tail : bytes_ - tail + head_;
}

void StagingRing::retire() {
    while (!batches_.empty() && batches_.front().closed && batches_.front().fence.poll()) batches_.pop_front();
    if (batches_.empty()) head_ = 0;
}

std::optional<std::size_t> StagingRing::allocate(std::size_t n, std::size_t align) {
    if (!map_ || n == 0 || n > bytes_) return std::nullopt;
    retire();
    const auto aligned = [&](std::size_t x) { return (x + align - 1) & ~(align - 1); };
    std::size_t at = aligned(head_);
    if (!batches_.empty()) {
        const std::size_t tail = batches_.front().begin;
        if (head_ > tail) {
            // Live bytes in [tail, head): room after head, else wrap to 0 (room before tail).
            if (at + n > bytes_) {
                if (n > tail) return std::nullopt;
                at = 0;
            }
        } else {
            // Wrapped (or exactly full): live bytes in [tail, end) and [0, head): room in [head, tail).
            if (at + n > tail) return std::nullopt;
        }
    } else if (at + n > bytes_) {
        at = 0;
    }
    // Extend the open batch when contiguous, else close it and open a new one.
    if (batches_.empty() || batches_.back().closed || batches_.back().end != head_ || at < head_) {
        if (!batches_.empty() && !batches_.back().closed) {
            batches_.back().fence.insert();
            batches_.back().closed = true;
        }
        Batch b;
        b.begin = at;
        b.end = at;
        batches_.push_back(std::move(b));
    }
    batches_.back().end = at + n;
    head_ = at + n;
    return at;
}

void StagingRing::close_batch() {
    if (!batches_.empty() && !batches_.back().closed) {
        batches_.back().fence.insert();
        batches_.back().closed = true;
    }
}

void StagingRing::wait_all() {
    close_batch();
    for (auto& b : batches_) b.fence.wait();
    batches_.clear();
    head_ = 0;
}

const void* StagingRing::stage_pixels(const void* data, std::size_t bytes) {
    if (const auto lent = pages_ ? pages_->locate(data, bytes) : std::nullopt) {
        glBindBuffer(GL_PIXEL_UNPACK_BUFFER, lent->buffer);
        return reinterpret_cast<const void*>(lent->offset);
    }
    if (auto off = allocate(bytes)) {
        std::memcpy(map_ + *off, data, bytes);
        glBindBuffer(GL_PIXEL_UNPACK_BUFFER, buffer_.get());
        return reinterpret_cast<const void*>(*off);
    }
    ++direct_uploads_;
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
    return data;
}

void StagingRing::upload_image(GLuint texture, GLint x, GLint y, GLsizei w, GLsizei h, GLenum format, GLenum type,
                               const void* data, std::size_t bytes) {
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
    glTextureSubImage2D(texture, 0, x, y, w, h, format, type, stage_pixels(data, bytes));
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
}

void StagingRing::upload_blocks(GLuint texture, GLint level, GLint x, GLint y, GLsizei side, GLenum internal_format,
                                std::span<const std::uint8_t> blocks) {
    const auto bytes = static_cast<GLsizei>(blocks.size());
    glCompressedTextureSubImage2D(texture, level, x, y, side, side, internal_format, bytes,
                                  stage_pixels(blocks.data(), blocks.size()));
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
}

void StagingRing::upload_buffer(GLuint buffer, std::size_t offset, const void* data, std::size_t bytes) {
    if (auto off = allocate(bytes, 4)) {
        std::memcpy(map_ + *off, data, bytes);
        glCopyNamedBufferSubData(buffer_.get(), buffer, GLintptr(*off), GLintptr(offset), GLsizeiptr(bytes));
    } else {
        ++direct_uploads_;
        glNamedBufferSubData(buffer, GLintptr(offset), GLsizeiptr(bytes), data);
    }
}

}  // namespace tessera::client::gl::detail
