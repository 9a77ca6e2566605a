#include "pk/output.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <stdexcept>

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#include <filesystem>

#include "internal_text.h"

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

AtomicFile::AtomicFile(std::string path) : path_(std::move(path)) {
  struct stat st;
  if (::stat(path_.c_str(), &st) == 0 && !S_ISREG(st.st_mode) && !S_ISDIR(st.st_mode)) {
    // A device or a pipe (/dev/null, /dev/stdout, a FIFO) is written in place: renaming a file over
    // it would replace the device with a file.
    fd_ = ::open(path_.c_str(), O_WRONLY | O_CLOEXEC);
    if (fd_ < 0) throw std::runtime_error(path_ + ": cannot write (" + std::strerror(errno) + ")");
    return;
  }
  temporary_ = path_ + ".tmp." + std::to_string(::getpid());
  fd_ = ::open(temporary_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd_ < 0) {
    throw std::runtime_error(path_ + ": cannot write (could not create " + temporary_ + ": " + std::strerror(errno) +
                             ")");
  }
}

AtomicFile::~AtomicFile() {
  if (fd_ < 0) return;
  ::close(fd_);
  if (!temporary_.empty()) ::unlink(temporary_.c_str());
}

void AtomicFile::Write(const char* data, size_t size) {
  if (fd_ < 0) throw std::logic_error(path_ + ": written after Commit()");
  while (size > 0) {
    const ssize_t n = ::write(fd_, data, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw std::runtime_error(path_ + ": write failed (" + std::strerror(errno) + ")");
    data += n;
    size -= static_cast<size_t>(n);
    written_ += static_cast<size_t>(n);
  }
  // Start the disk writes of each further 4 MB now, without waiting for them (Linux's
  // sync_file_range, advisory: an error here is fsync's to report), so that Commit's fsync finds
  // little left to write: the file is on disk almost as soon as the last row is computed.
  constexpr size_t kWritebackChunk = size_t{4} << 20;
  if (!temporary_.empty() && written_ - flushing_ >= kWritebackChunk) {
#ifdef __linux__
    ::sync_file_range(fd_, static_cast<off_t>(flushing_), static_cast<off_t>(written_ - flushing_),
                      SYNC_FILE_RANGE_WRITE);
#endif
    flushing_ = written_;
  }
}

void AtomicFile::Commit() {
  if (fd_ < 0) throw std::logic_error(path_ + ": committed twice");
  if (temporary_.empty()) {  // a device or a pipe, written in place
    const bool closed = ::close(fd_) == 0;
    fd_ = -1;
    if (!closed) throw std::runtime_error(path_ + ": write failed (" + std::strerror(errno) + ")");
    return;
  }
  // The contents reach the disk before the name does, and the new name before we return: a crash
  // leaves the old file or the new one, never an empty or partial one under the final name.
  const bool synced = ::fsync(fd_) == 0;
  const int sync_error = errno;
  const bool closed = ::close(fd_) == 0;
  fd_ = -1;
  if (!synced || !closed) {
    ::unlink(temporary_.c_str());
    throw std::runtime_error(path_ + ": write failed (" + std::strerror(synced ? errno : sync_error) + ")");
  }
  if (std::rename(temporary_.c_str(), path_.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    ::unlink(temporary_.c_str());
    throw std::runtime_error(path_ + ": cannot replace the file (" + why + ")");
  }
  const size_t slash = path_.find_last_of('/');
  SyncPath(slash == std::string::npos ? "." : (slash == 0 ? "/" : path_.substr(0, slash)), true);
}

void WriteFileAtomically(const std::string& path, const std::string& contents) {
  AtomicFile file(path);
  file.Write(contents);
  file.Commit();
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

std::string FormatNumber(double value) {
  char buf[48];
  return std::string(buf, internal::WriteNumber(value, buf));
}

void AppendNumber(std::string* out, double value) {
  char buf[48];
  out->append(buf, internal::WriteNumber(value, buf));
}

bool ParseNumber(const std::string& text, double* value) {
  const char* begin = text.data();
  const char* end = begin + text.size();
  while (begin < end && internal::AsciiSpace(*begin)) ++begin;
  while (end > begin && internal::AsciiSpace(end[-1])) --end;
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
