// The atlas build: a scene's materials (OBJ or glTF) -> images -> packed layout -> rewritten OBJ +
// one store.
#include "atlas_build.hpp"


#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "tessera/scene/atlas.hpp"
#include "tessera/storage/image_source.hpp"
#include "tessera/storage/output_file.hpp"

namespace tessera::tools {
namespace fs = std::filesystem;

namespace {

// A temporary file beside `target`, removed unless released.
class TempFile {
public:
    explicit TempFile(const fs::path& target) : path_(storage::temp_path_beside(target.string(), "tmp")) {
        storage::track_temp_path(path_.string());  // removed if the build is interrupted
    }
    ~TempFile() {
        if (!released_) {
            std::error_code ec;
            fs::remove(path_, ec);
        }
        storage::untrack_temp_path(path_.string());
    }
    TempFile(const TempFile&) = delete;
    TempFile& operator=(const TempFile&) = delete;
    const fs::path& path() const { return path_; }
    void release() { released_ = true; }

private:
    fs::path path_;
    bool released_ = false;
};

// A folder beside `target` for the images a glTF scene holds inside itself (OpenImageIO reads
// files), removed with everything in it unless empty of use.
class TempFolder {
public:
    explicit TempFolder(const fs::path& target) : path_(storage::temp_path_beside(target.string(), "images")) {
        storage::track_temp_path(path_.string());  // removed if the build is interrupted
    }
    ~TempFolder() {
        std::error_code ec;
        fs::remove_all(path_, ec);
        storage::untrack_temp_path(path_.string());
    }
    TempFolder(const TempFolder&) = delete;
    TempFolder& operator=(const TempFolder&) = delete;
    // Writes `bytes` to a new file in the folder (made on first use) and returns its path.
    Result<std::string> write(const std::vector<std::uint8_t>& bytes, const std::string& extension) {
        std::error_code ec;
        fs::create_directories(path_, ec);
        const fs::path file = path_ / ("image" + std::to_string(count_++) + extension);
        std::ofstream f(file, std::ios::binary | std::ios::trunc);
        f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
        f.flush();
        if (ec || !f) return make_error(Errc::io_error, "cannot write a temporary image in '" + path_.string() + "'");
        return file.string();
    }

private:
    fs::path path_;
    int count_ = 0;
};

// Whether two paths name one file: the same file (hard links too) where both exist, else the same
// path once `..`, `.` and symbolic links are resolved.
bool same_file(const std::string& a, const std::string& b) {
    std::error_code ec;
    if (fs::exists(a, ec) && fs::exists(b, ec)) return fs::equivalent(a, b, ec) && !ec;
    std::error_code ec1, ec2;
    return fs::weakly_canonical(a, ec1) == fs::weakly_canonical(b, ec2) && !ec1 && !ec2;
}

std::string material_list(const scene::AtlasImageRef& img) {
    std::string s;
    for (const auto& m : img.materials) s += (s.empty() ? "'" : ", '") + m + "'";
    return (img.materials.size() > 1 ? "materials " : "material ") + s;
}

// A texture whose read errors (an image damaged past its header is only found while the store is
// built) name the materials that use it, and the image in the scene rather than a temporary file.
class NamedTexture final : public storage::ImageSource {
public:
    NamedTexture(std::unique_ptr<storage::ImageSource> inner, std::string materials, std::string file, std::string shown)
        : inner_(std::move(inner)), materials_(std::move(materials)), file_(std::move(file)), shown_(std::move(shown)) {}
    const storage::SourceInfo& info() const override { return inner_->info(); }
    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const storage::ParallelFor& parallel) override {
        Status st = inner_->read_rows(y0, count, dst, parallel);
        if (st) return st;
        std::string message = st.error().message;
        if (file_ != shown_)
            for (auto at = message.find(file_); at != std::string::npos; at = message.find(file_, at + shown_.size()))
                message.replace(at, file_.size(), shown_);
        return make_error(st.error().code, materials_ + ": " + message);
    }

private:
    std::unique_ptr<storage::ImageSource> inner_;
    std::string materials_, file_, shown_;
};

}  // namespace

