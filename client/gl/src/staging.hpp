#pragma once
// The staging ring: one persistently mapped GL_PIXEL_UNPACK_BUFFER used as a byte ring, through
// which pages and page-table rectangles reach their textures (docs/client.md, "One frame, end to
// end", step 7). The CPU copies into the ring and issues glTextureSubImage2D from the buffer
// offset; the GPU reads it later.
//
// Regions are fenced in batches: close_batch() (once a frame, before the frame's draws) puts a
// fence after the uploads issued since the last one; a region is reused only once its batch's
// fence has signalled, which is polled (timeout 0), never waited on. When the ring has no room
// (the GPU is more than a ring's worth of uploads behind), allocate() answers nothing and the
// caller uploads straight from its own memory instead (GL copies client memory before the call
// returns, so the upload still happens, correctly and in order); direct_uploads counts those.
// Nothing in the render path waits on a fence.
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <span>

#include "gl_util.hpp"
#include "page_staging.hpp"

namespace tessera::client::gl::detail {

class StagingRing {
public:
    // bytes: the ring's size (the bound). 0: no ring (every upload is direct).
    explicit StagingRing(std::size_t bytes);
    ~StagingRing();
    StagingRing(const StagingRing&) = delete;
    StagingRing& operator=(const StagingRing&) = delete;

    bool ok() const { return bytes_ == 0 || map_ != nullptr; }
    // Offset of `n` free bytes aligned to `align` (a power of two), or nothing when the ring
    // has no room without waiting. The region belongs to the current batch.
    std::optional<std::size_t> allocate(std::size_t n, std::size_t align = 256);
    std::uint8_t* data() { return map_; }
    GLuint buffer() const { return buffer_.get(); }
    // Fences the current batch (if anything was allocated since the last call).
    void close_batch();
    // Frees the regions of batches whose fences have signalled (polled, never waited on).
    void retire();
    void wait_all();  // blocks; end of a run and tests

    // Uploads through the ring, or straight from the caller's memory when it has no room
    // (direct_uploads() counts those). A w x h rectangle of level 0 of `texture`:
    void upload_image(GLuint texture, GLint x, GLint y, GLsizei w, GLsizei h, GLenum format, GLenum type,
                      const void* data, std::size_t bytes);
    // A side x side square of compressed blocks into level `level` of `texture`:
    void upload_blocks(GLuint texture, GLint level, GLint x, GLint y, GLsizei side, GLenum internal_format,
                       std::span<const std::uint8_t> blocks);
    // `bytes` at `offset` of `buffer`, copied on the GPU in stream order with the draws:
    void upload_buffer(GLuint buffer, std::size_t offset, const void* data, std::size_t bytes);
    std::uint64_t direct_uploads() const { return direct_uploads_; }
    // Pixels that already lie in `pages` (lent to the runtime, written there by a transcoder) are
    // uploaded from where they are, not copied into the ring.
    void set_page_staging(const MappedPageStaging* pages) { pages_ = pages; }

    std::size_t capacity() const { return bytes_; }
    std::size_t in_use() const;  // bytes between the oldest live region and the head
    std::uint64_t batches_in_flight() const { return batches_.size(); }

private:
    struct Batch {
        std::size_t begin = 0, end = 0;  // [begin, end) of the ring (never wraps inside a batch)
        Fence fence;                     // pending until closed
        bool closed = false;
    };
    std::size_t bytes_ = 0;
    Buffer buffer_;
    std::uint8_t* map_ = nullptr;
    std::deque<Batch> batches_;  // oldest first; the last one may be open
    std::size_t head_ = 0;       // next free byte
    std::uint64_t direct_uploads_ = 0;
    const MappedPageStaging* pages_ = nullptr;

    // Where a pixel upload of `data` reads from: its copy in the ring, with the ring bound as the
    // unpack buffer, or `data` itself with none bound.
    const void* stage_pixels(const void* data, std::size_t bytes);
};

}  // namespace tessera::client::gl::detail
