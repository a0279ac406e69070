#include "diekf/eval/param_overlay.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <stdexcept>

namespace diekf {
namespace eval {

namespace {

std::string trim(const std::string& s) {
  std::size_t a = 0, b = s.size();
  while (a < b && std::isspace(static_cast<unsigned char>(s[a]))) ++a;
  while (b > a && std::isspace(static_cast<unsigned char>(s[b - 1]))) --b;
  return s.substr(a, b - a);
}

[[noreturn]] void bad(const std::string& key, const std::string& value, const char* expected) {
  throw std::runtime_error("--set " + key + "=" + value + ": expected " + expected);
}

bool parseDouble(const std::string& text, double* out) {
  const std::string t = trim(text);
  if (t.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(t.c_str(), &end);
  if (*end != '\0' || errno == ERANGE) return false;
  *out = v;
  return true;
}

}  // namespace

void ParamOverlay::addAssignment(const std::string& assignment) {
  const std::size_t eq = assignment.find('=');
  if (eq == std::string::npos) throw std::invalid_argument("--set expects key=value, got '" + assignment + "'");
  const std::string key = trim(assignment.substr(0, eq));
  if (key.empty()) throw std::invalid_argument("--set expects key=value, got '" + assignment + "'");
  overrides_[key] = trim(assignment.substr(eq + 1));
}

const std::string* ParamOverlay::find(const std::string& key) const {
  const auto it = overrides_.find(key);
  if (it == overrides_.end()) return nullptr;
  used_.insert(key);
  return &it->second;
}

bool ParamOverlay::get(const std::string& key, double* value) const {
  if (const std::string* s = find(key)) {
    if (!parseDouble(*s, value)) bad(key, *s, "a number");
    return true;
  }
  return base_ != nullptr && base_->get(key, value);
}

bool ParamOverlay::get(const std::string& key, int* value) const {
  if (const std::string* s = find(key)) {
    const std::string t = trim(*s);
    char* end = nullptr;
    errno = 0;
    const long v = t.empty() ? 0 : std::strtol(t.c_str(), &end, 10);
    if (t.empty() || *end != '\0' || errno == ERANGE || v < -2147483647L || v > 2147483647L) {
      bad(key, *s, "an integer");
    }
    *value = static_cast<int>(v);
    return true;
  }
  return base_ != nullptr && base_->get(key, value);
}

bool ParamOverlay::get(const std::string& key, bool* value) const {
  if (const std::string* s = find(key)) {
    std::string t = trim(*s);
    std::transform(t.begin(), t.end(), t.begin(), [](unsigned char c) { return std::tolower(c); });
    if (t == "true" || t == "1" || t == "yes" || t == "on") {
      *value = true;
    } else if (t == "false" || t == "0" || t == "no" || t == "off") {
      *value = false;
    } else {
      bad(key, *s, "true or false");
    }
    return true;
  }
  return base_ != nullptr && base_->get(key, value);
}

bool ParamOverlay::get(const std::string& key, std::string* value) const {
  if (const std::string* s = find(key)) {
    *value = *s;
    return true;
  }
  return base_ != nullptr && base_->get(key, value);
}

bool ParamOverlay::get(const std::string& key, std::vector<double>* value) const {
  if (const std::string* s = find(key)) {
    std::string t = trim(*s);
    if (!t.empty() && t.front() == '[') t.erase(0, 1);
    if (!t.empty() && t.back() == ']') t.pop_back();
    std::vector<double> out;
    std::size_t start = 0;
    while (!trim(t).empty()) {
      const std::size_t comma = t.find(',', start);
      const std::string item = t.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
      double v = 0.0;
      if (!parseDouble(item, &v)) bad(key, *s, "a list of numbers such as [0.2,-0.1,0.97]");
      out.push_back(v);
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
    *value = out;
    return true;
  }
  return base_ != nullptr && base_->get(key, value);
}

std::string ParamOverlay::origin() const {
  return base_ != nullptr ? base_->origin() + " + command line" : std::string("command line");
}

std::vector<std::string> ParamOverlay::unusedOverrides() const {
  std::vector<std::string> unused;
  for (const auto& kv : overrides_) {
    if (used_.count(kv.first) == 0) unused.push_back(kv.first);
  }
  return unused;
}

void applyCommandLine(const std::vector<std::string>& sets, const std::string& mode, int width_px,
                      EstimatorParams* params) {
  if (!sets.empty()) {
    ParamOverlay overrides(nullptr);
    for (const std::string& kv : sets) overrides.addAssignment(kv);
    loadEstimatorParams(overrides, params);
    const std::vector<std::string> unused = overrides.unusedOverrides();
    if (!unused.empty()) {
      std::string list;
      for (const std::string& k : unused) list += (list.empty() ? "" : ", ") + k;
      throw std::invalid_argument("unknown parameter key(s) in --set: " + list +
                                  " (use the keys of config/estimator.yaml)");
    }
  }
  if (!mode.empty()) params->mode = parseUpdateMode(mode);
  if (width_px > 0) {
    if (params->mode == UpdateMode::kFeature) {
      params->feature.working_width_px = width_px;
    } else {
      params->preprocess.working_width_px = width_px;
    }
  }
}

}  // namespace eval
}  // namespace diekf