Result<AtlasBuildSummary> build_atlas(const std::string& obj, const std::string& store, const std::string& obj_out,
                                      const storage::BuildOptions& options, const storage::AtlasPackOptions& pack,
                                      const storage::BuildProgressFn& progress, scene::UpAxis up) {
    TESSERA_TRY(storage::validate(options));
    if (obj_out.empty()) return make_error(Errc::invalid_argument, "--obj-out: no file given");
    if (same_file(obj_out, store)) return make_error(Errc::invalid_argument, "--obj-out and --output name the same file");

    auto input = scene::AtlasSceneInput::load(obj, up);
    if (!input) return input.error();
    const auto& refs = input->images();
    // Before anything is written: no output may replace a file the scene is read from (the store
    // and the OBJ are renamed into place, which would destroy the input without a word).
    {
        std::vector<std::pair<std::string, std::string>> inputs;  // path, what it is
        for (const auto& f : input->input_files()) inputs.emplace_back(f.path, f.role + " '" + f.path + "'");
        for (const auto& r : refs) {
            if (!r.texture.empty() && !r.embedded) inputs.emplace_back(r.texture, "texture '" + r.texture + "' of " + material_list(r));
            for (const auto& m : r.maps)
                if (!m.texture.empty() && !m.embedded) inputs.emplace_back(m.texture, "texture '" + m.texture + "' of " + material_list(r));
        }
        for (const auto& [out, flag] : {std::pair{store, "output"}, std::pair{obj_out, "--obj-out"}})
            for (const auto& [path, what] : inputs)
                if (same_file(out, path))
                    return make_error(Errc::invalid_argument, std::string(flag) + " '" + out + "' is the input " + what +
                                                                  "; choose another output path");
    }
    TempFolder embedded_images(store);

    // Open every texture and map now: a missing or unreadable one fails before any work is done.
    auto open = [&](const scene::AtlasImageRef& r, const scene::AtlasMapRef& m) -> Result<std::unique_ptr<storage::ImageSource>> {
        std::string file = m.texture;
        if (m.embedded) {
            auto written = embedded_images.write(*m.embedded, m.embedded_extension);
            if (!written) return written.error();
            file = *written;
        }
        // Say why the file cannot be a texture: "does not exist" for a folder sends the user
        // looking for the wrong mistake.
        std::error_code ec;
        const fs::file_status st = fs::status(file, ec);
        if (!fs::exists(st))
            return make_error(Errc::not_found, material_list(r) + ": texture '" + m.texture + "' does not exist");
        if (fs::is_directory(st))
            return make_error(Errc::invalid_argument, material_list(r) + ": texture '" + m.texture + "' is a directory, not an image");
        if (!fs::is_regular_file(st))
            return make_error(Errc::invalid_argument, material_list(r) + ": texture '" + m.texture + "' is not a regular file");
        auto src = storage::open_image_source(file);
        if (!src) {
            std::string message = src.error().message;
            if (m.embedded)  // name the image in the scene, not the temporary file
                if (auto at = message.find(file); at != std::string::npos) message.replace(at, file.size(), m.texture);
            return make_error(src.error().code, material_list(r) + ": " + message);
        }
        return std::unique_ptr<storage::ImageSource>(std::make_unique<NamedTexture>(std::move(*src), material_list(r), file, m.texture));
    };
    // The material layers this scene has: a role any cell has a map for (docs/atlas.md, "Material layers").
    std::vector<std::size_t> roles;
    for (std::size_t role = 0; role < scene::kMapRoles; ++role)
        if (std::any_of(refs.begin(), refs.end(), [&](const auto& r) { return !r.maps[role].texture.empty(); })) roles.push_back(role);
    std::vector<storage::AtlasItem> items(refs.size());
    std::vector<std::vector<storage::AtlasItem>> map_items(roles.size());
    for (auto& layer : map_items) layer.resize(refs.size());
    std::vector<storage::AtlasImageSize> sizes(refs.size());
    for (std::size_t i = 0; i < refs.size(); ++i) {
        const scene::AtlasImageRef& r = refs[i];
        if (r.solid()) {
            sizes[i] = {kSolidTileTexels, kSolidTileTexels};
        } else if (!r.texture.empty()) {
            auto src = open(r, r);
            if (!src) return src.error();
            sizes[i] = {(*src)->info().width, (*src)->info().height};
            items[i].source = std::move(*src);
        }
        items[i].colour = r.colour;
        items[i].wrap = r.repeats;
        items[i].opaque = r.opaque;
        for (std::size_t k = 0; k < roles.size(); ++k) {
            storage::AtlasItem& item = map_items[k][i];
            item.colour = r.map_values[roles[k]];
            item.wrap = r.repeats;
            item.opaque = true;
            const scene::AtlasMapRef& m = r.maps[roles[k]];
            if (m.texture.empty()) continue;
            auto src = open(r, m);
            if (!src) return src.error();
            if (sizes[i].width == 0) sizes[i] = {(*src)->info().width, (*src)->info().height};  // no colour texture: the first map's size
            item.source = std::move(*src);
        }
        // Maps of another size than the cell are resampled to it.
        for (std::size_t k = 0; k < roles.size(); ++k) {
            storage::AtlasItem& item = map_items[k][i];
            if (!item.source || (item.source->info().width == sizes[i].width && item.source->info().height == sizes[i].height)) continue;
            auto resized = storage::make_resized_source(std::move(item.source), sizes[i].width, sizes[i].height);
            if (!resized) return make_error(resized.error().code, material_list(r) + ": " + resized.error().message);
            item.source = std::move(*resized);
        }
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

    // The OBJ first, to a temporary file (an unwritable destination fails before the build); once
    // the store is built, again with the store's id in its header, which binds the scene to the
    // store: a viewer or server finds the scene beside its store only while the two belong together.
    TempFile tmp(obj_out);
    auto write_obj = [&](const std::string& obj_text) -> Status {
        std::ofstream f(tmp.path(), std::ios::binary | std::ios::trunc);
        if (!f) return make_error(Errc::io_error, "cannot write '" + obj_out + "'");
        f.write(obj_text.data(), static_cast<std::streamsize>(obj_text.size()));
        f.flush();
        if (!f) return make_error(Errc::io_error, "cannot write '" + obj_out + "'");
        return {};
    };
    TESSERA_TRY(write_obj(*text));

    auto source = storage::make_atlas_source(std::move(items), *layout);
    if (!source) return source.error();
    Result<storage::BuildSummary> built = make_error(Errc::invalid_argument, "not built");
    std::vector<std::string> layer_names;
    if (roles.empty()) {
        built = storage::build_store(**source, store, options, progress);
    } else {
        // One layer per role beside the colour ("base"): normal, metallic-roughness and occlusion
        // maps are data (values kept, lossless zstd), the emissive map colour (sRGB, as the base).
        std::vector<storage::LayerSource> layers;
        layers.push_back(storage::LayerSource{"base", std::move(*source), options.codec});
        layer_names.push_back("base");
        for (std::size_t k = 0; k < roles.size(); ++k) {
            const bool colour = roles[k] == std::size_t(scene::MapRole::emissive);
            auto layer = storage::make_atlas_source(std::move(map_items[k]), *layout,
                                                    colour ? storage::AtlasTexels::colour : storage::AtlasTexels::data);
            if (!layer) return layer.error();
            layers.push_back(storage::LayerSource{scene::kMapLayerNames[roles[k]], std::move(*layer),
                                                  colour ? std::optional<Codec>{} : std::optional<Codec>{Codec::zstd}});
            layer_names.push_back(scene::kMapLayerNames[roles[k]]);
        }
        storage::BuildOptions layered = options;
        layered.codec.reset();
        built = storage::build_layered_store(std::move(layers), store, layered, progress);
    }
    if (!built) return built.error();
    {
        char id_line[64];
        std::snprintf(id_line, sizeof id_line, "# tessera-store %016llx\n", static_cast<unsigned long long>(built->info.store_id));
        const std::size_t second_line = text->find('\n', text->find('\n') + 1) + 1;  // after "# tessera-atlas" and "# tessera-up"
        text->insert(second_line, id_line);
        if (auto st = write_obj(*text); !st.ok()) {
            std::error_code ec;
            fs::remove(store, ec);
            return st.error();
        }
    }

    std::error_code ec;
    if (Status st = storage::check_output_file(obj_out); !st) {  // something may have appeared there during the build
        fs::remove(store, ec);
        return st.error();
    }
    fs::rename(tmp.path(), obj_out, ec);
    if (ec) {
        fs::remove(store, ec);
        return make_error(Errc::io_error, "cannot rename into '" + obj_out + "' (the store was removed again)");
    }
    tmp.release();
    AtlasBuildSummary s;
    s.build = std::move(*built);
    s.images = refs.size();
    s.layers = std::move(layer_names);
    for (const auto& r : refs)
        for (const auto& m : r.maps) s.maps += m.texture.empty() ? 0 : 1;
    s.triangles = input->triangle_count();
    s.repeat_pieces = input->repeat_piece_count();
    s.up = input->up_axis();
    s.extent = input->extent();
    s.warnings = input->warnings();
    s.repeating_images = static_cast<std::size_t>(std::count_if(refs.begin(), refs.end(), [](const auto& r) { return r.repeats; }));
    return s;
}

}  // namespace tessera::tools
