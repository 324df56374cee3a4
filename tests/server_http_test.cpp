// Integration tests of `tessera serve` over HTTP: a real server process on loopback, spoken to
// over plain sockets.
#include <gtest/gtest.h>
#include <sys/syscall.h>
#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/x509.h>
#include <zlib.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "prometheus_text.hpp"
#include "server_process.hpp"
#include "tessera/storage/codec.hpp"
#include "tessera/storage/store_reader.hpp"

namespace {

using namespace std::chrono_literals;
using tessera::test::HttpConnection;
using tessera::test::http_get;
using tessera::test::ScratchDir;
using tessera::test::ServerProcess;
namespace fs = std::filesystem;

class ServerHttp : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        dir_ = new ScratchDir();
        store_ = dir_->file("terrain.tsr");
        auto r = tessera::test::run_tessera("build procedural:terrain:2000 --quiet -o " + store_);
        ASSERT_EQ(r.exit_code, 0) << r.out;
    }
    static void TearDownTestSuite() { delete dir_; }
    static ScratchDir* dir_;
    static std::string store_;
    ScratchDir dir;
};
ScratchDir* ServerHttp::dir_ = nullptr;
std::string ServerHttp::store_;

std::string hex16(std::uint64_t v) {
    char b[17];
    std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(v));
    return b;
}

TEST_F(ServerHttp, TilesWithEtagAnd304) {
    ServerProcess srv({"--store", store_}, dir.file("log"), "", true);
    ASSERT_TRUE(srv.running()) << srv.log();
    auto reader = tessera::storage::StoreReader::open(store_);
    ASSERT_TRUE(reader.ok());
    auto tile = (*reader)->read_tile({1, 2, 1});
    ASSERT_TRUE(tile.ok());
    HttpConnection c(srv.http_port());
    auto r = c.get("/v1/stores/terrain/tiles/1/2/1");
    ASSERT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(r.headers["content-type"], "image/jpeg");
    EXPECT_EQ(r.body, std::string(tile->bytes.begin(), tile->bytes.end()));
    const std::string etag = r.headers["etag"];
    EXPECT_EQ(etag, "\"" + hex16((*reader)->info().store_id) + "-" + hex16(tile->checksum) + "\"");
    EXPECT_NE(r.headers["cache-control"].find("max-age="), std::string::npos);
    // Same connection (keep-alive): revalidation.
    auto r304 = c.get("/v1/stores/terrain/tiles/1/2/1", {"If-None-Match: " + etag});
    EXPECT_EQ(r304.status, 304);
    EXPECT_TRUE(r304.body.empty());
    EXPECT_EQ(r304.headers["etag"], etag);
    auto other = c.get("/v1/stores/terrain/tiles/1/2/1", {"If-None-Match: \"0000000000000000-0000000000000000\""});
    EXPECT_EQ(other.status, 200);
    // A versioned URL is immutable.
    auto pinned = c.get("/v1/stores/terrain/tiles/1/2/1?v=" + hex16((*reader)->info().store_id));
    EXPECT_EQ(pinned.status, 200);
    EXPECT_NE(pinned.headers["cache-control"].find("immutable"), std::string::npos);
    EXPECT_EQ(c.get("/v1/stores/terrain/tiles/1/2/1?v=0123456789abcdef").status, 404);
    // HEAD: headers only.
    auto head = c.get("/v1/stores/terrain/tiles/1/2/1", {}, "HEAD");
    EXPECT_EQ(head.status, 200);
    EXPECT_EQ(head.headers["content-length"], std::to_string(tile->bytes.size()));
}

// The kernel's slice of each of a process's threads, by thread name, from /proc (se.slice, ns;
// -1 where the kernel does not print one).
std::multimap<std::string, long long> thread_slices(pid_t pid) {
    std::multimap<std::string, long long> out;
    for (const auto& e : fs::directory_iterator("/proc/" + std::to_string(pid) + "/task")) {
        std::ifstream comm(e.path() / "comm");
        std::string name, line;
        std::getline(comm, name);
        long long slice = -1;
        std::ifstream sched(e.path() / "sched");
        while (std::getline(sched, line))
            if (line.rfind("se.slice", 0) == 0) slice = std::stoll(line.substr(line.find(':') + 1));
        out.emplace(name, slice);
    }
    return out;
}

