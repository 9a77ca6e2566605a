#include "pk/output.h"

#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>

#include <fcntl.h>
#include <signal.h>
#include <sys/types.h>
#include <unistd.h>

#include <filesystem>

namespace pk {
namespace {

// fsync on a file, or on a directory (for the rename in it); false with errno on failure.
bool SyncPath(const std::string& path, bool directory) {
  const int fd = ::open(path.c_str(), directory ? (O_RDONLY | O_DIRECTORY) : O_RDONLY);
  if (fd < 0) return false;
  const bool ok = ::fsync(fd) == 0;
  ::close(fd);
  return ok;
}

}  // namespace

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
  // The contents reach the disk before the name does, and the new name before we return: a crash
  // leaves the old file or the new one, never an empty or partial one under the final name.
  if (!SyncPath(tmp, false)) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": write failed (fsync: " + std::strerror(errno) + ")");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": cannot replace the file");
  }
  const size_t slash = path.find_last_of('/');
  SyncPath(slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash)), true);
}

void RemoveStaleTemporaries(const std::string& directory) {
  std::error_code error;
  for (const auto& entry : std::filesystem::directory_iterator(directory, error)) {
    const std::string name = entry.path().filename().string();
    const size_t at = name.rfind(".tmp.");
    if (at == std::string::npos || at + 5 >= name.size()) continue;
    const std::string digits = name.substr(at + 5);
    if (digits.find_first_not_of("0123456789") != std::string::npos || digits.size() > 9) continue;
    const pid_t pid = static_cast<pid_t>(std::stol(digits));
    // A temporary of a process that is gone (killed between its write and its rename) is debris.
    if (pid != ::getpid() && ::kill(pid, 0) != 0 && errno == ESRCH) std::filesystem::remove(entry.path(), error);
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
