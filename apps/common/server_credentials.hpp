#pragma once
// What a client of `tessera serve` (the viewer, the load tester) presents: TLS roots for grpcs://
// and a bearer token (docs/server.md, "Security"). Errors are tools::Failure naming the file.
#include <string>

namespace tessera::tools {

// PEM roots from `ca_file`, or the system's bundle when it is empty.
std::string tls_roots_pem(const std::string& ca_file);

// The bearer token: `token` as given, or the first line of `token_file` without surrounding white
// space (files keep secrets out of process listings). Both given, or an empty file: an error.
std::string bearer_token(const std::string& token, const std::string& token_file);

}  // namespace tessera::tools