// The same, once `count` threads named `name` are there (a thread names itself as it starts).
std::multimap<std::string, long long> thread_slices_once(pid_t pid, const std::string& name, std::size_t count) {
    auto threads = thread_slices(pid);
    for (int i = 0; i < 100 && threads.count(name) < count; ++i) {
        std::this_thread::sleep_for(50ms);
        threads = thread_slices(pid);
    }
    return threads;
}

// Whether this kernel keeps a fair thread's sched_runtime (EEVDF custom slices, Linux 6.12+),
// asked on a scratch thread with the raw system calls.
bool kernel_keeps_fair_slices() {
    struct Attr {
        std::uint32_t size, policy;
        std::uint64_t flags;
        std::int32_t nice;
        std::uint32_t priority;
        std::uint64_t runtime, deadline, period;
        std::uint32_t util_min, util_max;
    };
    bool kept = false;
    std::thread([&] {
        Attr a;
        std::memset(&a, 0, sizeof a);
        a.size = sizeof a;
        a.runtime = 250000;
        if (syscall(SYS_sched_setattr, 0, &a, 0) != 0) return;
        Attr b;
        std::memset(&b, 0, sizeof b);
        kept = syscall(SYS_sched_getattr, 0, &b, sizeof b, 0) == 0 && b.runtime == 250000;
    }).join();
    return kept;
}

TEST_F(ServerHttp, EventLoopsAskForTheConfiguredSlice) {
    // docs/server.md, "Short slices": the HTTP event loops ask for --http-loop-slice-us; the
    // executor's workers and everything else keep the kernel's default. On a kernel without
    // custom slices the server runs the same and no thread has the slice.
    const bool kernel = kernel_keeps_fair_slices();
    ServerProcess srv({"--store", store_, "--http-threads", "2", "--http-loop-slice-us", "300", "--render-concurrency", "1"},
                      dir.file("log"), "", true);
    ASSERT_TRUE(srv.running()) << srv.log();
    ASSERT_EQ(tessera::test::http_get(srv.http_port(), "/v1/stores/terrain/tiles/0/0/0").status, 200);
    const auto threads = thread_slices_once(srv.pid(), "http-loop", 2);
    ASSERT_EQ(threads.count("http-loop"), 2u);
    ASSERT_EQ(threads.count("work-render"), 1u);
    ASSERT_GE(threads.count("work-read"), 1u);
    for (const auto& [name, slice] : threads) {
        if (name == "http-loop" && kernel)
            EXPECT_EQ(slice, 300000) << name;
        else
            EXPECT_NE(slice, 300000) << name << (kernel ? " took the loops' slice" : ": this kernel keeps no slices");
    }

    ServerProcess plain({"--store", store_, "--http-threads", "1", "--http-loop-slice-us", "0"}, dir.file("log2"), "", true);
    ASSERT_TRUE(plain.running()) << plain.log();
    const auto defaults = thread_slices_once(plain.pid(), "http-loop", 1);
    ASSERT_EQ(defaults.count("http-loop"), 1u);
    ASSERT_GE(defaults.count("work-read"), 1u);
    const long long loop = defaults.find("http-loop")->second;
    const long long read = defaults.find("work-read")->second;
    EXPECT_EQ(loop, read) << "with 0 the loop keeps the kernel's default slice";

    const auto bad = tessera::test::run_tessera("serve --store " + store_ + " --http-loop-slice-us 50");
    EXPECT_NE(bad.exit_code, 0);
    EXPECT_NE(bad.out.find("--http-loop-slice-us must be 0 or 100..100000"), std::string::npos) << bad.out;
}

