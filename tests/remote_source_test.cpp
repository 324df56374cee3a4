// Remote stores' pieces that need no server: the S3 Signature V4 signer against AWS's published
// example, location parsing, and the errors of an unreachable origin (the servers are in
// remote_store_test.py: s3rver, nginx, a flaky origin).
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "remote/http_client.hpp"
#include "remote/s3_sign.hpp"
#include "tessera/storage/remote_source.hpp"

using namespace tessera;
using namespace tessera::storage;

// docs.aws.amazon.com/AmazonS3/latest/API/sig-v4-header-based-auth.html, "Example: GET Object".
TEST(S3Signature, MatchesAwsPublishedGetObjectExample) {
    const remote::S3Credentials c{"AKIAIOSFODNN7EXAMPLE", "wJalrXUtnFEMI/K7MDENG/bPxRfiCYEXAMPLEKEY", ""};
    const std::map<std::string, std::string> headers{{"host", "examplebucket.s3.amazonaws.com"},
                                                     {"range", "bytes=0-9"},
                                                     {"x-amz-content-sha256", remote::kEmptyPayloadSha256},
                                                     {"x-amz-date", "20130524T000000Z"}};
    EXPECT_EQ(remote::sigv4_authorization("GET", "/test.txt", "", headers, remote::kEmptyPayloadSha256, c, "us-east-1", "s3",
                                          "20130524T000000Z"),
              "AWS4-HMAC-SHA256 Credential=AKIAIOSFODNN7EXAMPLE/20130524/us-east-1/s3/aws4_request, "
              "SignedHeaders=host;range;x-amz-content-sha256;x-amz-date, "
              "Signature=f0e8bdb87c964420e857bd35b5d6ed310bd44f0170aba48dd91039c6036bdb41");
    // One character of the secret changes the signature.
    const remote::S3Credentials other{c.access_key, "xJalrXUtnFEMI/K7MDENG/bPxRfiCYEXAMPLEKEY", ""};
    EXPECT_EQ(remote::sigv4_authorization("GET", "/test.txt", "", headers, remote::kEmptyPayloadSha256, other, "us-east-1", "s3",
                                          "20130524T000000Z")
                  .find("f0e8bdb8"),
              std::string::npos);
    EXPECT_EQ(remote::uri_encode_path("/maps/a b+c/x~y.tsr"), "/maps/a%20b%2Bc/x~y.tsr");
}

TEST(RemoteSource, LocationsAreCheckedBeforeAnyRequest) {
    EXPECT_TRUE(is_remote_location("s3://b/k.tsr"));
    EXPECT_TRUE(is_remote_location("https://h/p.tsr"));
    EXPECT_FALSE(is_remote_location("ftp://h/p.tsr"));
    EXPECT_FALSE(is_remote_location("/srv/p.tsr"));
    for (const char* bad : {"s3://bucket", "s3://bucket/", "s3:///key", "http://", "http://user@host/x.tsr", "http://host:port/x.tsr",
                            "http://[::1/x.tsr", "http://host:99999/x.tsr", "http://host:0/x.tsr", "http://[::1]x/x.tsr",
                            "http://a:b:80/x.tsr"}) {
        auto r = open_remote_source(bad);
        ASSERT_FALSE(r.ok()) << bad;
        EXPECT_EQ(r.error().code, Errc::invalid_argument) << bad << ": " << r.error().message;
    }
}

TEST(RemoteSource, AnUnreachableOriginFailsAfterItsRetries) {
    RemoteOptions o;
    o.attempts = 3;
    o.backoff = std::chrono::milliseconds(5);
    o.timeout = std::chrono::milliseconds(2000);
    const auto before = remote_counters().retries.load();
    // Port 1 on loopback: connection refused at once.
    auto r = open_remote_source("http://127.0.0.1:1/store.tsr", o);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::io_error);
    EXPECT_NE(r.error().message.find("127.0.0.1:1"), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find("after 3 tries"), std::string::npos) << r.error().message;
    EXPECT_EQ(remote_counters().retries.load() - before, 2u);
}

