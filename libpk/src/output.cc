#include "pk/output.h"

#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>

#include <unistd.h>

namespace pk {

void WriteFileAtomically(const std::string& path, const std::string& contents) {
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  {
    errno = 0;
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) {
      // errno says why (a missing directory, permissions) on the systems libpk builds on.
      const std::string why = errno != 0 ? std::string(": ") + std::strerror(errno) : std::string();
      throw std::runtime_error(path + ": cannot write (could not create " + tmp + why + ")");
    }
    out << contents;
    out.flush();
    if (!out) {
      std::remove(tmp.c_str());
      throw std::runtime_error(path + ": write failed");
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": cannot replace the file");
  }
}

// printf's %.Ng and strtod follow the C locale (a program that embeds libpk and sets a German one
// would write and read 0,25); std::to_chars and std::from_chars do not.
std::string FormatNumber(double value) {
  char buf[40];
  for (int precision = 6; precision <= 17; ++precision) {
    const auto end = std::to_chars(buf, buf + sizeof buf, value, std::chars_format::general, precision).ptr;
    double back = 0;
    const auto parsed = std::from_chars(buf, end, back);
    if ((parsed.ec == std::errc() && back == value) || precision == 17) return std::string(buf, end);
  }
  return "";
}

bool ParseNumber(const std::string& text, double* value) {
  const char* begin = text.data();
  const char* end = begin + text.size();
  while (begin < end && std::isspace(static_cast<unsigned char>(*begin))) ++begin;
  while (end > begin && std::isspace(static_cast<unsigned char>(end[-1]))) --end;
  const bool plus = begin < end && *begin == '+';  // from_chars takes a minus sign only
  if (plus) ++begin;
  if (begin == end || (plus && (*begin == '+' || *begin == '-'))) return false;
  double v = 0;
  const auto r = std::from_chars(begin, end, v, std::chars_format::general);
  if (r.ec != std::errc() || r.ptr != end || !std::isfinite(v)) return false;
  *value = v;
  return true;
}

}  // namespace pk
