#include "pk/output.h"

#include <cerrno>
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

std::string FormatNumber(double value) {
  char buf[40];
  for (int precision = 6; precision <= 17; ++precision) {
    std::snprintf(buf, sizeof buf, "%.*g", precision, value);
    double back = 0;
    if (std::sscanf(buf, "%lg", &back) == 1 && back == value) break;
  }
  return buf;
}

}  // namespace pk