TEST_F(ServerHttp, PngIsTheDecodedTile) {
    ServerProcess srv({"--store", store_}, dir.file("log"), "", true);
    ASSERT_TRUE(srv.running()) << srv.log();
    auto reader = tessera::storage::StoreReader::open(store_);
    ASSERT_TRUE(reader.ok());
    const auto& info = (*reader)->info();
    auto tile = (*reader)->read_tile({0, 3, 2});
    ASSERT_TRUE(tile.ok());
    std::vector<std::uint8_t> texels;
    ASSERT_TRUE(tessera::storage::decode_tile(info, *tile, texels).ok());
    auto r = http_get(srv.http_port(), "/v1/stores/terrain/tiles/0/3/2?format=png");
    ASSERT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(r.headers["content-type"], "image/png");
    ASSERT_GT(r.body.size(), 33u);
    EXPECT_EQ(r.body.substr(1, 3), "PNG");
    // Walk the chunks, inflate IDAT, undo the row filters (Sub or None), compare texels.
    std::string idat;
    std::uint32_t w = 0, h = 0;
    for (std::size_t p = 8; p + 12 <= r.body.size();) {
        auto be32 = [&](std::size_t o) {
            return (std::uint32_t(std::uint8_t(r.body[o])) << 24) | (std::uint32_t(std::uint8_t(r.body[o + 1])) << 16) |
                   (std::uint32_t(std::uint8_t(r.body[o + 2])) << 8) | std::uint32_t(std::uint8_t(r.body[o + 3]));
        };
        const std::uint32_t len = be32(p);
        const std::string type = r.body.substr(p + 4, 4);
        if (type == "IHDR") {
            w = be32(p + 8);
            h = be32(p + 12);
        }
        if (type == "IDAT") idat += r.body.substr(p + 8, len);
        p += 12 + len;
    }
    ASSERT_EQ(w, info.tile_size());
    ASSERT_EQ(h, info.tile_size());
    const std::size_t pixel = info.channels, row = std::size_t(w) * pixel;
    std::vector<std::uint8_t> raw((row + 1) * h);
    uLongf raw_len = static_cast<uLongf>(raw.size());
    ASSERT_EQ(uncompress(raw.data(), &raw_len, reinterpret_cast<const Bytef*>(idat.data()), static_cast<uLong>(idat.size())), Z_OK);
    std::vector<std::uint8_t> got(row * h);
    for (std::uint32_t y = 0; y < h; ++y) {
        const std::uint8_t* src = raw.data() + y * (row + 1);
        std::uint8_t* dst = got.data() + y * row;
        ASSERT_TRUE(src[0] == 0 || src[0] == 1);
        for (std::size_t i = 0; i < row; ++i)
            dst[i] = static_cast<std::uint8_t>(src[1 + i] + (src[0] == 1 && i >= pixel ? dst[i - pixel] : 0));
    }
    EXPECT_EQ(got, texels);
}

TEST_F(ServerHttp, MetricsParseAsPrometheusText) {
    ServerProcess srv({"--store", store_}, dir.file("log"));
    ASSERT_TRUE(srv.running()) << srv.log();
    for (int i = 0; i < 5; ++i) EXPECT_EQ(http_get(srv.http_port(), "/v1/stores/terrain/tiles/2/0/" + std::to_string(i % 2)).status, 200);
    EXPECT_EQ(http_get(srv.http_port(), "/v1/stores/nope/tiles/0/0/0").status, 404);
    auto r = http_get(srv.http_port(), "/metrics");
    ASSERT_EQ(r.status, 200);
    EXPECT_NE(r.headers["content-type"].find("text/plain; version=0.0.4"), std::string::npos);
    auto parsed = tessera::test::parse_prometheus_text(r.body);
    ASSERT_TRUE(parsed.ok()) << parsed.error << "\n" << r.body;
    // Requests, tiles, bytes, latency histograms, queue depths, cache hit ratio, per store.
    for (const char* family : {"tessera_http_requests_total", "tessera_http_request_duration_seconds",
                               "tessera_tiles_served_total", "tessera_http_response_bytes_total",
                               "tessera_grpc_tile_latency_seconds", "tessera_queue_pending", "tessera_cache_hit_ratio",
                               "tessera_store_data_loss_total", "tessera_stores", "tessera_tiles_sent_total"})
        EXPECT_TRUE(parsed.types.count(family)) << family << " missing";
    double tiles = 0;
    for (const auto& s : parsed.samples)
        if (s.name == "tessera_tiles_served_total" && s.labels.count("store") && s.labels.at("store") == "terrain")
            tiles += s.value;
    EXPECT_EQ(tiles, 5);
}

