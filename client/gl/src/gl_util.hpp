#pragma once
// Small GL helpers shared by the renderers: owning handles, program building from the embedded
// shaders (with `#include "file"` resolved), uniform setters.
#include <epoxy/gl.h>

#include <cstdint>
#include <string>
#include <string_view>
#include <utility>

#include "tessera/result.hpp"

namespace tessera::client::gl::detail {

// An owned GL object name, deleted with `Delete` (a function taking the name).
template <void (*Delete)(GLuint)>
class Handle {
public:
    Handle() = default;
    explicit Handle(GLuint id) : id_(id) {}
    ~Handle() { reset(); }
    Handle(Handle&& o) noexcept : id_(std::exchange(o.id_, 0)) {}
    Handle& operator=(Handle&& o) noexcept {
        if (this != &o) {
            reset();
            id_ = std::exchange(o.id_, 0);
        }
        return *this;
    }
    Handle(const Handle&) = delete;
    Handle& operator=(const Handle&) = delete;
    GLuint get() const { return id_; }
    explicit operator bool() const { return id_ != 0; }
    void reset() {
        if (id_) Delete(id_);
        id_ = 0;
    }

private:
    GLuint id_ = 0;
};

void delete_texture(GLuint id);
void delete_buffer(GLuint id);
void delete_framebuffer(GLuint id);
void delete_renderbuffer(GLuint id);
void delete_vertex_array(GLuint id);
void delete_program(GLuint id);
void delete_query(GLuint id);
void delete_sampler(GLuint id);

using Texture = Handle<delete_texture>;
using Buffer = Handle<delete_buffer>;
using Framebuffer = Handle<delete_framebuffer>;
using Renderbuffer = Handle<delete_renderbuffer>;
using VertexArray = Handle<delete_vertex_array>;
using Program = Handle<delete_program>;
using Query = Handle<delete_query>;
using Sampler = Handle<delete_sampler>;

Texture make_texture(GLenum target);
Buffer make_buffer();
Framebuffer make_framebuffer();
Renderbuffer make_renderbuffer();
VertexArray make_vertex_array();
Query make_query(GLenum target);
Sampler make_sampler();

// An owned fence.
class Fence {
public:
    Fence() = default;
    ~Fence() { reset(); }
    Fence(Fence&& o) noexcept : sync_(std::exchange(o.sync_, nullptr)) {}
    Fence& operator=(Fence&& o) noexcept {
        if (this != &o) {
            reset();
            sync_ = std::exchange(o.sync_, nullptr);
        }
        return *this;
    }
    Fence(const Fence&) = delete;
    Fence& operator=(const Fence&) = delete;

    void insert();  // after the commands issued so far
    // Signalled? Never waits (timeout 0; flushes so that the fence can signal at all).
    bool poll();
    void wait();    // blocks: the frame latency bound, the end of a run and tests
    bool pending() const { return sync_ != nullptr; }
    void reset();

private:
    GLsync sync_ = nullptr;
};

// `name` (an embedded shader) with its `#include "x"` lines replaced by x's text, after
// "#version 450 core" and `defines`. `#line` directives keep compiler messages pointing at files.
Result<std::string> assemble_shader(std::string_view name, std::string_view defines);
// Compiles and links a vertex + fragment program from embedded shaders. Errors carry the log.
Result<Program> build_program(std::string_view vertex, std::string_view fragment, std::string_view defines);

GLint uniform(const Program& p, const char* name);  // -1 when absent (optimised out)

// glGetError drained; empty when there was none, else "where: GL error 0x0500 ...".
std::string take_gl_errors(std::string_view where);

}  // namespace tessera::client::gl::detail
