#include "svg_plot.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include "atomic_file.hpp"
#include "failure.hpp"

namespace tessera::tools {
namespace {

struct Range {
    double lo = INFINITY, hi = -INFINITY;
    void add(double v) {
        if (!std::isfinite(v)) return;
        lo = std::min(lo, v);
        hi = std::max(hi, v);
    }
    void finish() {
        if (!(lo <= hi)) lo = 0, hi = 1;
        if (hi - lo < 1e-12) hi = lo + (lo == 0 ? 1 : std::abs(lo) * 0.1);
    }
};

// "Nice" tick step for a range: 1, 2 or 5 times a power of ten, about n ticks.
double tick_step(double span, int n) {
    const double raw = span / n, mag = std::pow(10.0, std::floor(std::log10(raw)));
    for (double m : {1.0, 2.0, 5.0, 10.0})
        if (m * mag >= raw) return m * mag;
    return 10 * mag;
}

std::string escape(const std::string& s) {
    std::string o;
    for (char c : s) {
        if (c == '<') o += "&lt;";
        else if (c == '>') o += "&gt;";
        else if (c == '&') o += "&amp;";
        else o += c;
    }
    return o;
}

std::string number(double v) { return fmt::format("{:g}", std::abs(v) < 1e-12 ? 0.0 : v); }

}  // namespace

std::string render_svg(const Plot& p) {
    const double left = 70, right = p.width - 70.0, top = 40, bottom = p.height - 60.0;
    Range xr, yr, y2r;
    bool has_y2 = false;
    for (const auto& s : p.series) {
        for (double v : s.x) xr.add(v);
        for (double v : s.y) (s.right_axis ? y2r : yr).add(v);
        has_y2 |= s.right_axis;
    }
    xr.finish();
    yr.finish();
    y2r.finish();
    yr.lo = std::min(yr.lo, 0.0);  // rates, counts: start at 0
    y2r.lo = std::min(y2r.lo, 0.0);
    const auto sx = [&](double v) { return left + (v - xr.lo) / (xr.hi - xr.lo) * (right - left); };
    const auto sy = [&](const Range& r, double v) { return bottom - (v - r.lo) / (r.hi - r.lo) * (bottom - top); };

    std::string o = fmt::format(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\" font-family=\"sans-serif\" "
        "font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n",
        p.width, p.height);
    o += fmt::format("<text x=\"{}\" y=\"22\" font-size=\"15\" text-anchor=\"middle\">{}</text>\n", p.width / 2,
                     escape(p.title));
    o += fmt::format("<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"#333\"/>\n", left, top,
                     right - left, bottom - top);
    // Ticks and grid.
    const double xs = tick_step(xr.hi - xr.lo, 8);
    for (double v = std::ceil(xr.lo / xs) * xs; v <= xr.hi + xs * 1e-9; v += xs)
        o += fmt::format(
            "<line x1=\"{0:.1f}\" y1=\"{1}\" x2=\"{0:.1f}\" y2=\"{2}\" stroke=\"#ddd\"/><text x=\"{0:.1f}\" y=\"{3}\" "
            "text-anchor=\"middle\">{4}</text>\n",
            sx(v), top, bottom, bottom + 16, number(v));
    const double ys = tick_step(yr.hi - yr.lo, 6);
    for (double v = std::ceil(yr.lo / ys) * ys; v <= yr.hi + ys * 1e-9; v += ys)
        o += fmt::format(
            "<line x1=\"{0}\" y1=\"{1:.1f}\" x2=\"{2}\" y2=\"{1:.1f}\" stroke=\"#ddd\"/><text x=\"{3}\" y=\"{4:.1f}\" "
            "text-anchor=\"end\">{5}</text>\n",
            left, sy(yr, v), right, left - 6, sy(yr, v) + 4, number(v));
    if (has_y2) {
        const double s2 = tick_step(y2r.hi - y2r.lo, 6);
        for (double v = std::ceil(y2r.lo / s2) * s2; v <= y2r.hi + s2 * 1e-9; v += s2)
            o += fmt::format("<text x=\"{}\" y=\"{:.1f}\">{}</text>\n", right + 6, sy(y2r, v) + 4, number(v));
        o += fmt::format(
            "<text transform=\"translate({},{}) rotate(90)\" text-anchor=\"middle\">{}</text>\n", p.width - 18,
            (top + bottom) / 2, escape(p.y2_label));
    }
    o += fmt::format("<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n", (left + right) / 2, p.height - 20,
                     escape(p.x_label));
    o += fmt::format("<text transform=\"translate(18,{}) rotate(-90)\" text-anchor=\"middle\">{}</text>\n",
                     (top + bottom) / 2, escape(p.y_label));
    // Series.
    for (const auto& s : p.series) {
        const Range& r = s.right_axis ? y2r : yr;
        const std::size_t n = std::min(s.x.size(), s.y.size());
        if (s.points) {
            for (std::size_t i = 0; i < n; ++i)
                if (std::isfinite(s.x[i]) && std::isfinite(s.y[i]))
                    o += fmt::format("<circle cx=\"{:.1f}\" cy=\"{:.1f}\" r=\"3\" fill=\"{}\"/>\n", sx(s.x[i]),
                                     sy(r, s.y[i]), s.colour);
            continue;
        }
        std::string pts;
        for (std::size_t i = 0; i < n; ++i) {
            if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
            pts += fmt::format("{:.1f},{:.1f} ", sx(s.x[i]), sy(r, s.y[i]));
        }
        if (!pts.empty())
            o += fmt::format("<polyline fill=\"none\" stroke=\"{}\" stroke-width=\"1.5\" points=\"{}\"/>\n", s.colour, pts);
    }
    // Legend.
    double ly = top + 14;
    for (const auto& s : p.series) {
        o += fmt::format(
            "<rect x=\"{}\" y=\"{}\" width=\"14\" height=\"4\" fill=\"{}\"/><text x=\"{}\" y=\"{}\">{}</text>\n",
            left + 10, ly - 4, s.colour, left + 30, ly + 1, escape(s.label + (s.right_axis ? " (right axis)" : "")));
        ly += 16;
    }
    o += "</svg>\n";
    return o;
}

void write_svg(const Plot& plot, const std::string& path) {
    write_file_atomically(path, [&](std::ostream& out) { out << render_svg(plot); });
}

}  // namespace tessera::tools
