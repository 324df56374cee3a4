#pragma once
// The store summary printed by `inspect`, `build` and `demo` (`inspect --json` prints
// storage::store_json).
#include <string>

#include "tessera/storage/types.hpp"

namespace tessera::tools {

void print_store_summary(const std::string& name, const storage::StoreInfo& info);

}  // namespace tessera::tools
