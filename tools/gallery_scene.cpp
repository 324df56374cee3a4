// The gallery sample scene (gallery_scene.hpp): geometry, materials and labelled textures.
#include "gallery_scene.hpp"


#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <vector>

#include "tessera/storage/image_source.hpp"
#include "tessera/storage/output_file.hpp"

namespace tessera::tools {
namespace fs = std::filesystem;

namespace {

// ---- A 5x7 font (A-Z, 0-9, space, comma, hyphen), one string per row, '#' set. ----
struct Glyph {
    char c;
    const char* rows[7];
};
constexpr Glyph kFont[] = {
    {'A', {" ### ", "#   #", "#   #", "#####", "#   #", "#   #", "#   #"}},
    {'B', {"#### ", "#   #", "#   #", "#### ", "#   #", "#   #", "#### "}},
    {'C', {" ### ", "#   #", "#    ", "#    ", "#    ", "#   #", " ### "}},
    {'D', {"#### ", "#   #", "#   #", "#   #", "#   #", "#   #", "#### "}},
    {'E', {"#####", "#    ", "#    ", "#### ", "#    ", "#    ", "#####"}},
    {'F', {"#####", "#    ", "#    ", "#### ", "#    ", "#    ", "#    "}},
    {'G', {" ### ", "#   #", "#    ", "# ###", "#   #", "#   #", " ####"}},
    {'H', {"#   #", "#   #", "#   #", "#####", "#   #", "#   #", "#   #"}},
    {'I', {" ### ", "  #  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### "}},
    {'J', {"  ###", "   # ", "   # ", "   # ", "   # ", "#  # ", " ##  "}},
    {'K', {"#   #", "#  # ", "# #  ", "##   ", "# #  ", "#  # ", "#   #"}},
    {'L', {"#    ", "#    ", "#    ", "#    ", "#    ", "#    ", "#####"}},
    {'M', {"#   #", "## ##", "# # #", "# # #", "#   #", "#   #", "#   #"}},
    {'N', {"#   #", "#   #", "##  #", "# # #", "#  ##", "#   #", "#   #"}},
    {'O', {" ### ", "#   #", "#   #", "#   #", "#   #", "#   #", " ### "}},
    {'P', {"#### ", "#   #", "#   #", "#### ", "#    ", "#    ", "#    "}},
    {'Q', {" ### ", "#   #", "#   #", "#   #", "# # #", "#  # ", " ## #"}},
    {'R', {"#### ", "#   #", "#   #", "#### ", "# #  ", "#  # ", "#   #"}},
    {'S', {" ####", "#    ", "#    ", " ### ", "    #", "    #", "#### "}},
    {'T', {"#####", "  #  ", "  #  ", "  #  ", "  #  ", "  #  ", "  #  "}},
    {'U', {"#   #", "#   #", "#   #", "#   #", "#   #", "#   #", " ### "}},
    {'V', {"#   #", "#   #", "#   #", "#   #", "#   #", " # # ", "  #  "}},
    {'W', {"#   #", "#   #", "#   #", "# # #", "# # #", "# # #", " # # "}},
    {'X', {"#   #", "#   #", " # # ", "  #  ", " # # ", "#   #", "#   #"}},
    {'Y', {"#   #", "#   #", " # # ", "  #  ", "  #  ", "  #  ", "  #  "}},
    {'Z', {"#####", "    #", "   # ", "  #  ", " #   ", "#    ", "#####"}},
    {'0', {" ### ", "#   #", "#  ##", "# # #", "##  #", "#   #", " ### "}},
    {'1', {"  #  ", " ##  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### "}},
    {'2', {" ### ", "#   #", "    #", "   # ", "  #  ", " #   ", "#####"}},
    {'3', {"#####", "   # ", "  #  ", "   # ", "    #", "#   #", " ### "}},
    {'4', {"   # ", "  ## ", " # # ", "#  # ", "#####", "   # ", "   # "}},
    {'5', {"#####", "#    ", "#### ", "    #", "    #", "#   #", " ### "}},
    {'6', {"  ## ", " #   ", "#    ", "#### ", "#   #", "#   #", " ### "}},
    {'7', {"#####", "    #", "   # ", "  #  ", " #   ", " #   ", " #   "}},
    {'8', {" ### ", "#   #", "#   #", " ### ", "#   #", "#   #", " ### "}},
    {'9', {" ### ", "#   #", "#   #", " ####", "    #", "   # ", " ##  "}},
    {',', {"     ", "     ", "     ", "     ", "     ", "  #  ", " #   "}},
    {'-', {"     ", "     ", "     ", "#####", "     ", "     ", "     "}},
    {' ', {"     ", "     ", "     ", "     ", "     ", "     ", "     "}},
};

const Glyph* glyph(char c) {
    for (const Glyph& g : kFont)
        if (g.c == c) return &g;
    return nullptr;
}

// ---- An RGB8 image in memory, and an ImageSource over it (for storage::write_image). ----
struct Image {
    std::uint32_t width = 0, height = 0;
    std::vector<std::uint8_t> rgb;
    Image(std::uint32_t w, std::uint32_t h) : width(w), height(h), rgb(std::size_t(w) * h * 3) {}
    void put(std::int64_t x, std::int64_t y, const std::array<std::uint8_t, 3>& c) {
        if (x < 0 || y < 0 || x >= width || y >= height) return;
        std::memcpy(&rgb[(std::size_t(y) * width + std::size_t(x)) * 3], c.data(), 3);
    }
    void fill_rect(std::int64_t x0, std::int64_t y0, std::int64_t w, std::int64_t h, const std::array<std::uint8_t, 3>& c) {
        for (std::int64_t y = y0; y < y0 + h; ++y)
            for (std::int64_t x = x0; x < x0 + w; ++x) put(x, y, c);
    }
    // Text with `scale`-texel font pixels and a one-font-pixel outline, top-left at (x, y).
    void text(std::int64_t x, std::int64_t y, const std::string& s, int scale, const std::array<std::uint8_t, 3>& ink,
              const std::array<std::uint8_t, 3>& outline) {
        for (int pass = 0; pass < 2; ++pass)
            for (std::size_t i = 0; i < s.size(); ++i) {
                const Glyph* g = glyph(s[i]);
                if (!g) continue;
                const std::int64_t gx = x + std::int64_t(i) * 6 * scale;
                for (int r = 0; r < 7; ++r)
                    for (int c = 0; c < 5; ++c) {
                        if (g->rows[r][c] != '#') continue;
                        if (pass == 0) fill_rect(gx + (c - 1) * scale, y + (r - 1) * scale, 3 * scale, 3 * scale, outline);
                        else fill_rect(gx + c * scale, y + r * scale, scale, scale, ink);
                    }
            }
    }
};

class ImageRows final : public storage::ImageSource {
public:
    explicit ImageRows(const Image& img) : img_(img) {
        info_.width = img.width;
        info_.height = img.height;
        info_.channels = 3;
        info_.description = "gallery texture";
    }
    const storage::SourceInfo& info() const override { return info_; }
    Status read_rows(std::uint32_t y0, std::uint32_t count, std::uint8_t* dst, const storage::ParallelFor&) override {
        const std::size_t row = std::size_t(img_.width) * 3;
        std::memcpy(dst, img_.rgb.data() + y0 * row, row * count);
        return {};
    }

private:
    const Image& img_;
    storage::SourceInfo info_;
};

std::array<std::uint8_t, 3> shade(const std::array<std::uint8_t, 3>& c, double f) {
    std::array<std::uint8_t, 3> out{};
    for (int i = 0; i < 3; ++i) out[i] = static_cast<std::uint8_t>(std::clamp(std::lround(c[i] * f), 0l, 255l));
    return out;
}

// The labelled pattern: a checker of 64-texel cells in two shades of `base`, dark grid lines, and
// in every 128-texel block the texture's name and the block's column,row.
Image make_texture(const std::string& name, std::uint32_t w, std::uint32_t h, const std::array<std::uint8_t, 3>& base) {
    Image img(w, h);
    const auto light = base, dark = shade(base, 0.78), line = shade(base, 0.35);
    for (std::uint32_t y = 0; y < h; ++y)
        for (std::uint32_t x = 0; x < w; ++x) {
            const bool odd = ((x / 64) + (y / 64)) % 2 != 0;
            const bool grid = x % 64 == 0 || y % 64 == 0;
            img.put(x, y, grid ? line : (odd ? dark : light));
        }
    const std::array<std::uint8_t, 3> white{255, 255, 255}, black{0, 0, 0};
    for (std::uint32_t by = 0; by * 128 < h; ++by)
        for (std::uint32_t bx = 0; bx * 128 < w; ++bx) {
            img.text(std::int64_t(bx) * 128 + 6, std::int64_t(by) * 128 + 6, name, 2, white, black);
            img.text(std::int64_t(bx) * 128 + 6, std::int64_t(by) * 128 + 26, std::to_string(bx) + "," + std::to_string(by), 2, white,
                     black);
        }
    // An orientation mark: a bright bar along the top edge (row 0 is the image's top, OBJ's v = 1).
    img.fill_rect(0, 0, w, 3, shade(base, 1.4));
    return img;
}

// ---- Geometry: quads (o, o + eu, o + eu + ev, o + ev), front face eu x ev, texture up along ev. ----
struct V3 {
    double x, y, z;
};
V3 operator+(V3 a, V3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
V3 operator*(V3 a, double s) { return {a.x * s, a.y * s, a.z * s}; }
V3 cross(V3 a, V3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
V3 unit(V3 a) {
    const double l = std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z);
    return a * (1.0 / l);
}

class ObjWriter {
public:
    void object(const std::string& name, const std::string& material) {
        faces_ << "o " << name << "\nusemtl " << material << "\n";
    }
    // uv0: texture coordinate of o; the quad spans uv0 .. uv0 + (1, 1).
    void quad(V3 o, V3 eu, V3 ev, double u0 = 0, double v0 = 0) {
        const V3 p[4] = {o, o + eu, o + eu + ev, o + ev};
        const double uv[4][2] = {{u0, v0}, {u0 + 1, v0}, {u0 + 1, v0 + 1}, {u0, v0 + 1}};
        const V3 n = unit(cross(eu, ev));
        vn_ << "vn " << n.x << " " << n.y << " " << n.z << "\n";
        ++normals_;
        faces_ << "f";
        for (int i = 0; i < 4; ++i) {
            v_ << "v " << p[i].x << " " << p[i].y << " " << p[i].z << "\n";
            vt_ << "vt " << uv[i][0] << " " << uv[i][1] << "\n";
            ++vertices_;
            faces_ << " " << vertices_ << "/" << vertices_ << "/" << normals_;
        }
        faces_ << "\n";
    }
    // A box standing on the floor, centre (cx, cz), half size s, height 2s: four sides and a top.
    void box(double cx, double cz, double s, double u0 = 0, double v0 = 0) {
        const V3 X{1, 0, 0}, Y{0, 1, 0}, Z{0, 0, 1};
        const double h = 2 * s;
        quad({cx + s, 0, cz + s}, Z * (-2 * s), Y * h, u0, v0);  // +X
        quad({cx - s, 0, cz - s}, Z * (2 * s), Y * h, u0, v0);   // -X
        quad({cx - s, 0, cz + s}, X * (2 * s), Y * h, u0, v0);   // +Z
        quad({cx + s, 0, cz - s}, X * (-2 * s), Y * h, u0, v0);  // -Z
        quad({cx - s, h, cz + s}, X * (2 * s), Z * (-2 * s), u0, v0);  // top
    }
    std::string text() const {
        return "# Tessera sample scene: a gallery (metres, Y up). `tessera source scene:gallery` wrote it.\nmtllib gallery.mtl\n" +
               v_.str() + vt_.str() + vn_.str() + faces_.str();
    }

private:
    std::ostringstream v_, vt_, vn_, faces_;
    int vertices_ = 0, normals_ = 0;
};

struct TextureSpec {
    const char* material;
    const char* label;
    std::uint32_t width, height;
    std::array<std::uint8_t, 3> colour;
};
constexpr TextureSpec kTextures[] = {
    {"floor", "FLOOR", 1000, 600, {150, 130, 100}},
    {"wall_north", "NORTH", 1024, 200, {90, 120, 170}},
    {"wall_south", "SOUTH", 1024, 200, {170, 100, 90}},
    {"wall_east", "EAST", 600, 200, {100, 160, 110}},
    {"wall_west", "WEST", 600, 200, {160, 150, 80}},
    {"box_1", "BOX 1", 256, 256, {200, 120, 40}},
    {"box_2", "BOX 2", 192, 192, {60, 170, 180}},
    {"box_3", "BOX 3", 320, 256, {150, 80, 170}},
};

Status write_text(const fs::path& p, const std::string& s) {
    std::ofstream f(p, std::ios::binary | std::ios::trunc);
    f << s;
    f.flush();
    if (!f) return make_error(Errc::io_error, "cannot write '" + p.string() + "'");
    return {};
}

}  // namespace

Status write_gallery_scene(const std::string& dir) {
    if (dir.empty()) return make_error(Errc::invalid_argument, "no output folder given");
    // "gallery/" names the folder "gallery" (its file name would otherwise be empty).
    std::string trimmed = dir;
    while (trimmed.size() > 1 && trimmed.back() == '/') trimmed.pop_back();
    const fs::path out(trimmed);
    std::error_code ec;
    if (fs::exists(out, ec)) {
        if (!fs::is_directory(out, ec)) return make_error(Errc::invalid_argument, "'" + dir + "' exists and is not a folder");
        if (!fs::is_empty(out, ec)) return make_error(Errc::invalid_argument, "folder '" + dir + "' is not empty");
    }
    const fs::path parent = out.has_parent_path() ? out.parent_path() : fs::path(".");
    if (!fs::is_directory(parent, ec)) return make_error(Errc::not_found, "folder '" + parent.string() + "' does not exist");
    const fs::path tmp = storage::temp_path_beside(out.string(), "tmp");
    storage::track_temp_path(tmp.string());  // removed if the command is interrupted
    struct Cleanup {
        fs::path p;
        bool armed = true;
        ~Cleanup() {
            std::error_code e;
            if (armed) fs::remove_all(p, e);
            storage::untrack_temp_path(p.string());
        }
    } cleanup{tmp};
    fs::remove_all(tmp, ec);
    if (!fs::create_directories(tmp / "textures", ec) || ec)
        return make_error(Errc::io_error, "cannot create '" + tmp.string() + "': " + ec.message());

    // Textures.
    const storage::ParallelFor serial = [](std::size_t n, const std::function<void(std::size_t, std::size_t)>& fn) { fn(0, n); };
    std::string mtl = "# Tessera sample scene: materials of gallery.obj.\n";
    for (const TextureSpec& t : kTextures) {
        const Image img = make_texture(t.label, t.width, t.height, t.colour);
        ImageRows rows(img);
        const std::string file = std::string("textures/") + t.material + ".png";
        TESSERA_TRY(storage::write_image((tmp / file).string(), rows, serial));
        mtl += std::string("\nnewmtl ") + t.material + "\nKd 1 1 1\nmap_Kd " + file + "\n";
    }
    mtl += "\nnewmtl plinth\nKd 0.7 0.25 0.2\n";  // a colour, no texture: a solid tile in the atlas

    // Geometry (OBJ's Y up; tessera's scene loader turns it to Z up).
    const V3 X{1, 0, 0}, Y{0, 1, 0}, Z{0, 0, 1};
    ObjWriter obj;
    obj.object("floor", "floor");
    obj.quad({-10, 0, 6}, X * 20, Z * -12);
    obj.object("wall_north", "wall_north");  // at z = -6, facing +Z (into the room)
    obj.quad({-10, 0, -6}, X * 20, Y * 4);
    obj.object("wall_south", "wall_south");  // at z = 6, facing -Z
    obj.quad({10, 0, 6}, X * -20, Y * 4);
    obj.object("wall_east", "wall_east");  // at x = 10, facing -X
    obj.quad({10, 0, -6}, Z * 12, Y * 4);
    obj.object("wall_west", "wall_west");  // at x = -10, facing +X
    obj.quad({-10, 0, 6}, Z * -12, Y * 4);
    obj.object("box_1", "box_1");
    obj.box(-3, 0, 0.75);
    obj.object("box_2", "box_2");
    obj.box(0, 0.8, 0.75, 1, -1);  // texture coordinates one whole repeat away: [1, 2] x [-1, 0]
    obj.object("box_3", "box_3");
    obj.box(3, -0.5, 0.75);
    obj.object("plinth", "plinth");
    obj.box(8, -4.5, 0.5);
    TESSERA_TRY(write_text(tmp / "gallery.obj", obj.text()));
    TESSERA_TRY(write_text(tmp / "gallery.mtl", mtl));

    if (fs::exists(out, ec)) fs::remove(out, ec);  // the empty folder checked above
    fs::rename(tmp, out, ec);
    if (ec) return make_error(Errc::io_error, "cannot rename into '" + dir + "': " + ec.message());
    cleanup.armed = false;
    return {};
}

}  // namespace tessera::tools
