// VtRenderer: the frame (feedback, depth and VT passes), its programs and uniforms, and the parts
// it is composed of: the page atlas (page_atlas.hpp), the GPU page tables (page_table_texture.hpp),
// the staging ring (staging.hpp) and the readbacks (readback_ring.hpp). See renderer.hpp and
// docs/renderer.md.
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <numeric>
#include <optional>
#include <utility>
#include <string>

#include "gl_util.hpp"
#include "page_atlas.hpp"
#include "slot_weights.hpp"
#include "tessera/client/page_table_layout.hpp"
#include "page_table_texture.hpp"
#include "readback_ring.hpp"
#include "scene_draw.hpp"
#include "staging.hpp"
#include "tessera/client/gl/renderer.hpp"

namespace tessera::client::gl {

namespace {

using namespace detail;

// Texture units of the layers sampled beside layer 0 (vt_layer_atlas[k]); 0, 1 and 3 hold the page
// table, the atlas and the fade weights.
constexpr std::array<GLint, 4> kLayerUnits = {2, 4, 5, 6};

// Uniform locations of a program built with vt_sample.glsl (scene.vert forwards most of them to
// the fragment shader: vt_sample.glsl, "Inputs").
struct VtUniforms {
    GLint view_projection = -1, bias = -1, main_pixel = -1;
    GLint table_column = -1, table_last_row = -1, levels = -1, texture_size = -1, texture_id = -1;
    GLint page_table = -1, atlas = -1, layer_atlas = -1, fade = -1, dir_offset = -1, dir_width = -1;
    ChunkUniforms chunk;

    explicit VtUniforms(const Program& p = Program()) {
        if (!p) return;
        view_projection = uniform(p, "u_view_projection");
        bias = uniform(p, "u_bias");
        main_pixel = uniform(p, "vt_main_pixel");
        table_column = uniform(p, "u_table_column");
        table_last_row = uniform(p, "u_table_last_row");
        levels = uniform(p, "u_levels");
        texture_size = uniform(p, "u_texture_size");
        texture_id = uniform(p, "vt_texture_id");
        page_table = uniform(p, "vt_page_table");
        dir_offset = uniform(p, "vt_dir_offset");
        dir_width = uniform(p, "vt_dir_width");
        atlas = uniform(p, "vt_atlas");
        layer_atlas = uniform(p, "vt_layer_atlas");
        fade = uniform(p, "vt_fade");
        chunk.chunk_offset = uniform(p, "u_chunk_offset");
        chunk.texel_shift = uniform(p, "u_texel_shift");
        chunk.chunk_page = uniform(p, "u_chunk_page");
        chunk.chunk_base = uniform(p, "u_chunk_base");
        chunk.chunk_bounds = uniform(p, "u_chunk_bounds");
        chunk.blend = uniform(p, "u_blend");
    }
};

class VtRendererImpl final : public VtRenderer {
public:
    explicit VtRendererImpl(const RendererConfig& c)
        : cfg_(c), page_staging_(c.staging_pages), staging_(c.staging_bytes), atlas_(staging_), tables_(staging_, atlas_) {
        staging_.set_page_staging(&page_staging_);
    }

