// The CPU reference renderer (cpu_reference.hpp). Written from docs/renderer.md, not from the
// shaders: nothing here includes vt_sample.glsl, reference.frag or scene/lod.hpp.
#include "cpu_reference.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "gl_util.hpp"
#include "scene_draw.hpp"

namespace tessera::test::cpu_reference {

namespace gl = client::gl;
namespace detail = client::gl::detail;

namespace {

using Rgba = std::array<double, 4>;

constexpr double kKnifeLod = 1e-3;          // lod this close to a level or tap-count boundary
constexpr double kKnifeAlpha = 2.0 / 255;   // filtered alpha this close to the cut-off
constexpr double kAlphaCutoff = 0.5;        // docs/renderer.md, "Cut-outs"
constexpr int kMaxLayers = 8;               // depth layers peeled (cut-outs over cut-outs)

double srgb_to_linear(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }
double linear_to_srgb(double l) { return l <= 0.0031308 ? l * 12.92 : 1.055 * std::pow(l, 1.0 / 2.4) - 0.055; }

Image to_image(const gl::ReferenceRenderer::Level& l, bool srgb) {
    Image im{l.width, l.height, std::vector<float>(l.rgba8.size())};
    for (std::size_t i = 0; i < l.rgba8.size(); ++i) {
        const double v = l.rgba8[i] / 255.0;
        im.rgba[i] = float(srgb && i % 4 != 3 ? srgb_to_linear(v) : v);
    }
    return im;
}

// Texel index along an axis of n texels: clamped to the edge, or wrapped.
std::int64_t texel_index(std::int64_t i, std::uint32_t n, bool repeat) {
    if (repeat) {
        const std::int64_t m = std::int64_t(n);
        return ((i % m) + m) % m;
    }
    return std::clamp<std::int64_t>(i, 0, std::int64_t(n) - 1);
}

// Bilinear at (u, v), in texels of `im` (texel i covers [i, i + 1)).
Rgba bilinear(const Image& im, double u, double v, bool repeat) {
    const double x = u - 0.5, y = v - 0.5;
    const double x0 = std::floor(x), y0 = std::floor(y);
    const double fx = x - x0, fy = y - y0;
    Rgba out{0, 0, 0, 0};
    for (int j = 0; j < 2; ++j)
        for (int i = 0; i < 2; ++i) {
            const double w = (i ? fx : 1 - fx) * (j ? fy : 1 - fy);
            if (w == 0) continue;
            const auto xi = texel_index(std::int64_t(x0) + i, im.width, repeat);
            const auto yi = texel_index(std::int64_t(y0) + j, im.height, repeat);
            const float* p = &im.rgba[(std::size_t(yi) * im.width + std::size_t(xi)) * 4];
            for (int c = 0; c < 4; ++c) out[std::size_t(c)] += w * p[c];
        }
    return out;
}

Rgba mix(const Rgba& a, const Rgba& b, double t) {
    Rgba o;
    for (std::size_t c = 0; c < 4; ++c) o[c] = a[c] + (b[c] - a[c]) * t;
    return o;
}

// Level `level` at level-0 texel coordinate (tx, ty).
Rgba sample_level(const Texture& t, std::size_t level, double tx, double ty) {
    const double s = std::ldexp(1.0, -int(level));
    return bilinear(t.levels[level], tx * s, ty * s, t.repeat);
}

// Trilinear at clamped lod lc: level floor(lc), blended with the next (or the second level the
// texture holds under it) by the fraction.
Rgba trilinear(const Texture& t, double lc, double tx, double ty) {
    const std::size_t l = std::size_t(std::floor(lc));
    const double f = lc - double(l);
    Rgba c = sample_level(t, l, tx, ty);
    if (f > 0 && l + 1 < t.levels.size()) {
        const double s = std::ldexp(1.0, -int(l + 1));
        const Image& coarse = t.second.empty() ? t.levels[l + 1] : t.second[l];
        c = mix(c, bilinear(coarse, tx * s, ty * s, t.repeat), f);
    }
    return c;
}

// One pixel's filter footprint, from the derivatives of its level-0 texel coordinate. A choice
// that turns on a rounding (a lod within kKnifeLod of a level or tap-count boundary, two
// derivatives equally long) has two legitimate outcomes: bit 0 of `flips` takes the other level
// or tap count, bit 1 the other axis.
struct Footprint {
    gl::Filter filter = gl::Filter::bilinear;
    double lod = 0;           // clamped lod (trilinear, anisotropic) or the level (bilinear)
    int taps = 1;
    double axis[2] = {0, 0};  // between the first and the last tap's outer ends
    bool knife = false;       // some choice could have gone the other way
};

Footprint footprint(const gl::RendererConfig& cfg, std::size_t levels, const double dx[2], const double dy[2], unsigned flips) {
    Footprint fp;
    fp.filter = cfg.filter;
    const double last = double(levels - 1);
    const double rx = std::hypot(dx[0], dx[1]), ry = std::hypot(dy[0], dy[1]);
    const double major = std::max(rx, ry), minor = std::min(rx, ry);
    // Of two outcomes `exact` and the ones a nudge either way gives: the other, when asked for.
    const auto pick = [&](auto exact, auto lower, auto upper, unsigned bit) {
        const auto other = lower != exact ? lower : upper;
        fp.knife = fp.knife || other != exact;
        return (flips & bit) ? other : exact;
    };
    if (cfg.filter == gl::Filter::bilinear) {
        // The nearest level: floor(lod + 0.5) clamped.
        const double lod = std::log2(major);
        const auto level_of = [&](double l) { return std::isnan(l) ? 0.0 : std::clamp(std::floor(l + 0.5), 0.0, last); };
        fp.lod = std::isfinite(lod) ? pick(level_of(lod), level_of(lod - kKnifeLod), level_of(lod + kKnifeLod), 1u) : level_of(lod);
        return fp;
    }
    const double max_aniso = double(cfg.max_anisotropy);
    const double lod = cfg.filter == gl::Filter::anisotropic ? std::log2(std::max(minor, major / max_aniso)) : std::log2(major);
    fp.lod = std::isnan(lod) ? 0.0 : std::clamp(lod, 0.0, last);
    if (cfg.filter == gl::Filter::trilinear) return fp;
    // Anisotropic: ceil(major / 2^lc) taps, 1..max, along the longer derivative.
    const auto taps_at = [&](double ratio) {
        const double n = std::ceil(ratio);
        return std::isnan(n) || n < 1 ? 1 : int(std::min(n, max_aniso));
    };
    const double ratio = major / std::exp2(fp.lod);
    fp.taps = pick(taps_at(ratio), taps_at(ratio * (1 - kKnifeLod)), taps_at(ratio * (1 + kKnifeLod)), 1u);
    const bool x_axis = rx >= ry;
    const bool tie = fp.taps > 1 && std::abs(rx - ry) <= kKnifeLod * major;
    const double* axis = pick(x_axis, tie ? !x_axis : x_axis, x_axis, 2u) ? dx : dy;
    fp.axis[0] = axis[0];
    fp.axis[1] = axis[1];
    return fp;
}

// The filtered texel of `t` at (tx, ty) with footprint fp.
Rgba filtered(const Texture& t, const Footprint& fp, double tx, double ty) {
    if (fp.filter == gl::Filter::bilinear) return sample_level(t, std::size_t(fp.lod), tx, ty);
    if (fp.filter == gl::Filter::trilinear) return trilinear(t, fp.lod, tx, ty);
    Rgba sum{0, 0, 0, 0};
    for (int i = 0; i < fp.taps; ++i) {
        const double o = (double(i) + 0.5) / fp.taps - 0.5;
        const Rgba c = trilinear(t, fp.lod, tx + o * fp.axis[0], ty + o * fp.axis[1]);
        for (std::size_t k = 0; k < 4; ++k) sum[k] += c[k];
    }
    for (auto& v : sum) v /= fp.taps;
    return sum;
}

// Lambert under the fixed sun of docs/renderer.md ("Layers"): the normal's x and y are the
// filtered red and alpha mapped to [-1, 1], z implied.
Rgba lit(Rgba colour, const Rgba& normal) {
    const double nx = normal[0] * 2 - 1, ny = normal[3] * 2 - 1;
    const double nz = std::sqrt(std::max(1 - nx * nx - ny * ny, 0.0));
    const double sx = -0.5, sy = -0.4, sz = 0.75, sl = std::sqrt(sx * sx + sy * sy + sz * sz);
    const double k = 0.35 + 0.65 * std::max((nx * sx + ny * sy + nz * sz) / sl, 0.0);
    for (std::size_t c = 0; c < 3; ++c) colour[c] *= k;
    return colour;
}

// One surface under a pixel, from the coordinate pass.
struct Hit {
    float depth = 0;
    std::uint32_t material = 0;
    double texel[2] = {0, 0};
    double dx[2] = {0, 0}, dy[2] = {0, 0};
};

const char* kCoordVert = R"(#version 450 core
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec2 a_texel;
uniform mat4 u_view_projection;
uniform vec3 u_chunk_offset;
uniform uvec2 u_texel_origin;
out vec2 v_local;
flat out uvec2 v_origin;
invariant gl_Position;
void main() {
    v_local = a_texel;
    v_origin = u_texel_origin;
    gl_Position = u_view_projection * vec4(a_position + u_chunk_offset, 1.0);
}
)";

// Writes what a pixel's sampling needs; layer k > 0 keeps only fragments behind layer k - 1's.
const char* kCoordFrag = R"(#version 450 core
in vec2 v_local;
flat in uvec2 v_origin;
uniform sampler2D u_previous;
uniform int u_peel;
layout(location = 0) out vec4 o_local_dx;
layout(location = 1) out vec4 o_dy_depth;
layout(location = 2) out uvec4 o_origin;
void main() {
    vec2 dx = dFdx(v_local), dy = dFdy(v_local);
    if (u_peel != 0) {
        vec4 p = texelFetch(u_previous, ivec2(gl_FragCoord.xy), 0);
        if (p.w == 0.0 || gl_FragCoord.z <= p.z) discard;
    }
    o_local_dx = vec4(v_local, dx);
    o_dy_depth = vec4(dy, gl_FragCoord.z, 1.0);
    o_origin = uvec4(v_origin, 0u, 0u);
}
)";

