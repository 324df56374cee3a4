#pragma once
// A strict parser and validator for the Prometheus text exposition format 0.0.4, for tests (the
// metrics unit tests, and integration tests that scrape a live server's /metrics).
//
//   auto r = tessera::test::parse_prometheus_text(body);
//   ASSERT_TRUE(r.ok()) << r.error;                       // "line 7: invalid label name \"1x\""
//   EXPECT_EQ(r.value("tessera_store_requests_total", {{"store", "a"}}), 3.0);
//
// Checked, with the first offending line number in the error:
//  * the text is empty or ends with '\n'; every line is a comment or a sample (no empty lines,
//    no leading whitespace, no trailing whitespace after a sample);
//  * "# HELP name text" (escapes \\ and \n only) and "# TYPE name counter|gauge|histogram|summary|untyped",
//    each at most once per family, TYPE before the family's first sample; other "#" lines are comments;
//  * samples: name{label="value",...} value [timestamp]: metric names [a-zA-Z_:][a-zA-Z0-9_:]*, label
//    names [a-zA-Z_][a-zA-Z0-9_]* (not __name__, not twice in one sample), label values quoted with
//    the escapes \\ \" \n only and valid UTF-8, values Go-ParseFloat-style decimal floats or
//    [+-]Inf / NaN (no hex floats), timestamps integers;
//  * no duplicate sample (same name and label set, whatever the label order);
//  * a family's lines are contiguous (stricter than 0.0.4, as OpenMetrics; a renderer that groups
//    families never trips it);
//  * histograms: only name_bucket/_sum/_count samples; per label set, le labels that parse as
//    floats, strictly increasing, ending with +Inf; bucket counts non-negative and non-decreasing;
//    _sum and _count present, _count equal to the +Inf bucket; le only on _bucket;
//  * summaries: quantile label on the name samples only; counters: value not negative.
#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

namespace tessera::test {

using PromLabels = std::map<std::string, std::string>;

struct PromSample {
    std::string name;    // as written: tessera_tile_seconds_bucket
    PromLabels labels;   // unescaped values; le included for buckets
    double value = 0;
    std::optional<std::int64_t> timestamp_ms;
    std::string family;  // tessera_tile_seconds for the _bucket/_sum/_count of a histogram
    std::size_t line = 0;
};

struct PromParseResult {
    std::string error;       // "line N: reason"; empty when the text is valid
    std::size_t error_line = 0;
    std::vector<PromSample> samples;            // in text order (empty on error)
    std::map<std::string, std::string> types;   // every family: counter|gauge|histogram|summary|untyped
    std::map<std::string, std::string> helps;   // families with a HELP line, unescaped

    bool ok() const { return error.empty(); }