    Status init() {
        const auto& c = cfg_;
        if (c.width == 0 || c.height == 0) return Error{Errc::invalid_argument, "renderer: zero width or height"};
        if (c.feedback_scale == 0) return Error{Errc::invalid_argument, "renderer: feedback_scale must be >= 1"};
        if (c.max_anisotropy < 1 || c.max_anisotropy > 8) return Error{Errc::invalid_argument, "renderer: max_anisotropy must be 1..8"};
        if (c.pool_slots == 0 || c.pool_slots > PageTableLayout::kMaxSlots)
            return Error{Errc::invalid_argument, fmt::format("renderer: pool_slots must be 1..{}", PageTableLayout::kMaxSlots)};
        if (c.tile_size <= 2 * c.border || c.border == 0)
            return Error{Errc::invalid_argument, fmt::format("renderer: tile_size {} and border {} leave no payload (border >= 1)", c.tile_size, c.border)};
        if (c.has_second_level() && (c.tile_size % 2 != 0 || c.border % 2 != 0))
            return Error{Errc::invalid_argument,
                         fmt::format("renderer: the trilinear and anisotropic filters need an even tile size and border "
                                     "(the atlas's second level halves pages), got {} and {}",
                                     c.tile_size, c.border)};
        // The anisotropic taps span under 2 * max_anisotropy texels of one level, and vt_sample.glsl
        // looks them up in the 2x2 pages around the centre: a page must be wider than that.
        if (c.filter == Filter::anisotropic && c.tile_size - 2 * c.border < 2 * c.max_anisotropy)
            return Error{Errc::invalid_argument,
                         fmt::format("renderer: the anisotropic filter at {}x needs pages of at least {} texels (payload), "
                                     "got {} (tile size {}, border {})",
                                     c.max_anisotropy, 2 * c.max_anisotropy, c.tile_size - 2 * c.border, c.tile_size, c.border)};
        if (c.readback_ring < 1 || c.readback_ring > 64) return Error{Errc::invalid_argument, "renderer: readback_ring must be 1..64"};
        if (c.frames_in_flight < 1 || c.frames_in_flight > 16)
            return Error{Errc::invalid_argument, "renderer: frames_in_flight must be 1..16"};
        if (!(c.feedback_prefetch_lod >= 0 && c.feedback_prefetch_lod <= 2))
            return Error{Errc::invalid_argument, "renderer: feedback_prefetch_lod must be 0..2"};
        if (!(c.feedback_guard_band >= 0 && c.feedback_guard_band <= 1))
            return Error{Errc::invalid_argument, "renderer: feedback_guard_band must be 0..1"};
        const std::size_t layers = 1 + c.more_layers.size();
        if (c.show_layer >= layers)
            return Error{Errc::invalid_argument, fmt::format("renderer: show_layer {} of a pool of {} layers", c.show_layer, layers)};
        if (c.normal_layer && (*c.normal_layer == 0 || *c.normal_layer >= layers))
            return Error{Errc::invalid_argument,
                         fmt::format("renderer: normal_layer {} must be one of layers 1..{}", *c.normal_layer, layers - 1)};
        if (c.normal_layer && c.material.any())
            return Error{Errc::invalid_argument, "renderer: normal_layer lights the terrain, material a glTF scene: not both"};
        for (const auto& l : {c.material.normal, c.material.metallic_roughness, c.material.occlusion, c.material.emissive})
            if (l && (*l == 0 || *l >= layers))
                return Error{Errc::invalid_argument, fmt::format("renderer: material layer {} must be one of layers 1..{}", *l, layers - 1)};
        for (std::size_t i = 0; i < layers; ++i) TESSERA_TRY(check_page_format_support(layer_config(i)));
        GLint max_size = 0;
        glGetIntegerv(GL_MAX_TEXTURE_SIZE, &max_size);
        const auto max_texture = static_cast<std::uint32_t>(std::max(max_size, 1));
        GLint64 max_ssbo = 0;
        glGetInteger64v(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &max_ssbo);
        if (!staging_.ok()) return Error{Errc::resource_exhausted, "renderer: cannot map the staging ring"};
        TESSERA_TRY(atlas_.init(c, max_texture));
        for (std::size_t i = 1; i < layers; ++i) {
            more_atlases_.push_back(std::make_unique<PageAtlas>(staging_));
            TESSERA_TRY(more_atlases_.back()->init(layer_config(i), max_texture));
        }
        pool_ = atlas_.pool_format();
        for (const auto& a : more_atlases_) {
            pool_.more_layers.push_back(a->pool_format().format);
            pool_.second_level = pool_.second_level || a->pool_format().second_level;
        }
        tables_.init(c.pool_slots, c.tile_size, c.border, max_texture, max_ssbo);

        TESSERA_TRY(build_programs(/*fading=*/0));
        TESSERA_TRY(weights_.init(atlas_.columns(), atlas_.rows()));

        fb_width_ = (c.width + c.feedback_scale - 1) / c.feedback_scale;
        fb_height_ = (c.height + c.feedback_scale - 1) / c.feedback_scale;
        // Derivatives per main-target pixel: a main pixel is fb_width / width feedback pixels (of a
        // feedback image widened by the guard band: 1 + g times fewer).
        const float widen = 1.0f + c.feedback_guard_band;
        for (int sparse = 0; sparse < 2; ++sparse)
            if (feedback_programs_[sparse])
                glProgramUniform2f(feedback_programs_[sparse].get(), feedback_us_[sparse].main_pixel, float(fb_width_) / float(c.width) / widen,
                                   float(fb_height_) / float(c.height) / widen);

        // Targets.
        auto main = make_colour_target(c.width, c.height, c.srgb);
        if (!main) return main.error();
        main_ = std::move(*main);
        fb_ids_ = make_texture(GL_TEXTURE_2D);
        glTextureStorage2D(fb_ids_.get(), 1, GL_RG32UI, GLsizei(fb_width_), GLsizei(fb_height_));
        glTextureParameteri(fb_ids_.get(), GL_TEXTURE_MIN_FILTER, GL_NEAREST);
        glTextureParameteri(fb_ids_.get(), GL_TEXTURE_MAG_FILTER, GL_NEAREST);
        fb_depth_ = make_renderbuffer();
        glNamedRenderbufferStorage(fb_depth_.get(), GL_DEPTH_COMPONENT32F, GLsizei(fb_width_), GLsizei(fb_height_));
        fb_fbo_ = make_framebuffer();
        glNamedFramebufferTexture(fb_fbo_.get(), GL_COLOR_ATTACHMENT0, fb_ids_.get(), 0);
        glNamedFramebufferRenderbuffer(fb_fbo_.get(), GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, fb_depth_.get());
        glNamedFramebufferReadBuffer(fb_fbo_.get(), GL_COLOR_ATTACHMENT0);
        if (glCheckNamedFramebufferStatus(fb_fbo_.get(), GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
            return Error{Errc::unsupported, "renderer: the RG32UI feedback target is incomplete"};

        TESSERA_TRY(feedback_.init(c.readback_ring, fb_width_, fb_height_));
        TESSERA_TRY(counters_.init(std::size_t(c.readback_ring) * 4));
        frame_fences_.resize(c.frames_in_flight);
        if (auto e = take_gl_errors("renderer setup"); !e.empty()) return Error{Errc::resource_exhausted, e};
        return Status();
    }

    // The VT pass: per page-table layout (dense, two-level) and, for frames where some cell's
    // blend weight is below full, a variant that reads the weights (built when first needed).
    // With cut-outs the depth pre-pass samples as the VT pass does, so it has the same variants,
    // and the feedback pass one per layout; otherwise they never read the page table.
    Status build_programs(int fading) {
        const auto& c = cfg_;
        const std::string defines = vt_shader_defines(c, atlas_.width(), atlas_.height());
        const auto set_units = [this](const Program& p, const VtUniforms& u) {
            if (!p) return;
            glProgramUniform1i(p.get(), u.page_table, 0);
            glProgramUniform1i(p.get(), u.atlas, 1);
            if (u.layer_atlas >= 0) {
                const auto n = cfg_.sampled_layers().size();
                glProgramUniform1iv(p.get(), u.layer_atlas, GLsizei(n), kLayerUnits.data());
            }
            if (u.fade >= 0) glProgramUniform1i(p.get(), u.fade, 3);
        };
        for (int sparse = 0; sparse < 2; ++sparse) {
            const std::string variant = defines + (sparse ? "#define VT_SPARSE_TABLE 1\n" : "") + (fading ? "#define VT_FADE 1\n" : "") +
                                        (fading && c.srgb ? "#define VT_FADE_ENCODED 1\n" : "");
            auto vt = build_program("scene.vert", "vt.frag", variant);
            if (!vt) return vt.error();
            vt_programs_[sparse][fading] = std::move(*vt);
            vt_us_[sparse][fading] = VtUniforms(vt_programs_[sparse][fading]);
            set_units(vt_programs_[sparse][fading], vt_us_[sparse][fading]);
            if (!c.alpha_test && (sparse || fading)) continue;
            auto depth = build_program("scene.vert", "depth.frag", variant);
            if (!depth) return depth.error();
            depth_programs_[sparse][fading] = std::move(*depth);
            depth_us_[sparse][fading] = VtUniforms(depth_programs_[sparse][fading]);
            set_units(depth_programs_[sparse][fading], depth_us_[sparse][fading]);
            if (fading) continue;
            auto fb = build_program("scene.vert", "feedback.frag", variant);
            if (!fb) return fb.error();
            feedback_programs_[sparse] = std::move(*fb);
            feedback_us_[sparse] = VtUniforms(feedback_programs_[sparse]);
            set_units(feedback_programs_[sparse], feedback_us_[sparse]);
        }
        return Status();
    }

    // ---- PageUploader -----------------------------------------------------------------------

    PagePoolFormat pool_format() const override { return pool_; }

    void upload_page(SlotId slot, const PageKey& page, std::span<const std::uint8_t> page_data, std::uint32_t tile_size) override {
        // One upload holds every layer's page, in layer order (PagePoolFormat::layer_offset).
        const PagePoolFormat& pool = pool_;
        if (page_data.size() != pool.upload_bytes(tile_size)) {
            ++stats_.malformed_uploads;
            return;
        }
        if (!page_staging_.locate(page_data.data(), page_data.size())) {
            ++stats_.pages_copied;
            stats_.page_bytes_copied += page_data.size();
        }
        const auto place = tables_.place(page);
        for (std::size_t i = 0; i < pool.layer_count(); ++i) {
            PageAtlas& a = atlas(i);
            if (!a.upload_page(slot, page, page_data.subspan(pool.layer_offset(i, tile_size), pool.layer_bytes(i, tile_size)),
                               tile_size, place)) {
                ++stats_.malformed_uploads;
                return;
            }
        }
        ++stats_.pages_uploaded;
    }

    void write_page_table(const PageTableWrite& w) override {
        count(w.sparse_block ? tables_.upload_block(w.texture, w.level, w.x0, w.y0, w.entries)
                             : tables_.upload_rect(w.texture, w.level, w.x0, w.y0, w.w, w.h, w.entries));
    }

    void set_slot_weights(std::span<const SlotWeight> weights) override {
        stats_.malformed_uploads += weights_.set(weights);
        if (weights_.below_full() > 0 && !vt_programs_[0][1] && !fading_build_failed_) {
            // The first blend: its shader variants. Should they fail (they never have where the
            // others built), pages are drawn at full weight.
            if (auto st = build_programs(/*fading=*/1); !st.ok()) {
                fading_build_failed_ = true;
                ++stats_.gl_errors;
            }
        }
    }

    // ---- Setup ------------------------------------------------------------------------------

    Status add_texture(TextureId texture, const storage::StoreInfo& info) override {
        TESSERA_TRY(tables_.add(texture, info));
        // A texture replacing the scene's one changes the chunks' page frames.
        if (has_scene_ && scene_texture_ == texture) set_page_layout(*tables_.find(texture));
        return Status();
    }

    Status set_scene(const scene::Scene& scene, TextureId texture) override {
        const VirtualTexture* t = tables_.find(texture);
        if (!t) return Error{Errc::invalid_argument, fmt::format("set_scene: texture {} was not added (add_texture first)", texture)};
        TESSERA_TRY(geometry_.upload(scene));
        set_page_layout(*t);
        depth_prepass_ = !scene::overdraw_free(scene);
        scene_texture_ = texture;
        has_scene_ = true;
        return Status();
    }

    // ---- Frames -----------------------------------------------------------------------------

    void set_feedback_camera(const scene::Camera& camera) override { feedback_camera_ = camera; }

    std::uint64_t render(const scene::Camera& camera, float lod_bias) override {
        ++frame_;
        ++stats_.frames;
        // Frame latency: the fence in this frame's slot is the frame frames_in_flight back.
        if (Fence& oldest = frame_fences_[frame_ % frame_fences_.size()]; !oldest.poll()) {
            ++stats_.gpu_waits;
            oldest.wait();
        }
        staging_.close_batch();  // the uploads since the last frame, fenced together
        staging_.retire();
        page_staging_.close_frame();  // likewise the lent page buffers given back since
        for (std::size_t i = 0; i <= more_atlases_.size(); ++i) atlas(i).make_page_mips();  // after the frame's page uploads, in stream order
        weights_.upload();  // this frame's weights
        stats_.fading_pages = weights_.below_full();
        // At full weight everywhere, the lookups need no weights.
        vt_fading_ = weights_.below_full() > 0 && vt_programs_[0][1] ? 1 : 0;

        const double aspect = double(cfg_.width) / double(cfg_.height);
        const auto vp = view_projection(camera, aspect);
        const VirtualTexture* tex = has_scene_ ? tables_.find(scene_texture_) : nullptr;
        bool front_to_back = false;
        if (tex) {
            geometry_.cull(camera, aspect);
            // A heightfield drawn front to back shades each visible pixel once without the pre-pass.
            front_to_back = depth_prepass_ && !cfg_.alpha_test && geometry_.order_front_to_back(camera);
            use_page_table(*tex);
            set_texture_uniforms(vt_program(), vt_u(), *tex);
            set_texture_uniforms(depth_program(), depth_u(), *tex);
            set_texture_uniforms(feedback_program(), feedback_u(), *tex);
            bind_atlases();
        }
        last_bias_ = lod_bias;
        stats_.visible_chunks = tex ? geometry_.visible_chunks() : 0;
        for (auto* p : {&depth_program(), &vt_program(), &feedback_program()}) {
            const VtUniforms& u = p == &depth_program() ? depth_u() : p == &vt_program() ? vt_u() : feedback_u();
            glProgramUniformMatrix4fv(p->get(), u.view_projection, 1, GL_FALSE, vp.data());
            glProgramUniform1f(p->get(), u.bias, lod_bias);
        }
        set_pass_state();

        // Feedback pass at 1/N: the ids of the nearest surface (its own depth buffer). Read back
        // after the main pass: a software rasterizer finishes a pass when it is read, so reading it
        // here would hold the CPU until then in the middle of the frame.
        const auto feedback_slot = feedback_.acquire();
        // A predicted view's feedback: its own culling, then the frame's again for the main pass.
        const std::optional<scene::Camera> feedback_camera = std::exchange(feedback_camera_, std::nullopt);
        const scene::Camera& fcam = feedback_camera && feedback_slot ? *feedback_camera : camera;
        if (&fcam != &camera) ++stats_.predicted_feedback;
        if (tex && &fcam != &camera) geometry_.cull(fcam, aspect);
        if (const auto slot = feedback_slot) {
            // Jitter: shift the feedback pass by a sub-pixel offset (clip-space translation, so
            // depth and the exact derivatives are unaffected) cycling over the N x N main pixels
            // one feedback pixel covers.
            scene::Mat4f fvp = &fcam == &camera ? vp : view_projection(fcam, aspect);
            if (cfg_.feedback_jitter && cfg_.feedback_scale > 1) {
                const std::uint32_t n = cfg_.feedback_scale, cells = n * n;
                // A full-period stride over the cells (odd multiplier coprime to n*n for n a power
                // of two; otherwise fall back to 1) spreads consecutive samples across the block.
                std::uint32_t stride = 2 * n + 1;
                while (std::gcd(stride, cells) != 1) ++stride;
                const std::uint32_t cell = std::uint32_t((frame_ * stride) % cells);
                const double jx = ((cell % n) + 0.5) / n - 0.5, jy = ((cell / n) + 0.5) / n - 0.5;  // feedback pixels
                const double dx = 2.0 * jx / fb_width_, dy = 2.0 * jy / fb_height_;                // NDC
                // T * VP with T translating clip x, y by (dx, dy) * w: column-major rows 0 and 1.
                const scene::Mat4f base = fvp;  // the feedback camera's (a predicted one's w row too)
                for (int c = 0; c < 4; ++c) {
                    fvp[std::size_t(c * 4 + 0)] += float(dx) * base[std::size_t(c * 4 + 3)];
                    fvp[std::size_t(c * 4 + 1)] += float(dy) * base[std::size_t(c * 4 + 3)];
                }
            }
            if (cfg_.feedback_guard_band > 0) {  // clip x, y scaled by 1/(1+g): a wider view
                const float k = 1.0f / (1.0f + cfg_.feedback_guard_band);
                for (int c = 0; c < 4; ++c) {
                    fvp[std::size_t(c * 4 + 0)] *= k;
                    fvp[std::size_t(c * 4 + 1)] *= k;
                }
            }
            glProgramUniformMatrix4fv(feedback_program().get(), feedback_u().view_projection, 1, GL_FALSE, fvp.data());
            glProgramUniform1f(feedback_program().get(), feedback_u().bias, lod_bias - cfg_.feedback_prefetch_lod);
            glBindFramebuffer(GL_FRAMEBUFFER, fb_fbo_.get());
            glViewport(0, 0, GLsizei(fb_width_), GLsizei(fb_height_));
            glDisable(GL_FRAMEBUFFER_SRGB);
            glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
            glDepthMask(GL_TRUE);
            glDepthFunc(GL_LESS);
            const GLuint none[4] = {0xFFFFFFFFu, 0xFFFFFFFFu, 0, 0};
            glClearBufferuiv(GL_COLOR, 0, none);
            const GLfloat far_depth = 1.0f;
            glClearBufferfv(GL_DEPTH, 0, &far_depth);
            if (tex) {
                glUseProgram(feedback_program().get());
                geometry_.draw(feedback_program(), feedback_u().chunk, fcam);
                if (&fcam != &camera) {  // the frame's culling and order again
                    geometry_.cull(camera, aspect);
                    if (front_to_back) front_to_back = geometry_.order_front_to_back(camera);
                }
            }
        } else {
            ++stats_.feedback_skipped;
        }

        // Main pass: depth pre-pass, then the VT pass at GL_LEQUAL with early fragment tests, so
        // each visible pixel is shaded and counted once (draw_main).
        begin_colour_pass(main_);
        const auto counter_slot = counters_.begin_frame();  // zeroes the counters
        if (tex) {
            // Textured pixels come from an occlusion query (the VT pass shades each visible pixel
            // once), not from a per-fragment atomic: atomics on one address from every fragment
            // serialise a software rasterizer's threads.
            if (depth_prepass_ && !front_to_back) ++stats_.depth_prepasses;
            if (counter_slot) glBeginQuery(GL_SAMPLES_PASSED, counters_.query(*counter_slot));
            draw_main(camera, front_to_back, counters_.counters());
            if (counter_slot) glEndQuery(GL_SAMPLES_PASSED);
        }
        glUseProgram(0);
        glDisable(GL_FRAMEBUFFER_SRGB);
        if (feedback_slot) feedback_.read(*feedback_slot, fb_fbo_.get(), frame_, lod_bias);
        glBindFramebuffer(GL_FRAMEBUFFER, 0);
        // The shader's atomics must land before the copy (and before the next frame's clear).
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        if (counter_slot)
            counters_.read(*counter_slot, frame_, bool(tex));
        else
            ++stats_.counters_skipped;
        frame_fences_[frame_ % frame_fences_.size()].insert();
        glFlush();  // start the GPU on this frame; never waits
        return frame_;
    }

    std::vector<std::uint8_t> render_preview(const scene::Camera& camera) override {
        if (!preview_.fbo) {
            auto t = make_colour_target(cfg_.width, cfg_.height, cfg_.srgb);
            if (!t) return {};
            preview_ = std::move(*t);
            preview_counters_ = make_buffer();
            const std::uint32_t zero[4] = {0, 0, 0, 0};
            glNamedBufferStorage(preview_counters_.get(), sizeof zero, zero, 0);
        }
        const VirtualTexture* tex = has_scene_ ? tables_.find(scene_texture_) : nullptr;
        begin_colour_pass(preview_);
        if (tex) {
            const auto vp = view_projection(camera, double(cfg_.width) / double(cfg_.height));
            geometry_.cull(camera, double(cfg_.width) / double(cfg_.height));
            const bool front_to_back = depth_prepass_ && !cfg_.alpha_test && geometry_.order_front_to_back(camera);
            use_page_table(*tex);
            set_texture_uniforms(vt_program(), vt_u(), *tex);
            set_texture_uniforms(depth_program(), depth_u(), *tex);
            bind_atlases();
            for (auto* p : {&depth_program(), &vt_program()}) {
                const VtUniforms& u = p == &depth_program() ? depth_u() : vt_u();
                glProgramUniformMatrix4fv(p->get(), u.view_projection, 1, GL_FALSE, vp.data());
                glProgramUniform1f(p->get(), u.bias, last_bias_);
            }
            set_pass_state();
            draw_main(camera, front_to_back, preview_counters_.get());
        }
        glUseProgram(0);
        glDisable(GL_FRAMEBUFFER_SRGB);
        glBindFramebuffer(GL_FRAMEBUFFER, 0);
        return read_colour(preview_);
    }

    bool poll_feedback(FeedbackFrame& out) override {
        feedback_.collect(false);
        return feedback_.take(out);
    }

    std::size_t poll_counters(std::vector<FrameCounters>& out) override {
        counters_.collect(false);
        return counters_.take(out);
    }

    void finish(std::vector<FrameCounters>* counters, FeedbackFrame* feedback) override {
        glFinish();
        while (glGetError() != GL_NO_ERROR) ++stats_.gl_errors;
        staging_.retire();
        page_staging_.close_frame();
        feedback_.collect(true);
        counters_.collect(true);
        if (counters) counters_.take(*counters);
        if (feedback) feedback_.take(*feedback);
    }

    std::vector<std::uint8_t> read_color() override { return read_colour(main_); }

    std::vector<std::uint8_t> read_page(SlotId slot, std::uint32_t layer) override {
        return layer <= more_atlases_.size() ? atlas(layer).read_page(slot) : std::vector<std::uint8_t>();
    }

    void present(int window_width, int window_height) override {
        glDisable(GL_FRAMEBUFFER_SRGB);  // copy the stored (encoded) values as they are
        glDisable(GL_SCISSOR_TEST);
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
        const GLfloat black[4] = {0, 0, 0, 1};
        glClearBufferfv(GL_COLOR, 0, black);
        glBlitNamedFramebuffer(main_.fbo.get(), 0, 0, 0, GLint(cfg_.width), GLint(cfg_.height), 0, 0, window_width,
                               window_height, GL_COLOR_BUFFER_BIT, GL_LINEAR);
    }

    PageStaging& page_staging() override { return page_staging_; }
    const RendererConfig& config() const override { return cfg_; }
    RendererStats stats() const override {
        RendererStats s = stats_;
        s.direct_uploads = staging_.direct_uploads();
        return s;
    }

private:
    void count(TableUpload r) {
        if (r == TableUpload::uploaded) ++stats_.table_uploads;
        if (r == TableUpload::malformed) ++stats_.malformed_uploads;
    }

    // Layer i's atlas configuration: layer 0's grid and filter, the layer's format.
    RendererConfig layer_config(std::size_t i) const {
        RendererConfig c = cfg_;
        if (i > 0) {
            c.page_format = cfg_.more_layers[i - 1].page_format;
            c.srgb = cfg_.more_layers[i - 1].srgb;
        }
        return c;
    }
    PageAtlas& atlas(std::size_t i) { return i == 0 ? atlas_ : *more_atlases_[i - 1]; }

    void set_page_layout(const VirtualTexture& t) { geometry_.set_page_layout(t.payload, t.texels[0], t.texels[1]); }

    void bind_atlases() {
        glBindTextureUnit(1, atlas(cfg_.show_layer).texture());

        const auto layers = cfg_.sampled_layers();
        for (std::size_t k = 0; k < layers.size(); ++k) glBindTextureUnit(GLuint(kLayerUnits[k]), atlas(layers[k]).texture());
        glBindTextureUnit(3, weights_.texture());
    }

    static void set_pass_state() {
        glEnable(GL_CULL_FACE);
        glCullFace(GL_BACK);
        glFrontFace(GL_CCW);
        glEnable(GL_DEPTH_TEST);
        glDisable(GL_BLEND);
        glDisable(GL_SCISSOR_TEST);
    }

    // The main pass into the bound colour target (cleared): depth pre-pass, then the VT pass at
    // GL_LEQUAL with early fragment tests, so each visible pixel is shaded and counted once, its
    // fallback counted in `counters`. A scene where no triangle can hide another
    // (scene::overdraw_free: the flat terrain) needs no pre-pass: the VT pass alone shades each
    // pixel once. Nor does a heightfield drawn front to back (displaced terrain): there each
    // pixel's first fragment is its visible one, and GL_LESS rejects the rest.
    void draw_main(const scene::Camera& camera, bool front_to_back, GLuint counters) {
        const bool prepass = depth_prepass_ && !front_to_back;
        if (prepass) {
            glColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
            glDepthFunc(GL_LESS);
            glUseProgram(depth_program().get());
            geometry_.draw(depth_program(), depth_u().chunk, camera, SceneGeometry::Chunks::opaque);
            glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
            glDepthMask(GL_FALSE);
        }
        glDepthFunc(prepass ? GL_LEQUAL : GL_LESS);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, counters);
        glUseProgram(vt_program().get());
        geometry_.draw(vt_program(), vt_u().chunk, camera, SceneGeometry::Chunks::opaque);
        if (geometry_.blended_visible()) {  // over the rest, far to near, writing no depth (docs/renderer.md)
            glDepthMask(GL_FALSE);
            glEnable(GL_BLEND);
            glBlendFuncSeparate(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA, GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
            geometry_.draw(vt_program(), vt_u().chunk, camera, SceneGeometry::Chunks::blended);
            glDisable(GL_BLEND);
        }
        glDepthMask(GL_TRUE);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, 0);
    }

    // Binds `t`'s page table and makes the VT program of its layout vt_program().
    void use_page_table(const VirtualTexture& t) {
        vt_sparse_ = t.sparse ? 1 : 0;
        t.bind();
    }
    Program& vt_program() { return vt_programs_[vt_sparse_][vt_fading_]; }
    const VtUniforms& vt_u() const { return vt_us_[vt_sparse_][vt_fading_]; }
    // The depth pre-pass and feedback programs: one each, or with cut-outs per layout (and, for
    // the pre-pass, blending), as the VT pass's.
    Program& depth_program() { return cfg_.alpha_test ? depth_programs_[vt_sparse_][vt_fading_] : depth_programs_[0][0]; }
    const VtUniforms& depth_u() const { return cfg_.alpha_test ? depth_us_[vt_sparse_][vt_fading_] : depth_us_[0][0]; }
    Program& feedback_program() { return feedback_programs_[cfg_.alpha_test ? vt_sparse_ : 0]; }
    const VtUniforms& feedback_u() const { return feedback_us_[cfg_.alpha_test ? vt_sparse_ : 0]; }

    void set_texture_uniforms(const Program& p, const VtUniforms& u, const VirtualTexture& t) {
        const GLuint id = p.get();
        glProgramUniform1i(id, u.table_column, GLint(t.pages[0]));
        glProgramUniform1i(id, u.table_last_row, GLint(t.pages[1]) - 1);
        glProgramUniform1ui(id, u.levels, t.levels);
        glProgramUniform2f(id, u.texture_size, float(t.texels[0]), float(t.texels[1]));
        glProgramUniform1ui(id, u.texture_id, t.id);
        if (t.sparse) {
            glProgramUniform1uiv(id, u.dir_offset, GLsizei(t.levels), t.dir_offset.data());
            glProgramUniform1uiv(id, u.dir_width, GLsizei(t.levels), t.dir_width.data());
        }
    }

    RendererConfig cfg_;
    MappedPageStaging page_staging_;
    StagingRing staging_;
    PageAtlas atlas_;                                     // layer 0
    std::vector<std::unique_ptr<PageAtlas>> more_atlases_;  // layers 1, 2, ...: the same grid
    PagePoolFormat pool_;                                   // every atlas's format, set by init
    PageTableTextures tables_;
    SlotWeights weights_;
    bool fading_build_failed_ = false;
    std::optional<scene::Camera> feedback_camera_;  // set_feedback_camera, for the next frame
    SceneGeometry geometry_;
    TextureId scene_texture_ = 0;
    bool has_scene_ = false;
    bool depth_prepass_ = true;  // false for scenes where no triangle can hide another

    Program depth_programs_[2][2], feedback_programs_[2];
    VtUniforms depth_us_[2][2], feedback_us_[2];
    // The VT programs: [two-level page table][reads the blending weights]; vt_program() is the
    // frame's (use_page_table, and render() by whether any cell is fading).
    Program vt_programs_[2][2];
    VtUniforms vt_us_[2][2];
    int vt_sparse_ = 0, vt_fading_ = 0;

    ColourTarget main_;
    ColourTarget preview_;       // render_preview's, made on first use
    Buffer preview_counters_;    // the fallback counters render_preview's VT pass writes (unread)
    float last_bias_ = 0;        // the bias the last frame drew with
    Texture fb_ids_;
    Renderbuffer fb_depth_;
    Framebuffer fb_fbo_;
    std::uint32_t fb_width_ = 0, fb_height_ = 0;

    FeedbackReadback feedback_;
    CounterReadback counters_;
    std::vector<Fence> frame_fences_;  // one per frame the GPU may be behind (frame_ modulo their count)

    std::uint64_t frame_ = 0;
    RendererStats stats_;
};

}  // namespace

Result<std::unique_ptr<VtRenderer>> VtRenderer::create(const RendererConfig& config) {
    auto r = std::make_unique<VtRendererImpl>(config);
    if (Status st = r->init(); !st) return st.error();
    return std::unique_ptr<VtRenderer>(std::move(r));
}

}  // namespace tessera::client::gl
