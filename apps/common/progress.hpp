#pragma once
// A one-line progress bar on stderr, drawn only when stderr is a terminal and not --quiet. It draws
// on its own duplicate of stderr, so it still reaches the terminal inside a StderrCapture.
#include <chrono>
#include <cstdint>
#include <cstdio>
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
    std::FILE* out_ = nullptr;
    bool drawn_ = false;
    std::chrono::steady_clock::time_point start_, last_;
};

// While it lives, what libraries print on stderr themselves (libpng prints "libpng error: ..." before
// handing OpenImageIO the same error, which then reaches us as an error value) goes to a temporary
// file instead, so that a failing command still prints exactly one error line. release() restores
// stderr and returns the text, for the caller to show when the command succeeds after all.
class StderrCapture {
public:
    StderrCapture();
    ~StderrCapture();
    StderrCapture(const StderrCapture&) = delete;
    StderrCapture& operator=(const StderrCapture&) = delete;
    std::string release();

private:
    int saved_ = -1;  // the real stderr while captured
    std::FILE* file_ = nullptr;
};

std::string human_bytes(std::uint64_t bytes);
std::string human_seconds(double s);

}  // namespace tessera::tools
