// VtRenderer: the physical page atlas, packed page tables, the staging ring, the feedback, depth
// and VT passes, and the feedback / counter readback rings. See renderer.hpp and docs/renderer.md.
#include <fmt/format.h>

#include <algorithm>
#include <numeric>
#include <cmath>
#include <cstring>
#include <deque>
#include <map>
#include <unordered_map>

#include "gl_util.hpp"
#include "scene_draw.hpp"
#include "page_mips.hpp"
#include "staging.hpp"
#include "tessera/client/gl/renderer.hpp"
#include "page_table.hpp"

namespace tessera::client::gl {

namespace {

using namespace detail;

constexpr std::uint32_t kMaxLevels = 32;
constexpr std::size_t kCounterBytes = 16;              // 4 uints, by kind: unused, unbiased only, biased only, both (vt.frag)
constexpr std::size_t kMaxUnpolledCounters = 1024;     // finished counter frames kept for poll_counters

// Uniform locations of a program built with vt_sample.glsl (scene.vert forwards most of them to
// the fragment shader: vt_sample.glsl, "Inputs").
struct VtUniforms {
    GLint view_projection = -1, bias = -1, main_pixel = -1;
    GLint table_column = -1, table_last_row = -1, levels = -1, texture_id = -1;
    GLint page_table = -1, atlas = -1, dir_offset = -1, dir_width = -1;
    ChunkUniforms chunk;

    explicit VtUniforms(const Program& p = Program()) {
        if (!p) return;
        view_projection = uniform(p, "u_view_projection");
        bias = uniform(p, "u_bias");
        main_pixel = uniform(p, "vt_main_pixel");
        table_column = uniform(p, "u_table_column");
        table_last_row = uniform(p, "u_table_last_row");
        levels = uniform(p, "u_levels");
        texture_id = uniform(p, "vt_texture_id");
        page_table = uniform(p, "vt_page_table");
        dir_offset = uniform(p, "vt_dir_offset");
        dir_width = uniform(p, "vt_dir_width");
        atlas = uniform(p, "vt_atlas");
        chunk.chunk_offset = uniform(p, "u_chunk_offset");
        chunk.chunk_page = uniform(p, "u_chunk_page");
        chunk.chunk_base = uniform(p, "u_chunk_base");
        chunk.chunk_bounds = uniform(p, "u_chunk_bounds");
    }
};

// A virtual texture's page table on the GPU: every level in one R32UI texture, level 0 at (0, 0),
// levels 1.. stacked in a column to its right (PageTable::dense_level_origin: closed-form, so the
// shader computes it; level sizes round up, so they are no mip chain).
struct VirtualTexture {
    TextureId id = 0;
    std::uint32_t levels = 0, payload = 0, border = 0;
    std::vector<std::int32_t> origin;      // 2 per level: table texel of the level's entry (0, 0)
    std::vector<std::uint32_t> pages;      // 2 per level: tiles_x, tiles_y
    std::vector<std::uint32_t> texels;     // 2 per level: width, height
    std::uint32_t table_width = 0, table_height = 0;
    Texture table;
    // Two-level table (sparse CPU tables; vt_sample.glsl's VT_SPARSE_TABLE) instead of `table`:
    // a directory per level (block slot + 1, 0: unallocated) and a pool of 32x32-entry blocks.
    bool sparse = false;
    std::vector<std::uint32_t> dir_offset, dir_width;  // per level
    Buffer directory, blocks;
    std::unordered_map<std::uint64_t, std::uint32_t> block_slot;  // (level, bx, by) -> pool slot
    std::vector<std::uint32_t> free_blocks;
};

std::string gl_renderer_name() {
    const auto* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    return r ? r : "unknown renderer";
}

// The atlas's GL internal format for the configured page format.
GLenum atlas_internal_format(const RendererConfig& c) {
    switch (c.page_format) {
        case PageFormat::bc1: return c.srgb ? GL_COMPRESSED_SRGB_S3TC_DXT1_EXT : GL_COMPRESSED_RGB_S3TC_DXT1_EXT;
        case PageFormat::bc4: return GL_COMPRESSED_RED_RGTC1;  // data, not colour: never sRGB
        case PageFormat::bc5: return GL_COMPRESSED_RG_RGTC2;
        case PageFormat::r16: return GL_R16;  // heights and other data: exact, never sRGB
        case PageFormat::r16f: return GL_R16F;
        case PageFormat::r32f: return GL_R32F;
        default: return c.srgb ? GL_SRGB8_ALPHA8 : GL_RGBA8;
    }
}

// The client-side format and type of an uncompressed page's texels.
std::pair<GLenum, GLenum> upload_format(PageFormat f) {
    switch (f) {
        case PageFormat::r16: return {GL_RED, GL_UNSIGNED_SHORT};
        case PageFormat::r16f: return {GL_RED, GL_HALF_FLOAT};
        case PageFormat::r32f: return {GL_RED, GL_FLOAT};
        default: return {GL_RGBA, GL_UNSIGNED_BYTE};
    }
}

// Whether this GL can hold the configured page format, and if not, why, naming the format (a
// missing format must be an error, never a black image). RGTC (bc4, bc5) is core since GL 3.0;
// S3TC (bc1) is an extension, and its sRGB form another.
Status check_page_format_support(const RendererConfig& c) {
    const auto refuse = [&](std::string why) {
        return Status(Error{Errc::unsupported, fmt::format("renderer: page format {}: {}", to_string(c.page_format), why)});
    };
    switch (c.page_format) {
        case PageFormat::rgba8: return {};
        case PageFormat::bc1:
            if (!epoxy_has_gl_extension("GL_EXT_texture_compression_s3tc"))
                return refuse("this GL lacks GL_EXT_texture_compression_s3tc (" + gl_renderer_name() + ")");
            if (c.srgb && !epoxy_has_gl_extension("GL_EXT_texture_sRGB") &&
                !epoxy_has_gl_extension("GL_EXT_texture_compression_s3tc_srgb"))
                return refuse("this GL has no sRGB S3TC format (GL_EXT_texture_sRGB) (" + gl_renderer_name() + ")");
            break;
        case PageFormat::bc4:
        case PageFormat::bc5: break;
        case PageFormat::r16:
        case PageFormat::r16f:
        case PageFormat::r32f: return {};  // core formats, colour-renderable (the page-mip pass draws into them)
        default: return refuse("the renderer's atlas does not hold it");
    }
    if (c.tile_size % 4 != 0) return refuse(fmt::format("tiles of {} texels are not whole 4x4 blocks", c.tile_size));
    if (c.filter != Filter::bilinear && c.tile_size % 8 != 0)
        return refuse(fmt::format("the second level of tiles of {} texels is not whole 4x4 blocks (a multiple of 8)", c.tile_size));
    return {};
}

class VtRendererImpl final : public VtRenderer {
public:
    explicit VtRendererImpl(const RendererConfig& c) : cfg_(c), staging_(c.staging_bytes) {}

