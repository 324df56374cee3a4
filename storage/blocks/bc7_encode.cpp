// BC7 encoding for the store builder: quality first, time second.
//
// Per block: a uniform block takes a table-made mode 5 block that decodes exactly. Otherwise every
// mode the effort level allows is encoded once, quickly: per subset, one endpoint pair from the
// texels' principal axis, quantised with the p-bits nearest, each texel's index the palette entry
// of least error, then endpoints re-fitted to those indices by least squares. The partitioned modes
// try only the partitions that a cheap estimate ranks best (the texels' squared distance from their
// subset's best-fit line, for all 64 partitions). The few best candidates are then encoded again
// with every p-bit pair, more least-squares rounds and a search of the neighbouring quantised
// endpoints, and the block with the least squared error wins. Opaque blocks (all 16 alphas 255)
// only try encodings that decode alpha 255.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <iterator>
#include <limits>
#include <utility>

#include "bc7_tables.hpp"
#include "tessera/blocks/bc7.hpp"

namespace tessera::blocks {
namespace {

using bc7::kModes;
using bc7::kNoPbit;
using bc7::kSharedPbit;
using bc7::kUniquePbit;

constexpr std::uint32_t kWorst = std::numeric_limits<std::uint32_t>::max();

// What an effort level spends.
struct Plan {
    int quick_lsq;       // least-squares rounds in the first pass over all candidates
    bool all_pbits;      // first pass: evaluate every p-bit pair, not only the pair nearest the endpoints
    int top2, top3;      // partitions tried per 2- and 3-subset mode
    bool more_modes;     // modes 0 and 2 (three subsets) for opaque blocks, 7 for the others
    bool rotations;      // modes 4 and 5 with each channel as the separate one, not only alpha
    int refine;          // best candidates encoded again, thoroughly
    int refine_lsq;      // their least-squares rounds
    int refine_passes;   // their passes of the neighbouring-endpoint search
    bool exhaustive;     // their indices: every palette entry tried per texel, not only the three
                         // around its projection onto the palette (measured: no gain)
};
constexpr Plan kPlans[4] = {
    {1, false, 1, 0, false, false, 1, 2, 0, false},
    {1, false, 3, 1, true, false, 1, 4, 1, false},
    {1, false, 6, 3, true, true, 2, 8, 3, false},
    {2, true, 16, 8, true, true, 4, 16, 8, true},
};

// An endpoint pair's problem: up to 16 texels of `nch` channels, the bits per channel, p-bits,
// index bits, error weights, and how hard to try.
struct FitParams {
    int nch = 0;
    int bits[4] = {};
    int pbit = kNoPbit;
    unsigned pmask = 0xF;  // allowed p-bit pairs: bit (p0 | p1 << 1)
    int index_bits = 0;
    int wt[4] = {};
    bool exhaustive = false;  // every palette entry per texel, not only those around its projection
    bool all_pbits = false;
    int lsq = 1;
    int passes = 0;
};

struct Points {
    int n = 0;
    int x[16][4] = {};
};

struct Fit {
    int q[2][4] = {};  // stored endpoint values, p-bits apart
    int p[2] = {};
    std::uint8_t idx[16] = {};
    std::uint32_t err = kWorst;
};

// An 8-bit endpoint channel from its stored value and p-bit (-1: none).
constexpr int dequant(int q, int bits, int p) { return p < 0 ? bc7::expand(q, bits) : bc7::expand((q << 1) | p, bits + 1); }

// For each endpoint width (4..8 bits before the p-bit), p-bit (none, 0, 1) and 8-bit value: the
// stored value whose dequantised value is nearest. For each index width (2..4): the index whose
// weight is nearest each weight 0..64.
struct Tables {
    std::uint8_t quant[5][3][256] = {};
    std::uint8_t nearest_index[5][65] = {};
    // For each 2- and 3-subset partition: the texels of subsets 1 and 2.
    struct Members {
        std::uint8_t count[3] = {};
        std::uint8_t texel[3][16] = {};
    };
    Members members[2][64];
    Tables() {
        for (unsigned subsets = 2; subsets <= 3; ++subsets)
            for (unsigned part = 0; part < 64; ++part) {
                Members& m = members[subsets - 2][part];
                const std::uint8_t* subset = bc7::partition(subsets, part);
                for (std::uint8_t t = 0; t < 16; ++t) m.texel[subset[t]][m.count[subset[t]]++] = t;
            }
        for (int bits = 4; bits <= 8; ++bits)
            for (int p = -1; p <= (bits < 8 ? 1 : -1); ++p)
                for (int v = 0; v < 256; ++v) {
                    int best = 0, best_d = 1 << 30;
                    for (int q = 0; q < (1 << bits); ++q) {
                        const int d = std::abs(dequant(q, bits, p) - v);
                        if (d < best_d) best_d = d, best = q;
                    }
                    quant[bits - 4][p + 1][v] = std::uint8_t(best);
                }
        for (unsigned ib = 2; ib <= 4; ++ib)
            for (int w = 0; w <= 64; ++w) {
                const std::uint8_t* wts = bc7::weights(ib);
                int best = 0;
                for (int k = 1; k < (1 << ib); ++k)
                    if (std::abs(wts[k] - w) < std::abs(wts[best] - w)) best = k;
                nearest_index[ib][w] = std::uint8_t(best);
            }
    }
};
const Tables& tables() {
    static const Tables t;
    return t;
}

// The stored value whose dequantised value is nearest `x` (0..255).
inline int quantize(float x, int bits, int p) { return tables().quant[bits - 4][p + 1][int(x + 0.5f)]; }

// Fits one endpoint pair to the points, N channels.
template <int N>
class Fitter {
public:
    Fitter(const FitParams& fp, const Points& pts) : fp_(fp), n_(pts.n) {
        for (int i = 0; i < n_; ++i)
            for (int c = 0; c < N; ++c) x_[i][c] = pts.x[i][c];
        for (int c = 0; c < N; ++c) {
            wt_[c] = fp.wt[c];
            sw_[c] = std::sqrt(float(fp.wt[c]));
        }
        entries_ = 1 << fp.index_bits;
        w_ = bc7::weights(unsigned(fp.index_bits));
    }

