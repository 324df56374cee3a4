#pragma once
// A scene that travels with its store: the atlas OBJ `tessera build --atlas` writes beside the
// store (STORE.obj beside STORE.tsr), bound to that build of the store by the store's id on one of
// its first comment lines ("# tessera-store 0123456789abcdef"). A viewer of the file, or a server
// serving it, finds the scene there (docs/atlas.md, "The scene travels with the store"); a rebuilt
// store with an old OBJ beside it has no scene until the OBJ is rebuilt too.
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "tessera/result.hpp"

namespace tessera::storage {

// STORE.obj for STORE.tsr (any extension replaced; appended when there is none).
std::string scene_path_beside(const std::string& store_path);

// The store id an atlas OBJ's header names ("# tessera-store HEX" among its first comment lines).
std::optional<std::uint64_t> scene_store_id(std::string_view text);

// The scene beside a store file, when there is one and it belongs to the store whose id is
// `store_id`: its path; nullopt otherwise. Reads at most the file's first 4 KiB.
std::optional<std::string> find_scene_beside(const std::string& store_path, std::uint64_t store_id);

// Reads `length` bytes of a scene file from `offset` (fewer at its end), with its total size.
struct SceneBytes {
    std::string data;
    std::uint64_t total = 0;
};
Result<SceneBytes> read_scene_bytes(const std::string& path, std::uint64_t offset, std::uint64_t length);

}  // namespace tessera::storage
