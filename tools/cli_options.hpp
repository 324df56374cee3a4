#pragma once
// Options that several subcommands share, defined once so that a word means the same on every
// command line: byte counts take units, and `--texels` is texels per side of a procedural store
// (`--size` is the viewer's WIDTHxHEIGHT).
#include <CLI/CLI.hpp>

#include <cstdint>
#include <limits>
#include <string>

namespace tessera::tools {

// A byte count as "256MiB" when it is a whole number of KiB, MiB, GiB or TiB, else as a number.
std::string bytes_text(std::uint64_t bytes);

// CLI11's AsSizeValue, as `serve` has always read its sizes: a whole number of bytes, optionally
// with a unit, case-insensitive, every unit a power of 1024: b, k/kb/kib, m/mb/mib, g/gb/gib,
// t/tb/tib (256MiB, 64k, 1g). A negative count, or one above `max` (the option's type), is an
// error: CLI11 alone reads -1 as 2^64-1 and lets a long number overflow. Its description is left
// out of the help, which shows `SIZE=DEFAULT`.
CLI::Validator bytes_transform(std::uint64_t max);

// A byte-count option (bytes_transform), its default shown in units.
template <class T>
CLI::Option* add_bytes_option(CLI::App& app, const std::string& name, T& bytes, const std::string& help) {
    return app.add_option(name, bytes, help)
        ->transform(bytes_transform(static_cast<std::uint64_t>(std::numeric_limits<T>::max())))
        ->type_name("SIZE")
        ->default_str(bytes_text(static_cast<std::uint64_t>(bytes)));
}

// An output file option: refuses, as the command line is read (before any work), a path that
// holds something other than a regular file (storage::check_output_file).
CLI::Validator output_file();

// Every floating-point option of `app` and its subcommands (CLI11's type name FLOAT), present and
// future, refuses nan and infinities: CLI11 reads them, and its Range and PositiveNumber checks
// let nan through (every comparison with it is false). Called once every command is registered.
void require_finite_numbers(CLI::App& app);

// How far the feedback reaches, as view and demo take it: --prefetch-lod (0..2 levels finer than
// sampled) and --guard-band (0..1 of the scene more on each side).
void add_feedback_reach_options(CLI::App& app, float& prefetch_lod, float& guard_band);

// `--texels N`: texels per side of the procedural terrain (`bench`, `demo`), checked by `check`.
// `--size N`, its former name, still works: hidden from the help, it prints a one-line notice on
// stderr once the command line is accepted (this sets the subcommand's final callback), and a
// WIDTHxHEIGHT given to it is an error that names --texels and --resolution.
CLI::Option* add_texels_option(CLI::App& app, std::uint32_t& texels, const std::string& help,
                               const CLI::Validator& check);

}  // namespace tessera::tools