TEST_F(ServerHttp, BadRequestsGetClearStatuses) {
    ServerProcess srv({"--store", store_, "--max-header", "2048"}, dir.file("log"), "", true);
    ASSERT_TRUE(srv.running()) << srv.log();
    const std::vector<std::pair<std::string, int>> cases{
        {"/v1/stores/terrain/tiles/0/0/0", 200},
        {"/v1/stores/nope/tiles/0/0/0", 404},
        {"/v1/stores/terrain/tiles/99/0/0", 404},
        {"/v1/stores/terrain/tiles/0/99999/0", 404},
        {"/v1/stores/terrain/tiles/0/-1/0", 400},
        {"/v1/stores/terrain/tiles/0/x/0", 400},
        {"/v1/stores/terrain/tiles/0/99999999999999999999/0", 400},
        {"/v1/stores/terrain/tiles/0/0", 400},
        {"/v1/stores/terrain/tiles/0/0/0/0", 400},
        {"/v1/stores/../etc/passwd", 400},
        {"/v1/stores/%2e%2e/tiles/0/0/0", 400},
        {"/v1/stores/a%2Fb/tiles/0/0/0", 400},
        {"/v1/stores/terrain/tiles/0/0/0?format=gif", 400},
        {"/v1/stores/terrain/tiles/0/0/0?evil=1", 400},
        {"/nothing-here", 404},
        {"/v1/stores/terrain", 200},
        {"/v1/stores", 200},
        {"/healthz", 200},
        {"/readyz", 200},
    };
    HttpConnection c(srv.http_port());
    for (const auto& [target, status] : cases) {
        auto r = c.get(target);
        EXPECT_EQ(r.status, status) << target << ": " << r.body;
        if (status >= 400) {
            EXPECT_FALSE(r.body.empty()) << target;
            EXPECT_LT(r.body.size(), 400u) << target;
        }
    }
    EXPECT_EQ(c.get("/v1/stores", {}, "POST").status, 405);
    // A head over --max-header, and garbage instead of HTTP: errors, and the server lives on.
    {
        HttpConnection big(srv.http_port());
        auto r = big.get("/healthz", {"X-Filler: " + std::string(4000, 'a')});
        EXPECT_TRUE(r.status == 431 || r.status == 400) << r.status;
    }
    {
        HttpConnection junk(srv.http_port());
        junk.send_raw("\x16\x03\x01 this is not HTTP\r\n\r\n");
        auto r = junk.read_reply();
        EXPECT_EQ(r.status, 400);
    }
    EXPECT_EQ(http_get(srv.http_port(), "/healthz").status, 200);
}

TEST_F(ServerHttp, TooManyConnectionsGet503) {
    ServerProcess srv({"--store", store_, "--max-connections", "4"}, dir.file("log"), "", true);
    ASSERT_TRUE(srv.running()) << srv.log();
    std::vector<std::unique_ptr<HttpConnection>> held;
    for (int i = 0; i < 4; ++i) {
        held.push_back(std::make_unique<HttpConnection>(srv.http_port()));
        ASSERT_EQ(held.back()->get("/healthz").status, 200);
    }
    const long rss_before = srv.rss_kib();
    for (int i = 0; i < 50; ++i) {
        HttpConnection extra(srv.http_port());
        auto r = extra.get("/v1/stores/terrain/tiles/0/0/0");
        EXPECT_EQ(r.status, 503);
        if (r.status == 503) {
            EXPECT_FALSE(r.headers["retry-after"].empty());
        }
    }
    EXPECT_LT(srv.rss_kib() - rss_before, 32 * 1024);
    // The admitted connections are still served.
    for (auto& c : held) EXPECT_EQ(c->get("/v1/stores/terrain/tiles/0/0/0").status, 200);
    held.clear();
    std::this_thread::sleep_for(200ms);
    EXPECT_EQ(http_get(srv.http_port(), "/healthz").status, 200);
}

