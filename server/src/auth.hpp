#pragma once
// Bearer-token check shared by gRPC and HTTP. Constant-time in the token's length, so response
// timing does not leak how much of a guess was right.
#include <string_view>

namespace tessera::server {

// True when auth is off (empty token) or `authorization` is "Bearer <token>" (scheme
// case-insensitive, one or more spaces).
inline bool authorized(std::string_view authorization, std::string_view token) {
    if (token.empty()) return true;
    constexpr std::string_view scheme = "bearer";
    if (authorization.size() <= scheme.size()) return false;
    for (std::size_t i = 0; i < scheme.size(); ++i) {
        char c = authorization[i];
        if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
        if (c != scheme[i]) return false;
    }
    std::string_view rest = authorization.substr(scheme.size());
    if (rest.empty() || rest.front() != ' ') return false;
    while (!rest.empty() && rest.front() == ' ') rest.remove_prefix(1);
    unsigned diff = rest.size() == token.size() ? 0u : 1u;
    for (std::size_t i = 0; i < token.size(); ++i)
        diff |= static_cast<unsigned char>(token[i]) ^ static_cast<unsigned char>(i < rest.size() ? rest[i] : 0);
    return diff == 0;
}

}  // namespace tessera::server
