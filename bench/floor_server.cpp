// The floor for serving tiles over HTTP/1.1 on this machine: a server that does nothing but the
// system calls a keep-alive tile response needs. bench/serve_vs_nginx.sh runs it as a third peer
// beside nginx and `tessera serve`, so that a peak ratio can be read against what any server
// could reach in the same minutes (docs/benchmarks.md, "The floor").
//
// Every tile of an export_tiles directory is loaded into memory at start, each with a prepared
// response (a head with the same header fields as tessera's, then the payload) in one buffer.
// A request is found by its target in a hash map; the loops do one recv and one send per request
// (epoll, edge-triggered) or batch both through io_uring (--uring, when built with liburing: one
// io_uring_enter per loop pass). --sendfile sends the head with MSG_MORE and the payload with
// sendfile(2) from the tile's file, as nginx does: whether skipping the copy into the socket pays
// for the second call (docs/benchmarks.md, "sendfile and speculative reads"). No timeouts, no
// limits, no metrics, no auth: a measuring instrument, not a server to deploy.
//
//   floor_server DIR [--port N] [--threads N] [--uring] [--sendfile]
//   prints "listening 127.0.0.1:PORT" once every loop listens
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/epoll.h>
#include <sys/sendfile.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <string_view>
#include <thread>
#include <unordered_map>
#include <vector>

#if defined(TESSERA_FLOOR_URING)
#include <liburing.h>
#endif

namespace {

namespace fs = std::filesystem;

// A prepared response: the whole of it (head and payload) in memory, and for --sendfile the head
// alone and the payload's file, sent from the page cache without a copy into the socket.
struct Response {
    std::string whole;
    std::size_t head_size = 0;
    int fd = -1;  // --sendfile: the tile's file, held open
};
// target -> its response.
std::unordered_map<std::string, Response> g_responses;
const Response kNotFound{"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\n\r\n", 0, -1};
bool g_sendfile = false;

bool load(const fs::path& dir) {
    std::ifstream urls(dir / "urls.txt");
    if (!urls) return false;
    std::string url;
    const std::string prefix = "/v1/stores/";
    while (std::getline(urls, url)) {
        if (url.rfind(prefix, 0) != 0) continue;
        std::ifstream f(dir / url.substr(prefix.size()), std::ios::binary);
        if (!f) {
            std::fprintf(stderr, "floor_server: %s listed but not found\n", url.c_str());
            return false;
        }
        std::string body((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
        // The fields tessera sends with a stored tile, so both heads cost the client the same.
        const std::string head = "HTTP/1.1 200 OK\r\nContent-Type: image/jpeg\r\n"
                                 "ETag: \"0123456789abcdef-0123456789abcdef\"\r\nCache-Control: public, max-age=60\r\n"
                                 "X-Tessera-Store-Version: 0123456789abcdef\r\nX-Tessera-Kind: present\r\n"
                                 "X-Tessera-Codec: jpeg\r\nX-Tessera-Checksum: 0123456789abcdef\r\nServer: floor\r\n"
                                 "Content-Length: " + std::to_string(body.size()) + "\r\n\r\n";
        Response r{head + body, head.size(), -1};
        if (g_sendfile) {
            r.fd = open((dir / url.substr(prefix.size())).c_str(), O_RDONLY | O_CLOEXEC);
            if (r.fd < 0) {
                std::perror("floor_server: open");
                return false;
            }
        }
        g_responses.emplace(url, std::move(r));
    }
    return !g_responses.empty();
}

// The response to the next complete request in [data, data + n), and how many bytes it took;
// 0 when the request is not complete yet.
std::size_t next_request(const char* data, std::size_t n, const Response*& response) {
    const std::string_view s(data, n);
    const std::size_t end = s.find("\r\n\r\n");
    if (end == std::string_view::npos) return 0;
    const std::size_t sp1 = s.find(' ');
    const std::size_t sp2 = sp1 == std::string_view::npos ? sp1 : s.find(' ', sp1 + 1);
    response = &kNotFound;
    if (sp2 != std::string_view::npos && sp2 < end) {
        auto it = g_responses.find(std::string(s.substr(sp1 + 1, sp2 - sp1 - 1)));
        if (it != g_responses.end()) response = &it->second;
    }
    return end + 4;
}

int listen_on(int port) {
    const int fd = socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0);
    const int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEPORT, &one, sizeof one);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || listen(fd, 1024) != 0) {
        std::perror("floor_server: bind");
        std::exit(1);
    }
    return fd;
}

