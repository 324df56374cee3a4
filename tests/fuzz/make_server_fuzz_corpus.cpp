// make_server_fuzz_corpus DIR: writes server_request_fuzz's seeds into DIR: HTTP requests for
// every route (tiles of each kind, the corrupted tile, ETag revalidation, version-pinned URLs,
// PNG, auth, malformed targets) and tile batches (valid, invalid, superseding, too large, over
// the pending limit, two viewers, raw records). The stores are written to a scratch directory
// first, exactly as the fuzzer writes them, for their versions and checksums.
#include <unistd.h>
#include <xxhash.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "server_fuzz_common.hpp"
#include "tessera.pb.h"

namespace {

using namespace tessera;
using namespace tessera::fuzz;

std::string hex16(std::uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return std::string(buf, 16);
}

struct Req {
    std::uint32_t store, level, x, y;
    float priority;
};

std::string batch(const std::vector<std::string>& stores, const std::vector<Req>& reqs, std::uint32_t deadline_ms = 0,
                  std::uint64_t frame = 0) {
    v1::TileBatch b;
    b.set_frame(frame);
    b.set_deadline_ms(deadline_ms);
    for (const auto& s : stores) b.add_stores(s);
    for (const Req& r : reqs) {
        auto* q = b.add_requests();
        q->set_store(r.store);
        q->set_level(r.level);
        q->set_x(r.x);
        q->set_y(r.y);
        q->set_priority(r.priority);
    }
    return b.SerializeAsString();
}

// Every tile of one level of a store, priorities descending from `top`.
std::vector<Req> level_tiles(const ExpectedStore& s, std::uint32_t store_index, std::uint32_t level, float top) {
    std::vector<Req> out;
    const auto& L = s.info.levels[level];
    for (std::uint32_t y = 0; y < L.tiles_y; ++y)
        for (std::uint32_t x = 0; x < L.tiles_x; ++x) out.push_back({store_index, level, x, y, top - float(out.size())});
    return out;
}

std::vector<Req> all_tiles(const ExpectedStore& s, std::uint32_t store_index) {
    std::vector<Req> out;
    for (std::uint32_t l = 0; l < s.info.level_count(); ++l)
        for (const Req& r : level_tiles(s, store_index, l, float(100 * (l + 1)))) out.push_back(r);
    return out;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: make_server_fuzz_corpus DIR\n");
        return 2;
    }
    const std::string out_dir = argv[1];
    std::string scratch = (std::filesystem::temp_directory_path() / "tessera-server-corpus-XXXXXX").string();
    if (!::mkdtemp(scratch.data())) {
        std::perror("mkdtemp");
        return 1;
    }
    std::vector<ExpectedStore> stores;
    const std::string err = write_server_fuzz_stores(scratch, stores);
    std::error_code ec;
    std::filesystem::remove_all(scratch, ec);
    if (!err.empty()) {
        std::fprintf(stderr, "make_server_fuzz_corpus: %s\n", err.c_str());
        return 1;
    }
    const ExpectedStore& a = stores[0];
    const ExpectedStore& b = stores[1];
    auto etag = [](const ExpectedStore& s, const tessera::TileKey& k, bool png = false) {
        const ExpectedTile* t = s.find(k);
        return "\"" + hex16(s.version) + "-" + hex16(XXH3_64bits(t->bytes.data(), t->bytes.size())) + (png ? "-png" : "") + "\"";
    };

    std::vector<std::pair<std::string, std::string>> seeds;
    auto add = [&](const std::string& name, std::string bytes) { seeds.emplace_back(name, std::move(bytes)); };
    const std::uint8_t plain = 0, authed = flag::auth_context, token = flag::auth_context | flag::valid_token;

