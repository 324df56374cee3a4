#include "cli_options.hpp"

#include <cmath>
#include <cstdio>

#include "tessera/storage/output_file.hpp"

namespace tessera::tools {

std::string bytes_text(std::uint64_t bytes) {
    static const char* const units[] = {"KiB", "MiB", "GiB", "TiB"};
    if (bytes == 0) return "0";
    std::string unit;
    for (const char* u : units) {
        if (bytes % 1024 != 0) break;
        bytes /= 1024;
        unit = u;
    }
    return std::to_string(bytes) + unit;
}

CLI::Validator bytes_transform(std::uint64_t max) {
    const CLI::Validator units = CLI::AsSizeValue(false);
    return CLI::Validator(
        [units, max](std::string& value) -> std::string {
            const std::string given = value;
            const std::size_t first = value.find_first_not_of(" \t");
            if (first != std::string::npos && value[first] == '-') return "'" + given + "': a byte count cannot be negative";
            if (std::string error = units(value); !error.empty()) return error;
            // The units applied; a number without one is left as given: whole decimal digits only.
            const std::size_t b = value.find_first_not_of(" \t"), e = value.find_last_not_of(" \t");
            const std::string digits = b == std::string::npos ? std::string() : value.substr(b, e - b + 1);
            if (digits.empty() || digits.find_first_not_of("0123456789") != std::string::npos)
                return "'" + given + "' is not a byte count (a whole number, optionally with a unit: 64k, 256MiB, 1g)";
            std::uint64_t n = 0;
            for (const char c : digits) {
                const unsigned d = unsigned(c - '0');
                if (n > (max - d) / 10) return "'" + given + "' is too large: at most " + std::to_string(max) + " bytes";
                n = n * 10 + d;
            }
            value = std::to_string(n);
            return {};
        },
        "", "bytes");
}

CLI::Validator output_file() {
    return CLI::Validator(
        [](std::string& path) -> std::string {
            const Status st = storage::check_output_file(path);
            return st ? std::string() : st.error().message;
        },
        "", "output file");
}

void require_finite_numbers(CLI::App& app) {
    const CLI::Validator finite(
        [](std::string& value) -> std::string {
            double v = 0;
            if (CLI::detail::lexical_cast(value, v) && !std::isfinite(v)) return "'" + value + "' is not a finite number";
            return {};  // a value that is not a number at all: CLI11's own conversion reports it
        },
        "", "finite");
    for (CLI::Option* opt : app.get_options())
        if (opt->get_type_name().rfind("FLOAT", 0) == 0) opt->transform(finite);  // first: before the option's own range check
    for (CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; })) require_finite_numbers(*sub);
}

void add_feedback_reach_options(CLI::App& app, float& prefetch_lod, float& guard_band) {
    app.add_option("--prefetch-lod", prefetch_lod, "feedback asks for pages this many levels finer than sampled (0..2)")
        ->capture_default_str()
        ->check(CLI::Range(0.0f, 2.0f));
    app.add_option("--guard-band", guard_band, "feedback sees this fraction more of the scene on each side (0..1)")
        ->capture_default_str()
        ->check(CLI::Range(0.0f, 1.0f));
}

CLI::Option* add_texels_option(CLI::App& app, std::uint32_t& texels, const std::string& help, const CLI::Validator& check) {
    CLI::Option* opt = app.add_option("--texels", texels, help)->check(check)->capture_default_str();
    // CLI11 leaves a hidden option's name out of its errors: these messages name --size themselves.
    const CLI::Validator former(
        [check](std::string& value) -> std::string {
            if (value.empty() || value.find_first_not_of("0123456789") != std::string::npos)
                return "--size '" + value + "': --size is the former name of --texels, texels per side of the terrain "
                       "(a number); the image size is --resolution WIDTHxHEIGHT";
            const std::string error = check(value);
            return error.empty() ? error : "--size (now --texels): " + error;
        },
        "", "former name");
    CLI::Option* old = app.add_option("--size", texels, "the former name of --texels")
                           ->group("")  // hidden: the help shows --texels only
                           ->check(former);
    // Once the whole command line is read (the subcommand's own callback: the commands run from main).
    app.final_callback([opt, old, command = app.get_name()] {
        if (old->count() > 0 && opt->count() > 0)
            throw CLI::ValidationError("--size", "the former name of --texels; give --texels only");
        if (old->count() > 0)
            std::fprintf(stderr, "tessera %s: note: --size is now --texels (texels per side); --size will be removed\n",
                         command.c_str());
    });
    return opt;
}

}  // namespace tessera::tools
