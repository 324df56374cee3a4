// `tessera loadtest` against a real `tessera serve` on loopback: sane figures in the JSON for 1
// and 4 viewers, an emulated link that adds its latency, a clear error when the server is down,
// and bad flags rejected. Short runs (about 2 s each): figures, not timings, are checked.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <csignal>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <sstream>
#include <thread>
#include <vector>

#include <sys/wait.h>
#include <unistd.h>

#include "server_process.hpp"
#include "test_util.hpp"

using tessera::test::run_tessera;
using tessera::test::ScratchDir;
using tessera::test::ServerProcess;

namespace {

// One server for every test: a 4096² JPEG store named "terrain".
class Server {
public:
    static Server& get() {
        static Server s;
        return s;
    }
    std::string address() const { return srv_->grpc_address(); }
    pid_t pid() const { return srv_->pid(); }
    std::string file(const std::string& name) const { return dir_->file(name); }

private:
    Server() {
        dir_ = std::make_unique<ScratchDir>();
        auto r = run_tessera("build procedural:terrain:4096 -o " + dir_->file("terrain.tsr") + " --quiet");
        if (r.exit_code != 0) throw std::runtime_error("build failed: " + r.out);
        srv_ = std::make_unique<ServerProcess>(std::vector<std::string>{"--store", dir_->file("terrain.tsr")},
                                               dir_->file("server.log"), "127.0.0.1:0", false);
        if (!srv_->running()) throw std::runtime_error("server did not start: " + srv_->log());
    }
    std::unique_ptr<ScratchDir> dir_;
    std::unique_ptr<ServerProcess> srv_;
};

nlohmann::json load(const std::string& path) {
    std::ifstream f(path);
    return nlohmann::json::parse(f);
}

void check_run(const nlohmann::json& r, unsigned viewers, double duration, double fps) {
    EXPECT_EQ(r["viewers"].get<unsigned>(), viewers);
    const double expected = duration * fps * viewers;
    const auto frames = r["frames"].get<double>() + r["frames_skipped"].get<double>();
    EXPECT_GT(frames, expected * 0.9) << r.dump();
    EXPECT_LT(frames, expected * 1.1 + viewers) << r.dump();
    EXPECT_GT(r["tiles"].get<std::uint64_t>(), 0u);
    EXPECT_GT(r["bytes_per_s"].get<double>(), 0.0);
    const auto& l = r["latency_ms"];
    EXPECT_GT(l["count"].get<std::uint64_t>(), 0u);
    EXPECT_LE(l["p50"].get<double>(), l["p99"].get<double>());
    EXPECT_LE(l["p99"].get<double>(), l["p999"].get<double>());
    EXPECT_LE(l["p999"].get<double>(), l["max"].get<double>());
    const double fb = r["fallback"].get<double>();
    EXPECT_GE(fb, 0.0);
    EXPECT_LE(fb, 1.0);
    EXPECT_EQ(r["failed"].get<std::uint64_t>(), 0u);
    EXPECT_EQ(r["per_viewer"].size(), viewers);
    for (const auto& v : r["per_viewer"])
        for (const auto& x : v["fallback_by_second"]) {
            EXPECT_GE(x.get<double>(), 0.0);
            EXPECT_LE(x.get<double>(), 1.0);
        }
}

}  // namespace

TEST(Loadtest, OneAndFourViewers) {
    auto& s = Server::get();
    const std::string json = s.file("lt.json"), plot = s.file("lt.svg");
    auto r = run_tessera("loadtest --server " + s.address() +
                         " --store terrain --viewers 1,4 --duration 1.5 --warmup 0.2 --fps 30 --seed 7 --json " + json +
                         " --plot " + plot + " --quiet");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("viewers"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("p99.9"), std::string::npos) << r.out;
    auto j = load(json);
    ASSERT_EQ(j["runs"].size(), 2u);
    check_run(j["runs"][0], 1, 1.5, 30);
    check_run(j["runs"][1], 4, 1.5, 30);
    EXPECT_TRUE(std::filesystem::exists(plot));
}

