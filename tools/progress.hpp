#pragma once
// A one-line progress bar on stderr, drawn only when stderr is a terminal and not --quiet.
#include <chrono>
#include <cstdint>
#include <string>

namespace tessera::tools {

class ProgressBar {
public:
    ProgressBar(std::string label, bool enabled);
    ~ProgressBar();
    ProgressBar(const ProgressBar&) = delete;
    ProgressBar& operator=(const ProgressBar&) = delete;

    // fraction in [0, 1]; detail is appended after the percentage. Redraws at most 10 times a second.
    void update(double fraction, const std::string& detail, bool force = false);
    void set_label(std::string label) { label_ = std::move(label); }
    void finish();  // clears the line

private:
    std::string label_;
    bool enabled_;
    bool drawn_ = false;
    std::chrono::steady_clock::time_point start_, last_;
};

std::string human_bytes(std::uint64_t bytes);
std::string human_seconds(double s);

}  // namespace tessera::tools
