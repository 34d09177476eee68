#pragma once
// Small file helpers shared by the writers of sequences and reports.
#include <filesystem>
#include <string>

#include "stillpoint/core/result.hpp"

namespace stillpoint {

// Writes `text` to `path` (replacing it); an error names the path when it
// cannot be opened or written (a full disk included).
Status writeTextFile(const std::filesystem::path& path, const std::string& text);

}  // namespace stillpoint