    const PromSample* find(std::string_view name, const PromLabels& labels = {}) const {
        for (const auto& s : samples)
            if (s.name == name && s.labels == labels) return &s;
        return nullptr;
    }
    std::optional<double> value(std::string_view name, const PromLabels& labels = {}) const {
        const PromSample* s = find(name, labels);
        return s ? std::optional<double>(s->value) : std::nullopt;
    }
    // Every sample called `name`, in text order.
    std::vector<const PromSample*> all(std::string_view name) const {
        std::vector<const PromSample*> out;
        for (const auto& s : samples)
            if (s.name == name) out.push_back(&s);
        return out;
    }
};

namespace prom_detail {

inline bool is_name_start(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_'; }
inline bool is_digit(char c) { return c >= '0' && c <= '9'; }
inline bool is_metric_name_char(char c, bool first) { return is_name_start(c) || c == ':' || (!first && is_digit(c)); }
inline bool is_label_name_char(char c, bool first) { return is_name_start(c) || (!first && is_digit(c)); }
inline bool is_blank(char c) { return c == ' ' || c == '\t'; }

inline bool is_metric_name(std::string_view s) {
    if (s.empty()) return false;
    for (std::size_t i = 0; i < s.size(); ++i)
        if (!is_metric_name_char(s[i], i == 0)) return false;
    return true;
}

inline bool is_valid_utf8(std::string_view s) {
    auto byte = [&](std::size_t k) { return static_cast<unsigned char>(s[k]); };
    for (std::size_t i = 0; i < s.size();) {
        const unsigned char c = byte(i);
        if (c < 0x80) {
            ++i;
            continue;
        }
        std::size_t n = 0;
        unsigned char lo = 0x80, hi = 0xBF;
        if (c >= 0xC2 && c <= 0xDF) n = 2;
        else if (c == 0xE0) n = 3, lo = 0xA0;
        else if ((c >= 0xE1 && c <= 0xEC) || c == 0xEE || c == 0xEF) n = 3;
        else if (c == 0xED) n = 3, hi = 0x9F;
        else if (c == 0xF0) n = 4, lo = 0x90;
        else if (c >= 0xF1 && c <= 0xF3) n = 4;
        else if (c == 0xF4) n = 4, hi = 0x8F;
        else return false;
        if (i + n > s.size() || byte(i + 1) < lo || byte(i + 1) > hi) return false;
        for (std::size_t k = 2; k < n; ++k)
            if (byte(i + k) < 0x80 || byte(i + k) > 0xBF) return false;
        i += n;
    }
    return true;
}

// For error messages: the text with control bytes and quotes escaped, cut at 60 bytes.
inline std::string show(std::string_view s) {
    std::string out = "\"";
    for (std::size_t i = 0; i < s.size() && i < 60; ++i) {
        const unsigned char c = static_cast<unsigned char>(s[i]);
        if (c == '"' || c == '\\') out += '\\', out += static_cast<char>(c);
        else if (c == '\n') out += "\\n";
        else if (c == '\t') out += "\\t";
        else if (c == '\r') out += "\\r";
        else if (c < 0x20 || c == 0x7F) {
            const char* hex = "0123456789abcdef";
            out += "\\x";
            out += hex[c >> 4];
            out += hex[c & 15];
        } else {
            out += static_cast<char>(c);
        }
    }
    if (s.size() > 60) out += "...";
    return out + "\"";
}

inline bool iequals(std::string_view a, std::string_view b) {
    if (a.size() != b.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i) {
        char x = a[i], y = b[i];
        if (x >= 'A' && x <= 'Z') x = static_cast<char>(x - 'A' + 'a');
        if (y >= 'A' && y <= 'Z') y = static_cast<char>(y - 'A' + 'a');
        if (x != y) return false;
    }
    return true;
}

// A float as Go's strconv.ParseFloat reads it (what Prometheus uses), minus hex floats and
// underscores: [+-](digits[.digits]|.digits)[(e|E)[+-]digits], [+-]Inf/Infinity and NaN in any
// case. Overflow is an error; underflow gives 0 or a subnormal, as in Go.
inline bool parse_float(std::string_view s, double& out) {
    if (s.empty()) return false;
    std::string_view body = s;
    bool negative = false, signed_ = false;
    if (body[0] == '+' || body[0] == '-') {
        negative = body[0] == '-';
        signed_ = true;
        body.remove_prefix(1);
    }
    if (iequals(body, "inf") || iequals(body, "infinity")) {
        out = negative ? -std::numeric_limits<double>::infinity() : std::numeric_limits<double>::infinity();
        return true;
    }
    if (!signed_ && iequals(body, "nan")) {
        out = std::numeric_limits<double>::quiet_NaN();
        return true;
    }
    std::size_t i = 0, int_digits = 0, frac_digits = 0;
    while (i < body.size() && is_digit(body[i])) ++i, ++int_digits;
    if (i < body.size() && body[i] == '.') {
        ++i;
        while (i < body.size() && is_digit(body[i])) ++i, ++frac_digits;
    }
    if (int_digits + frac_digits == 0) return false;
    if (i < body.size() && (body[i] == 'e' || body[i] == 'E')) {
        ++i;
        if (i < body.size() && (body[i] == '+' || body[i] == '-')) ++i;
        std::size_t exp_digits = 0;
        while (i < body.size() && is_digit(body[i])) ++i, ++exp_digits;
        if (exp_digits == 0) return false;
    }
    if (i != body.size()) return false;
    // from_chars takes a '-' but no '+'; the grammar was checked above.
    const std::string_view num = s[0] == '+' ? s.substr(1) : s;
    const auto r = std::from_chars(num.data(), num.data() + num.size(), out);
    if (r.ec == std::errc() && r.ptr == num.data() + num.size()) return true;
    if (r.ec != std::errc::result_out_of_range) return false;
    // Out of range: overflow (an error, as in Go) or underflow (Go answers the rounded value).
    const std::string copy(num);
    char* end = nullptr;
    errno = 0;
    const double d = std::strtod(copy.c_str(), &end);
    if (end != copy.c_str() + copy.size() || std::isinf(d)) return false;
    out = d;
    return true;
}

class Parser {
public:
    explicit Parser(std::string_view text) : text_(text) {}

    PromParseResult run() {
        std::size_t pos = 0;
        while (pos < text_.size() && result_.error.empty()) {
            ++line_no_;
            const std::size_t nl = text_.find('\n', pos);
            if (nl == std::string_view::npos) {
                fail("the text does not end with a newline");
                break;
            }
            line(text_.substr(pos, nl - pos));
            pos = nl + 1;
        }
        if (result_.error.empty() && !current_.empty()) finish_family(current_);
        if (!result_.error.empty()) {
            result_.samples.clear();
            result_.types.clear();
            result_.helps.clear();
            return std::move(result_);
        }
        for (const auto& [name, f] : families_) {
            result_.types[name] = f.type;
            if (f.help) result_.helps[name] = *f.help;
        }
        return std::move(result_);
    }

private:
    struct HistogramSeries {
        std::size_t first_line = 0;
        std::vector<std::pair<double, double>> buckets;  // le, value in text order
        std::optional<double> sum, count;
    };
    struct Family {
        std::string type = "untyped";
        bool has_type = false;
        bool has_samples = false;
        std::optional<std::string> help;
        std::map<PromLabels, HistogramSeries> series;  // histograms, keyed by labels without le
    };

    bool fail(const std::string& reason, std::size_t at = 0) {
        if (result_.error.empty()) {
            result_.error_line = at ? at : line_no_;
            result_.error = "line " + std::to_string(result_.error_line) + ": " + reason;
        }
        return false;
    }

    static std::string_view strip_suffix(std::string_view name, std::string_view suffix) {
        if (name.size() > suffix.size() && name.ends_with(suffix)) return name.substr(0, name.size() - suffix.size());
        return {};
    }

    // The family a sample belongs to: base of a declared histogram/summary, else its own name.
    std::string family_of(std::string_view name) const {
        for (std::string_view suffix : {std::string_view("_bucket"), std::string_view("_sum"), std::string_view("_count")}) {
            const std::string_view base = strip_suffix(name, suffix);
            if (base.empty()) continue;
            auto it = families_.find(std::string(base));
            if (it == families_.end()) continue;
            if (it->second.type == "histogram" || (it->second.type == "summary" && suffix != "_bucket"))
                return std::string(base);
        }
        return std::string(name);
    }

    // Makes `name` the current family: families are contiguous, so one seen before is an error.
    bool enter_family(const std::string& name) {
        if (name == current_) return true;
        if (!current_.empty() && !finish_family(current_)) return false;
        if (families_.count(name))
            return fail("family " + show(name) + " continues here after other families (its lines must be contiguous)");
        families_[name];
        current_ = name;
        return true;
    }

    // End-of-family checks: every histogram series complete and consistent.
    bool finish_family(const std::string& name) {
        const Family& f = families_[name];
        if (f.type != "histogram") return true;
        for (const auto& [key, s] : f.series) {
            const std::string what = "histogram " + show(name) + " series " + show_labels(key) + ": ";
            if (s.buckets.empty() || s.buckets.back().first != std::numeric_limits<double>::infinity())
                return fail(what + "no le=\"+Inf\" bucket", s.first_line);
            if (!s.count) return fail(what + "no _count sample", s.first_line);
            if (!s.sum) return fail(what + "no _sum sample", s.first_line);
            if (*s.count != s.buckets.back().second)
                return fail(what + "_count differs from the le=\"+Inf\" bucket", s.first_line);
        }
        return true;
    }

    static std::string show_labels(const PromLabels& ls) {
        std::string out = "{";
        for (const auto& [k, v] : ls) {
            if (out.size() > 1) out += ',';
            out += k + "=" + show(v);
        }
        return out + "}";
    }

    void line(std::string_view l) {
        if (l.empty()) {
            fail("empty line");
            return;
        }
        if (is_blank(l.front())) {
            fail("line starts with whitespace");
            return;
        }
        if (l.front() == '#') {
            comment(l);  // trailing blanks are part of a HELP text or comment
            return;
        }
        if (is_blank(l.back())) {
            fail("line ends with whitespace");
            return;
        }
        sample(l);
    }

    void comment(std::string_view l) {
        // The keyword as Prometheus finds it: first token after '#' and optional blanks.
        std::size_t i = 1;
        while (i < l.size() && is_blank(l[i])) ++i;
        std::size_t j = i;
        while (j < l.size() && !is_blank(l[j])) ++j;
        const std::string_view keyword = l.substr(i, j - i);
        if (keyword != "HELP" && keyword != "TYPE") return;  // a plain comment
        const bool help = keyword == "HELP";
        const std::string_view prefix = help ? "# HELP " : "# TYPE ";
        if (!l.starts_with(prefix)) {
            fail(std::string("malformed ") + std::string(keyword) + " line (expected \"" + std::string(prefix) + "name ...\")");
            return;
        }
        std::string_view rest = l.substr(prefix.size());
        const std::size_t sp = rest.find(' ');
        const std::string_view name = rest.substr(0, sp);
        if (!is_metric_name(name)) {
            fail("invalid metric name " + show(name) + " in " + std::string(keyword) + " line");
            return;
        }
        const std::string_view arg = sp == std::string_view::npos ? std::string_view() : rest.substr(sp + 1);
        if (!check_metadata_name(name)) return;
        const std::string fam(name);
        if (!enter_family(fam)) return;
        Family& f = families_[fam];
        if (help) {
            if (f.help) {
                fail("second HELP line for " + show(name));
                return;
            }
            std::string text;
            for (std::size_t k = 0; k < arg.size(); ++k) {
                if (arg[k] != '\\') {
                    text += arg[k];
                    continue;
                }
                if (k + 1 == arg.size()) {
                    fail("HELP text ends with a lone backslash");
                    return;
                }
                const char e = arg[++k];
                if (e == '\\') text += '\\';
                else if (e == 'n') text += '\n';
                else {
                    fail(std::string("invalid escape \\") + e + " in HELP text (only \\\\ and \\n)");
                    return;
                }
            }
            if (!is_valid_utf8(text)) {
                fail("HELP text is not valid UTF-8");
                return;
            }
            f.help = std::move(text);
            return;
        }
        if (f.has_type) {
            fail("second TYPE line for " + show(name));
            return;
        }
        if (f.has_samples) {
            fail("TYPE line for " + show(name) + " after its samples");
            return;
        }
        if (arg != "counter" && arg != "gauge" && arg != "histogram" && arg != "summary" && arg != "untyped") {
            fail("unknown metric type " + show(arg) + " for " + show(name));
            return;
        }
        if (arg == "histogram" || arg == "summary") {
            for (const char* suffix : {"_bucket", "_sum", "_count"}) {
                if (families_.count(fam + suffix)) {
                    fail("TYPE " + std::string(arg) + " for " + show(name) + " after samples named " + show(fam + suffix));
                    return;
                }
            }
        }
        f.type = std::string(arg);
        f.has_type = true;
    }

    // HELP/TYPE for name_bucket etc. while `name` is a histogram would be two families in one.
    bool check_metadata_name(std::string_view name) {
        for (std::string_view suffix : {std::string_view("_bucket"), std::string_view("_sum"), std::string_view("_count")}) {
            const std::string_view base = strip_suffix(name, suffix);
            if (base.empty()) continue;
            auto it = families_.find(std::string(base));
            if (it != families_.end() &&
                (it->second.type == "histogram" || (it->second.type == "summary" && suffix != "_bucket")))
                return fail("metadata for " + show(name) + " collides with " + it->second.type + " " + show(base));
        }
        return true;
    }

    void sample(std::string_view l) {
        PromSample s;
        s.line = line_no_;
        std::size_t i = 0;
        while (i < l.size() && is_metric_name_char(l[i], i == 0)) ++i;
        s.name = std::string(l.substr(0, i));
        if (s.name.empty() || (i < l.size() && l[i] != '{' && !is_blank(l[i]))) {
            std::size_t end = i;
            while (end < l.size() && l[end] != '{' && !is_blank(l[end])) ++end;
            fail("invalid metric name " + show(l.substr(0, end)));
            return;
        }
        if (i < l.size() && l[i] == '{' && !parse_labels(l, i, s.labels)) return;
        // One or more blanks, the value, then optionally blanks and a timestamp.
        if (i == l.size() || !is_blank(l[i])) {
            fail(i == l.size() ? "sample " + show(s.name) + " has no value" : "expected a blank before the value");
            return;
        }
        while (i < l.size() && is_blank(l[i])) ++i;
        std::size_t j = i;
        while (j < l.size() && !is_blank(l[j])) ++j;
        const std::string_view value = l.substr(i, j - i);
        if (!parse_float(value, s.value)) {
            fail("invalid sample value " + show(value));
            return;
        }
        if (j < l.size()) {
            while (j < l.size() && is_blank(l[j])) ++j;
            const std::string_view ts = l.substr(j);
            if (ts.find_first_of(" \t") != std::string_view::npos) {
                fail("unexpected text after the timestamp");
                return;
            }
            const std::string_view digits = !ts.empty() && (ts[0] == '+' || ts[0] == '-') ? ts.substr(1) : ts;
            const char* b = ts.data() + (ts[0] == '+' ? 1 : 0);  // from_chars takes '-' but no '+'
            std::int64_t t = 0;
            if (digits.empty() || !std::all_of(digits.begin(), digits.end(), is_digit) ||
                std::from_chars(b, ts.data() + ts.size(), t).ec != std::errc()) {
                fail("invalid timestamp " + show(ts));
                return;
            }
            s.timestamp_ms = t;
        }

        s.family = family_of(s.name);
        if (!enter_family(s.family)) return;
        Family& f = families_[s.family];
        f.has_samples = true;
        if (!seen_.emplace(s.name, s.labels).second) {
            fail("duplicate sample " + show(s.name) + " " + show_labels(s.labels));
            return;
        }
        if (!check_typed(f, s)) return;
        result_.samples.push_back(std::move(s));
    }

    // {name="value",...} starting at l[i] == '{'; blanks allowed around tokens, trailing comma allowed.
    bool parse_labels(std::string_view l, std::size_t& i, PromLabels& out) {
        ++i;
        auto skip = [&] {
            while (i < l.size() && is_blank(l[i])) ++i;
        };
        skip();
        while (true) {
            if (i == l.size()) return fail("unterminated label set");
            if (l[i] == '}') {
                ++i;
                return true;
            }
            std::size_t j = i;
            while (j < l.size() && is_label_name_char(l[j], j == i)) ++j;
            const std::string name(l.substr(i, j - i));
            if (name.empty() || (j < l.size() && l[j] != '=' && !is_blank(l[j]))) {
                std::size_t end = j;
                while (end < l.size() && l[end] != '=' && !is_blank(l[end]) && l[end] != ',' && l[end] != '}') ++end;
                return fail("invalid label name " + show(l.substr(i, std::max(end, i + 1) - i)));
            }
            if (name == "__name__") return fail("label name __name__ is reserved");
            i = j;
            skip();
            if (i == l.size() || l[i] != '=') return fail("expected '=' after label name " + show(name));
            ++i;
            skip();
            if (i == l.size() || l[i] != '"') return fail("label value for " + show(name) + " is not quoted");
            ++i;
            std::string value;
            bool closed = false;
            while (i < l.size()) {
                const char c = l[i++];
                if (c == '"') {
                    closed = true;
                    break;
                }
                if (c != '\\') {
                    value += c;
                    continue;
                }
                if (i == l.size()) break;
                const char e = l[i++];
                if (e == '\\') value += '\\';
                else if (e == '"') value += '"';
                else if (e == 'n') value += '\n';
                else return fail(std::string("invalid escape \\") + e + " in label value for " + show(name));
            }
            if (!closed) return fail("unterminated label value for " + show(name));
            if (!is_valid_utf8(value)) return fail("label value for " + show(name) + " is not valid UTF-8");
            if (!out.emplace(name, std::move(value)).second) return fail("label " + show(name) + " given twice");
            skip();
            if (i < l.size() && l[i] == ',') {
                ++i;
                skip();
            } else if (i == l.size() || l[i] != '}') {
                return fail(i == l.size() ? "unterminated label set" : "expected ',' or '}' after label " + show(name));
            }
        }
    }

    bool check_typed(Family& f, const PromSample& s) {
        if (f.type == "counter" && s.value < 0) return fail("counter " + show(s.name) + " is negative");
        if (f.type == "summary") {
            const bool quantile = s.labels.count("quantile") > 0;
            if (s.name == s.family && !quantile) return fail("summary sample " + show(s.name) + " has no quantile label");
            if (s.name != s.family && quantile) return fail("quantile label on " + show(s.name));
            if (quantile) {
                double q = 0;
                if (!parse_float(s.labels.at("quantile"), q)) return fail("invalid quantile label value");
            }
        }
        if (f.type != "histogram") return true;
        const std::string_view suffix = std::string_view(s.name).substr(s.family.size());
        if (suffix != "_bucket" && suffix != "_sum" && suffix != "_count")
            return fail("histogram " + show(s.family) + " has a sample " + show(s.name) +
                        " (only _bucket, _sum and _count)");
        PromLabels key = s.labels;
        const bool has_le = key.erase("le") > 0;
        HistogramSeries& series = f.series[key];
        if (!series.first_line) series.first_line = s.line;
        if (suffix == "_bucket") {
            if (!has_le) return fail("histogram bucket " + show(s.name) + " has no le label");
            double le = 0;
            if (!parse_float(s.labels.at("le"), le) || std::isnan(le))
                return fail("invalid le label value " + show(s.labels.at("le")));
            if (!(s.value >= 0)) return fail("bucket count " + show(s.name) + " is negative or NaN");
            if (!series.buckets.empty()) {
                const auto [prev_le, prev_value] = series.buckets.back();
                if (!(prev_le < le))
                    return fail("le=" + show(s.labels.at("le")) + " does not follow the previous bucket's le in increasing order");
                if (s.value < prev_value) return fail("bucket counts decrease at le=" + show(s.labels.at("le")));
            }
            series.buckets.emplace_back(le, s.value);
            return true;
        }
        if (has_le) return fail("le label on " + show(s.name));
        if (suffix == "_sum") series.sum = s.value;
        else {
            if (!(s.value >= 0)) return fail("histogram count " + show(s.name) + " is negative or NaN");
            series.count = s.value;
        }
        return true;
    }

    std::string_view text_;
    std::size_t line_no_ = 0;
    PromParseResult result_;
    std::map<std::string, Family> families_;
    std::string current_;
    std::set<std::pair<std::string, PromLabels>> seen_;
};

}  // namespace prom_detail

inline PromParseResult parse_prometheus_text(std::string_view text) { return prom_detail::Parser(text).run(); }

}  // namespace tessera::test
