#pragma once
// Reading a YAML file, and what went wrong in it, for every loader.
#include <yaml-cpp/depthguard.h>
#include <yaml-cpp/yaml.h>

#include <string>

#include "stillpoint/core/result.hpp"

namespace stillpoint {

// "line N: what" for a yaml-cpp exception. yaml-cpp reports nesting beyond
// its depth limit as "bad file"; that is said as it is.
inline std::string yamlErrorText(const YAML::Exception& e) {
  const auto* deep = dynamic_cast<const YAML::DeepRecursion*>(&e);
  const std::string what = deep ? "nested too deeply (" + std::to_string(deep->depth()) + " levels)" : e.msg;
  return "line " + std::to_string(e.mark.line + 1) + ": " + what;
}

// Parses the file at `path`; an error starts with `label` (e.g. "config 'x.yaml'")
// and never escapes as an exception: a missing file, a syntax error, nesting
// too deep, a directory or an I/O error while reading.
inline Result<YAML::Node> loadYamlFile(const std::string& path, const std::string& label) {
  try {
    return YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    return Error{label + ": cannot be opened"};
  } catch (const YAML::Exception& e) {
    return Error{label + ": " + yamlErrorText(e)};
  } catch (const std::exception& e) {
    return Error{label + ": " + e.what()};
  }
}

}  // namespace stillpoint
