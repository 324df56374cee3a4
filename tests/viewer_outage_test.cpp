// `tessera view --headless` against a real `tessera serve` over gRPC: a server killed mid-run
// (SIGKILL, never back) is reported on stderr as it happens, counted as unserved seconds in the
// summary and the per-frame stats, and fails the run (exit 3) beyond --max-outage; a server that
// stays up gives zero unserved seconds and exit 0. Tiny images, paced frames: a few seconds each.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "server_process.hpp"
#include "test_util.hpp"

using namespace std::chrono_literals;
using tessera::test::http_get;
using tessera::test::run_tessera;
using tessera::test::ScratchDir;
using tessera::test::ServerProcess;
using tessera::test::slurp;

namespace {

// `tessera ARGS` in the background, stdout and stderr to separate files.
class ViewProcess {
public:
    ViewProcess(const std::vector<std::string>& args, const std::string& out, const std::string& err) {
        std::vector<std::string> argv_s{TESSERA_BINARY};
        argv_s.insert(argv_s.end(), args.begin(), args.end());
        std::vector<char*> argv;
        for (auto& s : argv_s) argv.push_back(s.data());
        argv.push_back(nullptr);
        pid_ = ::fork();
        if (pid_ == 0) {
            const int o = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
            const int e = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
            ::dup2(o, 1);
            ::dup2(e, 2);
            ::execv(argv[0], argv.data());
            std::_Exit(127);
        }
    }
    ~ViewProcess() {
        if (pid_ > 0) {
            ::kill(pid_, SIGKILL);
            ::waitpid(pid_, nullptr, 0);
        }
    }
    ViewProcess(const ViewProcess&) = delete;
    ViewProcess& operator=(const ViewProcess&) = delete;

    bool running() {
        return pid_ > 0 && ::waitpid(pid_, &status_, WNOHANG) == 0;
    }
    // The exit code, 128 + signal for a signal death, -1 on timeout.
    int wait_exit(std::chrono::seconds timeout) {
        const auto deadline = std::chrono::steady_clock::now() + timeout;
        while (pid_ > 0 && std::chrono::steady_clock::now() < deadline) {
            if (::waitpid(pid_, &status_, WNOHANG) == pid_) {
                pid_ = -1;
                return WIFEXITED(status_) ? WEXITSTATUS(status_) : 128 + WTERMSIG(status_);
            }
            std::this_thread::sleep_for(20ms);
        }
        return -1;
    }

private:
    pid_t pid_ = -1;
    int status_ = 0;
};

// The value of an unlabelled Prometheus counter or gauge (0 when absent).
double metric(const std::string& text, const std::string& name) {
    const std::regex re("(^|\n)" + name + " ([0-9.e+]+)");
    std::smatch m;
    return std::regex_search(text, m, re) ? std::stod(m[2].str()) : 0.0;
}

// The summary's "server  X s unserved of Y s" figure (NaN when absent).
double summary_unserved(const std::string& out) {
    static const std::regex re(R"(server +([0-9.]+) s unserved of ([0-9.]+) s)");
    std::smatch m;
    return std::regex_search(out, m, re) ? std::stod(m[1].str()) : std::nan("");
}

struct StatsRow {
    bool connected = true;
    double unserved_s = 0;
};

// The per-frame CSV's connected and unserved_s columns, found by name in the header.
std::vector<StatsRow> read_stats(const std::string& path) {
    std::istringstream in(slurp(path));
    std::string line;
    std::getline(in, line);
    std::vector<std::string> header;
    std::stringstream hs(line);
    for (std::string c; std::getline(hs, c, ',');) header.push_back(c);
    const auto col = [&](const std::string& name) {
        for (std::size_t i = 0; i < header.size(); ++i)
            if (header[i] == name) return static_cast<int>(i);
        return -1;
    };
    const int connected = col("connected"), unserved = col("unserved_s");
    std::vector<StatsRow> rows;
    if (connected < 0 || unserved < 0) return rows;
    while (std::getline(in, line)) {
        std::vector<std::string> cells;
        std::stringstream ls(line);
        for (std::string c; std::getline(ls, c, ',');) cells.push_back(c);
        if (static_cast<int>(cells.size()) <= std::max(connected, unserved)) continue;
        rows.push_back({cells[connected] == "1", std::stod(cells[unserved])});
    }
    return rows;
}

class ViewerOutage : public ::testing::Test {
protected:
    void SetUp() override {
        auto r = run_tessera("build procedural:terrain:2048 --quiet -o " + dir_.file("terrain.tsr"));
        ASSERT_EQ(r.exit_code, 0) << r.out;
        server_ = std::make_unique<ServerProcess>(std::vector<std::string>{"--store", dir_.file("terrain.tsr")},
                                                  dir_.file("server.log"));
        ASSERT_TRUE(server_->running()) << server_->log();
    }