    // The best endpoint pair found, or error kWorst if its error is not below `bound`.
    Fit run(std::uint32_t bound) const {
        Fit best;
        float e[2][4];
        initial_endpoints(e);
        try_endpoints(e, best, kWorst);
        // Without a neighbour search to follow, results at or above the bound are of no use.
        const std::uint32_t stop = fp_.passes ? kWorst : bound;
        for (int it = 0; it < fp_.lsq && best.err > 0; ++it) {
            const std::uint32_t before = best.err;
            if (!least_squares(best.idx, e)) break;
            try_endpoints(e, best, stop);
            if (best.err >= before) break;
        }
        if (best.err > 0) neighbour_search(best);
        return best.err < bound ? best : Fit{};
    }

private:
    // Error of the best index per texel for endpoints q and p-bits p; indices into `out`. Gives
    // kWorst once the error reaches `stop`.
    std::uint32_t evaluate(const int q[2][4], const int p[2], std::uint8_t* out, std::uint32_t stop) const {
        const bool has_p = fp_.pbit != kNoPbit;
        int pal[16][N];
        for (int c = 0; c < N; ++c) {
            const int d0 = dequant(q[0][c], fp_.bits[c], has_p ? p[0] : -1);
            const int d1 = dequant(q[1][c], fp_.bits[c], has_p ? p[1] : -1);
            for (int k = 0; k < entries_; ++k) pal[k][c] = bc7::interpolate(d0, d1, w_[k]);
        }
        auto error = [&](int i, int k) {
            std::uint32_t e = 0;
            for (int c = 0; c < N; ++c) {
                const int d = x_[i][c] - pal[k][c];
                e += std::uint32_t(wt_[c] * d * d);
            }
            return e;
        };
        std::uint8_t idx[16];
        std::uint32_t total = 0;
        if (fp_.exhaustive || entries_ == 4) {
            for (int i = 0; i < n_; ++i) {
                std::uint32_t best = error(i, 0);
                int best_k = 0;
                for (int k = 1; k < entries_; ++k) {
                    const std::uint32_t e = error(i, k);
                    if (e < best) best = e, best_k = k;
                }
                idx[i] = std::uint8_t(best_k);
                total += best;
                if (total >= stop) return kWorst;
            }
        } else {
            // The entry nearest the texel's projection onto the palette's line, and its neighbours.
            int dir[N], len2 = 0;
            for (int c = 0; c < N; ++c) {
                dir[c] = pal[entries_ - 1][c] - pal[0][c];
                len2 += wt_[c] * dir[c] * dir[c];
            }
            const float scale = len2 > 0 ? 64.f / float(len2) : 0.f;
            const std::uint8_t* nearest = tables().nearest_index[fp_.index_bits];
            for (int i = 0; i < n_; ++i) {
                int dot = 0;
                for (int c = 0; c < N; ++c) dot += wt_[c] * (x_[i][c] - pal[0][c]) * dir[c];
                const int k0 = nearest[std::clamp(int(float(dot) * scale + 0.5f), 0, 64)];
                std::uint32_t best = error(i, k0);
                int best_k = k0;
                if (k0 > 0) {
                    const std::uint32_t e = error(i, k0 - 1);
                    if (e < best) best = e, best_k = k0 - 1;
                }
                if (k0 < entries_ - 1) {
                    const std::uint32_t e = error(i, k0 + 1);
                    if (e < best) best = e, best_k = k0 + 1;
                }
                idx[i] = std::uint8_t(best_k);
                total += best;
                if (total >= stop) return kWorst;
            }
        }
        std::memcpy(out, idx, std::size_t(n_));
        return total;
    }

