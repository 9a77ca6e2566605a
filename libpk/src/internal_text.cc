#include "internal_text.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "pk/output.h"

namespace pk {
namespace internal {

// ASCII only, whatever the C locale: names are ASCII, and a program that embeds libpk may have set a
// locale whose toupper maps other bytes (and calls through it cost more than the comparison).
std::string ToUpper(std::string s) {
  for (char& c : s) c = AsciiUpper(c);
  return s;
}

std::string ToLower(std::string s) {
  for (char& c : s) {
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
  }
  return s;
}

std::vector<std::string> OmegaArguments(const std::string& upper) {
  if (upper.rfind("OMEGA(", 0) != 0 || upper.back() != ')') return {};
  const std::string inside = upper.substr(6, upper.size() - 7);
  const size_t comma = inside.find(',');
  if (comma == std::string::npos) return {inside};
  return {inside.substr(0, comma), inside.substr(comma + 1)};
}

std::string Trim(const std::string& s) {
  size_t b = 0, e = s.size();
  while (b < e && AsciiSpace(s[b])) ++b;
  while (e > b && AsciiSpace(s[e - 1])) --e;
  return s.substr(b, e - b);
}

bool ParseDouble(const std::string& text, double* value) {
  return pk::ParseNumber(text, value);
}

std::string Printable(const std::string& text) {
  std::string out;
  for (size_t i = 0; i < text.size(); ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    // A UTF-8 sequence stays as it is; a control character or a stray byte is written as \xNN.
    size_t n = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
    for (size_t k = 1; k < n; ++k) {
      if (i + k >= text.size() || (static_cast<unsigned char>(text[i + k]) >> 6) != 0x2) n = 0;
    }
    if (n == 1 && c >= 0x20 && c != 0x7F) {
      out += text[i];
    } else if (n > 1) {
      out += text.substr(i, n);
      i += n - 1;
    } else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02X", c);
      out += buf;
    }
  }
  return out;
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