Result<detail::Program> coordinate_program() {
    const auto compile = [](GLenum kind, const char* src) -> Result<GLuint> {
        const GLuint s = glCreateShader(kind);
        glShaderSource(s, 1, &src, nullptr);
        glCompileShader(s);
        GLint ok = 0;
        glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
        if (!ok) {
            char log[2048] = {};
            glGetShaderInfoLog(s, sizeof log, nullptr, log);
            glDeleteShader(s);
            return Error{Errc::unsupported, fmt::format("cpu reference: coordinate shader: {}", log)};
        }
        return s;
    };
    auto vs = compile(GL_VERTEX_SHADER, kCoordVert);
    if (!vs) return vs.error();
    auto fs = compile(GL_FRAGMENT_SHADER, kCoordFrag);
    if (!fs) {
        glDeleteShader(*vs);
        return fs.error();
    }
    detail::Program p(glCreateProgram());
    glAttachShader(p.get(), *vs);
    glAttachShader(p.get(), *fs);
    glLinkProgram(p.get());
    glDeleteShader(*vs);
    glDeleteShader(*fs);
    GLint ok = 0;
    glGetProgramiv(p.get(), GL_LINK_STATUS, &ok);
    if (!ok) return Error{Errc::unsupported, "cpu reference: the coordinate program does not link"};
    return p;
}