int port_of(int fd) {
    sockaddr_in a{};
    socklen_t len = sizeof a;
    getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    return ntohs(a.sin_port);
}

struct Conn {
    int fd = -1;
    std::string in;                           // bytes of a request not yet complete
    std::vector<const Response*> pending;  // responses not yet sent, in order
    std::size_t sent = 0;                     // bytes of pending.front() already sent
    char buf[4096];
};

// Feeds what was read; queues the response to every complete request. False: close.
bool take(Conn& c, const char* data, std::size_t n) {
    c.in.append(data, n);
    std::size_t at = 0;
    for (;;) {
        const Response* response = nullptr;
        const std::size_t used = next_request(c.in.data() + at, c.in.size() - at, response);
        if (used == 0) break;
        at += used;
        c.pending.push_back(response);
    }
    c.in.erase(0, at);
    return c.in.size() < 65536 && c.pending.size() < 1024;
}

// Sends what is queued until done or the socket is full. False: the connection failed.
bool flush(Conn& c) {
    while (!c.pending.empty()) {
        const std::string& r = c.pending.front()->whole;
        ssize_t w;
        if (c.pending.front()->fd < 0) {
            w = send(c.fd, r.data() + c.sent, r.size() - c.sent, MSG_NOSIGNAL);
        } else if (const std::size_t head = c.pending.front()->head_size; c.sent < head) {
            w = send(c.fd, r.data() + c.sent, head - c.sent, MSG_NOSIGNAL | MSG_MORE);
        } else {
            off_t at = static_cast<off_t>(c.sent - head);
            w = sendfile(c.fd, c.pending.front()->fd, &at, r.size() - c.sent);
        }
        if (w < 0 && errno == EAGAIN) return true;  // EPOLLOUT's edge resumes it
        if (w <= 0) return false;
        c.sent += static_cast<std::size_t>(w);
        if (c.sent == r.size()) {
            c.pending.erase(c.pending.begin());
            c.sent = 0;
        }
    }
    return true;
}

void epoll_loop(int listener) {
    const int ep = epoll_create1(0);
    epoll_event ev{};
    ev.events = EPOLLIN;
    ev.data.ptr = nullptr;
    epoll_ctl(ep, EPOLL_CTL_ADD, listener, &ev);
    epoll_event events[128];
    for (;;) {
        const int n = epoll_wait(ep, events, 128, -1);
        for (int i = 0; i < n; ++i) {
            auto* c = static_cast<Conn*>(events[i].data.ptr);
            if (!c) {
                for (int fd; (fd = accept4(listener, nullptr, nullptr, SOCK_NONBLOCK)) >= 0;) {
                    const int one = 1;
                    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
                    auto* conn = new Conn;
                    conn->fd = fd;
                    epoll_event e{};
                    e.events = EPOLLIN | EPOLLOUT | EPOLLET | EPOLLRDHUP;
                    e.data.ptr = conn;
                    epoll_ctl(ep, EPOLL_CTL_ADD, fd, &e);
                }
                continue;
            }
            // Edge-triggered: read until the socket is empty (a read that does not fill the
            // buffer took all there was), answering as requests complete; while responses wait
            // for room, nothing more is read (EPOLLOUT's edge comes back here).
            bool open = flush(*c);
            while (open && c->pending.empty()) {
                const ssize_t r = recv(c->fd, c->buf, sizeof c->buf, 0);
                if (r < 0 && errno == EAGAIN) break;
                open = r > 0 && take(*c, c->buf, static_cast<std::size_t>(r)) && flush(*c);
                if (open && static_cast<std::size_t>(r) < sizeof c->buf) break;
            }
            if (!open) {
                close(c->fd);
                delete c;
            }
        }
    }
}

#if defined(TESSERA_FLOOR_URING)
enum : std::uint64_t { kAccept = 1, kRecv = 2, kSend = 3 };

using UringConn = Conn;

