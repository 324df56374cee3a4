#pragma once
// Integration-test helpers: a real `tessera serve` process on loopback (ephemeral ports, logs
// to a file), a minimal HTTP/1.1 client over a socket, and process memory readings.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "test_util.hpp"

namespace tessera::test {

inline std::string slurp(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

// A self-signed P-256 certificate for localhost (and 127.0.0.1) in `dir`, made with the openssl
// CLI. A failure is the test's failure, with openssl's own output: tools/setup.sh installs openssl.
inline ::testing::AssertionResult make_test_certificate(const ScratchDir& dir, std::string& cert, std::string& key) {
    cert = dir.file("cert.pem");
    key = dir.file("key.pem");
    const std::string out = dir.file("openssl.out");
    const std::string cmd = "openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes "
                            "-subj /CN=localhost -addext subjectAltName=DNS:localhost,IP:127.0.0.1 -days 1 "
                            "-keyout " + key + " -out " + cert + " >" + out + " 2>&1";
    const int rc = std::system(cmd.c_str());
    if (rc == 0) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << "cannot make a TLS test certificate with the openssl CLI (tools/setup.sh installs openssl): `"
                                         << cmd << "` failed (std::system returned " << rc << "): " << slurp(out);
}

// `tessera serve ARGS --grpc 127.0.0.1:0 --http 127.0.0.1:0`, started in the constructor,
// ready (ports known) when it returns; SIGKILLed in the destructor if still running.
class ServerProcess {
public:
    // grpc: the gRPC address ("" = off); http: whether to serve HTTP on an ephemeral port.
    ServerProcess(const std::vector<std::string>& args, const std::string& log_path,
                  const std::string& grpc = "127.0.0.1:0", bool http = true)
        : log_path_(log_path) {
        std::vector<std::string> argv_s{TESSERA_BINARY, "serve"};
        argv_s.insert(argv_s.end(), args.begin(), args.end());
        argv_s.insert(argv_s.end(), {"--grpc", grpc, "--http", http ? "127.0.0.1:0" : ""});
        std::vector<char*> argv;
        for (auto& s : argv_s) argv.push_back(s.data());
        argv.push_back(nullptr);
        pid_ = ::fork();
        if (pid_ == 0) {
            const int fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_APPEND, 0644);
            ::dup2(fd, 1);
            ::dup2(fd, 2);
            ::execv(argv[0], argv.data());
            std::_Exit(127);
        }
        // Wait for {"msg":"listening","grpc":"127.0.0.1:P","http":"127.0.0.1:Q",...}.
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
        static const std::regex re(R"re("msg":"listening","grpc":"([^"]*)","http":"([^"]*)")re");
        while (std::chrono::steady_clock::now() < deadline) {
            std::smatch m;
            const std::string log = slurp(log_path_);
            if (std::regex_search(log, m, re)) {
                grpc_address_ = m[1].str();
                http_port_ = port_of(m[2].str());
                listening_ = true;
                return;
            }
            int status = 0;
            if (::waitpid(pid_, &status, WNOHANG) == pid_) {
                exit_status_ = status;
                pid_ = -1;
                return;  // did not start: running() is false, log() says why
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
    }
    ~ServerProcess() {
        if (pid_ > 0) {
            ::kill(pid_, SIGKILL);
            ::waitpid(pid_, nullptr, 0);
        }
    }
    ServerProcess(const ServerProcess&) = delete;
    ServerProcess& operator=(const ServerProcess&) = delete;

    bool running() const { return pid_ > 0 && listening_; }
    pid_t pid() const { return pid_; }
    const std::string& grpc_address() const { return grpc_address_; }
    int http_port() const { return http_port_; }
    std::string log() const { return slurp(log_path_); }
    // How many times `text` occurs in the log so far.
    std::size_t log_count(const std::string& text) const {
        const std::string all = log();
        std::size_t n = 0;
        for (auto at = all.find(text); at != std::string::npos; at = all.find(text, at + 1)) ++n;
        return n;
    }
    void signal(int sig) const { ::kill(pid_, sig); }

    // Waits for the process to exit; its exit code, or nullopt on timeout (or a signal death: -sig).
    std::optional<int> wait_exit(std::chrono::milliseconds timeout) {
        const auto deadline = std::chrono::steady_clock::now() + timeout;
        while (pid_ > 0 && std::chrono::steady_clock::now() < deadline) {
            int status = 0;
            if (::waitpid(pid_, &status, WNOHANG) == pid_) {
                pid_ = -1;
                return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
        if (pid_ < 0 && exit_status_) return WIFEXITED(*exit_status_) ? WEXITSTATUS(*exit_status_) : -1;
        return std::nullopt;
    }

    // Resident memory in KiB (VmRSS), 0 when unknown.
    long rss_kib() const { return status_kib("VmRSS:"); }
    // The most resident memory the process has had so far (VmHWM), in KiB; 0 when unknown.
    long peak_rss_kib() const { return status_kib("VmHWM:"); }

private:
    long status_kib(const std::string& field) const {
        std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
        std::string line;
        while (std::getline(in, line))
            if (line.rfind(field, 0) == 0) return std::stol(line.substr(field.size()));
        return 0;
    }
    static int port_of(const std::string& hostport) {
        const auto c = hostport.rfind(':');
        return c == std::string::npos ? 0 : std::stoi(hostport.substr(c + 1));
    }
    pid_t pid_ = -1;
    std::string log_path_;
    std::string grpc_address_;
    int http_port_ = 0;
    bool listening_ = false;
    std::optional<int> exit_status_;
};

struct HttpReply {
    int status = 0;  // 0: no reply (connection failed or closed)
    std::map<std::string, std::string> headers;  // lower-case names
    std::string body;
};

// A blocking HTTP/1.1 connection to 127.0.0.1:port (one request at a time, keep-alive).
class HttpConnection {
public:
    explicit HttpConnection(int port) {
        fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(static_cast<std::uint16_t>(port));
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        timeval tv{10, 0};
        ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
        if (::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
            ::close(fd_);
            fd_ = -1;
        }
    }
    ~HttpConnection() {
        if (fd_ >= 0) ::close(fd_);
    }
    HttpConnection(const HttpConnection&) = delete;
    HttpConnection& operator=(const HttpConnection&) = delete;
    bool connected() const { return fd_ >= 0; }

    // Sends raw bytes (for malformed-request tests).
    bool send_raw(const std::string& bytes) {
        std::size_t off = 0;
        while (off < bytes.size()) {
            const ssize_t n = ::send(fd_, bytes.data() + off, bytes.size() - off, MSG_NOSIGNAL);
            if (n <= 0) return false;
            off += static_cast<std::size_t>(n);
        }
        return true;
    }

    HttpReply get(const std::string& target, const std::vector<std::string>& extra_headers = {},
                  const std::string& method = "GET") {
        std::string req = method + " " + target + " HTTP/1.1\r\nHost: 127.0.0.1\r\n";
        for (const auto& h : extra_headers) req += h + "\r\n";
        req += "\r\n";
        if (fd_ < 0 || !send_raw(req)) return {};
        return read_reply(method == "HEAD");
    }

    HttpReply read_reply(bool head = false) {
        HttpReply r;
        // Head.
        while (buf_.find("\r\n\r\n") == std::string::npos)
            if (!fill()) return r;
        const auto end = buf_.find("\r\n\r\n");
        std::istringstream head_in(buf_.substr(0, end));
        buf_.erase(0, end + 4);
        std::string line;
        std::getline(head_in, line);
        if (line.size() < 12) return r;
        r.status = std::stoi(line.substr(9, 3));
        while (std::getline(head_in, line)) {
            if (!line.empty() && line.back() == '\r') line.pop_back();
            const auto c = line.find(':');
            if (c == std::string::npos) continue;
            std::string name = line.substr(0, c);
            for (auto& ch : name) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
            std::string value = line.substr(c + 1);
            while (!value.empty() && value.front() == ' ') value.erase(0, 1);
            r.headers[name] = value;
        }
        std::size_t length = 0;
        if (auto it = r.headers.find("content-length"); it != r.headers.end()) length = std::stoul(it->second);
        if (head || r.status == 304) length = 0;
        while (buf_.size() < length)
            if (!fill()) break;
        r.body = buf_.substr(0, std::min(length, buf_.size()));
        buf_.erase(0, std::min(length, buf_.size()));
        return r;
    }

    // True when the server has closed the connection (reads EOF).
    bool closed_by_peer() {
        char c;
        const ssize_t n = ::recv(fd_, &c, 1, 0);
        if (n == 1) buf_ += c;
        return n == 0;
    }

private:
    bool fill() {
        char tmp[65536];
        const ssize_t n = ::recv(fd_, tmp, sizeof tmp, 0);
        if (n <= 0) return false;
        buf_.append(tmp, static_cast<std::size_t>(n));
        return true;
    }
    int fd_ = -1;
    std::string buf_;
};

inline HttpReply http_get(int port, const std::string& target, const std::vector<std::string>& headers = {}) {
    HttpConnection c(port);
    return c.get(target, headers);
}

}  // namespace tessera::test
