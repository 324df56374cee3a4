#pragma once
// The store summary printed by `inspect`, `build` and `demo`, as text or JSON.
#include <nlohmann/json.hpp>

#include <string>

#include "tessera/storage/types.hpp"

namespace tessera::tools {

void print_store_summary(const std::string& name, const storage::StoreInfo& info);
nlohmann::json store_summary_json(const std::string& name, const storage::StoreInfo& info);

}  // namespace tessera::tools