TEST(Loadtest, EmulatedLinkAddsLatency) {
    auto& s = Server::get();
    const auto run = [&](const std::string& name, int jitter_ms) {
        const std::string json = s.file(name);
        auto r = run_tessera("loadtest --server " + s.address() +
                             " --store terrain --viewers 2 --duration 2.5 --warmup 0 --fps 30 --latency 40 --jitter " +
                             std::to_string(jitter_ms) + " --path whip --json " + json + " --quiet");
        EXPECT_EQ(r.exit_code, 0) << r.out;
        return load(json);
    };
    const auto plain = run("link.json", 0), jittered = run("jitter.json", 20);
    const auto& l = plain["runs"][0]["latency_ms"];
    const auto& lj = jittered["runs"][0]["latency_ms"];
    ASSERT_GT(l["count"].get<std::uint64_t>(), 20u) << l.dump();
    ASSERT_GT(lj["count"].get<std::uint64_t>(), 20u) << lj.dump();
    EXPECT_DOUBLE_EQ(plain["link"]["latency_ms"].get<double>(), 40.0);
    EXPECT_DOUBLE_EQ(jittered["link"]["jitter_ms"].get<double>(), 20.0);
    // Histogram quantiles are within 3.2% of a sample; no sample is under 40 ms, and the median
    // is the link plus the server's own time and the viewers' frame pacing (measured 44.0-48.1
    // ms), not more than 15 ms over it.
    EXPECT_GE(l["p50"].get<double>(), 40.0 * 0.96) << l.dump();
    EXPECT_LE(l["p50"].get<double>(), 55.0) << l.dump();
    // Jitter: each reply waits 0-20 ms more, uniformly: up to 10 ms more on average (less where
    // the link's wait overlaps the server's own time, which grows on a busy machine: measured
    // 6.3-8.7 ms on an idle one, 3.8 ms with a build beside it and 2.6 ms inside the full suite
    // at -j2, the mean's spread about 0.7 ms), and some replies near the top of the range (max
    // measured 62.5-66.5 ms; without jitter at most the server's time over 40 ms). No jitter at
    // all would add about 0.
    const double added = lj["mean"].get<double>() - l["mean"].get<double>();
    EXPECT_GE(added, 1.5) << l.dump() << lj.dump();
    EXPECT_LE(added, 15.0) << l.dump() << lj.dump();
    EXPECT_GE(lj["max"].get<double>(), 55.0) << lj.dump();
    std::printf("  link 40 ms: p50 %.2f, mean %.2f, max %.2f ms; jitter 20 ms adds %.2f ms on average (max %.2f)\n",
                l["p50"].get<double>(), l["mean"].get<double>(), l["max"].get<double>(), added, lj["max"].get<double>());
}

