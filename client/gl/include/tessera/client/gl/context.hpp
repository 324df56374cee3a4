#pragma once
// An OpenGL 4.5 core context: headless (EGL, surfaceless platform: Mesa llvmpipe, or a GPU's EGL)
// or windowed (GLFW). Everything GL in Tessera runs on the thread that made the context current.
#include <memory>
#include <string>

#include "tessera/result.hpp"

struct GLFWwindow;

namespace tessera::client::gl {

class GlContext {
public:
    virtual ~GlContext() = default;
    // EGL_PLATFORM_SURFACELESS_MESA (falling back to the default EGL display); no window, render
    // into framebuffer objects. Error with a clear message when no GL 4.5 core context can be made.
    static Result<std::unique_ptr<GlContext>> create_headless();
    // A GLFW window with a GL 4.5 core context (vsync off). Error when there is no display.
    static Result<std::unique_ptr<GlContext>> create_window(int width, int height, const std::string& title);

    virtual void make_current() = 0;
    virtual GLFWwindow* window() = 0;  // nullptr when headless
    virtual void swap_buffers() = 0;   // no-op when headless
    virtual std::string renderer() const = 0;  // GL_RENDERER / GL_VERSION, for logs and reports
};

}  // namespace tessera::client::gl
