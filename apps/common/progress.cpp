#include "progress.hpp"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace tessera::tools {

ProgressBar::ProgressBar(std::string label, bool enabled)
    : label_(std::move(label)), enabled_(enabled && ::isatty(STDERR_FILENO) != 0),
      start_(std::chrono::steady_clock::now()), last_(start_ - std::chrono::seconds(1)) {
    if (!enabled_) return;
    const int fd = ::dup(STDERR_FILENO);
    out_ = fd >= 0 ? ::fdopen(fd, "w") : nullptr;
    if (!out_) {
        if (fd >= 0) ::close(fd);
        enabled_ = false;
    }
}

ProgressBar::~ProgressBar() {
    finish();
    if (out_) std::fclose(out_);
}

void ProgressBar::update(double fraction, const std::string& detail, bool force) {
    if (!enabled_) return;
    const auto now = std::chrono::steady_clock::now();
    if (!force && now - last_ < std::chrono::milliseconds(100)) return;
    last_ = now;
    fraction = std::clamp(fraction, 0.0, 1.0);
    constexpr int kWidth = 30;
    const int filled = static_cast<int>(fraction * kWidth);
    std::string bar(static_cast<std::size_t>(filled), '#');
    bar.append(static_cast<std::size_t>(kWidth - filled), '.');
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    std::string eta;
    if (fraction > 0.02 && fraction < 1.0) eta = "  ETA " + human_seconds(elapsed * (1.0 - fraction) / fraction);
    std::fprintf(out_, "\r\033[K%s [%s] %3.0f%%  %s%s", label_.c_str(), bar.c_str(), fraction * 100.0, detail.c_str(), eta.c_str());
    std::fflush(out_);
    drawn_ = true;
}

void ProgressBar::finish() {
    if (enabled_ && drawn_) {
        std::fprintf(out_, "\r\033[K");
        std::fflush(out_);
    }
    drawn_ = false;
}

StderrCapture::StderrCapture() {
    std::fflush(stderr);
    file_ = std::tmpfile();
    if (!file_) return;  // no capture: library messages stay on stderr
    saved_ = ::dup(STDERR_FILENO);
    if (saved_ < 0 || ::dup2(::fileno(file_), STDERR_FILENO) < 0) {
        if (saved_ >= 0) ::close(saved_);
        saved_ = -1;
        std::fclose(file_);
        file_ = nullptr;
    }
}

StderrCapture::~StderrCapture() { (void)release(); }

std::string StderrCapture::release() {
    std::string text;
    if (!file_) return text;
    std::fflush(stderr);
    ::dup2(saved_, STDERR_FILENO);
    ::close(saved_);
    saved_ = -1;
    std::rewind(file_);
    char buf[4096];
    std::size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, file_)) > 0) text.append(buf, n);
    std::fclose(file_);
    file_ = nullptr;
    return text;
}

std::string human_bytes(std::uint64_t b) {
    const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
    double v = static_cast<double>(b);
    int u = 0;
    while (v >= 1024.0 && u < 4) {
        v /= 1024.0;
        ++u;
    }
    char buf[32];
    std::snprintf(buf, sizeof buf, u == 0 ? "%.0f %s" : "%.1f %s", v, units[u]);
    return buf;
}

std::string human_seconds(double s) {
    char buf[32];
    if (s < 60) std::snprintf(buf, sizeof buf, "%.1fs", s);
    else if (s < 3600) std::snprintf(buf, sizeof buf, "%dm%02ds", int(s) / 60, int(s) % 60);
    else std::snprintf(buf, sizeof buf, "%dh%02dm", int(s) / 3600, (int(s) % 3600) / 60);
    return buf;
}

}  // namespace tessera::tools
