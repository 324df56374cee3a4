// ReferenceRenderer: the scene drawn from an ordinary mipmapped GL texture with the VT's LoD rule
// and filter, for PSNR and max error (docs/viewer.md, "Measures"). See renderer.hpp.
#include <fmt/format.h>

#include "gl_util.hpp"
#include "scene_draw.hpp"
#include "tessera/client/gl/reference_renderer.hpp"
#include "tessera/client/gl/renderer.hpp"

namespace tessera::client::gl {

namespace {

using namespace detail;

class ReferenceRendererImpl final : public ReferenceRenderer {
public:
    explicit ReferenceRendererImpl(const RendererConfig& c) : cfg_(c) {}

    Status init(std::span<const Level> levels, std::span<const Levels> layers, std::span<const Level> second,
                std::span<const Levels> layer_seconds) {
        if (cfg_.width == 0 || cfg_.height == 0) return Error{Errc::invalid_argument, "reference: zero width or height"};
        if (cfg_.max_anisotropy < 1 || cfg_.max_anisotropy > 8) return Error{Errc::invalid_argument, "reference: max_anisotropy must be 1..8"};
        if (levels.empty() || levels.size() > 32) return Error{Errc::invalid_argument, "reference: 1..32 levels"};
        const auto sampled = cfg_.sampled_layers();
        if (layers.size() != sampled.size())
            return Error{Errc::invalid_argument, fmt::format("reference: the config lights with {} more layers, got {}", sampled.size(),
                                                             layers.size())};
        for (std::size_t k = 0; k < layers.size(); ++k)
            if (layers[k].size() != levels.size())
                return Error{Errc::invalid_argument, fmt::format("reference: layer {} needs the colour's {} levels, got {}", sampled[k],
                                                                 levels.size(), layers[k].size())};
        for (std::size_t l = 0; l < levels.size(); ++l) {
            const auto& lv = levels[l];
            for (std::size_t k = 0; k < layers.size(); ++k)
                if (layers[k][l].width != lv.width || layers[k][l].height != lv.height || layers[k][l].rgba8.size() != lv.rgba8.size())
                    return Error{Errc::invalid_argument, fmt::format("reference: level {} of layer {} differs from the colour level", l, sampled[k])};
            if (lv.width == 0 || lv.height == 0 || lv.rgba8.size() != std::size_t(lv.width) * lv.height * 4)
                return Error{Errc::invalid_argument, fmt::format("reference: level {} is {}x{} with {} bytes", l, lv.width, lv.height, lv.rgba8.size())};
            if (l > 0 && (lv.width != std::max(1u, levels[l - 1].width / 2) || lv.height != std::max(1u, levels[l - 1].height / 2)))
                return Error{Errc::invalid_argument,
                             fmt::format("reference: levels not halving: level {} is {}x{} after {}x{} (GL mips round down; "
                                         "use power-of-two sides)",
                                         l, lv.width, lv.height, levels[l - 1].width, levels[l - 1].height)};
        }
        const bool blend_second = !second.empty() && cfg_.filter != Filter::bilinear && levels.size() > 1;
        if (!second.empty()) {
            if (second.size() + 1 != levels.size())
                return Error{Errc::invalid_argument,
                             fmt::format("reference: {} second levels for {} levels (one per level but the last)", second.size(), levels.size())};
            if (layer_seconds.size() != layers.size())
                return Error{Errc::invalid_argument, "reference: with second levels, every lighting layer needs its second levels too"};
            for (std::size_t l = 0; l < second.size(); ++l) {
                const auto& want = levels[l + 1];
                std::vector<const Level*> all = {&second[l]};
                for (const auto& ls : layer_seconds) all.push_back(l < ls.size() ? &ls[l] : nullptr);
                for (const Level* s : all)
                    if (!s || s->width != want.width || s->height != want.height || s->rgba8.size() != want.rgba8.size())
                        return Error{Errc::invalid_argument,
                                     fmt::format("reference: second level {} is not the size of level {} ({}x{})", l, l + 1, want.width,
                                                 want.height)};
            }
        }
        GLint max_size = 0;
        glGetIntegerv(GL_MAX_TEXTURE_SIZE, &max_size);
        if (levels[0].width > std::uint32_t(max_size) || levels[0].height > std::uint32_t(max_size))
            return Error{Errc::resource_exhausted,
                         fmt::format("reference: level 0 ({}x{}) does not fit the GPU's largest texture ({}^2): use the VT with every "
                                     "page resident instead",
                                     levels[0].width, levels[0].height, max_size)};
        // A layer's texels are colour with the sRGB curve where its atlas has it (an emissive map).
        const auto layer_srgb = [&](std::uint32_t layer) { return cfg_.srgb && cfg_.more_layers[layer - 1].srgb; };
        texture_ = level_texture(levels, cfg_.srgb);
        for (std::size_t k = 0; k < layers.size(); ++k) layers_.push_back(level_texture(layers[k], layer_srgb(sampled[k])));
        if (blend_second) {
            second_ = level_texture(second, cfg_.srgb);
            for (std::size_t k = 0; k < layers.size(); ++k) layer_seconds_.push_back(level_texture(layer_seconds[k], layer_srgb(sampled[k])));
        }
        if (auto e = take_gl_errors("reference texture"); !e.empty()) return Error{Errc::resource_exhausted, e};

        auto p = build_program("scene.vert", "reference.frag",
                               vt_shader_defines(cfg_, 1, 1) +
                                   fmt::format("#define REF_TEXTURE_SIZE vec2({}.0, {}.0)\n", levels[0].width, levels[0].height) +
                                   (blend_second ? "#define REF_SECOND_LEVELS\n" : ""));
        if (!p) return p.error();
        program_ = std::move(*p);
        const GLuint id = program_.get();
        u_view_projection_ = uniform(program_, "u_view_projection");
        chunk_.chunk_offset = uniform(program_, "u_chunk_offset");
        chunk_.texel_origin = uniform(program_, "u_texel_origin");
        chunk_.texel_shift = uniform(program_, "u_texel_shift");
        chunk_.blend = uniform(program_, "u_blend");
        glProgramUniform1i(id, uniform(program_, "ref_texture"), 0);
        // Units: 0 the colour, 1 its second levels, 2.. the other layers, 2 + kMaxLayers.. theirs.
        std::vector<GLint> units(kMaxLayers);
        for (std::size_t k = 0; k < kMaxLayers; ++k) units[k] = GLint(2 + k);
        if (!layers_.empty()) glProgramUniform1iv(id, uniform(program_, "ref_layers"), GLsizei(layers_.size()), units.data());
        if (blend_second) {
            glProgramUniform1i(id, uniform(program_, "ref_second"), 1);
            for (auto& u : units) u += GLint(kMaxLayers);
            if (!layers_.empty()) glProgramUniform1iv(id, uniform(program_, "ref_layer_seconds"), GLsizei(layers_.size()), units.data());
        }
        glProgramUniform1ui(id, uniform(program_, "u_levels"), std::uint32_t(levels.size()));

        auto t = make_colour_target(cfg_.width, cfg_.height, cfg_.srgb);
        if (!t) return t.error();
        target_ = std::move(*t);
        return Status();
    }

