#pragma once
// AWS Signature Version 4 for S3 requests without a body (GET, HEAD): the Authorization header
// from the method, the canonical URI, the headers to sign, the credentials and the time. Exposed
// for the tests, which check it against AWS's own published example.
#include <map>
#include <string>

namespace tessera::storage::remote {

struct S3Credentials {
    std::string access_key, secret_key, session_token;  // session_token: "" unless temporary
};

// SHA-256 of nothing: the payload hash of a request without a body.
inline constexpr const char* kEmptyPayloadSha256 = "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855";

// `headers`: every header to sign, names lower case (host, x-amz-date, x-amz-content-sha256 at
// least). `uri`: the path as sent (already percent-encoded). amz_date: YYYYMMDDTHHMMSSZ.
std::string sigv4_authorization(const std::string& method, const std::string& uri, const std::string& query,
                                const std::map<std::string, std::string>& headers, const std::string& payload_sha256,
                                const S3Credentials& credentials, const std::string& region, const std::string& service,
                                const std::string& amz_date);

// RFC 3986 percent-encoding of a path (unreserved characters and '/' kept).
std::string uri_encode_path(const std::string& path);

}  // namespace tessera::storage::remote