    // Endpoints at the extremes of the texels' projections onto their weighted principal axis.
    void initial_endpoints(float e[2][4]) const {
        float mean[N] = {};
        for (int i = 0; i < n_; ++i)
            for (int c = 0; c < N; ++c) mean[c] += float(x_[i][c]);
        for (int c = 0; c < N; ++c) mean[c] /= float(n_);
        float d[16][N];
        float cov[N][N] = {};
        for (int i = 0; i < n_; ++i) {
            for (int c = 0; c < N; ++c) d[i][c] = (float(x_[i][c]) - mean[c]) * sw_[c];
            for (int c = 0; c < N; ++c)
                for (int k = 0; k < N; ++k) cov[c][k] += d[i][c] * d[i][k];
        }
        // Power iteration from the channel of largest variance.
        int start = 0;
        for (int c = 1; c < N; ++c)
            if (cov[c][c] > cov[start][start]) start = c;
        float v[N] = {};
        v[start] = 1;
        for (int it = 0; it < 6; ++it) {
            float nv[N] = {}, len = 0;
            for (int c = 0; c < N; ++c)
                for (int k = 0; k < N; ++k) nv[c] += cov[c][k] * v[k];
            for (int c = 0; c < N; ++c) len += nv[c] * nv[c];
            if (len < 1e-12f) break;
            len = 1.f / std::sqrt(len);
            for (int c = 0; c < N; ++c) v[c] = nv[c] * len;
        }
        float tmin = 0, tmax = 0;
        for (int i = 0; i < n_; ++i) {
            float t = 0;
            for (int c = 0; c < N; ++c) t += d[i][c] * v[c];
            tmin = std::min(tmin, t);
            tmax = std::max(tmax, t);
        }
        for (int c = 0; c < N; ++c) {
            const float a = v[c] / sw_[c];
            e[0][c] = std::clamp(mean[c] + tmin * a, 0.f, 255.f);
            e[1][c] = std::clamp(mean[c] + tmax * a, 0.f, 255.f);
        }
    }

    // Quantises float endpoints with each allowed p-bit pair (or the pair nearest them) and keeps
    // the result in `best` if better; evaluations stop at `stop`.
    void try_endpoints(const float e[2][4], Fit& best, std::uint32_t stop) const {
        auto run = [&](int p0, int p1) {
            Fit f;
            f.p[0] = p0;
            f.p[1] = p1;
            const bool has_p = fp_.pbit != kNoPbit;
            for (int c = 0; c < N; ++c) {
                f.q[0][c] = quantize(e[0][c], fp_.bits[c], has_p ? p0 : -1);
                f.q[1][c] = quantize(e[1][c], fp_.bits[c], has_p ? p1 : -1);
            }
            f.err = evaluate(f.q, f.p, f.idx, std::min(stop, best.err));
            if (f.err < best.err) best = f;
        };
        if (fp_.pbit == kNoPbit) return run(0, 0);
        auto allowed = [&](int p0, int p1) {
            return ((fp_.pmask >> (p0 | (p1 << 1))) & 1) != 0 && (fp_.pbit != kSharedPbit || p0 == p1);
        };
        if (fp_.all_pbits) {
            for (int pair = 0; pair < 4; ++pair)
                if (allowed(pair & 1, pair >> 1)) run(pair & 1, pair >> 1);
            return;
        }
        float best_d = std::numeric_limits<float>::max();
        int bp0 = -1, bp1 = -1;
        for (int pair = 0; pair < 4; ++pair) {
            const int p0 = pair & 1, p1 = pair >> 1;
            if (!allowed(p0, p1)) continue;
            float d = 0;
            for (int c = 0; c < N; ++c)
                for (int k = 0; k < 2; ++k) {
                    const int pk = k ? p1 : p0;
                    const float diff = float(dequant(quantize(e[k][c], fp_.bits[c], pk), fp_.bits[c], pk)) - e[k][c];
                    d += float(wt_[c]) * diff * diff;
                }
            if (d < best_d) best_d = d, bp0 = p0, bp1 = p1;
        }
        if (bp0 >= 0) run(bp0, bp1);
    }