// The coordinate pass's target: three colour attachments and a depth buffer.
struct CoordTarget {
    detail::Texture local_dx, dy_depth, origin;
    detail::Renderbuffer depth;
    detail::Framebuffer fbo;
};

Result<CoordTarget> coordinate_target(std::uint32_t w, std::uint32_t h) {
    CoordTarget t;
    const auto colour = [&](GLenum format) {
        auto tex = detail::make_texture(GL_TEXTURE_2D);
        glTextureStorage2D(tex.get(), 1, format, GLsizei(w), GLsizei(h));
        glTextureParameteri(tex.get(), GL_TEXTURE_MIN_FILTER, GL_NEAREST);
        glTextureParameteri(tex.get(), GL_TEXTURE_MAG_FILTER, GL_NEAREST);
        return tex;
    };
    t.local_dx = colour(GL_RGBA32F);
    t.dy_depth = colour(GL_RGBA32F);
    t.origin = colour(GL_RGBA32UI);
    t.depth = detail::make_renderbuffer();
    glNamedRenderbufferStorage(t.depth.get(), GL_DEPTH_COMPONENT32F, GLsizei(w), GLsizei(h));
    t.fbo = detail::make_framebuffer();
    glNamedFramebufferTexture(t.fbo.get(), GL_COLOR_ATTACHMENT0, t.local_dx.get(), 0);
    glNamedFramebufferTexture(t.fbo.get(), GL_COLOR_ATTACHMENT1, t.dy_depth.get(), 0);
    glNamedFramebufferTexture(t.fbo.get(), GL_COLOR_ATTACHMENT2, t.origin.get(), 0);
    glNamedFramebufferRenderbuffer(t.fbo.get(), GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, t.depth.get());
    const GLenum bufs[] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1, GL_COLOR_ATTACHMENT2};
    glNamedFramebufferDrawBuffers(t.fbo.get(), 3, bufs);
    if (glCheckNamedFramebufferStatus(t.fbo.get(), GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
        return Error{Errc::unsupported, "cpu reference: coordinate target incomplete"};
    return t;
}

template <typename T>
std::vector<T> read_attachment(const CoordTarget& t, int index, GLenum format, GLenum type, std::uint32_t w, std::uint32_t h) {
    std::vector<T> v(std::size_t(w) * h * 4);
    glBindBuffer(GL_PIXEL_PACK_BUFFER, 0);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glNamedFramebufferReadBuffer(t.fbo.get(), GLenum(GL_COLOR_ATTACHMENT0 + index));
    glBindFramebuffer(GL_READ_FRAMEBUFFER, t.fbo.get());
    glReadPixels(0, 0, GLsizei(w), GLsizei(h), format, type, v.data());
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    return v;
}

}  // namespace

