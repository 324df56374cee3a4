#include "metrics.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <iterator>
#include <limits>
#include <stdexcept>
#include <string_view>
#include <system_error>

namespace tessera::server {

namespace {

constexpr auto relaxed = std::memory_order_relaxed;

bool is_name_start(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_'; }
bool is_digit(char c) { return c >= '0' && c <= '9'; }

// [a-zA-Z_:][a-zA-Z0-9_:]*  (by hand: no locale, no std::regex)
bool is_metric_name(std::string_view s) {
    if (s.empty()) return false;
    for (std::size_t i = 0; i < s.size(); ++i) {
        const char c = s[i];
        if (!(is_name_start(c) || c == ':' || (i > 0 && is_digit(c)))) return false;
    }
    return true;
}

// [a-zA-Z_][a-zA-Z0-9_]*
bool is_label_name(std::string_view s) {
    if (s.empty()) return false;
    for (std::size_t i = 0; i < s.size(); ++i) {
        const char c = s[i];
        if (!(is_name_start(c) || (i > 0 && is_digit(c)))) return false;
    }
    return true;
}

// Length of the well-formed UTF-8 sequence starting at s[i], 0 when ill-formed
// (overlong forms, surrogates and code points above U+10FFFF are ill-formed).
std::size_t utf8_sequence_length(std::string_view s, std::size_t i) {
    auto byte = [&](std::size_t k) { return static_cast<unsigned char>(s[k]); };
    const unsigned char c = byte(i);
    if (c < 0x80) return 1;
    std::size_t n = 0;
    unsigned char lo = 0x80, hi = 0xBF;  // allowed range of the second byte
    if (c >= 0xC2 && c <= 0xDF) n = 2;
    else if (c == 0xE0) n = 3, lo = 0xA0;
    else if ((c >= 0xE1 && c <= 0xEC) || c == 0xEE || c == 0xEF) n = 3;
    else if (c == 0xED) n = 3, hi = 0x9F;
    else if (c == 0xF0) n = 4, lo = 0x90;
    else if (c >= 0xF1 && c <= 0xF3) n = 4;
    else if (c == 0xF4) n = 4, hi = 0x8F;
    else return 0;
    if (i + n > s.size() || byte(i + 1) < lo || byte(i + 1) > hi) return 0;
    for (std::size_t k = 2; k < n; ++k)
        if (byte(i + k) < 0x80 || byte(i + k) > 0xBF) return 0;
    return n;
}

// Label values and help texts must be UTF-8 in the exposition; ill-formed bytes (a store named
// from a Latin-1 file name, say) become U+FFFD at registration, so the same bytes always map to
// the same series and the output always parses.
std::string sanitize_utf8(std::string_view s) {
    std::string out;
    out.reserve(s.size());
    for (std::size_t i = 0; i < s.size();) {
        const std::size_t n = utf8_sequence_length(s, i);
        if (n == 0) {
            out += "\xEF\xBF\xBD";
            ++i;
        } else {
            out.append(s.substr(i, n));
            i += n;
        }
    }
    return out;
}

// Validated labels, sorted by name: the key under which a family stores its series, so the
// same label set given in another order is the same series.
Labels canonical_labels(const Labels& labels, bool histogram) {
    Labels out;
    out.reserve(labels.size());
    for (const auto& [k, v] : labels) {
        if (!is_label_name(k)) throw std::invalid_argument("invalid metric label name \"" + k + "\"");
        if (k.starts_with("__")) throw std::invalid_argument("label names starting with __ are reserved: \"" + k + "\"");
        if (histogram && k == "le") throw std::invalid_argument("label name \"le\" is reserved for histogram buckets");
        out.emplace_back(k, sanitize_utf8(v));
    }
    std::sort(out.begin(), out.end());
    for (std::size_t i = 1; i < out.size(); ++i)
        if (out[i].first == out[i - 1].first)
            throw std::invalid_argument("label \"" + out[i].first + "\" given twice");
    return out;
}

// Drops a trailing +Inf (the +Inf bucket is implicit); bounds must be strictly increasing, no NaN.
std::vector<double> normalize_bounds(std::vector<double> b) {
    if (!b.empty() && b.back() == std::numeric_limits<double>::infinity()) b.pop_back();
    for (std::size_t i = 0; i < b.size(); ++i) {
        if (std::isnan(b[i])) throw std::invalid_argument("histogram bucket bound is NaN");
        if (i > 0 && !(b[i - 1] < b[i]))
            throw std::invalid_argument("histogram bucket bounds must be strictly increasing");
    }
    return b;
}

void cas_add(std::atomic<double>& a, double d) {
    double cur = a.load(relaxed);
    while (!a.compare_exchange_weak(cur, cur + d, relaxed, relaxed)) {
    }
}

// Shortest text that parses back to the same double, laid out like Go's
// strconv.FormatFloat(v, 'g', -1, 64) (what the Prometheus client libraries print): plain
// digits for decimal exponents -4..20, so integers up to 1e21 have no exponent; else 1.5e-05.
void append_double(std::string& out, double v) {
    if (std::isnan(v)) {
        out += "NaN";
        return;
    }
    if (std::isinf(v)) {
        out += v > 0 ? "+Inf" : "-Inf";
        return;
    }
    char buf[128];
    const auto sci = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::scientific);
    const std::string_view s(buf, static_cast<std::size_t>(sci.ptr - buf));
    const std::size_t e = s.find('e');
    int exp = 0;
    if (e != std::string_view::npos) {
        const char* p = s.data() + e + 1;
        if (*p == '+') ++p;
        std::from_chars(p, s.data() + s.size(), exp);
    }
    if (exp < -4 || exp >= 21) {
        out += s;
        return;
    }
    const auto fixed = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::fixed);
    out.append(buf, fixed.ptr);
}

void append_uint(std::string& out, std::uint64_t v) {
    char buf[24];
    const auto r = std::to_chars(buf, buf + sizeof buf, v);
    out.append(buf, r.ptr);
}

void append_escaped_help(std::string& out, std::string_view s) {
    for (char c : s) {
        if (c == '\\') out += "\\\\";
        else if (c == '\n') out += "\\n";
        else out += c;
    }
}

void append_escaped_label_value(std::string& out, std::string_view s) {
    for (char c : s) {
        if (c == '\\') out += "\\\\";
        else if (c == '"') out += "\\\"";
        else if (c == '\n') out += "\\n";
        else out += c;
    }
}

// name+suffix{k="v",...[,le="bound"]} followed by a space; no braces when there are no labels.
void append_series(std::string& out, std::string_view name, std::string_view suffix, const Labels& labels,
                   const std::string* le = nullptr) {
    out += name;
    out += suffix;
    if (!labels.empty() || le) {
        out += '{';
        bool first = true;
        for (const auto& [k, v] : labels) {
            if (!first) out += ',';
            first = false;
            out += k;
            out += "=\"";
            append_escaped_label_value(out, v);
            out += '"';
        }
        if (le) {
            if (!first) out += ',';
            out += "le=\"";
            out += *le;
            out += '"';
        }
        out += '}';
    }
    out += ' ';
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Gauge, Histogram

void Gauge::add(double d) { cas_add(value_, d); }

std::size_t next_metric_stripe() {
    static std::atomic<std::size_t> next{0};
    return next.fetch_add(1, relaxed) % kMetricStripes;
}

Histogram::Histogram(std::vector<double> upper_bounds)
    : bounds_(normalize_bounds(std::move(upper_bounds))),
      row_((bounds_.size() + 1 + 7) / 8 * 8),
      buckets_(std::make_unique<std::atomic<std::uint64_t>[]>(row_ * kMetricStripes)),
      sums_(std::make_unique<Sum[]>(kMetricStripes)) {}

void Histogram::observe(double v) {
    // A NaN has no bucket, and would turn _sum into NaN for the rest of the process: dropped.
    if (std::isnan(v)) return;
    // First bound >= v: a value equal to a bound counts in that bucket (Prometheus `le`);
    // above every bound (or +Inf) it lands in the implicit +Inf bucket at index size().
    const auto i = static_cast<std::size_t>(std::lower_bound(bounds_.begin(), bounds_.end(), v) - bounds_.begin());
    const std::size_t stripe = metric_stripe();
    buckets_[stripe * row_ + i].fetch_add(1, relaxed);
    cas_add(sums_[stripe].value, v);
}

Histogram::Snapshot Histogram::snapshot() const {
    Snapshot s;
    s.upper_bounds = bounds_;
    s.cumulative.resize(bounds_.size() + 1);
    std::uint64_t acc = 0;
    for (std::size_t i = 0; i <= bounds_.size(); ++i) {
        for (std::size_t stripe = 0; stripe < kMetricStripes; ++stripe) acc += buckets_[stripe * row_ + i].load(relaxed);
        s.cumulative[i] = acc;
    }
    // The count is the bucket total: the atomics are read one by one while observe() runs, and
    // the exposition requires _count == the +Inf bucket exactly.
    s.count = acc;
    for (std::size_t stripe = 0; stripe < kMetricStripes; ++stripe) s.sum += sums_[stripe].value.load(relaxed);
    return s;
}

// As Prometheus histogram_quantile(): find the bucket holding rank q*count and interpolate
// linearly between its lower bound (0 for the first bucket) and upper bound. A rank in the
// +Inf bucket answers the highest finite bound. q is clamped to [0, 1]; q = 0 answers the
// lower edge of the first non-empty bucket (the plain formula would divide by an empty bucket).
double Histogram::quantile(double q) const {
    const Snapshot s = snapshot();
    if (s.count == 0) return 0;
    if (std::isnan(q)) return std::numeric_limits<double>::quiet_NaN();
    if (s.upper_bounds.empty()) return std::numeric_limits<double>::quiet_NaN();  // only +Inf: no scale
    q = std::clamp(q, 0.0, 1.0);
    double rank = q * static_cast<double>(s.count);
    const std::size_t n = s.upper_bounds.size();
    std::size_t b = 0;
    while (b < n && !(s.cumulative[b] > 0 && static_cast<double>(s.cumulative[b]) >= rank)) ++b;
    if (b == n) return s.upper_bounds[n - 1];
    const double end = s.upper_bounds[b];
    if (b == 0 && end <= 0) return end;
    double start = 0;
    double in_bucket = static_cast<double>(s.cumulative[b]);
    if (b > 0) {
        start = s.upper_bounds[b - 1];
        in_bucket -= static_cast<double>(s.cumulative[b - 1]);
        rank -= static_cast<double>(s.cumulative[b - 1]);
    }
    return start + (end - start) * (rank / in_bucket);
}

std::vector<double> latency_buckets_seconds() {
    // 1-2-5 steps, 50 µs .. 10 s (17 bounds). Written as literals so they print as 5e-05, 0.0001, ...
    return {50e-6, 100e-6, 200e-6, 500e-6, 1e-3, 2e-3, 5e-3, 10e-3, 20e-3,
            50e-3, 100e-3, 200e-3, 500e-3, 1.0,  2.0,  5.0,  10.0};
}

// ---------------------------------------------------------------------------------------------
// MetricsRegistry

struct MetricsRegistry::Family {
    // One series: exactly one of the members is set, matching the family type (gauge families
    // hold either a Gauge or a callback per label set).
    struct Entry {
        std::unique_ptr<Counter> counter;
        std::unique_ptr<Gauge> gauge;
        std::unique_ptr<Histogram> histogram;
        std::function<double()> callback;
    };
    std::string help;
    Type type = Type::counter;
    std::vector<double> bounds;       // histogram families: one set of bounds for every series
    std::map<Labels, Entry> metrics;  // keyed by canonical (name-sorted) labels: render order

    // The series of `key`, added empty when there is none (the caller fills it).
    Entry& series(Labels key) { return metrics.try_emplace(std::move(key)).first->second; }

    static const char* type_name(Type t) {
        switch (t) {
            case Type::counter: return "counter";
            case Type::gauge: return "gauge";
            case Type::histogram: return "histogram";
        }
        return "untyped";
    }
};

MetricsRegistry::MetricsRegistry() = default;
MetricsRegistry::~MetricsRegistry() = default;

namespace {
constexpr std::string_view histogram_suffixes[] = {"_bucket", "_sum", "_count"};
}  // namespace

// Caller holds mutex_.
MetricsRegistry::Family& MetricsRegistry::family(const std::string& name, const std::string& help, Type type) {
    if (!is_metric_name(name)) throw std::invalid_argument("invalid metric name \"" + name + "\"");
    if (auto it = families_.find(name); it != families_.end()) {
        if (it->second->type != type)
            throw std::invalid_argument("metric \"" + name + "\" is a " + Family::type_name(it->second->type) +
                                        ", requested as a " + Family::type_name(type));
        return *it->second;  // the first help text stays
    }
    // A histogram's series are name_bucket/_sum/_count: no other family may be called that.
    for (std::string_view suffix : histogram_suffixes) {
        if (name.ends_with(suffix)) {
            auto base = families_.find(name.substr(0, name.size() - suffix.size()));
            if (base != families_.end() && base->second->type == Type::histogram)
                throw std::invalid_argument("metric \"" + name + "\" collides with histogram \"" + base->first + "\"");
        }
        if (type == Type::histogram && families_.count(name + std::string(suffix)))
            throw std::invalid_argument("histogram \"" + name + "\" collides with metric \"" + name +
                                        std::string(suffix) + "\"");
    }
    auto f = std::make_unique<Family>();
    f->help = sanitize_utf8(help);
    f->type = type;
    return *families_.emplace(name, std::move(f)).first->second;
}

Counter& MetricsRegistry::counter(const std::string& name, const std::string& help, const Labels& labels) {
    Labels key = canonical_labels(labels, false);
    std::lock_guard lock(mutex_);
    Family::Entry& e = family(name, help, Type::counter).series(std::move(key));
    if (!e.counter) e.counter = std::make_unique<Counter>();
    return *e.counter;
}

Gauge& MetricsRegistry::gauge(const std::string& name, const std::string& help, const Labels& labels) {
    Labels key = canonical_labels(labels, false);
    std::lock_guard lock(mutex_);
    Family::Entry& e = family(name, help, Type::gauge).series(std::move(key));
    if (e.callback) throw std::invalid_argument("gauge \"" + name + "\" with these labels is already a callback gauge");
    if (!e.gauge) e.gauge = std::make_unique<Gauge>();
    return *e.gauge;
}

Histogram& MetricsRegistry::histogram(const std::string& name, const std::string& help, const Labels& labels,
                                      std::vector<double> upper_bounds) {
    Labels key = canonical_labels(labels, true);
    std::vector<double> bounds = normalize_bounds(std::move(upper_bounds));
    std::lock_guard lock(mutex_);
    Family& f = family(name, help, Type::histogram);
    if (f.metrics.empty()) f.bounds = bounds;  // histogram families are never emptied: just created
    else if (f.bounds != bounds)
        throw std::invalid_argument("histogram \"" + name + "\" was registered with other bucket bounds");
    Family::Entry& e = f.series(std::move(key));
    if (!e.histogram) e.histogram = std::make_unique<Histogram>(std::move(bounds));
    return *e.histogram;
}

void MetricsRegistry::gauge_callback(const std::string& name, const std::string& help, const Labels& labels,
                                     std::function<double()> read) {
    if (!read) throw std::invalid_argument("gauge callback \"" + name + "\" is empty");
    Labels key = canonical_labels(labels, false);
    std::lock_guard lock(mutex_);
    Family::Entry& e = family(name, help, Type::gauge).series(std::move(key));
    if (e.gauge) throw std::invalid_argument("gauge \"" + name + "\" with these labels is already a plain gauge");
    e.callback = std::move(read);  // registering again replaces the callback
}

void MetricsRegistry::remove_callbacks(const std::string& name) {
    std::lock_guard lock(mutex_);
    auto it = families_.find(name);
    if (it == families_.end()) return;
    std::erase_if(it->second->metrics, [](const auto& kv) { return static_cast<bool>(kv.second.callback); });
    // An emptied family goes too, so the name may be registered again (with another type even).
    if (it->second->metrics.empty()) families_.erase(it);
}

std::string MetricsRegistry::render() const {
    std::string out;
    std::string le;
    // Callbacks run under the lock: remove_callbacks() returning means no callback of that name
    // is running or will run, so their owners may be destroyed. They must not call into the registry.
    std::lock_guard lock(mutex_);
    for (const auto& [name, f] : families_) {
        out += "# HELP ";
        out += name;
        if (!f->help.empty()) {
            out += ' ';
            append_escaped_help(out, f->help);
        }
        out += "\n# TYPE ";
        out += name;
        out += ' ';
        out += Family::type_name(f->type);
        out += '\n';
        for (const auto& [labels, e] : f->metrics) {
            switch (f->type) {
                case Type::counter:
                    append_series(out, name, "", labels);
                    append_uint(out, e.counter->value());
                    break;
                case Type::gauge: {
                    double v = std::numeric_limits<double>::quiet_NaN();
                    if (e.gauge) {
                        v = e.gauge->value();
                    } else {
                        try {
                            v = e.callback();
                        } catch (...) {
                            // A failing reader must not take /metrics down: NaN marks the gap.
                        }
                    }
                    append_series(out, name, "", labels);
                    append_double(out, v);
                    break;
                }
                case Type::histogram: {
                    const Histogram::Snapshot s = e.histogram->snapshot();
                    for (std::size_t i = 0; i < s.cumulative.size(); ++i) {
                        le.clear();
                        if (i < s.upper_bounds.size()) append_double(le, s.upper_bounds[i]);
                        else le = "+Inf";
                        append_series(out, name, "_bucket", labels, &le);
                        append_uint(out, s.cumulative[i]);
                        out += '\n';
                    }
                    append_series(out, name, "_sum", labels);
                    append_double(out, s.sum);
                    out += '\n';
                    append_series(out, name, "_count", labels);
                    append_uint(out, s.count);
                    break;
                }
            }
            out += '\n';
        }
    }
    return out;
}

}  // namespace tessera::server