TEST_F(ServerHttp, AuthAndCorruptTiles) {
    const std::string path = dir.file("broken.tsr");
    fs::copy_file(store_, path);
    std::uint64_t offset = 0;
    {
        auto reader = tessera::storage::StoreReader::open(path);
        ASSERT_TRUE(reader.ok());
        auto loc = (*reader)->locate({0, 2, 2});
        ASSERT_TRUE(loc.ok());
        offset = loc->offset + 100;
    }
    auto bytes = tessera::test::read_file(path);
    bytes[offset] ^= 0xFF;
    tessera::test::write_file(path, bytes);
    tessera::test::write_file(dir.file("token"), {'t', 'o', 'k'});
    ServerProcess srv({"--store", path, "--auth-token-file", dir.file("token")}, dir.file("log"), "", true);
    ASSERT_TRUE(srv.running()) << srv.log();
    EXPECT_EQ(http_get(srv.http_port(), "/healthz").status, 200);
    EXPECT_EQ(http_get(srv.http_port(), "/readyz").status, 200);
    auto unauth = http_get(srv.http_port(), "/v1/stores/broken/tiles/0/0/0");
    EXPECT_EQ(unauth.status, 401);
    EXPECT_NE(unauth.headers["www-authenticate"].find("Bearer"), std::string::npos);
    EXPECT_EQ(http_get(srv.http_port(), "/metrics").status, 401);
    EXPECT_EQ(http_get(srv.http_port(), "/v1/stores/broken/tiles/0/0/0", {"Authorization: Bearer nope"}).status, 401);
    EXPECT_EQ(http_get(srv.http_port(), "/v1/stores/broken/tiles/0/0/0", {"Authorization: Bearer tok"}).status, 200);
    for (int i = 0; i < 2; ++i) {
        auto bad = http_get(srv.http_port(), "/v1/stores/broken/tiles/0/2/2", {"Authorization: Bearer tok"});
        EXPECT_EQ(bad.status, 500);
        EXPECT_LT(bad.body.size(), 200u);
        auto png = http_get(srv.http_port(), "/v1/stores/broken/tiles/0/2/2?format=png", {"Authorization: Bearer tok"});
        EXPECT_EQ(png.status, 500);
    }
    EXPECT_NE(srv.log().find("failed its checksum"), std::string::npos);
}

TEST_F(ServerHttp, SigtermStopsAcceptingAndExitsZero) {
    ServerProcess srv({"--store", store_}, dir.file("log"), "", true);
    ASSERT_TRUE(srv.running()) << srv.log();
    HttpConnection c(srv.http_port());
    ASSERT_EQ(c.get("/readyz").status, 200);
    srv.signal(SIGTERM);
    EXPECT_EQ(srv.wait_exit(15s), std::optional<int>(0)) << srv.log();
    HttpConnection after(srv.http_port());
    EXPECT_FALSE(after.connected() && after.get("/healthz").status == 200);
}

}  // namespace

// A rotated secret: SIGHUP rereads --auth-token-file; the old token is refused from then on, the
// new one accepted; a file that cannot be read keeps the token in force.
TEST_F(ServerHttp, SighupRereadsTheTokenFile) {
    const std::string token_file = dir.file("token");
    auto write_token = [&](const std::string& t) {
        std::ofstream f(token_file, std::ios::trunc);
        f << t << "\n";
    };
    write_token("first-secret");
    ServerProcess srv({"--store", store_, "--auth-token-file", token_file, "--watch-interval", "0"}, dir.file("server.log"), "");
    ASSERT_TRUE(srv.running()) << srv.log();
    const std::string tile = "/v1/stores/terrain/tiles/0/0/0";
    auto status_with = [&](const std::string& t) { return http_get(srv.http_port(), tile, {"Authorization: Bearer " + t}).status; };
    EXPECT_EQ(status_with("first-secret"), 200);
    EXPECT_EQ(status_with("second-secret"), 401);
    write_token("second-secret");
    srv.signal(SIGHUP);
    // The reload is asynchronous to this test: wait for it (10 s at most).
    for (int i = 0; i < 200 && status_with("second-secret") != 200; ++i) std::this_thread::sleep_for(50ms);
    EXPECT_EQ(status_with("second-secret"), 200);
    EXPECT_EQ(status_with("first-secret"), 401);
    // An unreadable token file: the server keeps the second secret and says so.
    fs::remove(token_file);
    srv.signal(SIGHUP);
    for (int i = 0; i < 200 && srv.log().find("auth token not reloaded") == std::string::npos; ++i) std::this_thread::sleep_for(50ms);
    EXPECT_NE(srv.log().find("auth token not reloaded"), std::string::npos) << srv.log();
    EXPECT_EQ(status_with("second-secret"), 200);
    // That line is the log's own: JSON with ts, its quotes escaped (the path holds none here,
    // the message does).
    std::istringstream lines(srv.log());
    for (std::string line; std::getline(lines, line);) {
        if (line.find("auth token not reloaded") == std::string::npos) continue;
        const auto j = nlohmann::json::parse(line, nullptr, false);
        ASSERT_FALSE(j.is_discarded()) << line;
        EXPECT_TRUE(j.contains("ts") && j.contains("error")) << line;
    }
}