Texture make_texture(std::span<const gl::ReferenceRenderer::Level> levels, bool srgb, std::span<const gl::ReferenceRenderer::Level> second) {
    Texture t;
    for (const auto& l : levels) t.levels.push_back(to_image(l, srgb));
    for (const auto& l : second) t.second.push_back(to_image(l, srgb));
    return t;
}

Result<Frame> render(const gl::RendererConfig& cfg, std::span<const Material> materials, const scene::Camera& camera) {
    const std::uint32_t w = cfg.width, h = cfg.height;
    const std::size_t n = std::size_t(w) * h;
    auto program = coordinate_program();
    if (!program) return program.error();
    const GLint u_vp = glGetUniformLocation(program->get(), "u_view_projection");
    detail::ChunkUniforms chunk;
    chunk.chunk_offset = glGetUniformLocation(program->get(), "u_chunk_offset");
    chunk.texel_origin = glGetUniformLocation(program->get(), "u_texel_origin");
    const GLint u_peel = glGetUniformLocation(program->get(), "u_peel");
    glProgramUniform1i(program->get(), glGetUniformLocation(program->get(), "u_previous"), 0);
    const double aspect = double(w) / double(h);
    const auto vp = detail::view_projection(camera, aspect);
    glProgramUniformMatrix4fv(program->get(), u_vp, 1, GL_FALSE, vp.data());

    // Every surface under every pixel, nearest first once sorted.
    std::vector<std::vector<Hit>> hits(n);
    Frame frame;
    for (std::uint32_t m = 0; m < materials.size(); ++m) {
        detail::SceneGeometry geometry;
        if (auto st = geometry.upload(*materials[m].scene); !st) return st.error();
        geometry.cull(camera, aspect);
        const int layers = cfg.alpha_test ? kMaxLayers : 1;
        CoordTarget previous;
        for (int layer = 0; layer < layers; ++layer) {
            auto t = coordinate_target(w, h);
            if (!t) return t.error();
            glBindFramebuffer(GL_FRAMEBUFFER, t->fbo.get());
            glViewport(0, 0, GLsizei(w), GLsizei(h));
            glDisable(GL_FRAMEBUFFER_SRGB);
            glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
            glDepthMask(GL_TRUE);
            const float zero[4] = {0, 0, 0, 0};
            const GLuint uzero[4] = {0, 0, 0, 0};
            glClearBufferfv(GL_COLOR, 0, zero);
            glClearBufferfv(GL_COLOR, 1, zero);
            glClearBufferuiv(GL_COLOR, 2, uzero);
            const float far_depth = 1.0f;
            glClearBufferfv(GL_DEPTH, 0, &far_depth);
            glEnable(GL_CULL_FACE);
            glCullFace(GL_BACK);
            glFrontFace(GL_CCW);
            glEnable(GL_DEPTH_TEST);
            glDepthFunc(GL_LESS);
            glDisable(GL_BLEND);
            glDisable(GL_SCISSOR_TEST);
            glProgramUniform1i(program->get(), u_peel, layer > 0 ? 1 : 0);
            if (layer > 0) glBindTextureUnit(0, previous.dy_depth.get());
            glUseProgram(program->get());
            geometry.draw(*program, chunk, camera);
            glUseProgram(0);
            glBindFramebuffer(GL_FRAMEBUFFER, 0);
            if (auto e = detail::take_gl_errors("cpu reference: coordinate pass"); !e.empty()) return Error{Errc::unsupported, e};
            const auto a = read_attachment<float>(*t, 0, GL_RGBA, GL_FLOAT, w, h);
            const auto b = read_attachment<float>(*t, 1, GL_RGBA, GL_FLOAT, w, h);
            const auto o = read_attachment<std::uint32_t>(*t, 2, GL_RGBA_INTEGER, GL_UNSIGNED_INT, w, h);
            std::size_t found = 0;
            for (std::uint32_t y = 0; y < h; ++y)
                for (std::uint32_t x = 0; x < w; ++x) {
                    const std::size_t i = (std::size_t(y) * w + x) * 4;  // GL's rows run bottom up
                    if (b[i + 3] == 0) continue;
                    ++found;
                    Hit hit;
                    hit.depth = b[i + 2];
                    hit.material = m;
                    hit.texel[0] = double(o[i]) + double(a[i]);
                    hit.texel[1] = double(o[i + 1]) + double(a[i + 1]);
                    hit.dx[0] = a[i + 2];
                    hit.dx[1] = a[i + 3];
                    hit.dy[0] = b[i];
                    hit.dy[1] = b[i + 1];
                    hits[std::size_t(h - 1 - y) * w + x].push_back(hit);
                }
            frame.layers_peeled = std::max(frame.layers_peeled, std::size_t(layer + 1));
            if (found == 0) break;
            previous = std::move(*t);
        }
    }

    // Each pixel with every choice as exact arithmetic makes it and, on a knife edge, with each
    // combination of those choices the other way (bit 2: the alpha test's).
    frame.rgba.assign(n * 4, 0);
    frame.knife.assign(n, 0);
    frame.covered.assign(n, 0);
    frame.outcomes.assign(n, {});
    for (std::size_t p = 0; p < n; ++p) {
        auto& list = hits[p];
        std::stable_sort(list.begin(), list.end(), [](const Hit& a, const Hit& b) { return a.depth < b.depth; });
        for (unsigned flips = 0; flips < 8 && (flips == 0 || frame.knife[p]); ++flips) {
            Outcome o;
            for (const Hit& hit : list) {
                const Material& mat = materials[hit.material];
                const Footprint fp = footprint(cfg, mat.colour.levels.size(), hit.dx, hit.dy, flips);
                Rgba c = filtered(mat.colour, fp, hit.texel[0], hit.texel[1]);
                frame.knife[p] |= fp.knife;
                if (cfg.alpha_test) {
                    const bool near = std::abs(c[3] - kAlphaCutoff) < kKnifeAlpha;
                    frame.knife[p] |= near;
                    if ((c[3] < kAlphaCutoff) != (near && (flips & 4u))) continue;  // a hole: what lies behind shows
                    c[3] = 1;
                }
                if (!mat.normals.levels.empty()) c = lit(c, filtered(mat.normals, fp, hit.texel[0], hit.texel[1]));
                for (std::size_t k = 0; k < 4; ++k) {
                    double v = std::clamp(c[k], 0.0, 1.0);
                    if (cfg.srgb && k < 3) v = linear_to_srgb(v);
                    o.rgba[k] = std::uint8_t(std::lround(v * 255));
                }
                o.covered = true;
                break;
            }
            if (flips == 0) {
                std::copy_n(o.rgba.begin(), 4, &frame.rgba[p * 4]);
                frame.covered[p] = o.covered;
            } else {
                frame.outcomes[p].push_back(o);
            }
        }
    }
    return frame;
}

