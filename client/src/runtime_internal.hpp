#pragma once
// What the tests see of a runtime beyond its public interface: its page cache (slots, their
// states, page tables). Not installed: an embedder sees the runtime through runtime.hpp alone.
#include "residency.hpp"
#include "tessera/client/runtime.hpp"

namespace tessera::client {

// The page cache of a runtime made by Runtime::create.
const Residency& residency_of(const Runtime& runtime);

}  // namespace tessera::client
