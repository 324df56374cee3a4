// GL 4.5 core contexts: headless through EGL (surfaceless or device platform) or a GLFW window. libepoxy
// resolves GL and EGL entry points at run time; libEGL is probed with dlopen first, since epoxy
// aborts the process when it cannot load a library it needs.
#include "tessera/client/gl/context.hpp"

#include <dlfcn.h>
#include <link.h>
#include <epoxy/egl.h>
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <fmt/format.h>

#include <string>
#include <vector>

namespace tessera::client::gl {

namespace {

std::string gl_description() {
    const auto* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    const auto* v = reinterpret_cast<const char*>(glGetString(GL_VERSION));
    return fmt::format("{} | {}", r ? r : "?", v ? v : "?");
}

Status check_version(const char* what) {
    const int v = epoxy_gl_version();
    if (v < 45) return Error{Errc::unsupported, fmt::format("{}: GL {}.{} < 4.5 ({})", what, v / 10, v % 10, gl_description())};
    return Status();
}

class HeadlessContext final : public GlContext {
public:
    HeadlessContext(EGLDisplay display, EGLContext context) : display_(display), context_(context) {}
    // The display stays initialised: EGL displays are per process, not reference counted, so
    // eglTerminate would pull it from under any other context on it (and Mesa's driver, unloaded
    // by it, would leave LeakSanitizer unattributable frames).
    ~HeadlessContext() override {
        eglMakeCurrent(display_, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        eglDestroyContext(display_, context_);
        eglReleaseThread();
    }
    void make_current() override { eglMakeCurrent(display_, EGL_NO_SURFACE, EGL_NO_SURFACE, context_); }
    GLFWwindow* window() override { return nullptr; }
    void swap_buffers() override {}
    std::string renderer() const override { return renderer_; }
    void set_renderer(std::string r) { renderer_ = std::move(r); }

private:
    EGLDisplay display_;
    EGLContext context_;
    std::string renderer_;
};

std::string egl_error(const char* what) { return fmt::format("{} failed (EGL error 0x{:04x})", what, eglGetError()); }

// glfwTerminate unloads the GL driver the window's context loaded, while the driver still holds
// allocations: LeakSanitizer then reports them from an unloaded, unnameable module (so no
// suppression can name it). Marking every loaded library RTLD_NODELETE keeps the driver mapped
// until the process ends, as the headless context does by never calling eglTerminate.
void keep_loaded_libraries() {
    std::vector<std::string> names;
    dl_iterate_phdr(
        [](dl_phdr_info* info, std::size_t, void* out) {
            if (info->dlpi_name && *info->dlpi_name) static_cast<std::vector<std::string>*>(out)->push_back(info->dlpi_name);
            return 0;
        },
        &names);
    for (const auto& name : names) dlopen(name.c_str(), RTLD_LAZY | RTLD_NOLOAD | RTLD_NODELETE);
}

class WindowContext final : public GlContext {
public:
    explicit WindowContext(GLFWwindow* w) : window_(w) {}
    ~WindowContext() override {
        keep_loaded_libraries();
        glfwDestroyWindow(window_);
        glfwTerminate();
    }
    void make_current() override { glfwMakeContextCurrent(window_); }
    GLFWwindow* window() override { return window_; }
    void swap_buffers() override { glfwSwapBuffers(window_); }
    std::string renderer() const override { return renderer_; }
    void set_renderer(std::string r) { renderer_ = std::move(r); }

private:
    GLFWwindow* window_;
    std::string renderer_;
};

std::string glfw_error() {
    const char* desc = nullptr;
    const int code = glfwGetError(&desc);
    return code == GLFW_NO_ERROR ? std::string("unknown GLFW error") : fmt::format("{} (GLFW 0x{:x})", desc ? desc : "", code);
}

// The EGL displays worth trying, best first: Mesa's surfaceless platform (llvmpipe or a Mesa GPU
// driver, no window system), then each GPU the device platform lists (NVIDIA's driver offers
// that, not always surfaceless), then the default display.
std::vector<EGLDisplay> candidate_displays() {
    std::vector<EGLDisplay> out;
    if (!epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_EXT_platform_base")) return {eglGetDisplay(EGL_DEFAULT_DISPLAY)};
    if (epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_MESA_platform_surfaceless"))
        out.push_back(eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr));
    if (epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_EXT_platform_device") &&
        epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_EXT_device_enumeration")) {
        EGLDeviceEXT devices[16];
        EGLint count = 0;
        if (eglQueryDevicesEXT(16, devices, &count))
            for (EGLint i = 0; i < count; ++i) out.push_back(eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[i], nullptr));
    }
    out.push_back(eglGetDisplay(EGL_DEFAULT_DISPLAY));
    return out;
}

// A GL 4.5 core context on `display`, current without a surface, or why not.
Result<EGLContext> core_context_on(EGLDisplay display) {
    if (display == EGL_NO_DISPLAY) return Error{Errc::unsupported, "no EGL display"};
    EGLint major = 0, minor = 0;
    if (!eglInitialize(display, &major, &minor)) return Error{Errc::unsupported, egl_error("eglInitialize")};
    if (!eglBindAPI(EGL_OPENGL_API)) return Error{Errc::unsupported, egl_error("eglBindAPI(EGL_OPENGL_API)")};
    const EGLint config_attribs[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
    EGLConfig config = nullptr;
    EGLint configs = 0;
    if (!eglChooseConfig(display, config_attribs, &config, 1, &configs) || configs < 1) {
        const EGLint any_surface[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
        if (!eglChooseConfig(display, any_surface, &config, 1, &configs) || configs < 1)
            return Error{Errc::unsupported, "no EGL config with desktop OpenGL"};
    }
    const EGLint context_attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 5,
                                      EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    EGLContext context = eglCreateContext(display, config, EGL_NO_CONTEXT, context_attribs);
    if (context == EGL_NO_CONTEXT) return Error{Errc::unsupported, egl_error("eglCreateContext (OpenGL 4.5 core)")};
    if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
        std::string message = egl_error("eglMakeCurrent without a surface (EGL_KHR_surfaceless_context)");
        eglDestroyContext(display, context);
        return Error{Errc::unsupported, std::move(message)};
    }
    return context;
}

}  // namespace

Result<std::unique_ptr<GlContext>> GlContext::create_headless() {
    // epoxy dlopens libEGL.so.1 itself and aborts when it is missing: look first.
    void* lib = ::dlopen("libEGL.so.1", RTLD_NOW | RTLD_LOCAL);
    if (!lib) return Error{Errc::unsupported, "headless GL: libEGL.so.1 not found (install libegl1 and Mesa's libegl-mesa0)"};
    ::dlclose(lib);

    std::string why_not;
    for (EGLDisplay display : candidate_displays()) {
        Result<EGLContext> context = core_context_on(display);
        if (!context) {
            // The first display's reason is the one worth reporting: later ones are fallbacks.
            if (why_not.empty()) why_not = context.error().message;
            continue;
        }
        auto ctx = std::make_unique<HeadlessContext>(display, *context);
        if (Status st = check_version("headless GL"); !st) return st.error();
        ctx->set_renderer(gl_description());
        return std::unique_ptr<GlContext>(std::move(ctx));
    }
    return Error{Errc::unsupported, "headless GL: " + (why_not.empty() ? std::string("no EGL display") : why_not)};
}

Result<std::unique_ptr<GlContext>> GlContext::create_window(int width, int height, const std::string& title) {
    if (!glfwInit()) return Error{Errc::unsupported, "window: glfwInit: " + glfw_error()};
    glfwWindowHint(GLFW_CLIENT_API, GLFW_OPENGL_API);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 4);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 5);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
    GLFWwindow* w = glfwCreateWindow(width, height, title.c_str(), nullptr, nullptr);
    if (!w) {
        std::string message = "window: glfwCreateWindow (OpenGL 4.5 core): " + glfw_error();
        glfwTerminate();
        return Error{Errc::unsupported, message};
    }
    glfwMakeContextCurrent(w);
    glfwSwapInterval(0);
    auto ctx = std::make_unique<WindowContext>(w);
    if (Status st = check_version("window"); !st) return st.error();
    ctx->set_renderer(gl_description());
    return std::unique_ptr<GlContext>(std::move(ctx));
}

}  // namespace tessera::client::gl
