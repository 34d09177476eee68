#include "stillpoint/core/files.hpp"

#include <fstream>

namespace stillpoint {

Status writeTextFile(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
  out.close();
  if (!out) return Error{"cannot write " + path.string()};
  return Status::success();
}

}  // namespace stillpoint
