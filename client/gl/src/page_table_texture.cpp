#include "page_table_texture.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "tessera/client/page_table_layout.hpp"

namespace tessera::client::gl::detail {

namespace {

std::uint64_t dir_level_blocks(const VirtualTexture& t, std::uint32_t level) {
    const std::uint32_t rows = (t.pages[2 * level + 1] + PageTableLayout::kBlockSide - 1) >> PageTableLayout::kBlockShift;
    return std::uint64_t(t.dir_width[level]) * rows;
}

}  // namespace

void VirtualTexture::bind() const {
    if (sparse) {
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, directory.get());
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, blocks.get());
    } else {
        glBindTextureUnit(0, table.get());
    }
}

void PageTableTextures::init(std::uint32_t pool_slots, std::uint32_t tile_size, std::uint32_t border,
                             std::uint32_t max_texture, GLint64 max_ssbo) {
    pool_slots_ = pool_slots;
    tile_size_ = tile_size;
    border_ = border;
    max_texture_ = max_texture;
    max_ssbo_ = max_ssbo;
}

const VirtualTexture* PageTableTextures::find(TextureId texture) const {
    auto it = textures_.find(texture);
    return it == textures_.end() ? nullptr : &it->second;
}

std::optional<PagePlace> PageTableTextures::place(const PageKey& page) const {
    const VirtualTexture* t = find(page.texture);
    if (!t || page.level >= t->levels) return std::nullopt;
    return PagePlace{t->levels, std::int32_t(std::int64_t(page.x) * t->payload - t->border),
                     std::int32_t(std::int64_t(page.y) * t->payload - t->border), t->texels[2 * page.level],
                     t->texels[2 * page.level + 1]};
}

Status PageTableTextures::add(TextureId texture, const storage::StoreInfo& info) {
    if (info.levels.empty() || info.levels.size() > kMaxLevels)
        return Error{Errc::invalid_argument, fmt::format("texture {}: {} levels (1..{})", texture, info.levels.size(), kMaxLevels)};
    if (info.tile_size() != tile_size_ || info.border != border_)
        return Error{Errc::invalid_argument,
                     fmt::format("texture {}: tiles of {} texels with border {}, the renderer's pool holds {} with border {}",
                                 texture, info.tile_size(), info.border, tile_size_, border_)};
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
        const auto [x, y] = PageTableLayout::dense_level_origin(info.levels[0].tiles_x, info.levels[0].tiles_y, l);
        t.origin.insert(t.origin.end(), {std::int32_t(x), std::int32_t(y)});
    }
    const auto [table_width, table_height] = PageTableLayout::dense_packed_size(info.levels[0].tiles_x, info.levels[0].tiles_y);
    t.table_width = std::uint32_t(std::min<std::uint64_t>(table_width, UINT32_MAX));
    t.table_height = std::uint32_t(std::min<std::uint64_t>(table_height, UINT32_MAX));
    // Too large for the dense packing (what PageTable makes sparse): a two-level table.
    if (!PageTableLayout::dense_packing_fits(info.levels[0].tiles_x, info.levels[0].tiles_y)) {
        TESSERA_TRY(make_two_level(t));
        textures_[texture] = std::move(t);
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
    textures_[texture] = std::move(t);
    return Status();
}