    // Endpoints of least squared error for the given indices, channel by channel; false when every
    // texel has the same weight (no line to fit).
    bool least_squares(const std::uint8_t* idx, float e[2][4]) const {
        float a = 0, b = 0, cc = 0, x0[N] = {}, x1[N] = {};
        for (int i = 0; i < n_; ++i) {
            const float t = float(w_[idx[i]]) * (1.f / 64.f), s = 1.f - t;
            a += s * s;
            b += s * t;
            cc += t * t;
            for (int c = 0; c < N; ++c) {
                x0[c] += s * float(x_[i][c]);
                x1[c] += t * float(x_[i][c]);
            }
        }
        const float det = a * cc - b * b;
        if (std::fabs(det) < 1e-6f) return false;
        const float inv = 1.f / det;
        for (int c = 0; c < N; ++c) {
            e[0][c] = std::clamp((cc * x0[c] - b * x1[c]) * inv, 0.f, 255.f);
            e[1][c] = std::clamp((a * x1[c] - b * x0[c]) * inv, 0.f, 255.f);
        }
        return true;
    }

    // Steps each stored endpoint value one up and down, and flips p-bits (re-quantising the
    // endpoint around the same value), while that lowers the error.
    void neighbour_search(Fit& best) const {
        for (int pass = 0; pass < fp_.passes && best.err > 0; ++pass) {
            const std::uint32_t before = best.err;
            for (int k = 0; k < 2; ++k)
                for (int c = 0; c < N; ++c)
                    for (int d = -1; d <= 1; d += 2) {
                        const int v = best.q[k][c] + d;
                        if (v < 0 || v > (1 << fp_.bits[c]) - 1) continue;
                        Fit f = best;
                        f.q[k][c] = v;
                        f.err = evaluate(f.q, f.p, f.idx, best.err);
                        if (f.err < best.err) best = f;
                    }
            if (fp_.pbit != kNoPbit) {
                for (int k = 0; k < (fp_.pbit == kUniquePbit ? 2 : 1); ++k) {
                    Fit f = best;
                    for (int j = 0; j < 2; ++j)  // a shared p-bit: both endpoints
                        if (j == k || fp_.pbit == kSharedPbit) f.p[j] ^= 1;
                    if (!((fp_.pmask >> (f.p[0] | (f.p[1] << 1))) & 1)) continue;
                    for (int j = 0; j < 2; ++j)
                        for (int c = 0; c < N; ++c)
                            f.q[j][c] = quantize(float(dequant(best.q[j][c], fp_.bits[c], best.p[j])), fp_.bits[c], f.p[j]);
                    f.err = evaluate(f.q, f.p, f.idx, best.err);
                    if (f.err < best.err) best = f;
                }
            }
            if (best.err >= before) break;
        }
    }