// SIGHUP does not reapply --config; when the file changed since the start, the log says so at
// the reload and names the keys that changed, leaving out those the command line sets (it wins).
TEST_F(ServerHttp, SighupSaysAChangedConfigFileIsNotReread) {
    const std::string config = dir.file("tessera.conf");
    auto write_config = [&](const std::string& text) {
        std::ofstream f(config, std::ios::trunc);
        f << text;
    };
    write_config("cache-size = \"64MiB\"\nrequest-timeout = 4000\nmax-connections = 100\n");
    ServerProcess srv({"--store", store_, "--config", config, "--request-timeout", "3000", "--watch-interval", "0"},
                      dir.file("server.log"), "");
    ASSERT_TRUE(srv.running()) << srv.log();
    auto count = [&](const std::string& text) { return srv.log_count(text); };
    auto reload = [&] {
        const std::size_t before = count("\"msg\":\"reload\"");
        srv.signal(SIGHUP);
        for (int i = 0; i < 200 && count("\"msg\":\"reload\"") == before; ++i) std::this_thread::sleep_for(50ms);
        ASSERT_EQ(count("\"msg\":\"reload\""), before + 1) << srv.log();
    };
    reload();  // the file as it was: nothing to say
    EXPECT_EQ(count("config file changed"), 0u) << srv.log();

    // Changed, added, removed, and two the command line sets (request-timeout, and http, which
    // ServerProcess gives and the file did not have at the start).
    write_config("cache-size = \"32MiB\"\nrequest-timeout = 9000\nmax-header = \"16KiB\"\nhttp = \"127.0.0.1:1\"\n");
    reload();
    ASSERT_EQ(count("config file changed"), 1u) << srv.log();
    std::istringstream lines(srv.log());
    for (std::string line; std::getline(lines, line);) {
        if (line.find("config file changed") == std::string::npos) continue;
        const auto j = nlohmann::json::parse(line, nullptr, false);
        ASSERT_FALSE(j.is_discarded()) << line;
        EXPECT_EQ(j.value("level", ""), "warn") << line;
        EXPECT_EQ(j.value("keys", ""), "cache-size,max-header,max-connections") << line;
    }

    // A key no option has: a restart would fail, and the reload says so with the line.
    write_config("cache-size = \"32MiB\"\nbogus = 1\n");
    reload();
    EXPECT_EQ(count("a restart would refuse it"), 1u) << srv.log();
    EXPECT_NE(srv.log().find("tessera.conf:2: unknown option 'bogus'"), std::string::npos) << srv.log();

    // A file that no longer parses: said, and the server goes on.
    write_config("cache-size = \"32MiB\n");
    reload();
    EXPECT_EQ(count("config file unreadable at reload"), 1u) << srv.log();
    EXPECT_NE(srv.log().find("tessera.conf:1: unclosed quote"), std::string::npos) << srv.log();
    EXPECT_EQ(http_get(srv.http_port(), "/v1/stores/terrain/tiles/0/0/0").status, 200);
}