// More viewers than the server admits: the table shows the refused streams and the frames run
// with the stream down, not only the JSON.
// With --server-pid: the server's CPU per viewer-second per run, and a capacity plan from it.
TEST(Loadtest, ServerCpuGivesViewersPerCoreAndReplicas) {
    auto& s = Server::get();
    const std::string json = s.file("cpu.json");
    // The server's CPU time (user + system) as the kernel counts it, read here independently of
    // the load tester: the whole invocation (connect, warm-up, run) bounds what it reports.
    const auto cpu_s = [&] {
        std::ifstream in("/proc/" + std::to_string(s.pid()) + "/stat");
        std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        std::istringstream fields(stat.substr(stat.rfind(')') + 2));  // after "pid (comm) "
        std::vector<std::string> f((std::istream_iterator<std::string>(fields)), std::istream_iterator<std::string>());
        return f.size() > 12 ? (std::stod(f[11]) + std::stod(f[12])) / double(::sysconf(_SC_CLK_TCK)) : -1.0;
    };
    const double cpu_before = cpu_s();
    ASSERT_GE(cpu_before, 0.0);
    // Targets a working server holds with room (measured: p99 about 2 ms, fallback 0.2-0.4%), and a
    // load (4 viewers at 30 Hz, about 4% of a core for the generator) far from generator-bound.
    auto r = run_tessera("loadtest --server " + s.address() + " --server-pid " + std::to_string(s.pid()) +
                         " --store terrain --viewers 4 --duration 3 --warmup 0.3 --fps 30 --path whip --plan-viewers 10000 "
                         "--replica-cores 4 --ramp-p99-ms 100 --ramp-fallback 0.05 --json " + json + " --quiet");
    const double cpu_whole = cpu_s() - cpu_before;
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("srv-ms/vs"), std::string::npos) << r.out;
    const auto j = load(json);
    const auto& run = j["runs"][0];
    ASSERT_FALSE(run["generator_bound"].get<bool>()) << "the test's load must measure the server, not the generator: "
                                                      << run.dump();
    ASSERT_TRUE(run["server_cpu_s"].is_number()) << run.dump();
    const double server_cpu = run["server_cpu_s"].get<double>();
    EXPECT_GT(server_cpu, 0.0);  // the server did work for four viewers on a fast path
    // What it reports for the run is part of what the kernel counted for the whole invocation
    // (one clock tick of rounding allowed).
    EXPECT_LE(server_cpu, cpu_whole + 1.0 / double(::sysconf(_SC_CLK_TCK)) + 1e-9)
        << "reported " << server_cpu << " s, /proc counted " << cpu_whole << " s for the whole invocation";
    EXPECT_GT(run["generator_cpu_s"].get<double>(), 0.0);
    const double per_vs = run["server_cpu_s_per_viewer_s"].get<double>();
    EXPECT_NEAR(per_vs, server_cpu / (4 * 3.0), 1e-9);
    EXPECT_TRUE(run["pass"].get<bool>()) << run.dump();
    // The plan: viewers per core from the run, at least what /proc's whole-invocation figure gives.
    const auto& cap = j["capacity"];
    ASSERT_TRUE(cap["viewers_per_core"].is_number()) << cap.dump();
    const double per_core = cap["viewers_per_core"].get<double>();
    EXPECT_NEAR(per_core, 1.0 / per_vs, 1e-6);
    if (cpu_whole > 0) {
        EXPECT_GE(per_core, 0.99 * (4 * 3.0) / cpu_whole) << cap.dump();
    }
    EXPECT_EQ(cap["replica_cores"].get<unsigned>(), 4u);
    EXPECT_DOUBLE_EQ(cap["replicas"].get<double>(), std::ceil(10000.0 / (per_core * 4)));
    EXPECT_NE(r.out.find("capacity:"), std::string::npos) << r.out;
    std::printf("  server CPU %.3f s reported for the run, %.3f s by /proc for the whole invocation; %.0f viewers per core\n",
                server_cpu, cpu_whole, per_core);
    // A process that is not there is a usage error, before any viewer starts.
    auto bad = run_tessera("loadtest --server " + s.address() + " --server-pid 999999999 --store terrain --duration 0.5");
    EXPECT_EQ(bad.exit_code, 2) << bad.out;
    EXPECT_NE(bad.out.find("--server-pid"), std::string::npos) << bad.out;
}