// An origin that accepts connections and never answers: the read gives up at its deadline,
// not after attempts x timeout (here 4 x 10 s).
TEST(RemoteSource, ASilentOriginFailsAtTheReadsDeadline) {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    ASSERT_GE(fd, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    ASSERT_EQ(::listen(fd, 16), 0);  // the kernel completes connections; nobody reads them
    socklen_t len = sizeof addr;
    ASSERT_EQ(::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len), 0);
    RemoteOptions o;
    o.attempts = 4;
    o.timeout = std::chrono::milliseconds(10000);
    o.backoff = std::chrono::milliseconds(50);
    o.deadline = std::chrono::milliseconds(600);
    const auto t0 = std::chrono::steady_clock::now();
    auto r = open_remote_source("http://127.0.0.1:" + std::to_string(ntohs(addr.sin_port)) + "/store.tsr", o);
    const auto took = std::chrono::steady_clock::now() - t0;
    ::close(fd);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, Errc::io_error);
    EXPECT_NE(r.error().message.find("600 ms deadline"), std::string::npos) << r.error().message;
    EXPECT_LT(took, std::chrono::milliseconds(2000));
    EXPECT_GE(took, std::chrono::milliseconds(550));
}

// A DNS server that takes seconds to answer: requests wait for the lookup only until their own
// deadline, however many of them there are, and only one lookup runs at a time. Its answer is
// kept, so the requests after it go straight to connecting.
TEST(RemoteHttpClient, ASlowLookupHoldsNoRequestPastItsDeadline) {
    using namespace std::chrono;
    std::atomic<int> lookups{0}, running{0}, most_running{0};
    auto slow = [&](const std::string&, const std::string&) -> Result<std::vector<std::string>> {
        ++lookups;
        const int now = ++running;
        for (int seen = most_running.load(); now > seen && !most_running.compare_exchange_weak(seen, now);) {
        }
        std::this_thread::sleep_for(milliseconds(1500));
        --running;
        return std::vector<std::string>{"127.0.0.1"};
    };
    // Port 1 on loopback: nothing listens, so a request that gets past the lookup is refused.
    remote::HttpClient client({false, "tiles.example", "1"}, 8, milliseconds(10000), "", slow);
    std::vector<std::thread> threads;
    std::vector<std::string> errors(8);
    std::vector<milliseconds> took(8);
    for (int i = 0; i < 8; ++i)
        threads.emplace_back([&, i] {
            const auto t0 = steady_clock::now();
            auto r = client.request("GET", "/s.tsr", {}, 1 << 20, t0 + milliseconds(300));
            took[i] = duration_cast<milliseconds>(steady_clock::now() - t0);
            errors[i] = r.ok() ? "ok" : r.error().message;
        });
    for (auto& t : threads) t.join();
    for (int i = 0; i < 8; ++i) {
        EXPECT_LT(took[i], milliseconds(800)) << i;
        EXPECT_NE(errors[i].find("cannot resolve tiles.example before the read's deadline"), std::string::npos) << errors[i];
    }
    EXPECT_EQ(most_running.load(), 1) << "one lookup at a time";
    // The lookup finishes on its own; its answer is then used at once. A refused connection makes
    // the next request look the host up again (it may have moved), without waiting for it: the
    // old answer serves meanwhile, and one lookup runs at a time.
    std::this_thread::sleep_for(milliseconds(1500));
    for (int i = 0; i < 3; ++i) {
        const auto t0 = steady_clock::now();
        auto r = client.request("GET", "/s.tsr", {}, 1 << 20, t0 + milliseconds(300));
        ASSERT_FALSE(r.ok());
        EXPECT_EQ(r.error().message.find("resolve"), std::string::npos) << "refused by the port, not the lookup: " << r.error().message;
        EXPECT_LT(steady_clock::now() - t0, milliseconds(200)) << "waited for a lookup";
    }
    for (int i = 0; i < 100 && lookups.load() < 2; ++i) std::this_thread::sleep_for(milliseconds(5));  // its thread starting
    EXPECT_EQ(lookups.load(), 2);
    EXPECT_EQ(most_running.load(), 1);
    while (running.load() > 0) std::this_thread::sleep_for(milliseconds(10));  // the lookup holds references to this test
}

