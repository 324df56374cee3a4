// GL 4.5 core contexts: headless through EGL (surfaceless platform) or a GLFW window. libepoxy
// resolves GL and EGL entry points at run time; libEGL is probed with dlopen first, since epoxy
// aborts the process when it cannot load a library it needs.
#include "tessera/client/gl/context.hpp"

#include <dlfcn.h>
#include <epoxy/egl.h>
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <fmt/format.h>

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

class WindowContext final : public GlContext {
public:
    explicit WindowContext(GLFWwindow* w) : window_(w) {}
    ~WindowContext() override {
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

}  // namespace

Result<std::unique_ptr<GlContext>> GlContext::create_headless() {
    // epoxy dlopens libEGL.so.1 itself and aborts when it is missing: look first.
    void* lib = ::dlopen("libEGL.so.1", RTLD_NOW | RTLD_LOCAL);
    if (!lib) return Error{Errc::unsupported, "headless GL: libEGL.so.1 not found (install libegl1 and Mesa's libegl-mesa0)"};
    ::dlclose(lib);

    EGLDisplay display = EGL_NO_DISPLAY;
    if (epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_EXT_platform_base") &&
        epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_MESA_platform_surfaceless"))
        display = eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
    if (display == EGL_NO_DISPLAY) display = eglGetDisplay(EGL_DEFAULT_DISPLAY);
    if (display == EGL_NO_DISPLAY) return Error{Errc::unsupported, "headless GL: no EGL display"};
    EGLint major = 0, minor = 0;
    if (!eglInitialize(display, &major, &minor)) return Error{Errc::unsupported, "headless GL: " + egl_error("eglInitialize")};
    const auto fail = [&](std::string message) -> Result<std::unique_ptr<GlContext>> {
        return Error{Errc::unsupported, "headless GL: " + message};
    };
    if (!eglBindAPI(EGL_OPENGL_API)) return fail(egl_error("eglBindAPI(EGL_OPENGL_API)"));
    const EGLint config_attribs[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
    EGLConfig config = nullptr;
    EGLint configs = 0;
    if (!eglChooseConfig(display, config_attribs, &config, 1, &configs) || configs < 1) {
        const EGLint any_surface[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
        if (!eglChooseConfig(display, any_surface, &config, 1, &configs) || configs < 1)
            return fail("no EGL config with desktop OpenGL");
    }
    const EGLint context_attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 5,
                                      EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    EGLContext context = eglCreateContext(display, config, EGL_NO_CONTEXT, context_attribs);
    if (context == EGL_NO_CONTEXT) return fail(egl_error("eglCreateContext (OpenGL 4.5 core)"));
    if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
        eglDestroyContext(display, context);
        return fail(egl_error("eglMakeCurrent without a surface (EGL_KHR_surfaceless_context)"));
    }
    auto ctx = std::make_unique<HeadlessContext>(display, context);
    if (Status st = check_version("headless GL"); !st) return st.error();
    ctx->set_renderer(gl_description());
    return std::unique_ptr<GlContext>(std::move(ctx));
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