    const FitParams& fp_;
    int n_;
    int x_[16][N];
    int wt_[N];
    float sw_[N];
    int entries_;
    const std::uint8_t* w_;
};

Fit fit(const FitParams& fp, const Points& pts, std::uint32_t bound) {
    switch (fp.nch) {
        case 1: return Fitter<1>(fp, pts).run(bound);
        case 3: return Fitter<3>(fp, pts).run(bound);
        default: return Fitter<4>(fp, pts).run(bound);
    }
}

// A whole block's encoding in one mode.
struct Candidate {
    int mode = -1, partition = 0, rotation = 0, selector = 0;
    int q[6][4] = {};
    int p[6] = {};
    std::uint8_t color_idx[16] = {};  // the index set that serves colour (the only one outside modes 4, 5)
    std::uint8_t alpha_idx[16] = {};  // modes 4 and 5: the set that serves the separate channel
    std::uint32_t err = kWorst;
};

// Estimated error of each partition: per subset, the weighted squared distance of its texels from
// their best-fit line (the covariance's trace less its largest eigenvalue).
template <int N>
void estimate_partitions(const int px[16][4], const int wt[4], int subsets, float out[64]) {
    // Per texel: the channels and their pairwise products, in vectors of four (GCC / Clang vector
    // extension: SSE2 on x86-64, NEON on ARM).
    typedef std::int32_t V4i __attribute__((vector_size(16)));
    constexpr int kTerms = N + N * (N + 1) / 2, kVectors = (kTerms + 3) / 4;
    V4i terms[16][kVectors] = {}, all[kVectors] = {};
    for (int t = 0; t < 16; ++t) {
        std::int32_t flat[kVectors * 4] = {};
        int j = N;
        for (int c = 0; c < N; ++c) {
            flat[c] = px[t][c];
            for (int k = c; k < N; ++k) flat[j++] = px[t][c] * px[t][k];
        }
        std::memcpy(terms[t], flat, sizeof flat);
        for (int v = 0; v < kVectors; ++v) all[v] += terms[t][v];
    }
    float cw[N][N];
    for (int c = 0; c < N; ++c)
        for (int k = 0; k < N; ++k) cw[c][k] = std::sqrt(float(wt[c]) * float(wt[k]));
    for (int part = 0; part < 64; ++part) {
        // Sums over subsets 1 and 2; subset 0's are the rest.
        const Tables::Members& members = tables().members[subsets - 2][part];
        V4i vsum[3][kVectors] = {};
        for (int s = 1; s < subsets; ++s)
            for (int i = 0; i < members.count[s]; ++i)
                for (int v = 0; v < kVectors; ++v) vsum[s][v] += terms[members.texel[s][i]][v];
        for (int v = 0; v < kVectors; ++v) vsum[0][v] = all[v] - vsum[1][v] - vsum[2][v];
        std::int32_t sum[3][kVectors * 4];
        std::memcpy(sum, vsum, sizeof sum);
        const int n[3] = {members.count[0], members.count[1], members.count[2]};
        float total = 0;
        for (int s = 0; s < subsets; ++s) {
            float cov[N][N];
            const float inv_n = 1.f / float(n[s]);
            for (int c = 0, j = N; c < N; ++c)
                for (int k = c; k < N; ++k, ++j)
                    cov[c][k] = cov[k][c] = (float(sum[s][j]) - float(sum[s][c]) * float(sum[s][k]) * inv_n) * cw[c][k];
            // Largest eigenvalue, near enough: the Rayleigh quotient of the column of largest
            // variance (one power iteration from that axis).
            int start = 0;
            float trace = 0;
            for (int c = 0; c < N; ++c) {
                trace += cov[c][c];
                if (cov[c][c] > cov[start][start]) start = c;
            }
            float v[N];
            for (int c = 0; c < N; ++c) v[c] = cov[c][start];
            float num = 0, den = 0;
            for (int c = 0; c < N; ++c) {
                float cv = 0;
                for (int k = 0; k < N; ++k) cv += cov[c][k] * v[k];
                num += v[c] * cv;
                den += v[c] * v[c];
            }
            total += std::max(0.f, trace - (den > 0 ? num / den : 0.f));
        }
        out[part] = total;
    }
}

// The `count` partitions of least estimated error among the first `of`.
int best_partitions(const float est[64], int count, int of, int out[64]) {
    int order[64];
    for (int i = 0; i < of; ++i) order[i] = i;
    count = std::min(count, of);
    std::partial_sort(order, order + count, order + of, [&](int a, int b) { return est[a] < est[b]; });
    std::copy(order, order + count, out);
    return count;
}

class BlockEncoder {
public:
    BlockEncoder(const std::uint8_t rgba[64], const Bc7Options& opt) : plan_(kPlans[std::clamp(opt.effort, 0, 3)]) {
        for (int t = 0; t < 16; ++t) {
            for (int c = 0; c < 4; ++c) px_[t][c] = rgba[4 * t + c];
            opaque_ = opaque_ && rgba[4 * t + 3] == 255;
        }
        // Error weights per channel: the same total for R, G and B either way.
        static constexpr int kEven[4] = {16, 16, 16, 16}, kLuma[4] = {14, 28, 6, 16};
        std::copy_n(opt.perceptual ? kLuma : kEven, 4, wt_);
    }

