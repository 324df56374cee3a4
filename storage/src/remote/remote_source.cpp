// Remote stores (tessera/storage/remote_source.hpp): locations, S3 configuration, range reads
// with retries, versions.
#include "tessera/storage/remote_source.hpp"

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <mutex>
#include <random>
#include <thread>

#include "http_client.hpp"
#include "s3_sign.hpp"
#include "tessera/host_port.hpp"

namespace tessera::storage {

RemoteCounters& remote_counters() {
    static RemoteCounters c;
    return c;
}

bool is_remote_location(std::string_view location) {
    return location.starts_with("s3://") || location.starts_with("http://") || location.starts_with("https://");
}

namespace {

using remote::HttpClient;
using remote::without_query;
using remote::HttpResponse;
using remote::Origin;
using remote::S3Credentials;

std::string env(const char* name) {
    const char* v = std::getenv(name);
    return v ? std::string(v) : std::string();
}

// Where to send requests for a location, and how to sign them.
struct Target {
    Origin origin;
    std::string path;  // percent-encoded, from the root
    bool s3 = false;
    std::string region;
    S3Credentials credentials;  // empty access key: anonymous
};

Result<Origin> parse_origin(const std::string& url, std::string& rest) {
    Origin o;
    std::string_view v(url);
    if (v.starts_with("https://")) {
        o.tls = true;
        v.remove_prefix(8);
    } else if (v.starts_with("http://")) {
        v.remove_prefix(7);
    } else {
        return make_error(Errc::invalid_argument, "'" + without_query(url) + "' is not an http:// or https:// URL");
    }
    const std::size_t slash = v.find('/');
    std::string authority(v.substr(0, slash));
    rest = slash == std::string_view::npos ? "/" : std::string(v.substr(slash));
    if (authority.empty() || authority.find('@') != std::string::npos)
        return make_error(Errc::invalid_argument, "'" + without_query(url) + "': no host (user information is not supported)");
    const auto parts = split_host_port(authority);
    if (!parts || parts->host.empty() || (!parts->bracketed && parts->host.find(':') != std::string_view::npos))
        return make_error(Errc::invalid_argument, "'" + without_query(url) + "': bad host (an IPv6 address needs brackets)");
    o.host = std::string(parts->host);
    o.port = parts->port.empty() ? (o.tls ? "443" : "80") : std::string(parts->port);  // "HOST:" is the default port too
    if (const auto port = parse_port(o.port); !port || *port == 0)
        return make_error(Errc::invalid_argument, "'" + without_query(url) + "': bad port (1 to 65535)");
    return o;
}

// ~/.aws/credentials (or AWS_SHARED_CREDENTIALS_FILE), the profile's keys.
S3Credentials credentials_file() {
    S3Credentials c;
    std::string path = env("AWS_SHARED_CREDENTIALS_FILE");
    if (path.empty() && !env("HOME").empty()) path = env("HOME") + "/.aws/credentials";
    std::ifstream f(path);
    if (!f) return c;
    const std::string profile = env("AWS_PROFILE").empty() ? "default" : env("AWS_PROFILE");
    std::string line, section;
    auto trim = [](std::string s) {
        const auto b = s.find_first_not_of(" \t\r"), e = s.find_last_not_of(" \t\r");
        return b == std::string::npos ? std::string() : s.substr(b, e - b + 1);
    };
    while (std::getline(f, line)) {
        line = trim(line);
        if (line.empty() || line[0] == '#' || line[0] == ';') continue;
        if (line.front() == '[' && line.back() == ']') {
            section = trim(line.substr(1, line.size() - 2));
            continue;
        }
        if (section != profile) continue;
        const auto eq = line.find('=');
        if (eq == std::string::npos) continue;
        const std::string k = trim(line.substr(0, eq)), val = trim(line.substr(eq + 1));
        if (k == "aws_access_key_id") c.access_key = val;
        else if (k == "aws_secret_access_key") c.secret_key = val;
        else if (k == "aws_session_token") c.session_token = val;
    }
    return c;
}

Result<Target> resolve(const std::string& location) {
    Target t;
    if (!location.starts_with("s3://")) {
        std::string rest;
        auto o = parse_origin(location, rest);
        if (!o) return o.error();
        t.origin = *o;
        t.path = rest;
        return t;
    }
    const std::string bk = location.substr(5);
    const std::size_t slash = bk.find('/');
    if (slash == std::string::npos || slash == 0 || slash + 1 == bk.size())
        return make_error(Errc::invalid_argument, "'" + location + "' is not s3://BUCKET/KEY");
    const std::string bucket = bk.substr(0, slash), key = bk.substr(slash + 1);
    t.s3 = true;
    t.region = !env("AWS_REGION").empty() ? env("AWS_REGION") : !env("AWS_DEFAULT_REGION").empty() ? env("AWS_DEFAULT_REGION") : "us-east-1";
    t.credentials.access_key = env("AWS_ACCESS_KEY_ID");
    t.credentials.secret_key = env("AWS_SECRET_ACCESS_KEY");
    t.credentials.session_token = env("AWS_SESSION_TOKEN");
    if (t.credentials.access_key.empty() || t.credentials.secret_key.empty()) t.credentials = credentials_file();
    const std::string endpoint = !env("AWS_ENDPOINT_URL_S3").empty() ? env("AWS_ENDPOINT_URL_S3") : env("AWS_ENDPOINT_URL");
    if (!endpoint.empty()) {  // an S3-compatible service: path-style
        std::string rest;
        auto o = parse_origin(endpoint, rest);
        if (!o) return make_error(Errc::invalid_argument, "AWS_ENDPOINT_URL: " + o.error().message);
        t.origin = *o;
        std::string base = rest == "/" ? "" : rest;
        if (!base.empty() && base.back() == '/') base.pop_back();
        t.path = remote::uri_encode_path(base + "/" + bucket + "/" + key);
    } else if (bucket.find('.') == std::string::npos) {  // AWS, virtual-hosted
        t.origin = Origin{true, bucket + ".s3." + t.region + ".amazonaws.com", "443"};
        t.path = remote::uri_encode_path("/" + key);
    } else {  // dots in the name break the wildcard certificate: path-style
        t.origin = Origin{true, "s3." + t.region + ".amazonaws.com", "443"};
        t.path = remote::uri_encode_path("/" + bucket + "/" + key);
    }
    return t;
}

bool retryable(unsigned status) { return status == 408 || status == 429 || status >= 500; }

class RemoteSource final : public ByteSource {
public:
    RemoteSource(std::string location, Target target, const RemoteOptions& options)
        : location_(without_query(location)),
          target_(std::move(target)),
          options_(options),
          client_(target_.origin, options.max_concurrency, options.timeout, options.ca_file) {}