// A self-signed certificate for 127.0.0.1 (an EC key) valid from `from_days` to `to_days` days
// from now, written as PEM files.
void write_certificate(const std::string& cert_path, const std::string& key_path, long from_days, long to_days) {
    EVP_PKEY* key = EVP_EC_gen("P-256");
    ASSERT_NE(key, nullptr);
    X509* x = X509_new();
    X509_set_version(x, 2);
    ASN1_INTEGER_set(X509_get_serialNumber(x), 1);
    X509_gmtime_adj(X509_getm_notBefore(x), from_days * 86400);
    X509_gmtime_adj(X509_getm_notAfter(x), to_days * 86400);
    X509_set_pubkey(x, key);
    X509_NAME* name = X509_get_subject_name(x);
    X509_NAME_add_entry_by_txt(name, "CN", MBSTRING_ASC, reinterpret_cast<const unsigned char*>("127.0.0.1"), -1, -1, 0);
    X509_set_issuer_name(x, name);
    ASSERT_GT(X509_sign(x, key, EVP_sha256()), 0);
    std::FILE* f = std::fopen(cert_path.c_str(), "w");
    ASSERT_TRUE(f && PEM_write_X509(f, x) == 1);
    std::fclose(f);
    f = std::fopen(key_path.c_str(), "w");
    ASSERT_TRUE(f && PEM_write_PrivateKey(f, key, nullptr, nullptr, 0, nullptr, nullptr) == 1);
    std::fclose(f);
    X509_free(x);
    EVP_PKEY_free(key);
}

// A certificate past its end (or before its start) is served, since a clock may be wrong, but
// said to be out of date at start and at every reload: TLS clients refuse it, and it was taken up
// without a word.
TEST_F(ServerHttp, AnOutOfDateCertificateIsWarnedAbout) {
    const std::string cert = dir.file("c.pem"), key = dir.file("k.pem");
    write_certificate(cert, key, -30, -1);  // ended yesterday
    ServerProcess srv({"--store", store_, "--tls-cert", cert, "--tls-key", key, "--watch-interval", "0"}, dir.file("server.log"), "");
    ASSERT_TRUE(srv.running()) << srv.log();
    EXPECT_NE(srv.log().find("TLS certificate is out of date; clients will refuse it"), std::string::npos) << srv.log();
    EXPECT_NE(srv.log().find("expired on"), std::string::npos) << srv.log();
    // Renewed (valid from yesterday to tomorrow): reloaded, and no warning at that reload.
    write_certificate(cert, key, -1, 1);
    srv.signal(SIGHUP);
    for (int i = 0; i < 200 && srv.log().find("TLS certificate reloaded") == std::string::npos; ++i) std::this_thread::sleep_for(50ms);
    const std::string log = srv.log();
    ASSERT_NE(log.find("TLS certificate reloaded"), std::string::npos) << log;
    EXPECT_EQ(log.find("out of date", log.find("TLS certificate reloaded")), std::string::npos) << log;
    // One that starts next week: out of date again.
    write_certificate(cert, key, 7, 30);
    srv.signal(SIGHUP);
    for (int i = 0; i < 200 && srv.log().find("not valid before") == std::string::npos; ++i) std::this_thread::sleep_for(50ms);
    EXPECT_NE(srv.log().find("not valid before"), std::string::npos) << srv.log();
}

// A token in a query is never logged, however its key is spelled: "access%5Ftoken" is the token
// as the query parser reads it, and was logged in clear.
TEST_F(ServerHttp, QueryTokensAreNotLogged) {
    std::ofstream(dir.file("token")) << "query-secret\n";
    ServerProcess srv({"--store", store_, "--auth-token-file", dir.file("token"), "--log-level", "debug"}, dir.file("server.log"), "");
    ASSERT_TRUE(srv.running()) << srv.log();
    for (const std::string key : {"access_token", "access%5Ftoken", "%61ccess_token"})
        EXPECT_EQ(http_get(srv.http_port(), "/v1/stores/terrain/tiles/0/0/0?" + key + "=query-secret").status, 200) << key;
    for (int i = 0; i < 100 && srv.log().find("%61ccess_token") == std::string::npos; ++i) std::this_thread::sleep_for(50ms);
    EXPECT_NE(srv.log().find("%61ccess_token=REDACTED"), std::string::npos) << srv.log();
    EXPECT_EQ(srv.log().find("query-secret"), std::string::npos) << srv.log();
}