    // A paced headless run of `frames` frames at 30 fps (frames / 30 seconds of wall time at least).
    std::vector<std::string> view_args(unsigned frames, const std::string& max_outage) const {
        return {"view", "--store", "grpc://" + server_->grpc_address() + "/terrain", "--headless", "--size", "64x64",
                "--frames", std::to_string(frames), "--fps", "30", "--pace", "--no-warmup", "--max-outage", max_outage,
                "--stats", dir_.file("stats.csv")};
    }

    // Waits until the viewer's requests reach the server (its frames are running).
    bool wait_for_requests(ViewProcess& view, std::chrono::seconds timeout) const {
        const auto deadline = std::chrono::steady_clock::now() + timeout;
        while (std::chrono::steady_clock::now() < deadline && view.running()) {
            const auto reply = http_get(server_->http_port(), "/metrics");
            if (metric(reply.body, "tessera_grpc_requests_total") > 0) return true;
            std::this_thread::sleep_for(50ms);
        }
        return false;
    }

    ScratchDir dir_;
    std::unique_ptr<ServerProcess> server_;
};

TEST_F(ViewerOutage, ServerKilledMidRunIsReportedAndFailsTheRun) {
    // 150 frames at 30 fps: 5 s of wall time; the server dies shortly after the first requests.
    ViewProcess view(view_args(150, "1"), dir_.file("out.txt"), dir_.file("err.txt"));
    const bool requested = wait_for_requests(view, 60s);
    const std::string early = slurp(dir_.file("err.txt"));
    // A test that cannot run fails (docs/testing.md): no headless GL is a broken set-up, not a pass.
    if (!requested && early.find("headless GL") != std::string::npos)
        GTEST_FAIL() << "no headless OpenGL (tools/setup.sh installs Mesa's EGL): " << early;
    ASSERT_TRUE(requested) << slurp(dir_.file("out.txt")) << early;
    server_->signal(SIGKILL);
    const int code = view.wait_exit(120s);
    const std::string out = slurp(dir_.file("out.txt")), err = slurp(dir_.file("err.txt"));

    EXPECT_EQ(code, 3) << out << err;
    // One line when it went (not one per frame), naming the server.
    std::size_t lines = 0;
    for (auto p = err.find("unreachable at"); p != std::string::npos; p = err.find("unreachable at", p + 1)) ++lines;
    EXPECT_EQ(lines, 1u) << err;
    EXPECT_NE(err.find(server_->grpc_address()), std::string::npos) << err;
    EXPECT_NE(err.find("--max-outage"), std::string::npos) << err;
    // The summary counts the outage: most of the run after the kill.
    const double unserved = summary_unserved(out);
    EXPECT_GT(unserved, 1.0) << out;
    EXPECT_NE(out.find("still down at the end"), std::string::npos) << out;
    // Per frame: connected at first, down at the end with the same cumulative figure.
    const auto rows = read_stats(dir_.file("stats.csv"));
    ASSERT_EQ(rows.size(), 150u) << slurp(dir_.file("stats.csv")).substr(0, 400);
    EXPECT_TRUE(rows.front().connected);
    EXPECT_EQ(rows.front().unserved_s, 0.0);
    EXPECT_FALSE(rows.back().connected);
    EXPECT_GT(rows.back().unserved_s, 1.0);
    EXPECT_LE(rows.back().unserved_s, unserved + 0.05);
    for (std::size_t i = 1; i < rows.size(); ++i) EXPECT_GE(rows[i].unserved_s, rows[i - 1].unserved_s) << i;
}

TEST_F(ViewerOutage, ServerThatStaysUpGivesZeroUnservedAndExitZero) {
    ViewProcess view(view_args(60, "0"), dir_.file("out.txt"), dir_.file("err.txt"));
    const int code = view.wait_exit(120s);
    const std::string out = slurp(dir_.file("out.txt")), err = slurp(dir_.file("err.txt"));
    if (code != 0 && err.find("headless GL") != std::string::npos)
        GTEST_FAIL() << "no headless OpenGL (tools/setup.sh installs Mesa's EGL): " << err;
    EXPECT_EQ(code, 0) << out << err;
    EXPECT_EQ(err.find("unreachable"), std::string::npos) << err;
    EXPECT_EQ(summary_unserved(out), 0.0) << out;
    EXPECT_NE(out.find("connected throughout"), std::string::npos) << out;
    const auto rows = read_stats(dir_.file("stats.csv"));
    ASSERT_EQ(rows.size(), 60u);
    for (const auto& r : rows) {
        EXPECT_TRUE(r.connected);
        EXPECT_EQ(r.unserved_s, 0.0);
    }
}

}  // namespace
