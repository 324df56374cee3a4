// `tessera bench --quick` on a small procedural store: the sweep table (CSV and JSON) and the
// Pareto plots are written with sane figures, and bad flags are rejected (exit 2).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "test_util.hpp"

using tessera::test::run_tessera;
using tessera::test::ScratchDir;

TEST(Bench, QuickSweepWritesTableAndPlots) {
    ScratchDir dir;
    const std::string out = dir.file("bench");
    auto r = run_tessera("bench --quick --texels 512 --out " + out);
    ASSERT_EQ(r.exit_code, 0) << r.out;
    EXPECT_NE(r.out.find("recommended default:"), std::string::npos) << r.out;
    std::ifstream jf(out + "/bench.json");
    ASSERT_TRUE(jf) << r.out;
    const auto j = nlohmann::json::parse(jf);
    const auto& pts = j["points"];
    ASSERT_EQ(pts.size(), 3u) << j.dump(2);
    EXPECT_EQ(j["frames"].get<unsigned>(), 30u);
    for (const auto& p : pts) {
        EXPECT_GT(p["psnr_mean_db"].get<double>(), 20.0) << p.dump();
        EXPECT_GT(p["psnr_min_db"].get<double>(), 20.0) << p.dump();
        const double fb = p["fallback_rate"].get<double>();
        EXPECT_GE(fb, 0.0) << p.dump();
        EXPECT_LE(fb, 1.0) << p.dump();
        EXPECT_GT(p["frame_ms_mean"].get<double>(), 0.0) << p.dump();
        EXPECT_GT(p["build_s"].get<double>(), 0.0) << p.dump();
        EXPECT_GT(p["store_bytes"].get<std::uint64_t>(), 0u) << p.dump();
        EXPECT_GT(p["bytes_received"].get<std::uint64_t>(), 0u) << p.dump();
        EXPECT_GT(p["full_detail_ms"].get<double>(), 0.0) << p.dump();
        // The temporal measures (docs/viewer.md, "Measures"): a rate, and frames.
        const double pop = p["pop_rate"].get<double>();
        EXPECT_GE(pop, 0.0) << p.dump();
        EXPECT_LE(pop, 1.0) << p.dump();
        EXPECT_GE(p["time_to_detail_p50_frames"].get<double>(), 1.0) << p.dump();
    }
    // The lossless point is compared with a lossless reference: its error is the streaming's and
    // the filtering's only, so it is at least as good as the lossy baseline's.
    EXPECT_EQ(pts[1]["settings"]["codec"].get<std::string>(), "zstd");
    EXPECT_GE(pts[1]["psnr_mean_db"].get<double>() + 0.5, pts[0]["psnr_mean_db"].get<double>());
    EXPECT_GE(pts[2]["settings"]["latency_ms"].get<double>(), 20.0);

    std::ifstream cf(out + "/bench.csv");
    std::string line;
    int lines = 0;
    while (std::getline(cf, line)) ++lines;
    EXPECT_EQ(lines, 4);  // header + 3 points
    for (const char* svg : {"pareto_frame_psnr.svg", "pareto_bytes_psnr.svg", "pareto_detail_fallback.svg"}) {
        std::ifstream f(out + "/" + svg);
        std::stringstream s;
        s << f.rdbuf();
        EXPECT_NE(s.str().find("<svg"), std::string::npos) << svg;
        EXPECT_NE(s.str().find("Pareto front"), std::string::npos) << svg;
    }
}

TEST(Bench, BadFlags) {
    ScratchDir dir;
    const std::string base = "bench --quick --out " + dir.file("b") + " ";
    auto r = run_tessera(base + "--resolution 320by180");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_NE(r.out.find("--resolution"), std::string::npos) << r.out;
    r = run_tessera(base + "--frames 0");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    r = run_tessera(base + "--texels 17");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    r = run_tessera(base + "--only nosuchsweep");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    r = run_tessera(base + "--path nosuchpath");
    EXPECT_EQ(r.exit_code, 2) << r.out;
    EXPECT_NE(r.out.find("--path"), std::string::npos) << r.out;
    r = run_tessera("bench --quick --texels 512 --out /proc/nope");
    EXPECT_EQ(r.exit_code, 1) << r.out;
    EXPECT_NE(r.out.find("--out"), std::string::npos) << r.out;
}