TEST(Loadtest, RefusedStreamsShowInTheTable) {
    ScratchDir dir;
    auto b = run_tessera("build procedural:terrain:1024 -o " + dir.file("terrain.tsr") + " --quiet");
    ASSERT_EQ(b.exit_code, 0) << b.out;
    ServerProcess srv({"--store", dir.file("terrain.tsr"), "--max-viewers", "2"}, dir.file("server.log"), "127.0.0.1:0",
                      false);
    ASSERT_TRUE(srv.running()) << srv.log();
    const std::string json = dir.file("refused.json");
    auto r = run_tessera("loadtest --server " + srv.grpc_address() +
                         " --store terrain --viewers 4 --duration 2 --warmup 0 --fps 30 --seed 3 --json " + json +
                         " --quiet");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    // The column header line names the columns; the row for 4 viewers has a value under each.
    std::istringstream lines(r.out);
    std::vector<std::string> header, row;
    for (std::string line; std::getline(lines, line);) {
        std::istringstream words(line);
        std::vector<std::string> w{std::istream_iterator<std::string>(words), {}};
        if (!w.empty() && w[0] == "viewers") header = w;
        else if (!header.empty() && row.empty() && w.size() == header.size() && w[0] == "4") row = w;
    }
    ASSERT_FALSE(row.empty()) << r.out;
    const auto column = [&](const std::string& name) -> long {
        const auto it = std::find(header.begin(), header.end(), name);
        return it == header.end() ? -1 : std::stol(row[static_cast<std::size_t>(it - header.begin())]);
    };
    EXPECT_GT(column("streams"), 0) << r.out;  // under "refused"
    EXPECT_GT(column("discon"), 0) << r.out;
    EXPECT_NE(r.out.find("refused streams"), std::string::npos) << r.out;
    const auto run = load(json)["runs"][0];
    EXPECT_EQ(run["streams_refused"].get<long>(), column("streams")) << run.dump();
    EXPECT_EQ(run["frames_disconnected"].get<long>(), column("discon")) << run.dump();
    EXPECT_FALSE(run["pass"].get<bool>());
}

// A step in which no tile arrives (a link of 60 s) has no latency: "-" in the table and null in
// the JSON, never 0.00 ms, which reads as instant.
TEST(Loadtest, AStepWithNoTileHasNoLatency) {
    auto& s = Server::get();
    const std::string json = s.file("none.json");
    auto r = run_tessera("loadtest --server " + s.address() + " --store terrain --viewers 1 --duration 1 --warmup 0 --fps 30 "
                         "--latency 60000 --json " + json + " --quiet");
    ASSERT_EQ(r.exit_code, 0) << r.out;
    const auto run = load(json)["runs"][0];
    EXPECT_EQ(run["tiles"].get<long>(), 0) << run.dump();
    for (const char* k : {"mean", "p50", "p90", "p99", "p999", "max"}) EXPECT_TRUE(run["latency_ms"][k].is_null()) << k << run.dump();
    std::istringstream lines(r.out);
    bool row_seen = false;
    for (std::string line; std::getline(lines, line);) {
        std::istringstream words(line);
        std::vector<std::string> w{std::istream_iterator<std::string>(words), {}};
        if (w.size() < 12 || w[0] != "1") continue;
        row_seen = true;
        for (std::size_t i = 7; i < 12; ++i) EXPECT_EQ(w[i], "-") << line;  // p50 .. max
    }
    EXPECT_TRUE(row_seen) << r.out;
}

