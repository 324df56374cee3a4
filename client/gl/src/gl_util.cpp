#include "gl_util.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <vector>

#include "shaders.hpp"

namespace tessera::client::gl::detail {

void delete_texture(GLuint id) { glDeleteTextures(1, &id); }
void delete_buffer(GLuint id) { glDeleteBuffers(1, &id); }
void delete_framebuffer(GLuint id) { glDeleteFramebuffers(1, &id); }
void delete_renderbuffer(GLuint id) { glDeleteRenderbuffers(1, &id); }
void delete_vertex_array(GLuint id) { glDeleteVertexArrays(1, &id); }
void delete_program(GLuint id) { glDeleteProgram(id); }
void delete_query(GLuint id) { glDeleteQueries(1, &id); }
void delete_sampler(GLuint id) { glDeleteSamplers(1, &id); }

Texture make_texture(GLenum target) {
    GLuint id = 0;
    glCreateTextures(target, 1, &id);
    return Texture(id);
}
Buffer make_buffer() {
    GLuint id = 0;
    glCreateBuffers(1, &id);
    return Buffer(id);
}
Framebuffer make_framebuffer() {
    GLuint id = 0;
    glCreateFramebuffers(1, &id);
    return Framebuffer(id);
}
Renderbuffer make_renderbuffer() {
    GLuint id = 0;
    glCreateRenderbuffers(1, &id);
    return Renderbuffer(id);
}
VertexArray make_vertex_array() {
    GLuint id = 0;
    glCreateVertexArrays(1, &id);
    return VertexArray(id);
}

Sampler make_sampler() {
    GLuint id = 0;
    glCreateSamplers(1, &id);
    return Sampler(id);
}

Query make_query(GLenum target) {
    GLuint id = 0;
    glCreateQueries(target, 1, &id);
    return Query(id);
}

void Fence::insert() {
    reset();
    sync_ = glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0);
}

bool Fence::poll() {
    if (!sync_) return true;
    const GLenum r = glClientWaitSync(sync_, GL_SYNC_FLUSH_COMMANDS_BIT, 0);
    return r == GL_ALREADY_SIGNALED || r == GL_CONDITION_SATISFIED;
}

void Fence::wait() {
    if (!sync_) return;
    while (true) {
        const GLenum r = glClientWaitSync(sync_, GL_SYNC_FLUSH_COMMANDS_BIT, 1'000'000'000);
        if (r != GL_TIMEOUT_EXPIRED) break;
    }
}

void Fence::reset() {
    if (sync_) glDeleteSync(sync_);
    sync_ = nullptr;
}

namespace {

const EmbeddedShader* find_shader(std::string_view name) {
    for (const auto& s : embedded_shaders())
        if (name == s.name) return &s;
    return nullptr;
}

}  // namespace

Result<std::string> assemble_shader(std::string_view name, std::string_view defines) {
    const EmbeddedShader* main = find_shader(name);
    if (!main) return Error{Errc::not_found, fmt::format("no embedded shader {}", name)};
    // Source string numbers in #line: 0 = the main file, 1.. = includes in order (named in the
    // error message by build_program through the returned text's header comment).
    std::string out = "#version 450 core\n";
    out += defines;
    if (!defines.empty() && defines.back() != '\n') out += '\n';
    out += fmt::format("#line 1 0\n");
    std::string_view text = main->source;
    int line = 1, include_no = 0;
    while (!text.empty()) {
        const std::size_t eol = text.find('\n');
        const std::string_view l = text.substr(0, eol);
        text = eol == std::string_view::npos ? std::string_view{} : text.substr(eol + 1);
        const std::size_t inc = l.find("#include");
        if (inc != std::string_view::npos && l.find_first_not_of(" \t") == inc) {
            const std::size_t q0 = l.find('"', inc), q1 = q0 == std::string_view::npos ? q0 : l.find('"', q0 + 1);
            if (q1 == std::string_view::npos) return Error{Errc::invalid_argument, fmt::format("{}:{}: bad #include", name, line)};
            const std::string_view inc_name = l.substr(q0 + 1, q1 - q0 - 1);
            const EmbeddedShader* included = find_shader(inc_name);
            if (!included) return Error{Errc::not_found, fmt::format("{}:{}: no embedded shader {}", name, line, inc_name)};
            out += fmt::format("#line 1 {}\n", ++include_no);
            out += included->source;
            out += fmt::format("\n#line {} 0\n", line + 1);
        } else {
            out += l;
            out += '\n';
        }
        ++line;
    }
    return out;
}

namespace {

Result<GLuint> compile(GLenum stage, std::string_view name, std::string_view defines) {
    auto src = assemble_shader(name, defines);
    if (!src) return src.error();
    const GLuint s = glCreateShader(stage);
    const char* text = src->c_str();
    glShaderSource(s, 1, &text, nullptr);
    glCompileShader(s);
    GLint ok = 0;
    glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        GLint len = 0;
        glGetShaderiv(s, GL_INFO_LOG_LENGTH, &len);
        std::string log(static_cast<std::size_t>(std::max(len, 1)), '\0');
        glGetShaderInfoLog(s, len, nullptr, log.data());
        glDeleteShader(s);
        return Error{Errc::invalid_argument,
                     fmt::format("compiling {} (source 0 = {}, 1 = its include): {}", name, name, log.c_str())};
    }
    return s;
}

}  // namespace

Result<Program> build_program(std::string_view vertex, std::string_view fragment, std::string_view defines) {
    auto vs = compile(GL_VERTEX_SHADER, vertex, defines);
    if (!vs) return vs.error();
    auto fs = compile(GL_FRAGMENT_SHADER, fragment, defines);
    if (!fs) {
        glDeleteShader(*vs);
        return fs.error();
    }
    Program p(glCreateProgram());
    glAttachShader(p.get(), *vs);
    glAttachShader(p.get(), *fs);
    glLinkProgram(p.get());
    glDetachShader(p.get(), *vs);
    glDetachShader(p.get(), *fs);
    glDeleteShader(*vs);
    glDeleteShader(*fs);
    GLint ok = 0;
    glGetProgramiv(p.get(), GL_LINK_STATUS, &ok);
    if (!ok) {
        GLint len = 0;
        glGetProgramiv(p.get(), GL_INFO_LOG_LENGTH, &len);
        std::string log(static_cast<std::size_t>(std::max(len, 1)), '\0');
        glGetProgramInfoLog(p.get(), len, nullptr, log.data());
        return Error{Errc::invalid_argument, fmt::format("linking {} + {}: {}", vertex, fragment, log.c_str())};
    }
    return p;
}

GLint uniform(const Program& p, const char* name) { return glGetUniformLocation(p.get(), name); }

std::string take_gl_errors(std::string_view where) {
    std::string out;
    for (int i = 0; i < 16; ++i) {
        const GLenum e = glGetError();
        if (e == GL_NO_ERROR) break;
        out += out.empty() ? fmt::format("{}: GL error 0x{:04x}", where, e) : fmt::format(", 0x{:04x}", e);
    }
    return out;
}

}  // namespace tessera::client::gl::detail