    Candidate run() {
        // First pass: every candidate, quickly.
        consider(6, 0, 0, 0);
        for (int rot = 0; rot < (plan_.rotations ? 4 : 1); ++rot) {
            consider(5, 0, rot, 0);
            consider(4, 0, rot, 0);
            consider(4, 0, rot, 1);
        }
        int parts[64];
        float est[64];
        if (opaque_) {
            estimate_partitions<3>(px_, wt_, 2, est);
            const int n2 = best_partitions(est, plan_.top2, 64, parts);
            for (int i = 0; i < n2; ++i) consider(1, parts[i], 0, 0), consider(3, parts[i], 0, 0);
            if (plan_.more_modes) {
                estimate_partitions<3>(px_, wt_, 3, est);
                const int n3 = best_partitions(est, plan_.top3, 64, parts);
                for (int i = 0; i < n3; ++i) consider(2, parts[i], 0, 0);
                const int n0 = best_partitions(est, plan_.top3, 16, parts);  // mode 0: the first 16
                for (int i = 0; i < n0; ++i) consider(0, parts[i], 0, 0);
            }
        } else if (plan_.more_modes) {
            estimate_partitions<4>(px_, wt_, 2, est);
            const int n2 = best_partitions(est, plan_.top2, 64, parts);
            for (int i = 0; i < n2; ++i) consider(7, parts[i], 0, 0);
        }
        // Second pass: the best few again, thoroughly.
        for (int i = 0; i < kept_ && best_.err > 0; ++i) {
            const Candidate c = encode(top_[i].mode, top_[i].partition, top_[i].rotation, top_[i].selector, true, best_.err);
            if (c.err < best_.err) best_ = c;
        }
        return best_;
    }

private:
    struct Tried {
        std::uint32_t err;
        int mode, partition, rotation, selector;
    };

    // Encodes a candidate quickly; remembers it if among the best `plan_.refine`.
    void consider(int m, int partition, int rotation, int selector) {
        const std::uint32_t bound = kept_ > 0 && kept_ >= plan_.refine ? top_[std::size_t(kept_ - 1)].err : kWorst;
        const Candidate c = encode(m, partition, rotation, selector, false, bound);
        if (c.err >= bound) return;
        if (c.err < best_.err) best_ = c;
        int i = std::min(kept_, plan_.refine - 1);
        kept_ = std::min(kept_ + 1, plan_.refine);
        for (; i > 0 && top_[i - 1].err > c.err; --i) top_[i] = top_[i - 1];
        top_[i] = {c.err, m, partition, rotation, selector};
    }