Comparison compare(std::span<const std::uint8_t> have, const Frame& want) {
    Comparison c;
    double sq = 0;
    for (std::size_t p = 0; p < want.covered.size(); ++p) {
        const bool has = have[p * 4 + 3] != 0;
        c.knife += want.knife[p];
        // The exact outcome, or on a knife edge the one nearest to the pixel.
        Outcome exact;
        std::copy_n(&want.rgba[p * 4], 4, exact.rgba.begin());
        exact.covered = want.covered[p];
        bool fits = false, other = false;
        int worst = 0, sum_sq = 0;
        for (std::size_t k = 0; k <= want.outcomes[p].size(); ++k) {
            const Outcome& o = k == 0 ? exact : want.outcomes[p][k - 1];
            if (o.covered != has) continue;
            int w = 0, s2 = 0;
            for (std::size_t ch = 0; has && ch < 3; ++ch) {
                const int d = std::abs(int(have[p * 4 + ch]) - int(o.rgba[ch]));
                w = std::max(w, d);
                s2 += d * d;
            }
            if (!fits || s2 < sum_sq) {
                worst = w;
                sum_sq = s2;
                other = k != 0;
            }
            fits = true;
        }
        if (!fits) {
            ++c.coverage_differs;
            continue;
        }
        if (!has) continue;
        ++c.compared;
        c.alternative += other;
        sq += sum_sq;
        c.max_error = std::max(c.max_error, worst);
        c.over_3 += worst > 3;
        c.over_16 += worst > 16;
    }
    const double mse = sq / (3.0 * double(std::max<std::size_t>(c.compared, 1)));
    c.psnr = mse == 0 ? 99.0 : 10 * std::log10(255.0 * 255.0 / mse);
    return c;
}

std::string describe(const Comparison& c) {
    return fmt::format("vs CPU reference: {} px compared, PSNR {:.2f} dB, max error {}, {} off by >3, {} by >16; {} knife-edge px "
                       "({} nearer the other outcome), coverage differs in {}",
                       c.compared, c.psnr, c.max_error, c.over_3, c.over_16, c.knife, c.alternative, c.coverage_differs);
}

}  // namespace tessera::test::cpu_reference
