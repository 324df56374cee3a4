// Loads the OpenImageIO plugin module on first use (see sources_internal.hpp for why).
#include <dlfcn.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <mutex>

#include "oiio_plugin_abi.hpp"
#include "sources_internal.hpp"
#include "temp_file.hpp"

namespace tessera::storage {
namespace {

struct Plugin {
    tessera_oiio_open_fn open = nullptr;
    tessera_oiio_write_fn write = nullptr;
    std::string error;
};

const Plugin& plugin() {
    static Plugin p;
    static std::once_flag once;
    std::call_once(once, [] {
        namespace fs = std::filesystem;
        std::vector<fs::path> candidates;
        if (const char* env = std::getenv("TESSERA_OIIO_PLUGIN")) candidates.emplace_back(env);
        std::error_code ec;
        const fs::path exe_dir = fs::read_symlink("/proc/self/exe", ec).parent_path();
        if (!ec) {
            candidates.push_back(exe_dir / "libtessera_oiio.so");
            candidates.push_back(exe_dir / ".." / "lib" / "tessera" / "libtessera_oiio.so");
        }
#ifdef TESSERA_PLUGIN_BUILD_DIR
        candidates.push_back(fs::path(TESSERA_PLUGIN_BUILD_DIR) / "libtessera_oiio.so");
#endif
        std::string tried;
        for (const auto& c : candidates) {
            if (!fs::exists(c, ec)) {
                tried += " " + c.string();
                continue;
            }
            void* h = ::dlopen(c.c_str(), RTLD_NOW | RTLD_LOCAL);
            if (!h) {
                p.error = std::string("cannot load the OpenImageIO plugin: ") + ::dlerror();
                return;
            }
            p.open = reinterpret_cast<tessera_oiio_open_fn>(::dlsym(h, "tessera_oiio_open"));
            p.write = reinterpret_cast<tessera_oiio_write_fn>(::dlsym(h, "tessera_oiio_write"));
            if (!p.open || !p.write) p.error = "the OpenImageIO plugin " + c.string() + " lacks its entry points";
            return;  // the module stays loaded for the life of the process
        }
        p.error = "image files other than TIFF need the OpenImageIO plugin libtessera_oiio.so (looked in" + tried + ")";
    });
    return p;
}

}  // namespace

Result<std::unique_ptr<ImageSource>> open_oiio_source(const std::string& path) {
    const Plugin& p = plugin();
    if (!p.open) return make_error(Errc::unsupported, p.error);
    int code = 0;
    std::string error;
    ImageSource* s = p.open(path.c_str(), &code, &error);
    if (!s) return make_error(static_cast<Errc>(code), error);
    return std::unique_ptr<ImageSource>(s);
}

Status write_image(const std::string& path, ImageSource& source, const ParallelFor& parallel,
                   const std::function<void(std::uint32_t)>& progress) {
    const Plugin& p = plugin();
    if (!p.write) return make_error(Errc::unsupported, p.error);
    // A temporary file renamed into place once every byte is on disk: a failed write (a full
    // disk) leaves nothing at `path`, and the destructor removes the temporary file.
    auto temp = TempFile::create_beside(path, "tmp");
    if (!temp) return temp.error();
    ImageWriteRequest req{&path, &temp->path(), temp->fd(), &source, &parallel, nullptr, nullptr};
    if (progress) {
        req.progress = [](void* ctx, std::uint32_t rows) { (*static_cast<const std::function<void(std::uint32_t)>*>(ctx))(rows); };
        req.progress_ctx = const_cast<std::function<void(std::uint32_t)>*>(&progress);
    }
    std::string error;
    if (!p.write(&req, &error)) return make_error(Errc::io_error, error);
    if (Status st = temp->commit(path); !st) return make_error(Errc::io_error, "cannot write '" + path + "': " + st.error().message);
    return {};
}

}  // namespace tessera::storage
