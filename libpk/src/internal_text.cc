#include "internal_text.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace pk {
namespace internal {

std::string ToUpper(std::string s) {
  for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

std::string ToLower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::string Trim(const std::string& s) {
  size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return s.substr(b, e - b);
}

bool ParseDouble(const std::string& text, double* value) {
  if (text.empty()) return false;
  const char* begin = text.c_str();
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(begin, &end);
  if (end != begin + text.size() || errno == ERANGE || !std::isfinite(v)) return false;
  *value = v;
  return true;
}

std::string Join(const std::vector<std::string>& items, const std::string& separator) {
  std::string out;
  for (size_t i = 0; i < items.size(); ++i) {
    if (i) out += separator;
    out += items[i];
  }
  return out;
}

std::string Num(double v, const char* fmt) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}

std::string Cell(double v, const char* fmt, int width) {
  const std::string text = std::isfinite(v) ? Num(v, fmt) : "–";
  const int columns = std::isfinite(v) ? static_cast<int>(text.size()) : 1;
  return std::string(static_cast<size_t>(std::max(0, width - columns)), ' ') + text;
}

std::string LowerTriangle(const std::vector<std::string>& names, const Eigen::MatrixXd& m, int name_width) {
  std::string out;
  for (size_t i = 0; i < names.size(); ++i) {
    out += "  " + names[i] + std::string(static_cast<size_t>(std::max(0, name_width - static_cast<int>(names[i].size()))), ' ');
    for (size_t j = 0; j <= i; ++j) out += " " + Cell(m(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)), "%.3f", 7);
    out += "\n";
  }
  return out;
}

}  // namespace internal
}  // namespace pk
