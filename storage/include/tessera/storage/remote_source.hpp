#pragma once
// Stores in object storage or behind any HTTP server that answers range requests (as PMTiles
// readers use them): a ByteSource over `s3://BUCKET/KEY.tsr`, `https://HOST/PATH.tsr` or
// `http://...`, for StoreReader::open_source.
//
// - Every read is one range GET (the store reader already merges payloads adjacent in the file
//   into one read); at most `max_concurrency` requests per store at once.
// - Failures worth retrying (no connection, a timeout, 5xx, 408, 429) are retried with exponential
//   backoff and full jitter, `attempts` tries in all.
// - The object's ETag is its version: every GET carries If-Match (a strong ETag; with a weak one
//   or none, If-Unmodified-Since with its Last-Modified), and every answer's Content-Range total
//   must be the object's size, so bytes of a replaced object are never mixed with the old one's
//   (412 makes changed() true, and the server reopens the store as a new version).
// - S3: AWS Signature Version 4; credentials from AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY /
//   AWS_SESSION_TOKEN, else the shared credentials file (AWS_SHARED_CREDENTIALS_FILE or
//   ~/.aws/credentials, profile AWS_PROFILE or "default"), else anonymous; region AWS_REGION or
//   AWS_DEFAULT_REGION (default us-east-1); AWS_ENDPOINT_URL_S3 or AWS_ENDPOINT_URL for
//   S3-compatible services (MinIO, Ceph, s3rver), addressed path-style.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "tessera/result.hpp"
#include "tessera/storage/byte_source.hpp"

namespace tessera::storage {

struct RemoteOptions {
    unsigned max_concurrency = 8;                // requests in flight per store
    unsigned attempts = 4;                       // tries per read, the first included
    std::chrono::milliseconds timeout{10000};    // per request (connect, send, answer)
    std::chrono::milliseconds backoff{100};      // before the first retry; doubles each time, jittered
    // A whole read, every try and wait included: no read (and no request waiting on it) hangs
    // on a slow store for longer than this.
    std::chrono::milliseconds deadline{15000};
    std::string ca_file;                         // PEM roots for https ("": the system's)
};

// s3://, http:// or https://.
bool is_remote_location(std::string_view location);

// HEAD, then a source over the object. Errors name the location: not_found (404),
// invalid_argument (401/403, with a hint about credentials; a malformed location), io_error (no
// answer after the retries, or an answer that is not a range of the object).
Result<std::unique_ptr<ByteSource>> open_remote_source(const std::string& location, const RemoteOptions& options = {});

// The object's current version (its ETag, or its Last-Modified when it has none), by HEAD.
Result<std::string> remote_version(const std::string& location, const RemoteOptions& options = {});

// Totals over every remote source of the process, for metrics.
struct RemoteCounters {
    std::atomic<std::uint64_t> requests{0};  // HTTP requests sent (HEAD and GET, retries included)
    std::atomic<std::uint64_t> retries{0};   // of them, retries
    std::atomic<std::uint64_t> bytes{0};     // body bytes received by range GETs
    std::atomic<std::uint64_t> failures{0};  // reads that failed after every try
};
RemoteCounters& remote_counters();

}  // namespace tessera::storage
