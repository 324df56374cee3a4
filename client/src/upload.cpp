#include "tessera/client/upload.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace tessera::client {

namespace {

// Heap order for std::*_heap (a max-heap): `a` goes after `b`.
bool goes_after(const ReadyPage& a, const ReadyPage& b) {
    if (a.priority != b.priority) return a.priority < b.priority;
    return a.ticket > b.ticket;
}

}  // namespace

UploadQueue::UploadQueue(std::size_t max_pages_per_frame, std::size_t max_bytes_per_frame, std::size_t capacity)
    : max_pages_(max_pages_per_frame), max_bytes_(max_bytes_per_frame), capacity_(capacity) {
    heap_.reserve(std::min<std::size_t>(capacity_, 4096));
}

bool UploadQueue::push(ReadyPage&& page) {
    if (heap_.size() >= capacity_) return false;
    if (std::isnan(page.priority)) page.priority = -std::numeric_limits<float>::infinity();  // keeps the order strict
    queued_bytes_ += page.bytes;
    heap_.push_back(std::move(page));
    std::push_heap(heap_.begin(), heap_.end(), goes_after);
    return true;
}

std::size_t UploadQueue::take_frame(std::vector<ReadyPage>& out) {
    std::size_t taken = 0;
    std::size_t bytes = 0;
    while (!heap_.empty() && taken < max_pages_) {
        const ReadyPage& next = heap_.front();
        if (taken > 0 && bytes + next.bytes > max_bytes_) break;
        bytes += next.bytes;
        std::pop_heap(heap_.begin(), heap_.end(), goes_after);
        queued_bytes_ -= heap_.back().bytes;
        out.push_back(std::move(heap_.back()));
        heap_.pop_back();
        ++taken;
    }
    return taken;
}

std::size_t UploadQueue::drop_if(const std::function<bool(const ReadyPage&)>& stale) {
    const std::size_t before = heap_.size();
    std::erase_if(heap_, [&](const ReadyPage& p) {
        if (!stale(p)) return false;
        queued_bytes_ -= p.bytes;
        return true;
    });
    if (heap_.size() != before) std::make_heap(heap_.begin(), heap_.end(), goes_after);
    return before - heap_.size();
}

}  // namespace tessera::client