namespace {

// An origin on loopback that answers every request with what `answer` makes of its head (keep-
// alive: several requests a connection, one at a time). A thread per connection; stopped and
// joined by the destructor.
class CannedOrigin {
public:
    explicit CannedOrigin(std::function<std::string(const std::string& head)> answer) : answer_(std::move(answer)) {
        fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
        sockaddr_in addr{};
        addr.sin_family = AF_INET;
        addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
        EXPECT_EQ(::listen(fd_, 16), 0);
        socklen_t len = sizeof addr;
        ::getsockname(fd_, reinterpret_cast<sockaddr*>(&addr), &len);
        port_ = ntohs(addr.sin_port);
        accepter_ = std::thread([this] {
            for (;;) {
                const int c = ::accept(fd_, nullptr, nullptr);
                if (c < 0) return;
                std::lock_guard lock(mu_);
                conns_.push_back(c);
                threads_.emplace_back([this, c] { serve(c); });
            }
        });
    }
    ~CannedOrigin() {
        ::shutdown(fd_, SHUT_RDWR);
        ::close(fd_);
        accepter_.join();
        std::lock_guard lock(mu_);
        for (int c : conns_) ::shutdown(c, SHUT_RDWR);
        for (auto& t : threads_) t.join();
        for (int c : conns_) ::close(c);
    }
    std::string url(const std::string& path) const { return "http://127.0.0.1:" + std::to_string(port_) + path; }

private:
    void serve(int c) {
        std::string in;
        char buf[4096];
        for (;;) {
            const auto end = in.find("\r\n\r\n");
            if (end != std::string::npos) {
                const std::string out = answer_(in.substr(0, end + 4));
                in.erase(0, end + 4);
                if (::send(c, out.data(), out.size(), MSG_NOSIGNAL) != ssize_t(out.size())) return;
                continue;
            }
            const ssize_t n = ::recv(c, buf, sizeof buf, 0);
            if (n <= 0) return;
            in.append(buf, std::size_t(n));
        }
    }

    std::function<std::string(const std::string&)> answer_;
    int fd_ = -1;
    unsigned short port_ = 0;
    std::thread accepter_;
    std::mutex mu_;
    std::vector<int> conns_;
    std::vector<std::thread> threads_;
};

// "bytes=A-B" of a request head's Range header: {A, B}.
std::pair<std::uint64_t, std::uint64_t> range_of(const std::string& head) {
    const auto at = head.find("bytes=");
    if (at == std::string::npos) return {0, 0};
    const auto dash = head.find('-', at);
    return {std::stoull(head.substr(at + 6, dash - at - 6)), std::stoull(head.substr(dash + 1))};
}

}  // namespace

// A 206 must be the range asked for (RFC 9110 14.4: Content-Range names it). A proxy or cache
// that answers another range, or leaves Content-Range out, gives bytes that would be taken for
// the ones asked: an io_error, never the wrong bytes.
TEST(RemoteSource, A206OfAnotherRangeIsRefused) {
    const std::string object(1000, 'x');
    enum class Mode { right, shifted, no_header };
    std::atomic<Mode> mode{Mode::right};  // read by the origin's thread
    CannedOrigin origin([&](const std::string& head) {
        if (head.starts_with("HEAD"))
            return std::string("HTTP/1.1 200 OK\r\nContent-Length: 1000\r\nETag: \"v1\"\r\n\r\n");
        auto [a, b] = range_of(head);
        const std::string body = object.substr(a, b - a + 1);
        const Mode m = mode.load();
        const std::uint64_t from = m == Mode::shifted ? 0 : a;
        std::string r = "HTTP/1.1 206 Partial Content\r\nContent-Length: " + std::to_string(body.size()) + "\r\n";
        if (m != Mode::no_header)
            r += "Content-Range: bytes " + std::to_string(from) + "-" + std::to_string(from + body.size() - 1) + "/1000\r\n";
        return r + "\r\n" + body;
    });
    RemoteOptions o;
    o.attempts = 1;
    auto src = open_remote_source(origin.url("/s.tsr"), o);
    ASSERT_TRUE(src.ok()) << src.error().message;
    std::vector<std::uint8_t> buf(28);
    ASSERT_TRUE((*src)->read(100, 28, buf.data()).ok());
    mode = Mode::shifted;
    auto shifted = (*src)->read(100, 28, buf.data());
    ASSERT_FALSE(shifted.ok());
    EXPECT_EQ(shifted.error().code, Errc::io_error);
    EXPECT_NE(shifted.error().message.find("Content-Range bytes 0-27/1000"), std::string::npos) << shifted.error().message;
    mode = Mode::no_header;
    auto bare = (*src)->read(100, 28, buf.data());
    ASSERT_FALSE(bare.ok());
    EXPECT_NE(bare.error().message.find("without Content-Range"), std::string::npos) << bare.error().message;
}

// A signed URL's query (an Azure SAS, a CDN token) is a credential: errors and logs show the URL
// without it.
TEST(RemoteSource, ErrorsDoNotShowTheUrlsQuery) {
    CannedOrigin origin([](const std::string&) { return std::string("HTTP/1.1 403 Forbidden\r\nContent-Length: 0\r\n\r\n"); });
    RemoteOptions o;
    o.attempts = 1;
    auto r = open_remote_source(origin.url("/s.tsr?sv=2024&sig=SECRET"), o);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().message.find("SECRET"), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find("/s.tsr?..."), std::string::npos) << r.error().message;
}
