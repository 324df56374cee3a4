#pragma once
// An HTTP response header's value. Every header of a tile answer (an ETag of two hashes, a
// Cache-Control with max-age, hashes in hex) fits in kInline characters, which are held in place:
// building a tile's answer allocates nothing per header (a std::string keeps 15 in place, and
// these values are 16 to 40 long). Longer values go to the heap.
#include <algorithm>
#include <cstddef>
#include <cstring>
#include <ostream>
#include <string>
#include <string_view>

namespace tessera::server {

class HeaderValue {
public:
    static constexpr std::size_t kInline = 46;

    HeaderValue() = default;
    HeaderValue(std::string_view s) { assign(s); }          // NOLINT: implicit, as a string's
    HeaderValue(const char* s) : HeaderValue(std::string_view(s)) {}  // NOLINT
    HeaderValue(const std::string& s) : HeaderValue(std::string_view(s)) {}  // NOLINT
    HeaderValue(std::string&& s) {  // NOLINT
        if (s.size() <= kInline) assign(s);
        else heap_ = std::move(s), size_ = kOnHeap;
    }
    HeaderValue(const HeaderValue& o) { assign(o.view()); }
    HeaderValue& operator=(const HeaderValue& o) {
        if (this != &o) assign(o.view());
        return *this;
    }
    HeaderValue(HeaderValue&& o) noexcept { take(o); }
    HeaderValue& operator=(HeaderValue&& o) noexcept {
        if (this != &o) take(o);
        return *this;
    }

    std::string_view view() const { return size_ == kOnHeap ? std::string_view(heap_) : std::string_view(inline_, size_); }
    operator std::string_view() const { return view(); }  // NOLINT: reads as a string does
    std::string str() const { return std::string(view()); }
    std::size_t size() const { return view().size(); }
    bool empty() const { return view().empty(); }

    friend bool operator==(const HeaderValue& a, std::string_view b) { return a.view() == b; }
    friend std::ostream& operator<<(std::ostream& os, const HeaderValue& v) { return os << v.view(); }

private:
    static constexpr unsigned char kOnHeap = 0xFF;
    void assign(std::string_view s) {
        if (s.size() <= kInline) {
            std::memcpy(inline_, s.data(), s.size());
            size_ = static_cast<unsigned char>(s.size());
            heap_.clear();
        } else {
            heap_.assign(s);
            size_ = kOnHeap;
        }
    }
    void take(HeaderValue& o) {
        if (o.size_ == kOnHeap) {
            heap_ = std::move(o.heap_);
            size_ = kOnHeap;
        } else {
            assign(o.view());
        }
    }

    unsigned char size_ = 0;  // characters in place, or kOnHeap
    char inline_[kInline];
    std::string heap_;
};

}  // namespace tessera::server