void uring_loop(int listener) {
    io_uring ring{};
    io_uring_params p{};
    p.flags = IORING_SETUP_SINGLE_ISSUER | IORING_SETUP_COOP_TASKRUN;
    if (io_uring_queue_init_params(1024, &ring, &p) != 0) {
        std::fprintf(stderr, "floor_server: io_uring_queue_init failed (io_uring disabled here?)\n");
        std::exit(1);
    }
    auto sqe = [&] {
        io_uring_sqe* s = io_uring_get_sqe(&ring);
        if (!s) {
            io_uring_submit(&ring);
            s = io_uring_get_sqe(&ring);
        }
        return s;
    };
    auto tag = [](UringConn* c, std::uint64_t kind) { return reinterpret_cast<std::uint64_t>(c) | kind; };
    auto post_recv = [&](UringConn* c) {
        io_uring_sqe* s = sqe();
        io_uring_prep_recv(s, c->fd, c->buf, sizeof c->buf, 0);
        io_uring_sqe_set_data64(s, tag(c, kRecv));
    };
    auto post_send = [&](UringConn* c) {
        const std::string& r = c->pending.front()->whole;
        io_uring_sqe* s = sqe();
        io_uring_prep_send(s, c->fd, r.data() + c->sent, r.size() - c->sent, MSG_NOSIGNAL);
        io_uring_sqe_set_data64(s, tag(c, kSend));
    };
    io_uring_sqe* s = sqe();
    io_uring_prep_multishot_accept(s, listener, nullptr, nullptr, 0);
    io_uring_sqe_set_data64(s, kAccept);
    for (;;) {
        io_uring_submit_and_wait(&ring, 1);
        io_uring_cqe* cqe;
        unsigned head, seen = 0;
        io_uring_for_each_cqe(&ring, head, cqe) {
            ++seen;
            const std::uint64_t kind = cqe->user_data & 7;
            auto* c = reinterpret_cast<UringConn*>(cqe->user_data & ~std::uint64_t{7});
            if (kind == kAccept) {
                if (cqe->res < 0) continue;
                const int one = 1;
                setsockopt(cqe->res, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
                auto* conn = new UringConn;
                conn->fd = cqe->res;
                post_recv(conn);
            } else if (kind == kRecv) {
                const bool ok = cqe->res > 0 && take(*c, c->buf, static_cast<std::size_t>(cqe->res));
                if (!ok) {
                    close(c->fd);
                    delete c;
                } else if (!c->pending.empty()) {
                    post_send(c);
                } else {
                    post_recv(c);
                }
            } else if (kind == kSend) {
                if (cqe->res <= 0) {
                    close(c->fd);
                    delete c;
                    continue;
                }
                c->sent += static_cast<std::size_t>(cqe->res);
                if (c->sent == c->pending.front()->whole.size()) {
                    c->pending.erase(c->pending.begin());
                    c->sent = 0;
                }
                if (!c->pending.empty()) post_send(c);
                else post_recv(c);
            }
        }
        io_uring_cq_advance(&ring, seen);
    }
}
#endif

}  // namespace

int main(int argc, char** argv) {
    std::string dir;
    int port = 0;
    unsigned threads = std::max(1u, std::thread::hardware_concurrency());
    bool uring = false;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--port" && i + 1 < argc) port = std::atoi(argv[++i]);
        else if (a == "--threads" && i + 1 < argc) threads = static_cast<unsigned>(std::max(1, std::atoi(argv[++i])));
        else if (a == "--uring") uring = true;
        else if (a == "--sendfile") g_sendfile = true;
        else if (dir.empty() && a[0] != '-') dir = a;
        else {
            std::fprintf(stderr, "usage: floor_server DIR [--port N] [--threads N] [--uring] [--sendfile]\n");
            return 2;
        }
    }
    if (dir.empty()) {
        std::fprintf(stderr, "usage: floor_server DIR [--port N] [--threads N] [--uring] [--sendfile]\n");
        return 2;
    }
    if (uring && g_sendfile) {
        std::fprintf(stderr, "floor_server: --sendfile is for the epoll loops; not with --uring\n");
        return 2;
    }
#if !defined(TESSERA_FLOOR_URING)
    if (uring) {
        std::fprintf(stderr, "floor_server: built without liburing; --uring is not available\n");
        return 2;
    }
#endif
    if (!load(dir)) {
        std::fprintf(stderr, "floor_server: no tiles under %s (expected export_tiles' urls.txt and files)\n", dir.c_str());
        return 1;
    }
    std::vector<int> listeners{listen_on(port)};
    port = port_of(listeners[0]);
    for (unsigned i = 1; i < threads; ++i) listeners.push_back(listen_on(port));
    std::vector<std::thread> loops;
    for (int fd : listeners) {
#if defined(TESSERA_FLOOR_URING)
        if (uring) {
            loops.emplace_back([fd] { uring_loop(fd); });
            continue;
        }
#endif
        loops.emplace_back([fd] { epoll_loop(fd); });
    }
    std::printf("listening 127.0.0.1:%d (%zu tiles, %u %s loops)\n", port, g_responses.size(), threads,
                uring ? "io_uring" : "epoll");
    std::fflush(stdout);
    for (auto& t : loops) t.join();
}
