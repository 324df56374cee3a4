#pragma once
// Line and scatter plots as standalone SVG files: no plotting dependency, readable in any
// browser. Used by `tessera demo` (fallback rate and bias over time), `tessera loadtest` and
// `tessera bench` (Pareto fronts).
#include <string>
#include <vector>

namespace tessera::tools {

struct PlotSeries {
    std::string label;
    std::vector<double> x, y;
    std::string colour = "#1f77b4";
    bool points = false;      // markers instead of a line
    bool right_axis = false;  // plotted against the right-hand y axis
};

struct Plot {
    std::string title;
    std::string x_label, y_label, y2_label;  // y2: the right-hand axis (when a series uses it)
    std::vector<PlotSeries> series;
    int width = 900, height = 420;
};

// The SVG text. Non-finite values are skipped; empty series are listed in the legend only.
std::string render_svg(const Plot& plot);
// Writes it atomically (temporary file + rename). Throws tools::Failure on error.
void write_svg(const Plot& plot, const std::string& path);

}  // namespace tessera::tools