    // ---- HTTP ----
    add("http-healthz", http_input(plain, "GET", "/healthz"));
    add("http-readyz-head", http_input(authed, "HEAD", "/readyz?x=1"));
    add("http-metrics", http_input(plain, "GET", "/metrics"));
    add("http-metrics-auth", http_input(authed, "GET", "/metrics", "Bearer t0k"));
    add("http-metrics-no-auth", http_input(authed, "GET", "/metrics", "Bearer t0x"));
    add("http-stores", http_input(plain, "GET", "/v1/stores"));
    add("http-store-a", http_input(plain, "GET", "/v1/stores/a"));
    add("http-store-b-auth", http_input(token, "HEAD", "/v1/stores/b"));
    add("http-store-nope", http_input(plain, "GET", "/v1/stores/nope"));
    add("http-store-dotdot", http_input(plain, "GET", "/v1/stores/..%2fb"));
    add("http-store-percent", http_input(plain, "GET", "/v1/stores/%61"));
    add("http-tile-a", http_input(plain, "GET", "/v1/stores/a/tiles/0/0/0"));
    add("http-tile-a-versioned", http_input(plain, "GET", "/v1/stores/a/tiles/1/2/1?v=" + hex16(a.version)));
    add("http-tile-a-old-version", http_input(plain, "GET", "/v1/stores/a/tiles/1/2/1?v=1234"));
    add("http-tile-a-uniform", http_input(plain, "GET", "/v1/stores/a/tiles/0/1/1"));
    add("http-tile-a-absent", http_input(plain, "GET", "/v1/stores/a/tiles/0/2/1"));
    add("http-tile-a-shared", http_input(token, "GET", "/v1/stores/a/tiles/0/4/3"));
    add("http-tile-a-coarsest-png", http_input(plain, "GET", "/v1/stores/a/tiles/3/0/0?format=png"));
    add("http-tile-a-uniform-png", http_input(plain, "HEAD", "/v1/stores/a/tiles/0/1/1?format=png&v=" + hex16(a.version)));
    add("http-tile-a-out-of-range", http_input(plain, "GET", "/v1/stores/a/tiles/0/6/0"));
    add("http-tile-a-bad-level", http_input(plain, "GET", "/v1/stores/a/tiles/9/0/0"));
    add("http-tile-a-leading-zero", http_input(plain, "GET", "/v1/stores/a/tiles/00/0/0"));
    add("http-tile-a-inm", http_input(plain, "GET", "/v1/stores/a/tiles/0/3/0", "", etag(a, {0, 3, 0})));
    add("http-tile-a-inm-weak-list", http_input(plain, "GET", "/v1/stores/a/tiles/0/3/0", "", "\"x\", W/" + etag(a, {0, 3, 0})));
    add("http-tile-a-inm-star", http_input(token, "HEAD", "/v1/stores/a/tiles/2/0/0", "", "*"));
    add("http-tile-a-inm-png", http_input(plain, "GET", "/v1/stores/a/tiles/2/0/0?format=png", "", etag(a, {2, 0, 0}, true)));
    add("http-tile-b", http_input(plain, "GET", "/v1/stores/b/tiles/0/1/1"));
    add("http-tile-b-uniform", http_input(plain, "GET", "/v1/stores/b/tiles/0/1/0?format=png"));
    add("http-tile-b-corrupt", http_input(plain, "GET", "/v1/stores/b/tiles/0/0/0"));
    add("http-tile-b-corrupt-png", http_input(token, "GET", "/v1/stores/b/tiles/0/0/0?format=png"));
    add("http-tile-b-corrupt-inm", http_input(plain, "GET", "/v1/stores/b/tiles/0/0/0", "", etag(b, kCorruptKey)));
    add("http-tile-b-auth", http_input(authed, "GET", "/v1/stores/b/tiles/2/0/0", "bearer   t0k"));
    add("http-tile-b-wrong-token", http_input(authed, "GET", "/v1/stores/b/tiles/2/0/0", "Bearer t0kk"));
    add("http-post", http_input(plain, "POST", "/v1/stores/a/tiles/0/0/0"));
    add("http-query-twice", http_input(plain, "GET", "/v1/stores/a/tiles/0/0/0?format=png&format=png"));
    add("http-query-unknown", http_input(plain, "GET", "/v1/stores/a/tiles/0/0/0?q=%41"));
    add("http-dot-segment", http_input(plain, "GET", "/v1/stores/../a"));
    add("http-bad-char", http_input(plain, "GET", "/v1/stores/a b"));
    add("http-not-found", http_input(plain, "GET", "/favicon.ico", "", "", "image/png"));
    // The browser routes: Deep Zoom, IIIF, XYZ, the viewer, preflights and query tokens.
    add("http-dzi-info", http_input(plain, "GET", "/dzi/a.dzi"));
    add("http-dzi-tile", http_input(plain, "GET", "/dzi/a_files/9/1_1.jpg"));
    add("http-dzi-edge-png", http_input(plain, "GET", "/dzi/b_files/8/0_0.png?v=" + hex16(b.version)));
    add("http-dzi-small", http_input(token, "HEAD", "/dzi/a_files/0/0_0.jpg"));
    add("http-iiif-info", http_input(plain, "GET", "/iiif/a/info.json", "", "", "application/ld+json"));
    add("http-iiif-base", http_input(plain, "GET", "/iiif/b"));
    add("http-iiif-tile", http_input(plain, "GET", "/iiif/a/0,0,60,60/60,60/0/default.jpg"));
    add("http-iiif-pct", http_input(plain, "GET", "/iiif/a/pct:10.5,0,50,50/^!300,200/!90/gray.png"));
    add("http-iiif-square", http_input(authed, "GET", "/iiif/b/square/max/180/color.jpg?access_token=t0k"));
    add("http-iiif-bad", http_input(plain, "GET", "/iiif/a/0,0,0,9/max/45/bitonal.gif"));
    add("http-xyz", http_input(plain, "GET", "/xyz/a/2/1/0.png"));
    add("http-xyz-edge", http_input(plain, "GET", "/xyz/b/3/9/9.jpg"));
    add("http-view", http_input(plain, "GET", "/view/a"));
    add("http-index", http_input(plain, "GET", "/"));
    add("http-static", http_input(plain, "GET", "/static/openseadragon/images/home_rest.png"));
    add("http-options", http_input(authed, "OPTIONS", "/iiif/a/info.json"));