// A directory of every level's blocks, all unallocated, and a pool of 5 blocks per physical page
// plus the coarse levels' (PageTable's bound on allocated blocks), or every block of the texture
// when that is fewer. SSBOs: no GL_MAX_TEXTURE_SIZE limit, only the largest shader storage block.
Status PageTableTextures::make_two_level(VirtualTexture& t) {
    std::vector<std::uint32_t> offset, width;
    std::uint64_t total = 0, coarse = 0;
    for (std::uint32_t l = 0; l < t.levels; ++l) {
        const std::uint32_t w = t.pages[2 * l], h = t.pages[2 * l + 1];
        offset.push_back(std::uint32_t(std::min<std::uint64_t>(total, ~0u)));
        width.push_back((w + PageTableLayout::kBlockSide - 1) >> PageTableLayout::kBlockShift);
        total += std::uint64_t(width.back()) * ((h + PageTableLayout::kBlockSide - 1) >> PageTableLayout::kBlockShift);
        coarse += w <= PageTableLayout::kBlockSide && h <= PageTableLayout::kBlockSide;
    }
    const std::uint64_t pool = std::min<std::uint64_t>(total, 5 * std::uint64_t(pool_slots_) + coarse);
    const std::uint64_t dir_bytes = total * 4, pool_bytes = pool * PageTableLayout::kBlockEntries * 4;
    const auto mib = [](std::uint64_t b) { return double(b) / double(1u << 20); };
    if (std::int64_t(dir_bytes) > max_ssbo_ || std::int64_t(pool_bytes) > max_ssbo_)
        return Error{Errc::resource_exhausted,
                     fmt::format("texture {}: its two-level page table needs a {:.1f} MiB directory and a {:.1f} MiB block pool "
                                 "({} blocks of 32x32 entries for {} pool slots), over the GPU's largest shader storage "
                                 "block ({:.1f} MiB)",
                                 t.id, mib(dir_bytes), mib(pool_bytes), pool, pool_slots_, mib(std::uint64_t(max_ssbo_)))};
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

TableUpload PageTableTextures::upload_rect(TextureId texture, std::uint8_t level, std::uint32_t x0, std::uint32_t y0,
                                           std::uint32_t w, std::uint32_t h, std::span<const std::uint32_t> entries) {
    auto it = textures_.find(texture);
    if (it == textures_.end() || level >= it->second.levels || entries.size() != std::size_t(w) * h || w == 0 || h == 0)
        return TableUpload::malformed;
    const auto& t = it->second;
    if (t.sparse || std::uint64_t(x0) + w > t.pages[2 * level] || std::uint64_t(y0) + h > t.pages[2 * level + 1])
        return TableUpload::malformed;
    const auto gpu = gpu_entries(entries);
    const auto x = GLint(t.origin[2 * level] + std::int32_t(x0)), y = GLint(t.origin[2 * level + 1] + std::int32_t(y0));
    staging_.upload_image(t.table.get(), x, y, GLsizei(w), GLsizei(h), GL_RED_INTEGER, GL_UNSIGNED_INT, gpu.data(),
                          gpu.size_bytes());
    return TableUpload::uploaded;
}

// A dense texture receiving a block turns two-level (its CPU table chose sparse under a smaller
// byte bound). Block slots come from the texture's pool, sized so that it cannot run out while the
// runtime's pool is the renderer's (PageTable holds at most 5 blocks per resident page, and frees
// come first); if it does, the block stays unallocated here and lookups fall back to a coarser
// resident page: blurrier, never wrong.
TableUpload PageTableTextures::upload_block(TextureId texture, std::uint8_t level, std::uint32_t bx, std::uint32_t by,
                                            std::span<const std::uint32_t> entries) {
    auto it = textures_.find(texture);
    if (it == textures_.end() || level >= it->second.levels || (!entries.empty() && entries.size() != PageTableLayout::kBlockEntries))
        return TableUpload::malformed;
    VirtualTexture& t = it->second;
    if (!t.sparse && !make_two_level(t).ok()) return TableUpload::malformed;
    if (bx >= t.dir_width[level] || std::uint64_t(by) * t.dir_width[level] + bx >= dir_level_blocks(t, level))
        return TableUpload::malformed;
    const std::uint64_t key = (std::uint64_t(level) << 40) | (std::uint64_t(by) << 20) | bx;
    const std::size_t dir_at = (std::size_t(t.dir_offset[level]) + std::size_t(by) * t.dir_width[level] + bx) * 4;
    auto slot = t.block_slot.find(key);
    if (entries.empty()) {
        if (slot == t.block_slot.end()) return TableUpload::unchanged;
        const std::uint32_t none = 0;
        staging_.upload_buffer(t.directory.get(), dir_at, &none, 4);
        t.free_blocks.push_back(slot->second);
        t.block_slot.erase(slot);
        return TableUpload::uploaded;
    }
    const bool allocate = slot == t.block_slot.end();
    if (allocate) {
        if (t.free_blocks.empty()) return TableUpload::malformed;
        slot = t.block_slot.emplace(key, t.free_blocks.back()).first;
        t.free_blocks.pop_back();
    }
    // The block's entries land before its directory entry names it (both in stream order).
    const auto gpu = gpu_entries(entries);
    const std::size_t block_at = std::size_t(slot->second) * PageTableLayout::kBlockEntries * 4;
    staging_.upload_buffer(t.blocks.get(), block_at, gpu.data(), gpu.size_bytes());
    if (allocate) {
        const std::uint32_t named = slot->second + 1;
        staging_.upload_buffer(t.directory.get(), dir_at, &named, 4);
    }
    return TableUpload::uploaded;
}

// The CPU entry with its slot replaced by the slot's atlas cell (PageAtlas::cell_code); an
// invalid entry (0: nothing resident) as it is.
std::span<const std::uint32_t> PageTableTextures::gpu_entries(std::span<const std::uint32_t> entries) {
    gpu_entries_.resize(entries.size());
    for (std::size_t i = 0; i < entries.size(); ++i) {
        const PageEntry e = entries[i];
        gpu_entries_[i] = PageTableLayout::entry_valid(e)
                              ? PageTableLayout::make_entry(atlas_.cell_code(PageTableLayout::entry_slot(e)), PageTableLayout::entry_level(e))
                              : e;
    }
    return gpu_entries_;
}

}  // namespace tessera::client::gl::detail
