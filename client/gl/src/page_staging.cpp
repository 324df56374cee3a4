#include "page_staging.hpp"

namespace tessera::client::gl::detail {

MappedPageStaging::MappedPageStaging(std::uint32_t buffers) : count_(buffers) {}

MappedPageStaging::~MappedPageStaging() {
    in_flight_.clear();
    for (auto& c : chunks_)
        if (c.map) glUnmapNamedBuffer(c.buffer.get());
}

bool MappedPageStaging::grow() {
    if (made() + kChunk > count_) return false;
    Chunk c;
    c.buffer = make_buffer();
    // Write-only, coherent: the transcoders never read their destination back (transcode.cpp
    // writes each byte of it once), so write-combined memory is fine.
    const GLbitfield flags = GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
    const auto bytes = static_cast<GLsizeiptr>(page_bytes_ * kChunk);
    glNamedBufferStorage(c.buffer.get(), bytes, nullptr, flags);
    c.map = static_cast<std::uint8_t*>(glMapNamedBufferRange(c.buffer.get(), 0, bytes, flags));
    if (!c.map) {
        count_ = made();  // no more mappings: what is made is all there is
        return false;
    }
    const auto first = made();
    chunks_.push_back(std::move(c));
    for (std::uint32_t i = kChunk; i-- > 0;) free_.push_back(first + i);
    return true;
}

StagingBuffer MappedPageStaging::acquire(std::size_t bytes) {
    if (bytes == 0) return {};
    // 256-byte aligned pages: larger than any driver's unpack offset alignment.
    if (page_bytes_ == 0) page_bytes_ = (bytes + 255) & ~std::size_t(255);
    if (bytes > page_bytes_) return {};
    if (free_.empty()) retire();
    if (free_.empty() && !grow()) return {};
    const std::uint32_t id = free_.back();
    free_.pop_back();
    ++lent_;
    std::uint8_t* at = chunks_[id / kChunk].map + std::size_t(id % kChunk) * page_bytes_;
    return StagingBuffer{id, {at, bytes}};
}

void MappedPageStaging::release(std::uint32_t id) {
    if (id >= made() || lent_ == 0) return;
    --lent_;
    returned_.push_back(id);
}

void MappedPageStaging::close_frame() {
    if (!returned_.empty()) {
        Returned r;
        r.fence.insert();  // after every upload issued from them
        r.ids.swap(returned_);
        in_flight_.push_back(std::move(r));
    }
    retire();
}

void MappedPageStaging::retire() {
    while (!in_flight_.empty() && in_flight_.front().fence.poll()) {
        for (const auto id : in_flight_.front().ids) free_.push_back(id);
        in_flight_.pop_front();
    }
}

void MappedPageStaging::wait_all() {
    close_frame();
    for (auto& r : in_flight_) {
        r.fence.wait();
        for (const auto id : r.ids) free_.push_back(id);
    }
    in_flight_.clear();
}

std::optional<MappedPageStaging::Where> MappedPageStaging::locate(const void* data, std::size_t bytes) const {
    const auto* p = static_cast<const std::uint8_t*>(data);
    const std::size_t chunk_bytes = page_bytes_ * kChunk;
    for (const auto& c : chunks_)
        if (p >= c.map && bytes <= chunk_bytes && std::size_t(p - c.map) <= chunk_bytes - bytes)
            return Where{c.buffer.get(), std::size_t(p - c.map)};
    return std::nullopt;
}

}  // namespace tessera::client::gl::detail