    Status init() {
        const auto& c = cfg_;
        if (c.width == 0 || c.height == 0) return Error{Errc::invalid_argument, "renderer: zero width or height"};
        if (c.feedback_scale == 0) return Error{Errc::invalid_argument, "renderer: feedback_scale must be >= 1"};
        if (c.max_anisotropy < 1 || c.max_anisotropy > 8) return Error{Errc::invalid_argument, "renderer: max_anisotropy must be 1..8"};
        if (c.pool_slots == 0 || c.pool_slots > PageTable::kMaxSlots)
            return Error{Errc::invalid_argument, fmt::format("renderer: pool_slots must be 1..{}", PageTable::kMaxSlots)};
        if (c.tile_size <= 2 * c.border || c.border == 0)
            return Error{Errc::invalid_argument, fmt::format("renderer: tile_size {} and border {} leave no payload (border >= 1)", c.tile_size, c.border)};
        if (c.filter != Filter::bilinear && (c.tile_size % 2 != 0 || c.border % 2 != 0))
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
        if (!(c.feedback_prefetch_lod >= 0 && c.feedback_prefetch_lod <= 2))
            return Error{Errc::invalid_argument, "renderer: feedback_prefetch_lod must be 0..2"};
        if (!(c.feedback_guard_band >= 0 && c.feedback_guard_band <= 1))
            return Error{Errc::invalid_argument, "renderer: feedback_guard_band must be 0..1"};
        TESSERA_TRY(check_page_format_support(c));
        GLint max_size = 0;
        glGetIntegerv(GL_MAX_TEXTURE_SIZE, &max_size);
        max_texture_ = static_cast<std::uint32_t>(std::max(max_size, 1));
        glGetInteger64v(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &max_ssbo_);
        if (!staging_.ok()) return Error{Errc::resource_exhausted, "renderer: cannot map the staging ring"};

        // The atlas: a near-square grid of tile_size cells.
        const std::uint32_t per_row_max = max_texture_ / c.tile_size;
        columns_ = std::max<std::uint32_t>(1, static_cast<std::uint32_t>(std::ceil(std::sqrt(double(c.pool_slots)))));
        columns_ = std::min({columns_, std::max<std::uint32_t>(per_row_max, 1), kMaxAtlasCells});
        const std::uint32_t rows = (c.pool_slots + columns_ - 1) / columns_;
        if (rows > kMaxAtlasCells)
            return Error{Errc::resource_exhausted, fmt::format("renderer: a pool of {} slots needs {} atlas rows of {} cells; the "
                                                               "GPU page-table entry holds at most {} (fewer slots)",
                                                               c.pool_slots, rows, columns_, kMaxAtlasCells)};
        atlas_width_ = columns_ * c.tile_size;
        atlas_height_ = rows * c.tile_size;
        if (per_row_max == 0 || atlas_width_ > max_texture_ || atlas_height_ > max_texture_)
            return Error{Errc::resource_exhausted,
                         fmt::format("renderer: a pool of {} slots of {}^2 texels needs a {}x{} atlas; the GPU's largest "
                                     "texture is {}^2 (fewer slots or smaller tiles)",
                                     c.pool_slots, c.tile_size, atlas_width_, atlas_height_, max_texture_)};
        // RGBA8 with one level: a rectangle texture, which the shader samples in texel coordinates
        // (no normalisation, no mip level to select): fewer instructions per lookup on a software
        // rasterizer. Block formats cannot live in a rectangle texture: always 2D.
        const bool two_levels = c.filter != Filter::bilinear;
        const bool blocks = is_block_compressed(c.page_format);
        atlas_internal_format_ = atlas_internal_format(c);
        atlas_ = make_texture(two_levels || blocks ? GL_TEXTURE_2D : GL_TEXTURE_RECTANGLE);
        glTextureStorage2D(atlas_.get(), two_levels ? 2 : 1, atlas_internal_format_, GLsizei(atlas_width_), GLsizei(atlas_height_));
        glTextureParameteri(atlas_.get(), GL_TEXTURE_MIN_FILTER, two_levels ? GL_LINEAR_MIPMAP_LINEAR : GL_LINEAR);
        glTextureParameteri(atlas_.get(), GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        glTextureParameteri(atlas_.get(), GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
        glTextureParameteri(atlas_.get(), GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
        if (!blocks) {  // compressed textures cannot be cleared; only mapped cells are ever sampled
            const std::uint8_t zero[4] = {0, 0, 0, 0};
            glClearTexImage(atlas_.get(), 0, GL_RGBA, GL_UNSIGNED_BYTE, zero);
            if (two_levels) {
                glClearTexImage(atlas_.get(), 1, GL_RGBA, GL_UNSIGNED_BYTE, zero);
                TESSERA_TRY(page_mips_.init(atlas_.get(), atlas_internal_format_, columns_, rows, c.tile_size,
                                            c.srgb && c.page_format == PageFormat::rgba8));
            }
        }
        // The second level: rendered on the GPU for RGBA8 pages (page_mips.hpp); for block formats,
        // which cannot be rendered into, made by the transcode threads and uploaded with the page.
        atlas_mips_ = two_levels && !blocks;
        second_level_uploads_ = two_levels && blocks;
        if (auto e = take_gl_errors("page atlas"); !e.empty())
            return Error{Errc::resource_exhausted, fmt::format("renderer: {}x{} atlas: {}", atlas_width_, atlas_height_, e)};

        // Programs.
        const std::string defines = vt_shader_defines(c, atlas_width_, atlas_height_);
        auto depth = build_program("scene.vert", "depth.frag", defines);
        if (!depth) return depth.error();
        auto vt = build_program("scene.vert", "vt.frag", defines);
        if (!vt) return vt.error();
        auto vt_sparse = build_program("scene.vert", "vt.frag", defines + "#define VT_SPARSE_TABLE 1\n");
        if (!vt_sparse) return vt_sparse.error();
        vt_other_program_ = std::move(*vt_sparse);
        vt_other_u_ = VtUniforms(vt_other_program_);
        auto fb = build_program("scene.vert", "feedback.frag", defines);
        if (!fb) return fb.error();
        depth_program_ = std::move(*depth);
        vt_program_ = std::move(*vt);
        feedback_program_ = std::move(*fb);
        depth_u_ = VtUniforms(depth_program_);
        vt_u_ = VtUniforms(vt_program_);
        feedback_u_ = VtUniforms(feedback_program_);
        for (auto* pu : {&vt_u_, &feedback_u_, &vt_other_u_}) {
            const GLuint p = pu == &vt_u_         ? vt_program_.get()
                             : pu == &feedback_u_ ? feedback_program_.get()
                                                  : vt_other_program_.get();
            const auto& u = *pu;
            glProgramUniform1i(p, u.page_table, 0);
            glProgramUniform1i(p, u.atlas, 1);
        }
        fb_width_ = (c.width + c.feedback_scale - 1) / c.feedback_scale;
        fb_height_ = (c.height + c.feedback_scale - 1) / c.feedback_scale;
        // Derivatives per main-target pixel: a main pixel is fb_width / width feedback pixels (of a
        // feedback image widened by the guard band: 1 + g times fewer).
        const float widen = 1.0f + c.feedback_guard_band;
        glProgramUniform2f(feedback_program_.get(), feedback_u_.main_pixel, float(fb_width_) / float(c.width) / widen,
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

        // Readback rings: persistently mapped, coherent; read once their fence has signalled.
        const GLbitfield read_flags = GL_MAP_READ_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
        const std::size_t fb_bytes = std::size_t(fb_width_) * fb_height_ * 8;
        feedback_slots_.resize(c.readback_ring);
        for (auto& s : feedback_slots_) {
            s.pbo = make_buffer();
            glNamedBufferStorage(s.pbo.get(), GLsizeiptr(fb_bytes), nullptr, read_flags);
            s.map = static_cast<const std::uint32_t*>(glMapNamedBufferRange(s.pbo.get(), 0, GLsizeiptr(fb_bytes), read_flags));
            if (!s.map) return Error{Errc::resource_exhausted, "renderer: cannot map a feedback readback buffer"};
        }
        counter_slots_.resize(std::size_t(c.readback_ring) * 4);
        for (auto& slot : counter_slots_) slot.textured = make_query(GL_SAMPLES_PASSED);
        counters_ = make_buffer();
        glNamedBufferStorage(counters_.get(), kCounterBytes, nullptr, GL_DYNAMIC_STORAGE_BIT);
        counter_readback_ = make_buffer();
        const auto ring_bytes = GLsizeiptr(counter_slots_.size() * kCounterBytes);
        glNamedBufferStorage(counter_readback_.get(), ring_bytes, nullptr, read_flags);
        counter_map_ = static_cast<const std::uint32_t*>(glMapNamedBufferRange(counter_readback_.get(), 0, ring_bytes, read_flags));
        if (!counter_map_) return Error{Errc::resource_exhausted, "renderer: cannot map the counter readback ring"};
        if (auto e = take_gl_errors("renderer setup"); !e.empty()) return Error{Errc::resource_exhausted, e};
        return Status();
    }

    ~VtRendererImpl() override {
        for (auto& s : feedback_slots_)
            if (s.map) glUnmapNamedBuffer(s.pbo.get());
        if (counter_map_) glUnmapNamedBuffer(counter_readback_.get());
    }

    // ---- PageUploader -----------------------------------------------------------------------

    PagePoolFormat pool_format() const override { return {cfg_.page_format, second_level_uploads_}; }

    void upload_page(SlotId slot, const PageKey& page, std::span<const std::uint8_t> page_data, std::uint32_t tile_size) override {
        if (tile_size != cfg_.tile_size || slot >= cfg_.pool_slots ||
            page_data.size() != page_upload_bytes(cfg_.page_format, tile_size, second_level_uploads_)) {
            ++stats_.malformed_uploads;
            return;
        }
        const auto x = GLint((slot % columns_) * tile_size), y = GLint((slot / columns_) * tile_size);
        if (!is_block_compressed(cfg_.page_format)) {
            const auto [format, type] = upload_format(cfg_.page_format);
            upload(atlas_.get(), x, y, GLsizei(tile_size), GLsizei(tile_size), format, type, page_data.data(), page_data.size());
            if (atlas_mips_) place_page_mip(slot, page);
        } else {
            const std::size_t level0 = page_bytes(cfg_.page_format, tile_size);
            upload_blocks(0, x, y, GLsizei(tile_size), page_data.first(level0));
            if (second_level_uploads_) upload_blocks(1, x / 2, y / 2, GLsizei(tile_size / 2), page_data.subspan(level0));
        }
        ++stats_.pages_uploaded;
    }

    // The second level of the cell `slot` now holding `page` (trilinear, anisotropic;
    // page_mips.hpp): the parent page's texels over it when the parent is in the atlas, else its
    // 2x2 means; and the page's own texels into the second level of its children in the atlas.
    void place_page_mip(SlotId slot, const PageKey& page) {
        if (slot_pages_.size() != cfg_.pool_slots) slot_pages_.assign(cfg_.pool_slots, PageKey{0xFFFF, 31, 0, 0});
        PageKey& old = slot_pages_[slot];
        if (auto it = resident_slots_.find(old); it != resident_slots_.end() && it->second == slot) resident_slots_.erase(it);
        old = page;
        resident_slots_[page] = slot;
        const auto t = textures_.find(page.texture);
        const bool known = t != textures_.end() && page.level < t->second.levels;
        const bool last = known && std::uint32_t(page.level) + 1 >= t->second.levels;  // blends nothing coarser
        // Level-0 atlas texel of the corner of the parent tile's quarter over `child`.
        const auto quarter = [&](const PageKey& child, SlotId parent_slot) {
            const std::uint32_t ts = cfg_.tile_size, P = ts - 2 * cfg_.border, B = cfg_.border;
            return std::pair{(parent_slot % columns_) * ts + (child.x & 1) * (P / 2) + B / 2,
                             (parent_slot / columns_) * ts + (child.y & 1) * (P / 2) + B / 2};
        };
        if (!last) {
            if (auto p = resident_slots_.find(page.parent()); known && p != resident_slots_.end()) {
                const auto [x, y] = quarter(page, p->second);
                page_mips_.copy_from_parent(slot % columns_, slot / columns_, x, y);
            } else {
                mark_page_mip(slot, page);
            }
        }
        if (!known || page.level == 0) return;
        for (std::uint32_t k = 0; k < 4; ++k) {
            const PageKey child{page.texture, std::uint8_t(page.level - 1), 2 * page.x + (k & 1), 2 * page.y + (k >> 1)};
            if (auto c = resident_slots_.find(child); c != resident_slots_.end()) {
                const auto [x, y] = quarter(child, slot);
                page_mips_.copy_from_parent(c->second % columns_, c->second / columns_, x, y);
            }
        }
    }

    // The cell's 2x2 means, placed by its page so that they are clamped at the texture's edges; a
    // page of a texture not added is halved as it is.
    void mark_page_mip(SlotId slot, const PageKey& page) {
        std::int32_t ox = 0, oy = 0;
        std::uint32_t lw = UINT32_MAX, lh = UINT32_MAX;
        if (auto it = textures_.find(page.texture); it != textures_.end() && page.level < it->second.levels) {
            const VirtualTexture& t = it->second;
            ox = std::int32_t(std::int64_t(page.x) * t.payload - t.border);
            oy = std::int32_t(std::int64_t(page.y) * t.payload - t.border);
            lw = t.texels[2 * page.level];
            lh = t.texels[2 * page.level + 1];
        }
        page_mips_.mark(slot % columns_, slot / columns_, ox, oy, lw, lh);
    }

    void upload_page_table(TextureId texture, std::uint8_t level, std::uint32_t x0, std::uint32_t y0, std::uint32_t w,
                           std::uint32_t h, std::span<const std::uint32_t> entries) override {
        auto it = textures_.find(texture);
        if (it == textures_.end() || level >= it->second.levels || entries.size() != std::size_t(w) * h || w == 0 ||
            h == 0) {
            ++stats_.malformed_uploads;
            return;
        }
        const auto& t = it->second;
        if (t.sparse || std::uint64_t(x0) + w > t.pages[2 * level] || std::uint64_t(y0) + h > t.pages[2 * level + 1]) {
            ++stats_.malformed_uploads;
            return;
        }
        const auto gpu = gpu_entries(entries);
        upload(t.table.get(), GLint(t.origin[2 * level] + std::int32_t(x0)), GLint(t.origin[2 * level + 1] + std::int32_t(y0)),
               GLsizei(w), GLsizei(h), GL_RED_INTEGER, GL_UNSIGNED_INT, gpu.data(), gpu.size_bytes());
        ++stats_.table_uploads;
    }

    // Mirrors a sparse PageTable's blocks. A dense texture receiving one turns two-level (its CPU
    // table chose sparse under a smaller byte bound). Block slots come from the texture's pool,
    // sized so that it cannot run out while the runtime's pool is the renderer's (PageTable holds
    // at most 5 blocks per resident page, and frees come first); if it does, the block stays
    // unallocated here and lookups fall back to a coarser resident page: blurrier, never wrong.
    void upload_page_table_block(TextureId texture, std::uint8_t level, std::uint32_t bx, std::uint32_t by,
                                 std::span<const std::uint32_t> entries) override {
        auto it = textures_.find(texture);
        if (it == textures_.end() || level >= it->second.levels ||
            (!entries.empty() && entries.size() != PageTable::kBlockEntries)) {
            ++stats_.malformed_uploads;
            return;
        }
        VirtualTexture& t = it->second;
        if (!t.sparse && !make_two_level(t).ok()) {
            ++stats_.malformed_uploads;
            return;
        }
        if (bx >= t.dir_width[level] || std::uint64_t(by) * t.dir_width[level] + bx >= dir_level_blocks(t, level)) {
            ++stats_.malformed_uploads;
            return;
        }
        const std::uint64_t key = (std::uint64_t(level) << 40) | (std::uint64_t(by) << 20) | bx;
        const std::size_t dir_at = (std::size_t(t.dir_offset[level]) + std::size_t(by) * t.dir_width[level] + bx) * 4;
        auto slot = t.block_slot.find(key);
        if (entries.empty()) {
            if (slot == t.block_slot.end()) return;
            const std::uint32_t none = 0;
            upload_buffer(t.directory.get(), dir_at, &none, 4);
            t.free_blocks.push_back(slot->second);
            t.block_slot.erase(slot);
            ++stats_.table_uploads;
            return;
        }
        if (slot == t.block_slot.end()) {
            if (t.free_blocks.empty()) {
                ++stats_.malformed_uploads;
                return;
            }
            slot = t.block_slot.emplace(key, t.free_blocks.back()).first;
            t.free_blocks.pop_back();
            // The block's entries land before its directory entry names it (both in stream order).
            const auto gpu = gpu_entries(entries);
            upload_buffer(t.blocks.get(), std::size_t(slot->second) * PageTable::kBlockEntries * 4, gpu.data(), gpu.size_bytes());
            const std::uint32_t named = slot->second + 1;
            upload_buffer(t.directory.get(), dir_at, &named, 4);
        } else {
            const auto gpu = gpu_entries(entries);
            upload_buffer(t.blocks.get(), std::size_t(slot->second) * PageTable::kBlockEntries * 4, gpu.data(), gpu.size_bytes());
        }
        ++stats_.table_uploads;
    }

    // The GPU's page-table entries: the CPU entry (page_table.hpp: bit 31 valid, bits 24..28
    // resident level, bits 0..23 slot) with the slot replaced by its atlas cell, column in bits
    // 0..11 and row in bits 12..23, so the shader places a page without a division. Valid until
    // the next call.
    std::span<const std::uint32_t> gpu_entries(std::span<const std::uint32_t> entries) {
        gpu_entries_.resize(entries.size());
        for (std::size_t i = 0; i < entries.size(); ++i) {
            const std::uint32_t e = entries[i];
            const std::uint32_t slot = e & 0xFFFFFFu;
            gpu_entries_[i] = (e >> 31) == 0 ? e : (e & 0xFF000000u) | (slot % columns_) | ((slot / columns_) << 12);
        }
        return gpu_entries_;
    }

    // ---- Setup ------------------------------------------------------------------------------

    Status add_texture(TextureId texture, const storage::StoreInfo& info) override {
        if (info.levels.empty() || info.levels.size() > kMaxLevels)
            return Error{Errc::invalid_argument, fmt::format("texture {}: {} levels (1..{})", texture, info.levels.size(), kMaxLevels)};
        if (info.tile_size() != cfg_.tile_size || info.border != cfg_.border)
            return Error{Errc::invalid_argument,
                         fmt::format("texture {}: tiles of {} texels with border {}, the renderer's pool holds {} with border {}",
                                     texture, info.tile_size(), info.border, cfg_.tile_size, cfg_.border)};
        VirtualTexture t;
        t.id = texture;
        t.levels = info.level_count();
        t.payload = info.tile_payload;
        t.border = info.border;
        for (std::uint32_t l = 0; l < t.levels; ++l) {
            const auto& li = info.levels[l];
            if (li.tiles_x == 0 || li.tiles_y == 0 || li.tiles_x > kMaxPagesPerAxis || li.tiles_y > kMaxPagesPerAxis)
                return Error{Errc::invalid_argument, fmt::format("texture {}: level {} has {}x{} pages", texture, l, li.tiles_x, li.tiles_y)};
            t.pages.insert(t.pages.end(), {li.tiles_x, li.tiles_y});
            t.texels.insert(t.texels.end(), {li.width, li.height});
            const auto [x, y] = PageTable::dense_level_origin(info.levels[0].tiles_x, info.levels[0].tiles_y, l);
            t.origin.insert(t.origin.end(), {std::int32_t(x), std::int32_t(y)});
        }
        const auto [table_width, table_height] = PageTable::dense_packed_size(info.levels[0].tiles_x, info.levels[0].tiles_y);
        t.table_width = std::uint32_t(std::min<std::uint64_t>(table_width, UINT32_MAX));
        t.table_height = std::uint32_t(std::min<std::uint64_t>(table_height, UINT32_MAX));
        // Too large for the dense packing (what PageTable makes sparse): a two-level table.
        if (!PageTable::dense_packing_fits(info.levels[0].tiles_x, info.levels[0].tiles_y)) {
            TESSERA_TRY(make_two_level(t));
            install_texture(texture, std::move(t));
            return Status();
        }
        if (t.table_width > max_texture_ || t.table_height > max_texture_)
            return Error{Errc::resource_exhausted,
                         fmt::format("texture {}: its packed page table is {}x{} entries, over the GPU's largest texture ({}^2)",
                                     texture, t.table_width, t.table_height, max_texture_)};
        t.table = make_texture(GL_TEXTURE_2D);
        glTextureStorage2D(t.table.get(), 1, GL_R32UI, GLsizei(t.table_width), GLsizei(t.table_height));
        glTextureParameteri(t.table.get(), GL_TEXTURE_MIN_FILTER, GL_NEAREST);
        glTextureParameteri(t.table.get(), GL_TEXTURE_MAG_FILTER, GL_NEAREST);
        // Clamped: the anisotropic filter gathers 2x2 entries, the second row or column may lie past the edge.
        glTextureParameteri(t.table.get(), GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
        glTextureParameteri(t.table.get(), GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
        const std::uint32_t zero = 0;
        glClearTexImage(t.table.get(), 0, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
        if (auto e = take_gl_errors("page table"); !e.empty())
            return Error{Errc::resource_exhausted, fmt::format("texture {}: {}x{} page table: {}", texture, t.table_width, t.table_height, e)};
        install_texture(texture, std::move(t));
        return Status();
    }

    // A texture replacing the scene's one changes the chunks' page frames.
    void install_texture(TextureId texture, VirtualTexture&& t) {
        if (has_scene_ && scene_texture_ == texture) geometry_.set_page_layout(t.payload, t.texels[0], t.texels[1]);
        textures_[texture] = std::move(t);
    }

    Status set_scene(const scene::Scene& scene, TextureId texture) override {
        if (!textures_.contains(texture))
            return Error{Errc::invalid_argument, fmt::format("set_scene: texture {} was not added (add_texture first)", texture)};
        TESSERA_TRY(geometry_.upload(scene));
        const VirtualTexture& t = textures_.find(texture)->second;
        geometry_.set_page_layout(t.payload, t.texels[0], t.texels[1]);
        depth_prepass_ = !scene::overdraw_free(scene);
        scene_texture_ = texture;
        has_scene_ = true;
        return Status();
    }

    // ---- Frames -----------------------------------------------------------------------------

    std::uint64_t render(const scene::Camera& camera, float lod_bias) override {
        ++frame_;
        ++stats_.frames;
        staging_.close_batch();  // the uploads since the last frame, fenced together
        staging_.retire();
        if (atlas_mips_) page_mips_.run();  // after the frame's page uploads, in stream order

        const double aspect = double(cfg_.width) / double(cfg_.height);
        const auto vp = view_projection(camera, aspect);
        const VirtualTexture* tex = nullptr;
        if (has_scene_) {
            auto it = textures_.find(scene_texture_);
            if (it != textures_.end()) tex = &it->second;
        }
        bool front_to_back = false;
        if (tex) {
            geometry_.cull(camera, aspect);
            // A heightfield drawn front to back shades each visible pixel once without the pre-pass.
            front_to_back = depth_prepass_ && geometry_.order_front_to_back(camera);
            use_page_table(*tex);
            set_texture_uniforms(vt_program_, vt_u_, *tex);
            set_texture_uniforms(feedback_program_, feedback_u_, *tex);
            glBindTextureUnit(1, atlas_.get());
        }
        stats_.visible_chunks = tex ? geometry_.visible_chunks() : 0;
        for (auto* p : {&depth_program_, &vt_program_, &feedback_program_}) {
            const VtUniforms& u = p == &depth_program_ ? depth_u_ : p == &vt_program_ ? vt_u_ : feedback_u_;
            glProgramUniformMatrix4fv(p->get(), u.view_projection, 1, GL_FALSE, vp.data());
            glProgramUniform1f(p->get(), u.bias, lod_bias);
        }
        glEnable(GL_CULL_FACE);
        glCullFace(GL_BACK);
        glFrontFace(GL_CCW);
        glEnable(GL_DEPTH_TEST);
        glDisable(GL_BLEND);
        glDisable(GL_SCISSOR_TEST);

        // Feedback pass at 1/N: the ids of the nearest surface (its own depth buffer). Read back
        // after the main pass: a software rasterizer finishes a pass when it is read, so reading it
        // here would hold the CPU until then in the middle of the frame.
        const auto feedback_slot = acquire_feedback_slot();
        if (const auto slot = feedback_slot) {
            // Jitter: shift the feedback pass by a sub-pixel offset (clip-space translation, so
            // depth and the exact derivatives are unaffected) cycling over the N x N main pixels
            // one feedback pixel covers.
            scene::Mat4f fvp = vp;
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
                for (int c = 0; c < 4; ++c) {
                    fvp[std::size_t(c * 4 + 0)] += float(dx) * vp[std::size_t(c * 4 + 3)];
                    fvp[std::size_t(c * 4 + 1)] += float(dy) * vp[std::size_t(c * 4 + 3)];
                }
            }
            if (cfg_.feedback_guard_band > 0) {  // clip x, y scaled by 1/(1+g): a wider view
                const float k = 1.0f / (1.0f + cfg_.feedback_guard_band);
                for (int c = 0; c < 4; ++c) {
                    fvp[std::size_t(c * 4 + 0)] *= k;
                    fvp[std::size_t(c * 4 + 1)] *= k;
                }
            }
            glProgramUniformMatrix4fv(feedback_program_.get(), feedback_u_.view_projection, 1, GL_FALSE, fvp.data());
            glProgramUniform1f(feedback_program_.get(), feedback_u_.bias, lod_bias - cfg_.feedback_prefetch_lod);
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
                glUseProgram(feedback_program_.get());
                geometry_.draw(feedback_program_, feedback_u_.chunk, camera);
            }
        } else {
            ++stats_.feedback_skipped;
        }

        // Main pass: depth pre-pass, then the VT pass at GL_LEQUAL with early fragment tests, so
        // each visible pixel is shaded and counted once. A scene where no triangle can hide another
        // (scene::overdraw_free: the flat terrain) needs no pre-pass: the VT pass alone shades
        // each pixel once. Nor does a heightfield drawn front to back (displaced terrain): there
        // each pixel's first fragment is its visible one, and GL_LESS rejects the rest.
        const bool prepass = depth_prepass_ && !front_to_back;
        begin_colour_pass(main_);
        const std::uint32_t zero = 0;
        glClearNamedBufferData(counters_.get(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
        const auto counter_slot = acquire_counter_slot();
        if (tex) {
            if (prepass) {
                ++stats_.depth_prepasses;
                glColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
                glDepthFunc(GL_LESS);
                glUseProgram(depth_program_.get());
                geometry_.draw(depth_program_, depth_u_.chunk, camera);
                glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
                glDepthMask(GL_FALSE);
            }
            glDepthFunc(prepass ? GL_LEQUAL : GL_LESS);
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, counters_.get());
            glUseProgram(vt_program_.get());
            // Textured pixels come from an occlusion query (the VT pass shades each visible pixel
            // once), not from a per-fragment atomic: atomics on one address from every fragment
            // serialise a software rasterizer's threads.
            if (counter_slot) glBeginQuery(GL_SAMPLES_PASSED, counter_slots_[*counter_slot].textured.get());
            geometry_.draw(vt_program_, vt_u_.chunk, camera);
            if (counter_slot) glEndQuery(GL_SAMPLES_PASSED);
            glDepthMask(GL_TRUE);
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, 0);
        }
        glUseProgram(0);
        glDisable(GL_FRAMEBUFFER_SRGB);
        if (feedback_slot) {
            auto& s = feedback_slots_[*feedback_slot];
            glBindFramebuffer(GL_READ_FRAMEBUFFER, fb_fbo_.get());
            glBindBuffer(GL_PIXEL_PACK_BUFFER, s.pbo.get());
            glPixelStorei(GL_PACK_ALIGNMENT, 4);
            glReadPixels(0, 0, GLsizei(fb_width_), GLsizei(fb_height_), GL_RG_INTEGER, GL_UNSIGNED_INT, nullptr);
            glBindBuffer(GL_PIXEL_PACK_BUFFER, 0);
            s.fence.insert();
            s.busy = true;
            s.frame = frame_;
            s.bias = lod_bias;
        }
        glBindFramebuffer(GL_FRAMEBUFFER, 0);
        // The shader's atomics must land before the copy (and before the next frame's clear).
        glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
        if (counter_slot) {
            auto& s = counter_slots_[*counter_slot];
            glCopyNamedBufferSubData(counters_.get(), counter_readback_.get(), 0, GLintptr(*counter_slot * kCounterBytes),
                                     kCounterBytes);
            s.fence.insert();
            s.busy = true;
            s.frame = frame_;
            s.has_query = bool(tex);
        } else {
            ++stats_.counters_skipped;
        }
        glFlush();  // start the GPU on this frame; never waits
        return frame_;
    }

    bool poll_feedback(FeedbackFrame& out) override {
        collect_feedback(false);
        if (!has_ready_) return false;
        std::swap(out, ready_);
        has_ready_ = false;
        return true;
    }

    std::size_t poll_counters(std::vector<FrameCounters>& out) override {
        collect_counters(false);
        const std::size_t n = finished_counters_.size();
        out.insert(out.end(), finished_counters_.begin(), finished_counters_.end());
        finished_counters_.clear();
        return n;
    }

    void finish(std::vector<FrameCounters>* counters, FeedbackFrame* feedback) override {
        glFinish();
        while (glGetError() != GL_NO_ERROR) ++stats_.gl_errors;
        staging_.retire();
        collect_feedback(true);
        collect_counters(true);
        if (counters) {
            counters->insert(counters->end(), finished_counters_.begin(), finished_counters_.end());
            finished_counters_.clear();
        }
        if (feedback && has_ready_) {
            std::swap(*feedback, ready_);
            has_ready_ = false;
        }
    }

    std::vector<std::uint8_t> read_color() override { return read_colour(main_); }

    std::vector<std::uint8_t> read_page(SlotId slot) override {
        if (slot >= cfg_.pool_slots || is_block_compressed(cfg_.page_format)) return {};
        const auto [format, type] = upload_format(cfg_.page_format);
        std::vector<std::uint8_t> out(page_bytes(cfg_.page_format, cfg_.tile_size));
        glPixelStorei(GL_PACK_ALIGNMENT, 1);
        glBindBuffer(GL_PIXEL_PACK_BUFFER, 0);
        const auto ts = GLsizei(cfg_.tile_size);
        glGetTextureSubImage(atlas_.get(), 0, GLint((slot % columns_) * cfg_.tile_size), GLint((slot / columns_) * cfg_.tile_size),
                             0, ts, ts, 1, format, type, GLsizei(out.size()), out.data());
        return out;
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

    const RendererConfig& config() const override { return cfg_; }
    RendererStats stats() const override { return stats_; }

private:
    struct FeedbackSlot {
        Buffer pbo;
        const std::uint32_t* map = nullptr;
        Fence fence;
        bool busy = false;
        std::uint64_t frame = 0;
        float bias = 0;
    };
    struct CounterSlot {
        Fence fence;
        Query textured;  // GL_SAMPLES_PASSED of the VT pass: the textured pixels
        bool has_query = false;  // the VT pass ran (a frame without a texture counts nothing)
        bool busy = false;
        std::uint64_t frame = 0;
    };

    // Copies `bytes` of `data` into the staging ring and uploads the rectangle from there; when
    // the ring has no room, uploads from `data` directly (still correct and in order).
    void upload(GLuint texture, GLint x, GLint y, GLsizei w, GLsizei h, GLenum format, GLenum type, const void* data,
                std::size_t bytes) {
        glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
        glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
        if (auto off = staging_.allocate(bytes)) {
            std::memcpy(staging_.data() + *off, data, bytes);
            glBindBuffer(GL_PIXEL_UNPACK_BUFFER, staging_.buffer());
            glTextureSubImage2D(texture, 0, x, y, w, h, format, type, reinterpret_cast<const void*>(*off));
            glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
        } else {
            ++stats_.direct_uploads;
            glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
            glTextureSubImage2D(texture, 0, x, y, w, h, format, type, data);
        }
    }

    // A side x side square of blocks into atlas level `level`, through the staging ring like
    // upload() (or straight from `blocks` when the ring is full).
    void upload_blocks(GLint level, GLint x, GLint y, GLsizei side, std::span<const std::uint8_t> blocks) {
        const auto bytes = static_cast<GLsizei>(blocks.size());
        if (auto off = staging_.allocate(blocks.size())) {
            std::memcpy(staging_.data() + *off, blocks.data(), blocks.size());
            glBindBuffer(GL_PIXEL_UNPACK_BUFFER, staging_.buffer());
            glCompressedTextureSubImage2D(atlas_.get(), level, x, y, side, side, atlas_internal_format_, bytes,
                                          reinterpret_cast<const void*>(*off));
            glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
        } else {
            ++stats_.direct_uploads;
            glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
            glCompressedTextureSubImage2D(atlas_.get(), level, x, y, side, side, atlas_internal_format_, bytes, blocks.data());
        }
    }

    static std::uint64_t dir_level_blocks(const VirtualTexture& t, std::uint32_t level) {
        const std::uint32_t rows = (t.pages[2 * level + 1] + PageTable::kBlockSide - 1) >> PageTable::kBlockShift;
        return std::uint64_t(t.dir_width[level]) * rows;
    }

    // The two-level table of `t`: a directory of every level's blocks, all unallocated, and a pool
    // of 5 blocks per physical page plus the coarse levels' (PageTable's bound on allocated
    // blocks), or every block of the texture when that is fewer. Both are SSBOs: no
    // GL_MAX_TEXTURE_SIZE limit, only the largest shader storage block.
    Status make_two_level(VirtualTexture& t) {
        std::vector<std::uint32_t> offset, width;
        std::uint64_t total = 0, coarse = 0;
        for (std::uint32_t l = 0; l < t.levels; ++l) {
            const std::uint32_t w = t.pages[2 * l], h = t.pages[2 * l + 1];
            offset.push_back(std::uint32_t(std::min<std::uint64_t>(total, ~0u)));
            width.push_back((w + PageTable::kBlockSide - 1) >> PageTable::kBlockShift);
            total += std::uint64_t(width.back()) * ((h + PageTable::kBlockSide - 1) >> PageTable::kBlockShift);
            coarse += w <= PageTable::kBlockSide && h <= PageTable::kBlockSide;
        }
        const std::uint64_t pool = std::min<std::uint64_t>(total, 5 * std::uint64_t(cfg_.pool_slots) + coarse);
        const std::uint64_t dir_bytes = total * 4, pool_bytes = pool * PageTable::kBlockEntries * 4;
        const auto mib = [](std::uint64_t b) { return double(b) / double(1u << 20); };
        if (std::int64_t(dir_bytes) > max_ssbo_ || std::int64_t(pool_bytes) > max_ssbo_)
            return Error{Errc::resource_exhausted,
                         fmt::format("texture {}: its two-level page table needs a {:.1f} MiB directory and a {:.1f} MiB block pool "
                                     "({} blocks of 32x32 entries for {} pool slots), over the GPU's largest shader storage "
                                     "block ({:.1f} MiB)",
                                     t.id, mib(dir_bytes), mib(pool_bytes), pool, cfg_.pool_slots, mib(std::uint64_t(max_ssbo_)))};
        Buffer directory = make_buffer(), blocks = make_buffer();
        glNamedBufferStorage(directory.get(), GLsizeiptr(dir_bytes), nullptr, GL_DYNAMIC_STORAGE_BIT);
        const std::uint32_t zero = 0;
        glClearNamedBufferData(directory.get(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
        glNamedBufferStorage(blocks.get(), GLsizeiptr(pool_bytes), nullptr, GL_DYNAMIC_STORAGE_BIT);
        if (auto e = take_gl_errors("two-level page table"); !e.empty())
            return Error{Errc::resource_exhausted, fmt::format("texture {}: {:.1f} MiB directory and {:.1f} MiB block pool: {}", t.id,
                                                               mib(dir_bytes), mib(pool_bytes), e)};
        t.sparse = true;
        t.table = Texture();
        t.dir_offset = std::move(offset);
        t.dir_width = std::move(width);
        t.directory = std::move(directory);
        t.blocks = std::move(blocks);
        t.block_slot.clear();
        t.free_blocks.clear();
        for (auto s = std::uint32_t(pool); s-- > 0;) t.free_blocks.push_back(s);
        return Status();
    }

    // Binds `t`'s page table and puts the VT program of its layout in vt_program_.
    void use_page_table(const VirtualTexture& t) {
        if (t.sparse != vt_program_sparse_) {
            std::swap(vt_program_, vt_other_program_);
            std::swap(vt_u_, vt_other_u_);
            vt_program_sparse_ = t.sparse;
        }
        if (t.sparse) {
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, t.directory.get());
            glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, t.blocks.get());
        } else {
            glBindTextureUnit(0, t.table.get());
        }
    }

    // Copies `bytes` of `data` to `offset` of `buffer` through the staging ring (directly when it
    // has no room), in stream order with the draws: no wait.
    void upload_buffer(GLuint buffer, std::size_t offset, const void* data, std::size_t bytes) {
        if (auto off = staging_.allocate(bytes, 4)) {
            std::memcpy(staging_.data() + *off, data, bytes);
            glCopyNamedBufferSubData(staging_.buffer(), buffer, GLintptr(*off), GLintptr(offset), GLsizeiptr(bytes));
        } else {
            ++stats_.direct_uploads;
            glNamedBufferSubData(buffer, GLintptr(offset), GLsizeiptr(bytes), data);
        }
    }

    void set_texture_uniforms(const Program& p, const VtUniforms& u, const VirtualTexture& t) {
        const GLuint id = p.get();
        glProgramUniform1i(id, u.table_column, GLint(t.pages[0]));
        glProgramUniform1i(id, u.table_last_row, GLint(t.pages[1]) - 1);
        glProgramUniform1ui(id, u.levels, t.levels);
        glProgramUniform1ui(id, u.texture_id, t.id);
        if (t.sparse) {
            glProgramUniform1uiv(id, u.dir_offset, GLsizei(t.levels), t.dir_offset.data());
            glProgramUniform1uiv(id, u.dir_width, GLsizei(t.levels), t.dir_width.data());
        }
    }

    std::optional<std::size_t> acquire_feedback_slot() {
        for (int attempt = 0; attempt < 2; ++attempt) {
            for (std::size_t i = 0; i < feedback_slots_.size(); ++i)
                if (!feedback_slots_[i].busy) return i;
            collect_feedback(false);
        }
        return std::nullopt;
    }

    // Finished feedback readbacks: the newest becomes ready_ (older ones are dropped); their slots
    // are free again. `all`: after glFinish, every busy slot is finished.
    void collect_feedback(bool all) {
        FeedbackSlot* newest = nullptr;
        for (auto& s : feedback_slots_) {
            if (!s.busy || !(all || s.fence.poll())) continue;
            s.busy = false;
            s.fence.reset();
            if (!newest || s.frame > newest->frame) newest = &s;
        }
        if (!newest || (has_ready_ && ready_.frame >= newest->frame)) return;
        ready_.frame = newest->frame;
        ready_.bias = newest->bias;
        ready_.width = fb_width_;
        ready_.height = fb_height_;
        ready_.ids.resize(std::size_t(fb_width_) * fb_height_);
        // GL's row 0 is the bottom; FeedbackFrame's row 0 is the top. RG32UI: low word first.
        for (std::uint32_t y = 0; y < fb_height_; ++y) {
            const std::uint32_t* row = newest->map + std::size_t(fb_height_ - 1 - y) * fb_width_ * 2;
            FeedbackId* dst = ready_.ids.data() + std::size_t(y) * fb_width_;
            for (std::uint32_t x = 0; x < fb_width_; ++x) dst[x] = FeedbackId(row[2 * x]) | (FeedbackId(row[2 * x + 1]) << 32);
        }
        has_ready_ = true;
    }

    std::optional<std::size_t> acquire_counter_slot() {
        for (int attempt = 0; attempt < 2; ++attempt) {
            for (std::size_t i = 0; i < counter_slots_.size(); ++i)
                if (!counter_slots_[i].busy) return i;
            collect_counters(false);
        }
        return std::nullopt;
    }

    void collect_counters(bool all) {
        std::vector<std::size_t> done;
        for (std::size_t i = 0; i < counter_slots_.size(); ++i) {
            auto& s = counter_slots_[i];
            if (s.busy && (all || s.fence.poll())) done.push_back(i);
        }
        std::sort(done.begin(), done.end(), [&](std::size_t a, std::size_t b) { return counter_slots_[a].frame < counter_slots_[b].frame; });
        for (const auto i : done) {
            auto& s = counter_slots_[i];
            const std::uint32_t* v = counter_map_ + i * (kCounterBytes / 4);
            // The query ended before the fence, so its result is there once the fence is.
            GLuint textured = 0;
            if (s.has_query) glGetQueryObjectuiv(s.textured.get(), GL_QUERY_RESULT, &textured);
            finished_counters_.push_back(FrameCounters{s.frame, textured, v[1] + v[3], v[2] + v[3]});
            s.busy = false;
            s.fence.reset();
        }
        while (finished_counters_.size() > kMaxUnpolledCounters) finished_counters_.pop_front();
    }

    RendererConfig cfg_;
    std::uint32_t max_texture_ = 0;
    StagingRing staging_;
    Texture atlas_;
    GLenum atlas_internal_format_ = GL_RGBA8;
    bool atlas_mips_ = false;  // trilinear and anisotropic, RGBA8: the atlas's second level (page_mips.hpp)
    bool second_level_uploads_ = false;  // trilinear and anisotropic, block formats: uploaded with each page
    PageMipPass page_mips_;
    std::vector<PageKey> slot_pages_;                               // the page each slot holds (atlas_mips_)
    std::unordered_map<PageKey, SlotId, PageKeyHash> resident_slots_;  // and back: at most pool_slots
    std::uint32_t columns_ = 1, atlas_width_ = 0, atlas_height_ = 0;
    static constexpr std::uint32_t kMaxAtlasCells = 4096;  // per side: 12 bits each in a GPU entry
    std::vector<std::uint32_t> gpu_entries_;               // gpu_entries' scratch
    std::map<TextureId, VirtualTexture> textures_;
    SceneGeometry geometry_;
    TextureId scene_texture_ = 0;
    bool has_scene_ = false;
    bool depth_prepass_ = true;  // false for scenes where no triangle can hide another

    Program depth_program_, vt_program_, feedback_program_;
    VtUniforms depth_u_, vt_u_, feedback_u_;
    // The VT program for the other page-table layout (two-level while vt_program_ is dense, and
    // the other way round): use_page_table swaps them to the scene texture's.
    Program vt_other_program_;
    VtUniforms vt_other_u_;
    bool vt_program_sparse_ = false;
    GLint64 max_ssbo_ = 0;

    ColourTarget main_;
    Texture fb_ids_;
    Renderbuffer fb_depth_;
    Framebuffer fb_fbo_;
    std::uint32_t fb_width_ = 0, fb_height_ = 0;

    std::vector<FeedbackSlot> feedback_slots_;
    FeedbackFrame ready_;
    bool has_ready_ = false;

    Buffer counters_, counter_readback_;
    const std::uint32_t* counter_map_ = nullptr;
    std::vector<CounterSlot> counter_slots_;
    std::deque<FrameCounters> finished_counters_;

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
