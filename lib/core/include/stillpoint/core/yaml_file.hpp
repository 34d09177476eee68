#pragma once
// What went wrong in a YAML file, for the error messages of every loader.
#include <yaml-cpp/depthguard.h>
#include <yaml-cpp/yaml.h>

#include <string>

namespace stillpoint {

// "line N: what" for a yaml-cpp exception. yaml-cpp reports nesting beyond
// its depth limit as "bad file"; that is said as it is.
inline std::string yamlErrorText(const YAML::Exception& e) {
  const auto* deep = dynamic_cast<const YAML::DeepRecursion*>(&e);
  const std::string what = deep ? "nested too deeply (" + std::to_string(deep->depth()) + " levels)" : e.msg;
  return "line " + std::to_string(e.mark.line + 1) + ": " + what;
}

}  // namespace stillpoint