    // HEAD: size and version. Also the cheap version probe (remote_version).
    struct Head {
        std::uint64_t size = 0;
        std::string version;        // the ETag, else "modified " + Last-Modified
        std::string last_modified;  // "" when the origin sent none
    };
    Result<Head> head() const {
        auto r = send("HEAD", {}, 0);
        if (!r) return r.error();
        if (r->status != 200) return status_error(*r, "HEAD");
        const std::string length = r->header("content-length");
        std::uint64_t size = 0;
        try {
            size = std::stoull(length);
        } catch (...) {
            return make_error(Errc::io_error, location_ + ": HEAD gave no Content-Length");
        }
        Head h{size, r->header("etag"), r->header("last-modified")};
        if (h.version.empty()) h.version = "modified " + h.last_modified;
        return h;
    }

    Status open() {
        auto h = head();
        if (!h) return h.error();
        size_ = h->size;
        version_ = h->version;
        last_modified_ = h->last_modified;
        return {};
    }

    std::uint64_t size() const override { return size_; }
    std::string version() const override { return version_; }

    Status read(std::uint64_t offset, std::uint64_t length, std::uint8_t* dst) const override {
        if (length == 0) return {};
        if (offset > size_ || length > size_ - offset) return make_error(Errc::corrupt, location_ + ": read past the end of the object");
        std::vector<std::pair<std::string, std::string>> extra{
            {"range", "bytes=" + std::to_string(offset) + "-" + std::to_string(offset + length - 1)}};
        // Pin the version: If-Match with a strong ETag (a weak one never matches, RFC 9110), else
        // If-Unmodified-Since with the Last-Modified seen at open (a weak ETag's origin too); the
        // answer's total size is checked too, so a replaced object's bytes are never taken for the
        // old one's.
        if (!version_.empty() && version_.front() == '"') extra.emplace_back("if-match", version_);
        else if (!last_modified_.empty()) extra.emplace_back("if-unmodified-since", last_modified_);
        // Error answers carry small bodies (S3's XML): room for them beyond a short range.
        auto r = send("GET", extra, std::max<std::uint64_t>(length + 1, 64 * 1024));
        if (!r) {
            remote_counters().failures.fetch_add(1, std::memory_order_relaxed);
            return r.error();
        }
        if (r->status == 412) {  // If-Match failed: replaced since it was opened
            changed_.store(true);
            return make_error(Errc::io_error, location_ + ": the object changed since it was opened (412)");
        }
        if (r->status == 206 && r->body.size() == length) {
            // Content-Range: bytes A-B/TOTAL (RFC 9110 14.4: a 206 to one range must carry it).
            // The bytes must be the ones asked for (a proxy or cache that answers another range
            // gives bytes that would be taken for these), and another total is another object.
            const std::string cr = r->header("content-range");
            const std::string asked = "bytes " + std::to_string(offset) + "-" + std::to_string(offset + length - 1) + "/";
            const auto slash = cr.rfind('/');
            if (slash == std::string::npos || cr.compare(0, slash + 1, asked) != 0) {
                remote_counters().failures.fetch_add(1, std::memory_order_relaxed);
                return make_error(Errc::io_error, location_ + ": asked for " + asked.substr(0, asked.size() - 1) + ", the answer is " +
                                                      (cr.empty() ? std::string("a 206 without Content-Range") : "Content-Range " + cr));
            }
            if (cr.substr(slash + 1) != "*" && cr.substr(slash + 1) != std::to_string(size_)) {
                changed_.store(true);
                return make_error(Errc::io_error, location_ + ": the object changed since it was opened (now " + cr.substr(slash + 1) +
                                                      " bytes, was " + std::to_string(size_) + ")");
            }
            std::copy(r->body.begin(), r->body.end(), dst);
            return {};
        }
        if (r->status == 200 && r->body.size() == size_ && size_ <= length + 1) {  // a server that ignores ranges, small object
            std::copy_n(r->body.begin() + std::ptrdiff_t(offset), length, dst);
            return {};
        }
        remote_counters().failures.fetch_add(1, std::memory_order_relaxed);
        if (r->status != 206 && r->status != 200) return status_error(*r, "GET");
        return make_error(Errc::io_error, location_ + ": asked for " + std::to_string(length) + " bytes at " + std::to_string(offset) +
                                              ", got " + std::to_string(r->body.size()) + " (status " + std::to_string(r->status) + ")");
    }

