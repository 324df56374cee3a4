#include "scene_draw.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>
#include <utility>

namespace tessera::client::gl::detail {

namespace {
bool any_block_layer(const RendererConfig& c) {
    if (is_block_compressed(c.page_format)) return true;
    return std::any_of(c.more_layers.begin(), c.more_layers.end(), [](const auto& l) { return is_block_compressed(l.page_format); });
}
// VT_LAYERS and what lights with them (vt_sample.glsl, material.glsl).
std::string material_defines(const RendererConfig& c) {
    const auto layers = c.sampled_layers();
    if (layers.empty()) return {};
    std::string d = fmt::format("#define VT_LAYERS {}\n", layers.size());
    if (c.normal_layer) return d + "#define VT_LIT 1\n";
    d += "#define VT_MATERIAL 1\n";
    int k = 0;
    const std::pair<const std::optional<std::uint32_t>*, const char*> roles[] = {{&c.material.normal, "VT_NORMAL_MAP"},
                                                                                {&c.material.metallic_roughness, "VT_MR_MAP"},
                                                                                {&c.material.occlusion, "VT_OCCLUSION_MAP"},
                                                                                {&c.material.emissive, "VT_EMISSIVE_MAP"}};
    for (const auto& [layer, name] : roles)
        if (*layer) d += fmt::format("#define {} {}\n", name, k++);
    return d;
}
}  // namespace

std::string vt_shader_defines(const RendererConfig& c, std::uint32_t atlas_width, std::uint32_t atlas_height) {
    const int filter = c.filter == Filter::bilinear ? 0 : c.filter == Filter::trilinear ? 1 : 2;  // vt_sample.glsl's VT_*
    return fmt::format(
        "#define VT_FILTER {}\n#define VT_TILE_SIZE {}u\n#define VT_BORDER {}u\n#define VT_MAX_ANISOTROPY float({})\n"
        "#define VT_ATLAS_SIZE vec2({}.0, {}.0)\n#define VT_NO_DATA_COLOUR vec4({:.9g}, {:.9g}, {:.9g}, {:.9g})\n",
        filter, c.tile_size, c.border, c.max_anisotropy, atlas_width, atlas_height, kNoDataColour[0], kNoDataColour[1],
        kNoDataColour[2], kNoDataColour[3]) +
           // The rectangle atlas (one level of RGBA8 pages): see VtRenderer's atlas.
           (!c.has_second_level() && !is_block_compressed(c.page_format) && c.more_layers.empty()
                ? "#define VT_ATLAS_RECT 1\n"
                : "") +

           // Lighting by a normal layer or a material's maps: vt_sample also samples those layers' atlases
           // (docs/renderer.md, "Layers" and "Materials").
           material_defines(c) +
           // Block atlases' second levels have their own border blocks at the texture's edges.
           (c.has_second_level() && any_block_layer(c) ? "#define VT_BLOCK_EDGES 1\n" : "") +
           // Cut-outs: every pass discards where the texture's alpha is below vt_alpha_cutoff.
           (c.alpha_test ? "#define VT_ALPHA_TEST 1\n" : "");
}

SceneGeometry::SceneGeometry() : vao_(make_vertex_array()) {}

Status SceneGeometry::upload(const scene::Scene& s) {
    std::size_t vertex_count = 0, index_count = 0;
    for (const auto& c : s.chunks) {
        vertex_count += c.vertices.size();
        index_count += c.indices.size();
        for (const auto i : c.indices)
            if (i >= c.vertices.size())
                return Error{Errc::invalid_argument, fmt::format("scene {}: index {} out of range ({} vertices)", s.name, i, c.vertices.size())};
    }
    if (vertex_count > std::size_t(std::numeric_limits<GLint>::max()))
        return Error{Errc::resource_exhausted, fmt::format("scene {}: too many vertices", s.name)};
    static_assert(sizeof(scene::Vertex) == 5 * sizeof(float), "Vertex must be five packed floats");
    chunks_.clear();
    visible_.clear();
    blend_begin_ = 0;
    any_blend_ = false;
    ordered_ = false;
    // A heightfield scene only when every chunk is a grid of the one chunk grid.
    chunk_pitch_ = s.chunk_pitch > 0 && std::all_of(s.chunks.begin(), s.chunks.end(), [](const scene::Chunk& c) {
                       return c.grid_quads > 0 && c.grid_quads <= 4096 &&
                              c.indices.size() == std::size_t(c.grid_quads) * c.grid_quads * 6 &&
                              c.vertices.size() == std::size_t(c.grid_quads + 1) * (c.grid_quads + 1) &&
                              c.grid_quad_size[0] > 0 && c.grid_quad_size[1] > 0;
                   })
                       ? s.chunk_pitch
                       : 0;
    vertices_ = make_buffer();
    indices_ = make_buffer();
    const auto vbytes = static_cast<GLsizeiptr>(std::max<std::size_t>(vertex_count, 1) * sizeof(scene::Vertex));
    const auto ibytes = static_cast<GLsizeiptr>(std::max<std::size_t>(index_count, 1) * sizeof(std::uint32_t));
    glNamedBufferStorage(vertices_.get(), vbytes, nullptr, GL_DYNAMIC_STORAGE_BIT);
    glNamedBufferStorage(indices_.get(), ibytes, nullptr, GL_DYNAMIC_STORAGE_BIT);
    // Vertex normals (attribute 2) where the scene has them; a chunk without them reads zeros, and
    // without any the attribute is off (its constant value, (0, 0, 0)): material.glsl lights facets.
    const bool with_normals = std::any_of(s.chunks.begin(), s.chunks.end(), [](const scene::Chunk& c) { return !c.normals.empty(); });
    normals_ = Buffer();
    if (with_normals) {
        normals_ = make_buffer();
        const std::vector<float> zeros(std::max<std::size_t>(vertex_count, 1) * 3, 0.0f);
        glNamedBufferStorage(normals_.get(), static_cast<GLsizeiptr>(zeros.size() * sizeof(float)), zeros.data(), GL_DYNAMIC_STORAGE_BIT);
    }
    std::size_t v = 0, i = 0;
    for (const auto& c : s.chunks) {
        if (c.indices.empty() || c.vertices.empty()) continue;
        ChunkDraw d;
        d.origin = c.origin;
        d.texel_origin[0] = c.texel_origin[0];
        d.texel_origin[1] = c.texel_origin[1];
        d.grid_quads = c.grid_quads;
        d.quad_size[0] = c.grid_quad_size[0];
        d.quad_size[1] = c.grid_quad_size[1];
        d.grid_chunk[0] = c.grid_chunk[0];
        d.grid_chunk[1] = c.grid_chunk[1];
        d.blend = c.blend;
        any_blend_ = any_blend_ || c.blend;
        d.index_count = static_cast<GLsizei>(c.indices.size());
        d.index_offset = i * sizeof(std::uint32_t);
        d.base_vertex = static_cast<GLint>(v);
        for (int a = 0; a < 3; ++a) {
            d.bmin[a] = std::numeric_limits<double>::infinity();
            d.bmax[a] = -std::numeric_limits<double>::infinity();
        }
        // A chunk whose texels are its ground positions (the terrain's) can address pages from
        // a frame that follows the camera (draw, below).
        d.texel_is_ground = c.origin[0] == double(c.texel_origin[0]) && c.origin[1] == double(c.texel_origin[1]);
        for (const auto& vx : c.vertices) {
            for (int a = 0; a < 3; ++a) {
                d.bmin[a] = std::min(d.bmin[a], c.origin[a] + double(vx.position[a]));
                d.bmax[a] = std::max(d.bmax[a], c.origin[a] + double(vx.position[a]));
            }
            for (int a = 0; a < 2; ++a) {
                d.texel_is_ground = d.texel_is_ground && vx.texel[a] == vx.position[a] && vx.texel[a] >= 0.0f;
                d.texel_extent[a] = std::max(d.texel_extent[a], double(vx.texel[a]));
            }
        }
        glNamedBufferSubData(vertices_.get(), static_cast<GLintptr>(v * sizeof(scene::Vertex)),
                             static_cast<GLsizeiptr>(c.vertices.size() * sizeof(scene::Vertex)), c.vertices.data());
        glNamedBufferSubData(indices_.get(), static_cast<GLintptr>(d.index_offset),
                             static_cast<GLsizeiptr>(c.indices.size() * sizeof(std::uint32_t)), c.indices.data());
        if (with_normals && c.normals.size() == 3 * c.vertices.size())
            glNamedBufferSubData(normals_.get(), static_cast<GLintptr>(v * 3 * sizeof(float)),
                                 static_cast<GLsizeiptr>(c.normals.size() * sizeof(float)), c.normals.data());
        v += c.vertices.size();
        i += c.indices.size();
        chunks_.push_back(d);
    }
    const GLuint vao = vao_.get();
    glVertexArrayVertexBuffer(vao, 0, vertices_.get(), 0, sizeof(scene::Vertex));
    glVertexArrayElementBuffer(vao, indices_.get());
    glEnableVertexArrayAttrib(vao, 0);
    glEnableVertexArrayAttrib(vao, 1);
    glVertexArrayAttribFormat(vao, 0, 3, GL_FLOAT, GL_FALSE, 0);
    glVertexArrayAttribFormat(vao, 1, 2, GL_FLOAT, GL_FALSE, 3 * sizeof(float));
    glVertexArrayAttribBinding(vao, 0, 0);
    glVertexArrayAttribBinding(vao, 1, 0);
    if (with_normals) {
        glVertexArrayVertexBuffer(vao, 1, normals_.get(), 0, 3 * sizeof(float));
        glVertexArrayAttribFormat(vao, 2, 3, GL_FLOAT, GL_FALSE, 0);
        glVertexArrayAttribBinding(vao, 2, 1);
        glEnableVertexArrayAttrib(vao, 2);
    } else {
        glDisableVertexArrayAttrib(vao, 2);
    }
    if (auto e = take_gl_errors("scene upload"); !e.empty()) return Error{Errc::resource_exhausted, e};
    return Status();
}

namespace {

// Rows of clip = P * V * (p - camera), in double (as scene::world_to_clip).
std::array<std::array<double, 4>, 4> clip_rows(const scene::Camera& c, double aspect) {
    const auto r = c.right(), u = c.up(), f = c.forward();
    const double t = 1.0 / std::tan(c.fov_y / 2.0), n = c.near_plane, fa = c.far_plane;
    const double a = (fa + n) / (n - fa), b = 2.0 * fa * n / (n - fa);
    std::array<std::array<double, 4>, 4> m{};
    for (int i = 0; i < 3; ++i) {
        m[0][i] = t / aspect * r[i];
        m[1][i] = t * u[i];
        m[2][i] = -a * f[i];
        m[3][i] = f[i];  // w = -ez = forward . d
    }
    m[2][3] = b;
    return m;
}

}  // namespace

void SceneGeometry::cull(const scene::Camera& camera, double aspect) {
    visible_.clear();
    ordered_ = false;
    const auto m = clip_rows(camera, aspect);
    for (std::uint32_t k = 0; k < chunks_.size(); ++k) {
        const auto& d = chunks_[k];
        // A chunk is outside when all 8 corners are outside one clip plane.
        int out[6] = {0, 0, 0, 0, 0, 0};
        for (int corner = 0; corner < 8; ++corner) {
            const double p[3] = {((corner & 1) ? d.bmax[0] : d.bmin[0]) - camera.position[0],
                                 ((corner & 2) ? d.bmax[1] : d.bmin[1]) - camera.position[1],
                                 ((corner & 4) ? d.bmax[2] : d.bmin[2]) - camera.position[2]};
            double clip[4];
            for (int row = 0; row < 4; ++row) clip[row] = m[row][0] * p[0] + m[row][1] * p[1] + m[row][2] * p[2] + m[row][3];
            const double w = clip[3] * (1.0 + 1e-6) + 1e-9;  // a hair of slack
            out[0] += clip[0] < -w;
            out[1] += clip[0] > w;
            out[2] += clip[1] < -w;
            out[3] += clip[1] > w;
            out[4] += clip[2] < -w;
            out[5] += clip[2] > w;
        }
        if (std::none_of(std::begin(out), std::end(out), [](int o) { return o == 8; })) visible_.push_back(k);
    }
    // Blended chunks last, the farthest first (by their boxes' centres): each blends over what is
    // behind it. Within a chunk triangles keep their order. (Most scenes have none: no work.)
    blend_begin_ = visible_.size();
    if (!any_blend_) return;
    const auto first_blended = std::stable_partition(visible_.begin(), visible_.end(), [&](std::uint32_t k) { return !chunks_[k].blend; });
    blend_begin_ = std::size_t(first_blended - visible_.begin());
    auto distance2 = [&](std::uint32_t k) {
        const auto& d = chunks_[k];
        double s = 0;
        for (int a = 0; a < 3; ++a) {
            const double c = 0.5 * (d.bmin[a] + d.bmax[a]) - camera.position[a];
            s += c * c;
        }
        return s;
    };
    std::stable_sort(first_blended, visible_.end(), [&](std::uint32_t a, std::uint32_t b) { return distance2(a) > distance2(b); });
}

namespace {

// x rounded to a float no smaller (up) or no larger (down) than x.
float float_up(double x) {
    float f = static_cast<float>(x);
    return double(f) < x ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}
float float_down(double x) {
    float f = static_cast<float>(x);
    return double(f) > x ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}

}  // namespace

void SceneGeometry::PageFrame::set(const std::uint32_t origin[2], std::uint32_t payload, const std::uint32_t size[2]) {
    for (int a = 0; a < 2; ++a) {
        const std::uint32_t p = origin[a] / payload;
        const double start = double(p) * payload;
        page[a] = static_cast<std::int32_t>(p);
        base[a] = static_cast<float>(origin[a] - p * payload);  // below P: exact
        // Rounded inwards: a bound that is not a float (past 2^24 texels from the frame's page)
        // is one no fragment of the chunk gets near.
        bounds[a] = float_up(-start);
        bounds[2 + a] = float_down(double(size[a]) - start);
    }
}

void SceneGeometry::set_page_layout(std::uint32_t payload, std::uint32_t width, std::uint32_t height) {
    payload_ = payload;
    size_[0] = width;
    size_[1] = height;
    for (auto& d : chunks_) {
        d.has_frame = true;
        d.frame.set(d.texel_origin, payload, size_);
    }
}

// Why the order is front to back: a ray's path over the ground plane is a straight line from the
// camera, so the grid cells it crosses get no nearer the camera's cell in either axis: |i - ci|
// and |j - cj| never decrease along it. A surface point can only hide one in a cell the ray
// reaches later, which has a larger |i - ci| + |j - cj|; cells are drawn by that sum, chunks of
// the chunk grid likewise. Within a quad, the ray crosses the diagonal from the camera's side, so
// the triangle on that side goes first. (Ties between points at equal depth go to the first.)
bool SceneGeometry::order_front_to_back(const scene::Camera& camera) {
    if (chunk_pitch_ <= 0) return false;
    std::size_t quads = 0;
    for (const auto k : visible_) quads += std::size_t(chunks_[k].grid_quads) * chunks_[k].grid_quads;
    if (quads > kMaxOrderedQuads) return false;
    const auto cell_of = [](double x) {  // a cell index; far-away ones clamped (same order)
        return static_cast<std::int64_t>(std::clamp(std::floor(x), -1e15, 1e15));
    };
    const std::int64_t cam_chunk[2] = {cell_of(camera.position[0] / chunk_pitch_), cell_of(camera.position[1] / chunk_pitch_)};
    const auto chunk_key = [&](std::uint32_t k) {
        const auto& d = chunks_[k];
        return std::abs(d.grid_chunk[0] - cam_chunk[0]) + std::abs(d.grid_chunk[1] - cam_chunk[1]);
    };
    std::stable_sort(visible_.begin(), visible_.end(), [&](std::uint32_t a, std::uint32_t b) { return chunk_key(a) < chunk_key(b); });
    order_scratch_.clear();
    order_scratch_.reserve(quads * 6);
    for (const auto k : visible_) {
        auto& d = chunks_[k];
        const std::uint32_t q = d.grid_quads, n = q + 1;
        const double cu = (camera.position[0] - d.origin[0]) / d.quad_size[0];
        const double cv = (camera.position[1] - d.origin[1]) / d.quad_size[1];
        // The camera's cell, clamped to one past the grid: beyond that the order is the same.
        const auto ci = std::clamp<std::int64_t>(cell_of(cu), -1, q), cj = std::clamp<std::int64_t>(cell_of(cv), -1, q);
        // Counting sort of the quads by |i - ci| + |j - cj| (at most 2q + 2).
        const auto key = [&](std::uint32_t i, std::uint32_t j) {
            return std::size_t(std::abs(std::int64_t(i) - ci) + std::abs(std::int64_t(j) - cj));
        };
        order_count_.assign(2 * std::size_t(q) + 4, 0);
        for (std::uint32_t j = 0; j < q; ++j)
            for (std::uint32_t i = 0; i < q; ++i) ++order_count_[key(i, j) + 1];
        for (std::size_t b = 1; b < order_count_.size(); ++b) order_count_[b] += order_count_[b - 1];
        d.ordered_offset = order_scratch_.size() * sizeof(std::uint32_t);
        const std::size_t base = order_scratch_.size();
        order_scratch_.resize(base + std::size_t(q) * q * 6);
        for (std::uint32_t j = 0; j < q; ++j)
            for (std::uint32_t i = 0; i < q; ++i) {
                const std::uint32_t a = j * n + i, b = a + 1, e = a + n + 1, f = a + n;
                std::uint32_t* out = order_scratch_.data() + base + std::size_t(order_count_[key(i, j)]++) * 6;
                // The lower-right triangle (x - y >= i - j) first when the camera is on its side.
                const std::uint32_t lower[3] = {a, b, e}, upper[3] = {a, e, f};
                const bool lower_first = cu - cv > double(i) - double(j);
                std::memcpy(out, lower_first ? lower : upper, sizeof lower);
                std::memcpy(out + 3, lower_first ? upper : lower, sizeof lower);
            }
    }
    if (!ordered_indices_) ordered_indices_ = make_buffer();
    glNamedBufferData(ordered_indices_.get(), GLsizeiptr(std::max<std::size_t>(order_scratch_.size(), 1) * sizeof(std::uint32_t)),
                      order_scratch_.data(), GL_STREAM_DRAW);
    ordered_ = true;
    return true;
}

void SceneGeometry::draw(const Program& program, const ChunkUniforms& u, const scene::Camera& camera, Chunks which) const {
    glBindVertexArray(vao_.get());
    glVertexArrayElementBuffer(vao_.get(), ordered_ ? ordered_indices_.get() : indices_.get());
    const std::size_t begin = which == Chunks::blended ? blend_begin_ : 0;
    const std::size_t end = which == Chunks::opaque ? blend_begin_ : visible_.size();
    for (std::size_t i = begin; i < end; ++i) {
        const auto& d = chunks_[visible_[i]];
        if (u.blend >= 0) glProgramUniform1i(program.get(), u.blend, d.blend ? 1 : 0);
        const auto off = scene::camera_relative(d.origin, camera.position);
        glProgramUniform3f(program.get(), u.chunk_offset, off[0], off[1], off[2]);
        // The texel frame: the chunk's texel origin, or for a terrain chunk wider than
        // kExactChunkTexels the texel under the camera (clamped into the chunk), so that the
        // interpolated offsets from it are small where texels are large on screen. From the
        // chunk's origin they reach the chunk's side, and a 2^18-texel chunk (a 2^24 terrain's)
        // keeps 1/64 of a texel: edges moved by up to a quarter of a texel (docs/stability.md).
        // The shift from the origin is a whole number below 2^24: exact.
        std::uint32_t origin[2] = {d.texel_origin[0], d.texel_origin[1]};
        float shift[2] = {0.0f, 0.0f};
        const PageFrame* frame = &d.frame;
        PageFrame moved;
        if (d.texel_is_ground && d.has_frame && std::max(d.texel_extent[0], d.texel_extent[1]) > kExactChunkTexels) {
            for (int a = 0; a < 2; ++a) {
                const double lo = double(d.texel_origin[a]);
                const double at = std::clamp(std::floor(camera.position[a]), lo, lo + std::floor(d.texel_extent[a]));
                origin[a] = static_cast<std::uint32_t>(at);
                shift[a] = static_cast<float>(lo - at);
            }
            moved.set(origin, payload_, size_);
            frame = &moved;
        }
        glProgramUniform2ui(program.get(), u.texel_origin, origin[0], origin[1]);
        if (u.texel_shift >= 0) glProgramUniform2fv(program.get(), u.texel_shift, 1, shift);
        if (u.chunk_page >= 0 && d.has_frame) {
            glProgramUniform2iv(program.get(), u.chunk_page, 1, frame->page);
            glProgramUniform2fv(program.get(), u.chunk_base, 1, frame->base);
            glProgramUniform4fv(program.get(), u.chunk_bounds, 1, frame->bounds);
        }
        glDrawElementsBaseVertex(GL_TRIANGLES, d.index_count, GL_UNSIGNED_INT,
                                 reinterpret_cast<const void*>(ordered_ ? d.ordered_offset : d.index_offset), d.base_vertex);
    }
    glBindVertexArray(0);
}

scene::Mat4f view_projection(const scene::Camera& camera, double aspect) {
    return scene::multiply(scene::projection(camera, aspect), scene::view_rotation(camera));
}

void begin_colour_pass(const ColourTarget& t) {
    glBindFramebuffer(GL_FRAMEBUFFER, t.fbo.get());
    glViewport(0, 0, GLsizei(t.width), GLsizei(t.height));
    if (t.srgb) glEnable(GL_FRAMEBUFFER_SRGB);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    glDepthMask(GL_TRUE);
    glClearBufferfv(GL_COLOR, 0, kBackground);
    const GLfloat far_depth = 1.0f;
    glClearBufferfv(GL_DEPTH, 0, &far_depth);
}

Result<ColourTarget> make_colour_target(std::uint32_t width, std::uint32_t height, bool srgb) {
    ColourTarget t;
    t.width = width;
    t.height = height;
    t.srgb = srgb;
    t.colour = make_texture(GL_TEXTURE_2D);
    glTextureStorage2D(t.colour.get(), 1, srgb ? GL_SRGB8_ALPHA8 : GL_RGBA8, GLsizei(width), GLsizei(height));
    glTextureParameteri(t.colour.get(), GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTextureParameteri(t.colour.get(), GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    t.depth = make_renderbuffer();
    glNamedRenderbufferStorage(t.depth.get(), GL_DEPTH_COMPONENT32F, GLsizei(width), GLsizei(height));
    t.fbo = make_framebuffer();
    glNamedFramebufferTexture(t.fbo.get(), GL_COLOR_ATTACHMENT0, t.colour.get(), 0);
    glNamedFramebufferRenderbuffer(t.fbo.get(), GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, t.depth.get());
    const GLenum status = glCheckNamedFramebufferStatus(t.fbo.get(), GL_FRAMEBUFFER);
    if (status != GL_FRAMEBUFFER_COMPLETE)
        return Error{Errc::unsupported, fmt::format("colour target {}x{} incomplete (0x{:04x})", width, height, status)};
    if (auto e = take_gl_errors("colour target"); !e.empty()) return Error{Errc::resource_exhausted, e};
    return t;
}

std::vector<std::uint8_t> read_colour(const ColourTarget& t) {
    const std::size_t row = std::size_t(t.width) * 4;
    std::vector<std::uint8_t> bottom_up(row * t.height), out(row * t.height);
    glBindBuffer(GL_PIXEL_PACK_BUFFER, 0);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glNamedFramebufferReadBuffer(t.fbo.get(), GL_COLOR_ATTACHMENT0);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, t.fbo.get());
    glReadPixels(0, 0, GLsizei(t.width), GLsizei(t.height), GL_RGBA, GL_UNSIGNED_BYTE, bottom_up.data());
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    // GL's row 0 is the bottom of the image.
    for (std::uint32_t y = 0; y < t.height; ++y)
        std::memcpy(out.data() + std::size_t(y) * row, bottom_up.data() + std::size_t(t.height - 1 - y) * row, row);
    return out;
}

}  // namespace tessera::client::gl::detail

namespace tessera::client::gl {

std::vector<std::uint32_t> RendererConfig::sampled_layers() const {
    if (show_layer != 0) return {};
    if (normal_layer) return {*normal_layer};
    std::vector<std::uint32_t> out;
    for (const auto& l : {material.normal, material.metallic_roughness, material.occlusion, material.emissive})
        if (l) out.push_back(*l);
    return out;
}

}  // namespace tessera::client::gl
