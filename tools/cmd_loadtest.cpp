// tessera loadtest: the command line (docs/loadtest.md). The application is apps/loadtest.
#include "cli_options.hpp"
#include "commands.hpp"
#include "interrupt.hpp"
#include "loadtest.hpp"
#include "path_option.hpp"

namespace tessera::tools {

Command add_loadtest(CLI::App& app) {
    auto o = std::make_shared<LoadTestOptions>();
    CLI::App* c = app.add_subcommand("loadtest", "Simulated viewers (no GL) against a Tessera server: tile latency, throughput, fallback");
    c->add_option("--server", o->server, "the server's gRPC address, HOST:PORT (grpcs://HOST:PORT: TLS); several replicas as IP:PORT,IP:PORT or "
                                         "dns:///NAME:PORT (every address of NAME), streams spread round robin")->required();
    c->add_option("--token", o->token, "bearer token for the server");
    c->add_option("--token-file", o->token_file, "read the bearer token from this file (first line)");
    c->add_flag("--tls", o->tls, "TLS to the server (as grpcs://)");
    c->add_option("--tls-ca", o->tls_ca, "PEM roots to verify the server (default: the system's; implies --tls)");
    c->add_option("--store", o->store, "store name on the server")->required();
    c->add_option("--viewers", o->viewers, "simulated viewers; a list (1,16,64) runs each in turn")
        ->delimiter(',')
        ->capture_default_str()
        ->check(CLI::Range(1u, 4096u));
    auto* trace = c->add_option("--trace", o->trace, "replay this feedback trace (tessera view --trace), each viewer from its own offset");
    c->add_option("--path", o->path, "compute feedback on the CPU along a " + camera_path_help() + " (default flyover)")
        ->excludes(trace);
    c->add_option("--fps", o->fps, "frames per second per viewer (a fixed schedule)")->capture_default_str()->check(CLI::Range(1.0, 1000.0));
    c->add_option("--duration", o->duration, "measured seconds per run")->capture_default_str()->check(CLI::Range(0.1, 86400.0));
    c->add_option("--warmup", o->warmup, "seconds before measuring (excluded)")->capture_default_str()->check(CLI::Range(0.0, 3600.0));
    c->add_flag("--ramp", o->ramp, "step viewers 1, 2, 4, ... up to --max-viewers; report the most meeting both targets");
    c->add_option("--ramp-p99-ms", o->ramp_p99_ms, "ramp target: p99 tile latency, ms, 0.001..3600000")->capture_default_str()->check(CLI::Range(0.001, 3600000.0));
    c->add_option("--ramp-fallback", o->ramp_fallback, "ramp target: fallback rate (fraction)")->capture_default_str()->check(CLI::Range(0.0, 1.0));
    c->add_option("--max-viewers", o->max_viewers, "ramp: the largest step")->capture_default_str()->check(CLI::Range(1u, 4096u));
    c->add_option("--seed", o->seed, "seed for phases, offsets, jitter")->capture_default_str()->check(CLI::NonNegativeNumber);
    c->add_option("--feedback-size", o->feedback_size, "feedback buffer, WxH")->capture_default_str();
    c->add_option("--view-size", o->view_size, "view the feedback stands for, WxH (--path)")->capture_default_str();
    add_bytes_option(*c, "--ram-cache", o->ram_cache, "RAM tile cache per viewer, e.g. 64MiB (0: off, every miss goes to the server)");
    c->add_option("--pool", o->pool, "physical pages per viewer")->capture_default_str()->check(CLI::Range(16u, 1u << 20));
    c->add_option("--latency", o->latency_ms, "emulated link: added latency, ms")->check(CLI::Range(0.0, 60000.0));
    c->add_option("--jitter", o->jitter_ms, "emulated link: added uniform jitter, ms")->check(CLI::Range(0.0, 60000.0));
    c->add_option("--bandwidth", o->bandwidth_mbit, "emulated link: bandwidth cap per viewer, Mbit/s (0: none)")->check(CLI::Range(0.0, 1e6));
    c->add_option("--threads", o->threads, "driver threads (0: min(viewers, cores))")->capture_default_str();
    c->add_option("--connect-timeout", o->connect_timeout, "seconds to wait for the server before giving up, 0.001..3600")->capture_default_str()->check(CLI::Range(0.001, 3600.0));
    c->add_option("--json", o->json, "write the results as JSON")->check(output_file());
    c->add_option("--plot", o->plot, "write a plot (SVG): fallback and p99 over time, or vs viewers")->check(output_file());
    c->add_flag("-q,--quiet", o->quiet, "no progress lines");
    c->add_option("--server-pid", o->server_pid,
                  "the server's process id on this machine: its CPU time per viewer-second is measured (/proc), and "
                  "viewers per core and the replicas for --plan-viewers are derived")
        ->check(CLI::Range(1, 1 << 30));
    c->add_option("--plan-viewers", o->plan_viewers, "capacity plan: viewers to serve")->capture_default_str()
        ->check(CLI::Range(1u, 100000000u));
    c->add_option("--replica-cores", o->replica_cores, "capacity plan: cores per server replica (0: this machine's)")
        ->capture_default_str();
    return [o]() -> int {
        remove_temp_files_on_interrupt();  // before any thread is started
        return run_loadtest(*o);
    };
}

}  // namespace tessera::tools