    // Mode m with the given partition, rotation and selector; kWorst once the error reaches `bound`.
    Candidate encode(int m, int partition, int rotation, int selector, bool thorough, std::uint32_t bound) const {
        const bc7::Mode& mode = kModes[m];
        Candidate cand;
        cand.mode = m;
        cand.partition = partition;
        cand.rotation = rotation;
        cand.selector = selector;
        FitParams fp;
        fp.lsq = thorough ? plan_.refine_lsq : plan_.quick_lsq;
        fp.passes = thorough ? plan_.refine_passes : 0;
        fp.all_pbits = plan_.all_pbits || thorough;
        fp.exhaustive = thorough && plan_.exhaustive;
        fp.pbit = mode.pbits;
        if (mode.rotation_bits) {  // modes 4 and 5: colour and the separate channel fitted apart
            int order[4] = {0, 1, 2, 3};  // block channel of each stored channel
            if (rotation) std::swap(order[rotation - 1], order[3]);
            Points pts;
            pts.n = 16;
            fp.nch = 3;
            fp.index_bits = selector ? mode.index2_bits : mode.index_bits;
            for (int c = 0; c < 3; ++c) fp.bits[c] = mode.color_bits, fp.wt[c] = wt_[order[c]];
            for (int t = 0; t < 16; ++t)
                for (int c = 0; c < 3; ++c) pts.x[t][c] = px_[t][order[c]];
            const Fit fc = fit(fp, pts, bound);
            if (fc.err == kWorst) return cand;
            fp.nch = 1;
            fp.index_bits = selector ? mode.index_bits : mode.index2_bits;
            fp.bits[0] = mode.alpha_bits;
            fp.wt[0] = wt_[order[3]];
            for (int t = 0; t < 16; ++t) pts.x[t][0] = px_[t][order[3]];
            const Fit fa = fit(fp, pts, bound - fc.err);
            if (fa.err == kWorst) return cand;
            for (int k = 0; k < 2; ++k) {
                for (int c = 0; c < 3; ++c) cand.q[k][c] = fc.q[k][c];
                cand.q[k][3] = fa.q[k][0];
            }
            std::memcpy(cand.color_idx, fc.idx, 16);
            std::memcpy(cand.alpha_idx, fa.idx, 16);
            cand.err = fc.err + fa.err;
            return cand;
        }
        // One index set: RGB (alpha 255) in modes 0-3; RGBA in modes 6 and 7 unless the block is
        // opaque, where alpha is left out of the fit and stored as 255 (both p-bits 1).
        const bool opaque_alpha = mode.alpha_bits && opaque_;
        fp.nch = mode.alpha_bits && !opaque_ ? 4 : 3;
        for (int c = 0; c < 4; ++c) fp.bits[c] = c < 3 ? mode.color_bits : mode.alpha_bits, fp.wt[c] = wt_[c];
        fp.index_bits = mode.index_bits;
        fp.pmask = opaque_alpha ? 0x8 : 0xF;
        const std::uint8_t* subset = bc7::partition(mode.subsets, unsigned(partition));
        std::uint32_t err = 0;
        for (int s = 0; s < mode.subsets; ++s) {
            Points pts;
            int where[16];
            for (int t = 0; t < 16; ++t)
                if (subset[t] == s) {
                    where[pts.n] = t;
                    for (int c = 0; c < fp.nch; ++c) pts.x[pts.n][c] = px_[t][c];
                    ++pts.n;
                }
            const Fit f = fit(fp, pts, bound - err);
            if (f.err == kWorst) return cand;
            for (int k = 0; k < 2; ++k) {
                for (int c = 0; c < fp.nch; ++c) cand.q[2 * s + k][c] = f.q[k][c];
                if (opaque_alpha) cand.q[2 * s + k][3] = (1 << mode.alpha_bits) - 1;
                cand.p[2 * s + k] = f.p[k];
            }
            for (int i = 0; i < pts.n; ++i) cand.color_idx[where[i]] = f.idx[i];
            err += f.err;
        }
        cand.err = err;
        return cand;
    }

