#pragma once
// Errors as values at library boundaries; exceptions are used only inside the tools.
#include <cassert>
#include <string>
#include <utility>
#include <variant>

namespace tessera {

enum class Errc {
    invalid_argument,  // caller passed something out of contract (bad flag, bad key)
    not_found,         // file, store or tile that does not exist
    io_error,          // the OS refused a read/write
    corrupt,           // checksum mismatch, truncation, bad index: the bytes cannot be trusted
    unsupported,       // well-formed but not something we handle (format, version, sample type)
    out_of_range,      // key outside the store's geometry
    resource_exhausted,
    cancelled,
};

const char* errc_name(Errc code);

struct Error {
    Errc code;
    std::string message;
};

template <class T>
class [[nodiscard]] Result {
public:
    Result(T value) : v_(std::move(value)) {}  // NOLINT: implicit on purpose
    Result(Error error) : v_(std::move(error)) {}  // NOLINT

    bool ok() const { return v_.index() == 0; }
    explicit operator bool() const { return ok(); }

    T& value() & { assert(ok()); return std::get<0>(v_); }
    const T& value() const& { assert(ok()); return std::get<0>(v_); }
    T&& value() && { assert(ok()); return std::get<0>(std::move(v_)); }
    T* operator->() { return &value(); }
    const T* operator->() const { return &value(); }
    T& operator*() & { return value(); }
    const T& operator*() const& { return value(); }

    const Error& error() const { assert(!ok()); return std::get<1>(v_); }

private:
    std::variant<T, Error> v_;
};

class [[nodiscard]] Status {
public:
    Status() = default;
    Status(Error error) : error_(std::move(error)), ok_(false) {}  // NOLINT
    bool ok() const { return ok_; }
    explicit operator bool() const { return ok_; }
    const Error& error() const { assert(!ok_); return error_; }

private:
    Error error_{Errc::invalid_argument, {}};
    bool ok_ = true;
};

inline Error make_error(Errc code, std::string message) { return Error{code, std::move(message)}; }

}  // namespace tessera

// Propagate an error from an expression returning Status or Result<T>.
#define TESSERA_TRY(expr)                                   \
    do {                                                    \
        auto tessera_try_result_ = (expr);                  \
        if (!tessera_try_result_.ok()) return tessera_try_result_.error(); \
    } while (0)