    void cancel() const override { client_.cancel(); }

    bool changed() const override {
        if (changed_.load()) return true;
        // After a failure: has the object been replaced? One HEAD at most per second.
        const auto now = std::chrono::steady_clock::now();
        {
            std::lock_guard lock(probe_mutex_);
            if (now - last_probe_ < std::chrono::seconds(1)) return false;
            last_probe_ = now;
        }
        auto h = head();
        if (h && (h->version != version_ || h->size != size_)) changed_.store(true);
        if (!h && h.error().code == Errc::not_found) changed_.store(true);  // deleted
        return changed_.load();
    }

private:
    Error status_error(const HttpResponse& r, const char* what) const {
        const std::string s = std::to_string(r.status);
        if (r.status == 404) return Error{Errc::not_found, location_ + ": no such object (" + what + " " + s + ")"};
        if (r.status == 401 || r.status == 403)
            return Error{Errc::invalid_argument,
                         location_ + ": access denied (" + what + " " + s + ")" +
                             (target_.s3 ? (target_.credentials.access_key.empty()
                                                ? "; no credentials: set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY or ~/.aws/credentials"
                                                : "; check the credentials, AWS_REGION and the bucket policy")
                                         : std::string())};
        return Error{Errc::io_error, location_ + ": " + what + " answered " + s};
    }