    Plan plan_;
    int px_[16][4];
    int wt_[4];
    bool opaque_ = true;
    Candidate best_;
    std::array<Tried, 4> top_{};  // the best first-pass candidates, least error first
    int kept_ = 0;
};
static_assert(std::all_of(std::begin(kPlans), std::end(kPlans),
                          [](const Plan& p) { return p.refine >= 1 && p.refine <= 4; }),
              "top_ holds the candidates to refine, and there is at least one");

// Mode 5 endpoints whose palette entry 1 (weight 21) is exactly each 8-bit value: uniform blocks.
struct UniformTable {
    std::uint8_t lo[256] = {}, hi[256] = {};
    UniformTable() {
        int best[256];
        std::fill(best, best + 256, 1 << 30);
        for (int a = 0; a < 128; ++a)
            for (int b = 0; b < 128; ++b) {
                const int v = bc7::interpolate(bc7::expand(a, 7), bc7::expand(b, 7), bc7::kWeights2[1]);
                if (std::abs(a - b) < best[v]) best[v] = std::abs(a - b), lo[v] = std::uint8_t(a), hi[v] = std::uint8_t(b);
            }
    }
};

Candidate uniform_block(const std::uint8_t* t) {
    static const UniformTable table;
    Candidate c;
    c.mode = 5;
    for (int ch = 0; ch < 3; ++ch) c.q[0][ch] = table.lo[t[ch]], c.q[1][ch] = table.hi[t[ch]];
    c.q[0][3] = c.q[1][3] = t[3];
    std::fill(c.color_idx, c.color_idx + 16, std::uint8_t(1));
    c.err = 0;
    return c;
}

class BitWriter {
public:
    explicit BitWriter(std::uint8_t* out) : out_(out) { std::memset(out_, 0, 16); }
    void put(unsigned v, unsigned n) {
        for (unsigned i = 0; i < n; ++i, ++pos_) out_[pos_ >> 3] |= std::uint8_t(((v >> i) & 1) << (pos_ & 7));
    }

private:
    std::uint8_t* out_;
    unsigned pos_ = 0;
};

// Writes a candidate's bits. An anchor texel's index must have its top bit 0: where it has not, its
// subset's endpoints trade places and its indices are mirrored (the weights are symmetric, so the
// texels stay the same).
void pack(Candidate c, std::uint8_t out[16]) {
    const bc7::Mode& mode = kModes[c.mode];
    unsigned anchor[3];
    bc7::anchors(mode.subsets, unsigned(c.partition), anchor);
    const std::uint8_t* subset = bc7::partition(mode.subsets, unsigned(c.partition));
    if (mode.rotation_bits) {
        const int cn = 1 << (c.selector ? mode.index2_bits : mode.index_bits);
        const int an = 1 << (c.selector ? mode.index_bits : mode.index2_bits);
        if (c.color_idx[0] >= cn / 2) {
            for (int ch = 0; ch < 3; ++ch) std::swap(c.q[0][ch], c.q[1][ch]);
            for (auto& i : c.color_idx) i = std::uint8_t(cn - 1 - i);
        }
        if (c.alpha_idx[0] >= an / 2) {
            std::swap(c.q[0][3], c.q[1][3]);
            for (auto& i : c.alpha_idx) i = std::uint8_t(an - 1 - i);
        }
    } else {
        const int n = 1 << mode.index_bits;
        for (int s = 0; s < mode.subsets; ++s) {
            if (c.color_idx[anchor[s]] < n / 2) continue;
            std::swap(c.q[2 * s], c.q[2 * s + 1]);
            std::swap(c.p[2 * s], c.p[2 * s + 1]);
            for (int t = 0; t < 16; ++t)
                if (subset[t] == s) c.color_idx[t] = std::uint8_t(n - 1 - c.color_idx[t]);
        }
    }
    BitWriter w(out);
    w.put(1u << c.mode, unsigned(c.mode) + 1);
    w.put(unsigned(c.partition), mode.partition_bits);
    w.put(unsigned(c.rotation), mode.rotation_bits);
    w.put(unsigned(c.selector), mode.selector_bits);
    const int ends = 2 * mode.subsets;
    for (int ch = 0; ch < 3; ++ch)
        for (int e = 0; e < ends; ++e) w.put(unsigned(c.q[e][ch]), mode.color_bits);
    for (int e = 0; e < ends && mode.alpha_bits; ++e) w.put(unsigned(c.q[e][3]), mode.alpha_bits);
    if (mode.pbits == kUniquePbit)
        for (int e = 0; e < ends; ++e) w.put(unsigned(c.p[e]), 1);
    if (mode.pbits == kSharedPbit)
        for (int s = 0; s < mode.subsets; ++s) w.put(unsigned(c.p[2 * s]), 1);
    auto is_anchor = [&](unsigned t) {
        return t == 0 || (mode.subsets >= 2 && t == anchor[1]) || (mode.subsets == 3 && t == anchor[2]);
    };
    // Modes 4 and 5: the primary set serves colour unless mode 4's selector bit is set.
    const std::uint8_t* primary = (mode.rotation_bits && c.selector) ? c.alpha_idx : c.color_idx;
    const std::uint8_t* secondary = c.selector ? c.color_idx : c.alpha_idx;
    for (unsigned t = 0; t < 16; ++t) w.put(primary[t], mode.index_bits - (is_anchor(t) ? 1u : 0u));
    if (mode.index2_bits)
        for (unsigned t = 0; t < 16; ++t) w.put(secondary[t], mode.index2_bits - (is_anchor(t) ? 1u : 0u));
}

}  // namespace

void encode_bc7_block(const std::uint8_t rgba[64], std::uint8_t out[16], const Bc7Options& opt) {
    if (std::equal(rgba + 4, rgba + 64, rgba, rgba + 60)) return pack(uniform_block(rgba), out);
    pack(BlockEncoder(rgba, opt).run(), out);
}

void encode_bc7(const std::uint8_t* rgba, std::uint32_t size, std::uint8_t* out, const Bc7Options& opt) {
    std::uint8_t texels[64];
    for (std::uint32_t by = 0; by < size; by += 4)
        for (std::uint32_t bx = 0; bx < size; bx += 4, out += 16) {
            for (unsigned y = 0; y < 4; ++y)
                std::memcpy(texels + 16 * y, rgba + (std::size_t(by + y) * size + bx) * 4, 16);
            encode_bc7_block(texels, out, opt);
        }
}

}  // namespace tessera::blocks
