// The atlas build: OBJ materials -> images -> packed layout -> rewritten OBJ + one store.
#include "atlas_build.hpp"

#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include "tessera/client/scene/atlas.hpp"
#include "tessera/storage/image_source.hpp"

namespace tessera::tools {
namespace fs = std::filesystem;

namespace {

// A temporary file beside `target`, removed unless released.
class TempFile {
public:
    explicit TempFile(const fs::path& target)
        : path_((target.has_parent_path() ? target.parent_path() : fs::path(".")) /
                (".tmp-" + std::to_string(::getpid()) + "-" + target.filename().string())) {}
    ~TempFile() {
        if (!released_) {
            std::error_code ec;
            fs::remove(path_, ec);
        }
    }
    TempFile(const TempFile&) = delete;
    TempFile& operator=(const TempFile&) = delete;
    const fs::path& path() const { return path_; }
    void release() { released_ = true; }

private:
    fs::path path_;
    bool released_ = false;
};

bool same_file(const std::string& a, const std::string& b) {
    std::error_code ec1, ec2;
    return fs::weakly_canonical(a, ec1) == fs::weakly_canonical(b, ec2) && !ec1 && !ec2;
}

std::string material_list(const scene::AtlasImageRef& img) {
    std::string s;
    for (const auto& m : img.materials) s += (s.empty() ? "'" : ", '") + m + "'";
    return (img.materials.size() > 1 ? "materials " : "material ") + s;
}

}  // namespace

Result<AtlasBuildSummary> build_atlas(const std::string& obj, const std::string& store, const std::string& obj_out,
                                      const storage::BuildOptions& options, const storage::AtlasPackOptions& pack,
                                      const storage::BuildProgressFn& progress, scene::UpAxis up) {
    TESSERA_TRY(storage::validate(options));
    if (obj_out.empty()) return make_error(Errc::invalid_argument, "--obj-out: no file given");
    if (same_file(obj_out, store)) return make_error(Errc::invalid_argument, "--obj-out and --output name the same file");
    if (same_file(obj_out, obj)) return make_error(Errc::invalid_argument, "--obj-out would overwrite the input OBJ");

    auto input = scene::ObjAtlasInput::load(obj, up);
    if (!input) return input.error();
    const auto& refs = input->images();

    // Open every texture now: a missing or unreadable one fails before any work is done.
    std::vector<storage::AtlasItem> items(refs.size());
    std::vector<storage::AtlasImageSize> sizes(refs.size());
    for (std::size_t i = 0; i < refs.size(); ++i) {
        const scene::AtlasImageRef& r = refs[i];
        if (r.texture.empty()) {
            items[i].colour = r.colour;
            sizes[i] = {kSolidTileTexels, kSolidTileTexels};
            continue;
        }
        std::error_code ec;
        if (!fs::is_regular_file(r.texture, ec))
            return make_error(Errc::not_found, material_list(r) + ": texture '" + r.texture + "' does not exist");
        auto src = storage::open_image_source(r.texture);
        if (!src) return make_error(src.error().code, material_list(r) + ": " + src.error().message);
        sizes[i] = {(*src)->info().width, (*src)->info().height};
        items[i].source = std::move(*src);
        items[i].wrap = r.repeats;
    }
    auto layout = storage::pack_atlas(sizes, pack);
    if (!layout) return layout.error();
    std::vector<scene::AtlasRect> rects(refs.size());
    for (std::size_t i = 0; i < refs.size(); ++i) {
        const storage::AtlasCell& c = layout->cells[i];
        rects[i] = {c.x, c.y, c.width, c.height};
    }
    auto text = input->rewrite(rects, layout->width, layout->height,
                               fs::path(obj).filename().string() + " (store " + fs::path(store).filename().string() + ")");
    if (!text) return text.error();

    // The OBJ first, to a temporary file (an unwritable destination fails before the build).
    TempFile tmp(obj_out);
    {
        std::ofstream f(tmp.path(), std::ios::binary | std::ios::trunc);
        if (!f) return make_error(Errc::io_error, "cannot write '" + obj_out + "'");
        f.write(text->data(), static_cast<std::streamsize>(text->size()));
        f.flush();
        if (!f) return make_error(Errc::io_error, "cannot write '" + obj_out + "'");
    }

    auto source = storage::make_atlas_source(std::move(items), *layout);
    if (!source) return source.error();
    auto built = storage::build_store(**source, store, options, progress);
    if (!built) return built.error();

    std::error_code ec;
    fs::rename(tmp.path(), obj_out, ec);
    if (ec) {
        fs::remove(store, ec);
        return make_error(Errc::io_error, "cannot rename into '" + obj_out + "' (the store was removed again)");
    }
    tmp.release();
    AtlasBuildSummary s;
    s.build = std::move(*built);
    s.images = refs.size();
    s.triangles = input->triangle_count();
    s.repeat_pieces = input->repeat_piece_count();
    s.up = input->up_axis();
    s.extent = input->extent();
    s.repeating_images = static_cast<std::size_t>(std::count_if(refs.begin(), refs.end(), [](const auto& r) { return r.repeats; }));
    return s;
}

}  // namespace tessera::tools