    // One request with retries (transport failures and retryable statuses), signed for S3.
    Result<HttpResponse> send(const std::string& method, const std::vector<std::pair<std::string, std::string>>& extra,
                              std::uint64_t max_body) const {
        thread_local std::mt19937_64 rng{std::random_device{}()};
        Result<HttpResponse> last = make_error(Errc::io_error, location_ + ": no attempt made");
        // The read's own deadline, or the request's it is made for when that comes first.
        const auto deadline = std::min(std::chrono::steady_clock::now() + options_.deadline, read_deadline());
        unsigned tries = 0;
        for (unsigned attempt = 0; attempt < std::max(1u, options_.attempts); ++attempt) {
            if (client_.cancelled()) break;
            if (attempt > 0) {
                // Full jitter: uniform in [0, backoff * 2^(attempt-1)]; no retry that the
                // deadline would cut short before it starts.
                const auto cap = options_.backoff * (1u << std::min(attempt - 1, 10u));
                std::uniform_int_distribution<long long> d(0, std::max<long long>(1, cap.count()));
                const auto pause = std::chrono::milliseconds(d(rng));
                if (std::chrono::steady_clock::now() + pause >= deadline) break;
                remote_counters().retries.fetch_add(1, std::memory_order_relaxed);
                std::this_thread::sleep_for(pause);
            }
            ++tries;
            auto headers = extra;
            if (target_.s3 && !target_.credentials.access_key.empty()) {
                const std::time_t now = std::time(nullptr);
                std::tm tm{};
                gmtime_r(&now, &tm);
                char amz[17];
                std::strftime(amz, sizeof amz, "%Y%m%dT%H%M%SZ", &tm);
                std::map<std::string, std::string> signed_headers{{"host", client_.host_header()},
                                                                  {"x-amz-content-sha256", remote::kEmptyPayloadSha256},
                                                                  {"x-amz-date", amz}};
                if (!target_.credentials.session_token.empty()) signed_headers["x-amz-security-token"] = target_.credentials.session_token;
                const std::string auth = remote::sigv4_authorization(method, target_.path, "", signed_headers, remote::kEmptyPayloadSha256,
                                                                     target_.credentials, target_.region, "s3", amz);
                for (const auto& [k, v] : signed_headers)
                    if (k != "host") headers.emplace_back(k, v);
                headers.emplace_back("authorization", auth);
            }
            remote_counters().requests.fetch_add(1, std::memory_order_relaxed);
            last = client_.request(method, target_.path, headers, max_body, deadline);
            if (!last && last.error().code == Errc::cancelled) return last.error();
            if (last && !retryable(last->status)) {
                if (method == "GET") remote_counters().bytes.fetch_add(last->body.size(), std::memory_order_relaxed);
                return last;
            }
        }
        if (last) return last;  // a retryable status every time: the caller reports it
        return make_error(Errc::io_error, last.error().message + " (after " + std::to_string(tries) + " tr" +
                                              (tries == 1 ? "y" : "ies") + ", within the read's " +
                                              std::to_string(options_.deadline.count()) + " ms deadline)");
    }

    std::string location_;  // as errors show it: without its query (it may hold a credential)
    Target target_;
    RemoteOptions options_;
    mutable HttpClient client_;
    std::uint64_t size_ = 0;
    std::string version_;
    std::string last_modified_;  // as seen at open ("" when the origin sent none)
    mutable std::atomic<bool> changed_{false};
    mutable std::mutex probe_mutex_;
    mutable std::chrono::steady_clock::time_point last_probe_{};
};

}  // namespace

Result<std::unique_ptr<ByteSource>> open_remote_source(const std::string& location, const RemoteOptions& options) {
    auto t = resolve(location);
    if (!t) return t.error();
    auto src = std::make_unique<RemoteSource>(location, std::move(*t), options);
    TESSERA_TRY(src->open());
    return std::unique_ptr<ByteSource>(std::move(src));
}

Result<std::string> remote_version(const std::string& location, const RemoteOptions& options) {
    auto t = resolve(location);
    if (!t) return t.error();
    RemoteOptions once = options;
    once.max_concurrency = 1;
    RemoteSource src(location, std::move(*t), once);
    auto h = src.head();
    if (!h) return h.error();
    return h->version;
}

}  // namespace tessera::storage