// A later step that cannot connect (the server killed during the first) ends the run, but the
// first step's results are reported, and the exit status says it failed.
TEST(Loadtest, AFailedStepKeepsTheStepsBeforeIt) {
    ScratchDir dir;
    auto b = run_tessera("build procedural:terrain:1024 -o " + dir.file("terrain.tsr") + " --quiet");
    ASSERT_EQ(b.exit_code, 0) << b.out;
    auto srv = std::make_unique<ServerProcess>(std::vector<std::string>{"--store", dir.file("terrain.tsr")},
                                               dir.file("server.log"), "127.0.0.1:0", false);
    ASSERT_TRUE(srv->running()) << srv->log();
    const std::string json = dir.file("steps.json");
    // The server goes 1 s after the first step has started (its 4 s measured), whatever the
    // machine's speed: the run's progress lines are read as they come.
    const std::string cmd = std::string(TESSERA_BINARY) + " loadtest --server " + srv->grpc_address() +
                            " --store terrain --viewers 1,2 --duration 4 --warmup 0 --fps 30 --connect-timeout 2 --json " +
                            json + " 2>&1";
    FILE* pipe = ::popen(cmd.c_str(), "r");
    ASSERT_NE(pipe, nullptr);
    struct Run {
        std::string out;
        int exit_code = -1;
    } r;
    std::thread killer;
    char line[4096];
    while (std::fgets(line, sizeof line, pipe)) {
        r.out += line;
        if (!killer.joinable() && r.out.find("loadtest: 1 viewer for") != std::string::npos)
            killer = std::thread([&] {
                std::this_thread::sleep_for(std::chrono::seconds(1));
                srv->signal(SIGKILL);
            });
    }
    const int status = ::pclose(pipe);
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    ASSERT_TRUE(killer.joinable()) << "the first step never started:\n" << r.out;
    killer.join();
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("the 2-viewer step failed"), std::string::npos) << r.out;
    const auto j = load(json);
    ASSERT_EQ(j["runs"].size(), 1u) << j.dump();
    EXPECT_EQ(j["runs"][0]["viewers"].get<unsigned>(), 1u);
    EXPECT_GT(j["runs"][0]["frames_disconnected"].get<long>(), 0) << j["runs"][0].dump();
    EXPECT_EQ(j["failed_step"]["viewers"].get<unsigned>(), 2u) << j.dump();
}

TEST(Loadtest, ServerDownIsAClearError) {
    // Port 1 on loopback: nobody listens there.
    auto r = run_tessera("loadtest --server 127.0.0.1:1 --store terrain --viewers 2 --duration 1 --connect-timeout 1 --quiet");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("tessera: error: --server 127.0.0.1:1"), std::string::npos) << r.out;
}

// --path takes what `tessera view --path` takes: every built-in path and a path file.
TEST(Loadtest, PathsAreTheViewersPaths) {
    auto& s = Server::get();
    const std::string file = s.file("low.path");
    std::ofstream(file) << "# tessera camera path v1\n# time_s x y z yaw_deg pitch_deg\n"
                           "0 500 500 400 45 -30\n2 3500 3500 400 45 -30\n";
    for (const std::string& path : {file, std::string("walk"), std::string("orbit"), std::string("auto")}) {
        SCOPED_TRACE(path);
        const std::string json = s.file("path.json");
        auto r = run_tessera("loadtest --server " + s.address() + " --store terrain --viewers 1 --duration 1 --warmup 0 "
                             "--fps 30 --path " + path + " --json " + json + " --quiet");
        ASSERT_EQ(r.exit_code, 0) << r.out;
        const auto j = load(json);
        EXPECT_EQ(j["feedback"].get<std::string>(), "path:" + path);
        EXPECT_GT(j["runs"][0]["tiles"].get<std::uint64_t>(), 0u) << j.dump();
    }
    // A path file that does not parse: the parser's error, naming the file and line.
    const std::string bad = s.file("bad.path");
    std::ofstream(bad) << "0 1 2 3 4 5\n1 1 2\n";
    auto r = run_tessera("loadtest --server " + s.address() + " --store terrain --duration 0.5 --warmup 0 --path " + bad);
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_NE(r.out.find(bad + ":2: "), std::string::npos) << r.out;
}