    Status set_scene(const scene::Scene& scene) override { return geometry_.upload(scene); }

    void set_repeat(bool repeat) override {
        const GLint wrap = repeat ? GL_REPEAT : GL_CLAMP_TO_EDGE;
        std::vector<const Texture*> all = {&texture_, &second_};
        for (const auto* v : {&layers_, &layer_seconds_})
            for (const Texture& t : *v) all.push_back(&t);
        for (const Texture* t : all)
            if (*t)
                for (const GLenum axis : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T}) glTextureParameteri(t->get(), axis, wrap);
    }

    void render(const scene::Camera& camera) override {
        const double aspect = double(cfg_.width) / double(cfg_.height);
        const auto vp = view_projection(camera, aspect);
        geometry_.cull(camera, aspect);
        glProgramUniformMatrix4fv(program_.get(), u_view_projection_, 1, GL_FALSE, vp.data());
        begin_colour_pass(target_);
        glEnable(GL_CULL_FACE);
        glCullFace(GL_BACK);
        glFrontFace(GL_CCW);
        glEnable(GL_DEPTH_TEST);
        // Ties (coplanar faces) go to the last drawn, as in the VT renderer's colour pass after its
        // depth pre-pass; without overlapping faces this is GL_LESS.
        glDepthFunc(GL_LEQUAL);
        glDisable(GL_BLEND);
        glDisable(GL_SCISSOR_TEST);
        glBindTextureUnit(0, texture_.get());
        if (second_) glBindTextureUnit(1, second_.get());
        for (std::size_t k = 0; k < layers_.size(); ++k) glBindTextureUnit(GLuint(2 + k), layers_[k].get());
        for (std::size_t k = 0; k < layer_seconds_.size(); ++k) glBindTextureUnit(GLuint(2 + kMaxLayers + k), layer_seconds_[k].get());
        glUseProgram(program_.get());
        geometry_.draw(program_, chunk_, camera, SceneGeometry::Chunks::opaque);
        if (geometry_.blended_visible()) {  // as the VT pass: over the rest, far to near, no depth writes
            glDepthMask(GL_FALSE);
            glEnable(GL_BLEND);
            glBlendFuncSeparate(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA, GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
            geometry_.draw(program_, chunk_, camera, SceneGeometry::Chunks::blended);
            glDisable(GL_BLEND);
            glDepthMask(GL_TRUE);
        }
        glUseProgram(0);
        glDisable(GL_FRAMEBUFFER_SRGB);
        glBindFramebuffer(GL_FRAMEBUFFER, 0);
    }

    std::vector<std::uint8_t> read_color() override { return read_colour(target_); }

private:
    // A mipmapped RGBA8 texture of `levels` (GL_LINEAR_MIPMAP_LINEAR, clamped at the edges).
    static Texture level_texture(std::span<const Level> levels, bool srgb) {
        Texture t = make_texture(GL_TEXTURE_2D);
        glTextureStorage2D(t.get(), GLsizei(levels.size()), srgb ? GL_SRGB8_ALPHA8 : GL_RGBA8, GLsizei(levels[0].width),
                           GLsizei(levels[0].height));
        glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
        glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
        glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
        for (std::size_t l = 0; l < levels.size(); ++l)
            glTextureSubImage2D(t.get(), GLint(l), 0, 0, GLsizei(levels[l].width), GLsizei(levels[l].height), GL_RGBA,
                                GL_UNSIGNED_BYTE, levels[l].rgba8.data());
        glTextureParameteri(t.get(), GL_TEXTURE_BASE_LEVEL, 0);
        glTextureParameteri(t.get(), GL_TEXTURE_MAX_LEVEL, GLint(levels.size() - 1));
        glTextureParameteri(t.get(), GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
        glTextureParameteri(t.get(), GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        glTextureParameteri(t.get(), GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
        glTextureParameteri(t.get(), GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
        return t;
    }

    RendererConfig cfg_;
    Texture texture_;
    static constexpr std::size_t kMaxLayers = 4;  // sampled_layers: at most a material's four maps
    std::vector<Texture> layers_;         // the layers lighting the colour (sampled_layers' order)
    Texture second_;                      // the block atlas's second levels, when given (trilinear, anisotropic)
    std::vector<Texture> layer_seconds_;  // and the lighting layers'

    Program program_;
    GLint u_view_projection_ = -1;
    ChunkUniforms chunk_;
    SceneGeometry geometry_;
    ColourTarget target_;
};

}  // namespace

Result<std::unique_ptr<ReferenceRenderer>> ReferenceRenderer::create(const RendererConfig& config, std::span<const Level> levels,
                                                                    std::span<const Levels> layers, std::span<const Level> second_levels,
                                                                    std::span<const Levels> layer_second_levels) {
    auto r = std::make_unique<ReferenceRendererImpl>(config);
    if (Status st = r->init(levels, layers, second_levels, layer_second_levels); !st) return st.error();
    return std::unique_ptr<ReferenceRenderer>(std::move(r));
}

}  // namespace tessera::client::gl
