#pragma once
// The memory pages are decoded into, lent to the runtime (PageStaging in upload.hpp): page-sized
// buffers in persistently mapped GL_PIXEL_UNPACK_BUFFERs of kChunk pages each, made as the
// runtime's demand grows, up to a bound. A transcode thread writes a page
// straight into the buffer, and upload_page issues glTextureSubImage2D from its offset: the
// page's texels are not copied again on the CPU (through the staging ring they were, once more).
//
// A buffer given back is reused only once the GPU has read it: the buffers given back during a
// frame are fenced together when the next frame starts (close_frame), and return to the free list
// when that fence has signalled (polled, never waited on). When none is free, acquire answers
// nothing and the runtime decodes into its own memory (the staging ring then copies it). What the
// bound must cover: the pages the runtime stages (PageLoader::kStagingBuffers, 64) and the
// uploads of the frames the GPU has not finished yet.
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <vector>

#include "gl_util.hpp"
#include "tessera/client/upload.hpp"

namespace tessera::client::gl::detail {

class MappedPageStaging final : public PageStaging {
public:
    static constexpr std::uint32_t kChunk = 32;
    // `buffers` pages at most; each page as large as the first acquire asked (a later, larger
    // request gets nothing).
    explicit MappedPageStaging(std::uint32_t buffers);
    ~MappedPageStaging();
    MappedPageStaging(const MappedPageStaging&) = delete;
    MappedPageStaging& operator=(const MappedPageStaging&) = delete;

    StagingBuffer acquire(std::size_t bytes) override;
    void release(std::uint32_t id) override;

    // Fences what was given back since the last call; frees what earlier fences cover.
    void close_frame();
    void wait_all();  // blocks: the end of a run and tests

    // The buffer and offset `bytes` at `data` lie at, when they lie in lent memory.
    struct Where {
        GLuint buffer = 0;
        std::size_t offset = 0;
    };
    std::optional<Where> locate(const void* data, std::size_t bytes) const;
    std::uint32_t lent() const { return lent_; }     // buffers the runtime holds now
    std::uint32_t made() const { return std::uint32_t(chunks_.size()) * kChunk; }

private:
    bool grow();
    void retire();

    struct Returned {
        Fence fence;
        std::vector<std::uint32_t> ids;
    };
    struct Chunk {
        Buffer buffer;
        std::uint8_t* map = nullptr;
    };
    std::uint32_t count_;
    std::size_t page_bytes_ = 0;  // 0: no acquire yet
    std::vector<Chunk> chunks_;
    std::vector<std::uint32_t> free_;
    std::vector<std::uint32_t> returned_;  // given back this frame, not fenced yet
    std::deque<Returned> in_flight_;       // oldest first
    std::uint32_t lent_ = 0;
};

}  // namespace tessera::client::gl::detail