TEST(Loadtest, BadFlags) {
    auto& s = Server::get();
    const std::string base = "loadtest --server " + s.address() + " --store terrain ";
    auto r = run_tessera(base + "--viewers 0");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    r = run_tessera(base + "--fps -5");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    r = run_tessera(base + "--feedback-size 160by90 --duration 0.5 --warmup 0");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_NE(r.out.find("--feedback-size"), std::string::npos) << r.out;
    r = run_tessera(base + "--path nosuchpath --duration 0.5 --warmup 0");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_NE(r.out.find("--path"), std::string::npos) << r.out;
    r = run_tessera(base + "--trace /nonexistent/trace --duration 0.5 --warmup 0");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("--trace"), std::string::npos) << r.out;
    {  // a trace recorded on a larger store: its pages are outside this one (it would run clean, asking nothing)
        const std::string big = tessera::test::cached_store("procedural:terrain:8192", "terrain.tsr");
        const std::string trace = s.file("big.trace");
        auto v = run_tessera("view --headless --frames 20 --size 64x36 --store " + big + " --trace " + trace);
        ASSERT_EQ(v.exit_code, 0) << v.out;
        r = run_tessera(base + "--trace " + trace + " --duration 0.5 --warmup 0");
        EXPECT_EQ(r.exit_code, 2) << r.out;
        EXPECT_NE(r.out.find("recorded on another store"), std::string::npos) << r.out;
    }
    r = run_tessera("loadtest --server " + s.address() + " --store nosuchstore --duration 0.5");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("nosuchstore"), std::string::npos) << r.out;
    r = run_tessera("loadtest --store terrain");
    EXPECT_EQ(r.exit_code, 2) << r.out;
}

// A secured deployment can be load-tested: TLS (grpcs:// or --tls with --tls-ca) and a bearer
// token (--token or --token-file); a wrong token, or plain text to a TLS server, is a clear error.
TEST(Loadtest, TlsAndTokenServer) {
    ScratchDir dir;
    std::string cert, key;
    ASSERT_TRUE(tessera::test::make_test_certificate(dir, cert, key));
    {
        std::ofstream t(dir.file("token"));
        t << "  l0ad-t3st-token \n";
    }
    auto& s = Server::get();
    ServerProcess srv({"--store", s.file("terrain.tsr"), "--tls-cert", cert, "--tls-key", key, "--auth-token-file", dir.file("token")},
                      dir.file("server.log"), "127.0.0.1:0", false);
    ASSERT_TRUE(srv.running()) << srv.log();
    const std::string port = srv.grpc_address().substr(srv.grpc_address().rfind(':') + 1);
    const std::string json = dir.file("r.json");
    auto r = run_tessera("loadtest --server grpcs://localhost:" + port + " --tls-ca " + cert + " --token-file " + dir.file("token") +
                         " --store terrain --viewers 2 --duration 1 --warmup 0.5 --quiet --json " + json);
    ASSERT_EQ(r.exit_code, 0) << r.out;
    const auto j = load(json);
    ASSERT_EQ(j["runs"].size(), 1u);
    EXPECT_GT(j["runs"][0]["tiles"].get<std::uint64_t>(), 0u) << j.dump();
    EXPECT_EQ(j["runs"][0]["failed"].get<std::uint64_t>(), 0u);
    // The token inline, TLS by flag.
    r = run_tessera("loadtest --server localhost:" + port + " --tls --tls-ca " + cert + " --token l0ad-t3st-token --store terrain "
                    "--viewers 1 --duration 0.5 --warmup 0 --quiet");
    EXPECT_EQ(r.exit_code, 0) << r.out;
    // A wrong token: refused before any viewer starts, and says why.
    r = run_tessera("loadtest --server grpcs://localhost:" + port + " --tls-ca " + cert + " --token wrong --store terrain --duration 0.5");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("UNAUTHENTICATED"), std::string::npos) << r.out;
    // No TLS to a TLS-only server: an error that suggests it.
    r = run_tessera("loadtest --server localhost:" + port + " --token l0ad-t3st-token --store terrain --duration 0.5 --connect-timeout 2");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("--tls"), std::string::npos) << r.out;
    // Both a token and a token file, or an empty token file: flag errors.
    {
        std::ofstream e(dir.file("empty"));
    }
    r = run_tessera("loadtest --server grpcs://localhost:" + port + " --token a --token-file " + dir.file("token") + " --store terrain");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    r = run_tessera("loadtest --server grpcs://localhost:" + port + " --token-file " + dir.file("empty") + " --store terrain");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("empty"), std::string::npos) << r.out;
}
