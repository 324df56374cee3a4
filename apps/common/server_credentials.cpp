#include "server_credentials.hpp"

#include <fmt/format.h>

#include <fstream>
#include <sstream>

#include "failure.hpp"

namespace tessera::tools {
namespace {

std::string slurp(const std::string& path, const char* what) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Failure(fmt::format("cannot read {} '{}'", what, path));
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

}  // namespace

std::string tls_roots_pem(const std::string& ca_file) {
    const std::string pem = slurp(ca_file.empty() ? "/etc/ssl/certs/ca-certificates.crt" : ca_file, "the TLS roots");
    if (pem.find("-----BEGIN CERTIFICATE-----") == std::string::npos)
        throw Failure(fmt::format("'{}' holds no PEM certificate", ca_file.empty() ? "/etc/ssl/certs/ca-certificates.crt" : ca_file));
    return pem;
}

std::string bearer_token(const std::string& token, const std::string& token_file) {
    if (!token.empty() && !token_file.empty()) throw Failure("give --token or --token-file, not both", 2);
    if (token_file.empty()) return token;
    std::string t = slurp(token_file, "the token file");
    const auto nl = t.find_first_of("\r\n");
    if (nl != std::string::npos) t.resize(nl);
    const auto b = t.find_first_not_of(" \t"), e = t.find_last_not_of(" \t");
    t = b == std::string::npos ? std::string() : t.substr(b, e - b + 1);
    if (t.empty()) throw Failure(fmt::format("the token file '{}' is empty", token_file));
    return t;
}

}  // namespace tessera::tools