    // ---- batches ----
    const std::vector<std::string> ab = {"a", "b"};
    const std::uint8_t one = 0, read_all = 7u << flag::reads_shift;
    auto nb = [](unsigned n) { return static_cast<std::uint8_t>((n - 1) << flag::batches_shift); };
    add("batch-a-level0", batch_input(one, {batch(ab, level_tiles(a, 0, 0, 50))}));
    add("batch-all-tiles", batch_input(one, {batch(ab, [&] {
                                              auto r = all_tiles(a, 0);
                                              for (const Req& q : all_tiles(b, 1)) r.push_back(q);
                                              return r;
                                          }())}));
    add("batch-b-corrupt-first", batch_input(authed, {batch({"b"}, {{0, 0, 0, 0, 9}, {0, 0, 1, 0, 1}, {0, 2, 0, 0, 0}})}));
    add("batch-invalid", batch_input(one, {batch({"a", "nope", "../x", "b"},
                                                 {{5, 0, 0, 0, 1},
                                                  {1, 0, 0, 0, 1},
                                                  {2, 0, 0, 0, 1},
                                                  {0, 0, 0, 0, std::numeric_limits<float>::quiet_NaN()},
                                                  {0, 0, 0, 0, std::numeric_limits<float>::infinity()},
                                                  {0, 7, 0, 0, 1},
                                                  {3, 0, 3, 0, 1},
                                                  {0, 0, 0, 0, 2},
                                                  {0, 0, 0, 0, 3},
                                                  {3, 0, 0, 0, 1}})}));
    add("batch-deadline", batch_input(one, {batch(ab, level_tiles(a, 0, 0, 1), 1)}));
    {
        auto first = level_tiles(a, 0, 0, 50);
        auto second = level_tiles(a, 0, 1, 70);
        for (std::size_t i = 0; i < first.size(); i += 3) second.push_back(first[i]);
        auto third = level_tiles(b, 1, 0, 5);
        third.push_back({0, 0, 0, 0, 1});
        add("batch-supersede", batch_input(nb(3), {batch(ab, first), batch(ab, second), batch(ab, third)}));
        add("batch-supersede-read-some", batch_input(nb(3) | (3u << flag::reads_shift),
                                                     {batch(ab, first), batch(ab, second), batch(ab, third)}));
        add("batch-supersede-read-all", batch_input(nb(2) | read_all, {batch(ab, first), batch(ab, first)}));
        add("batch-two-viewers", batch_input(nb(3) | flag::two_viewers | (1u << flag::reads_shift),
                                             {batch(ab, first), batch(ab, third), batch(ab, second)}));
        add("batch-pending-limit", batch_input(authed | nb(2) | flag::two_viewers, {batch(ab, first), batch(ab, all_tiles(b, 1))}));
    }
    {
        std::vector<Req> big;
        for (std::uint32_t i = 0; i < 65; ++i) big.push_back({i % 2, 0, i % 3, i % 2, float(i)});
        add("batch-too-large", batch_input(nb(2), {batch(ab, level_tiles(a, 0, 1, 3)), batch(ab, big)}));
        big.resize(49);
        add("batch-too-large-auth", batch_input(authed, {batch(ab, big)}));
    }
    {
        std::string raw;
        raw += raw_record(0, 0, 0, 0, 1.0f);
        raw += raw_record(1, 0, 1, 0, 2.0f);
        raw += raw_record(2, 0, 0, 0, 1.0f);
        raw += raw_record(3, 0, 0, 0, 1.0f);
        raw += raw_record(4, 0, 0, 0, 1.0f);
        raw += raw_record(0, 0xff, 0xffff, 0, 1.0f);
        raw += raw_record(0, 1, 2, 1, std::numeric_limits<float>::quiet_NaN());
        raw += raw_record(1, 0, 0, 0, 5.0f);
        add("batch-raw-records", batch_input(one, {raw}));
        add("batch-raw-then-proto", batch_input(nb(2) | (2u << flag::reads_shift), {raw, batch(ab, level_tiles(a, 0, 2, 9))}));
    }

    for (const auto& [name, bytes] : seeds) {
        const std::string path = out_dir + "/" + name;
        std::ofstream f(path, std::ios::binary | std::ios::trunc);
        f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
        if (!f) {
            std::fprintf(stderr, "make_server_fuzz_corpus: cannot write %s\n", path.c_str());
            return 1;
        }
    }
    std::printf("make_server_fuzz_corpus: wrote %zu seeds to %s\n", seeds.size(), out_dir.c_str());
    return 0;
}
