// Output sets: a manifest written last marks the files of one run as complete (pk/output.h).
#include <boost/crc.hpp>

#include <algorithm>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

#include <unistd.h>

#include "io/csv_lines.h"
#include "pk/error.h"
#include "pk/output.h"

namespace pk {

const char* const kManifestName = "MANIFEST";

namespace {

namespace fs = std::filesystem;

struct Fingerprint {
  unsigned long long bytes = 0;
  unsigned crc32 = 0;
};

// Size and CRC-32 of the file at `path`; false when it cannot be read.
bool Fingerprinted(const std::string& path, Fingerprint* out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  boost::crc_32_type crc;
  char buf[1 << 16];
  Fingerprint f;
  while (in) {
    in.read(buf, sizeof buf);
    const auto n = static_cast<size_t>(in.gcount());
    crc.process_bytes(buf, n);
    f.bytes += n;
  }
  f.crc32 = crc.checksum();
  *out = f;
  return true;
}

std::string Hex(unsigned v) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%08x", v);
  return buf;
}

// The files `directory`'s manifest lists, when it has one. Names with a path are not a run's own
// (a manifest edited by hand), and are left out.
std::vector<std::string> ListedFiles(const std::string& directory) {
  std::vector<std::string> names;
  std::ifstream in(directory + "/" + kManifestName);
  std::string line;
  while (std::getline(in, line)) {
    const auto fields = internal::SplitCsvLine(line);
    if (fields.size() != 3 || fields[0] == "FILE" || fields[0].empty() || fields[0][0] == '#') continue;
    if (fields[0].find('/') != std::string::npos || fields[0] == "." || fields[0] == "..") continue;
    names.push_back(fields[0]);
  }
  return names;
}

std::string DirectoryOf(const std::string& path) {
  const fs::path parent = fs::path(path).parent_path();
  return parent.empty() ? "." : parent.string();
}

}  // namespace

void CompleteOutputSet(const std::string& directory, const std::vector<std::string>& files,
                       const std::string& program) {
  std::ostringstream text;
  const std::time_t now = std::time(nullptr);
  char when[32];
  std::strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&now));
  text << "# The files of one " << program << " run (" << when << ", process " << ::getpid()
       << "), complete: a reader refuses a file of this directory that is not listed here as it is now.\n";
  text << "FILE,BYTES,CRC32\n";
  for (const std::string& name : files) {
    Fingerprint f;
    if (!Fingerprinted(directory + "/" + name, &f)) throw std::runtime_error(directory + "/" + name + ": cannot read back");
    text << name << "," << f.bytes << "," << Hex(f.crc32) << "\n";
  }
  const std::vector<std::string> previous = ListedFiles(directory);
  WriteFileAtomically(directory + "/" + kManifestName, text.str());
  // The last run's files that this one did not write again (a plot of a subject the new data lack,
  // say) must not stay beside the new set. One that cannot be removed is listed nowhere now, and
  // readers refuse it, so the set stays whole and the run is not failed for it.
  for (const std::string& name : previous) {
    if (std::find(files.begin(), files.end(), name) == files.end()) std::remove((directory + "/" + name).c_str());
  }
}

void CheckOutputSet(const std::string& path, const std::string& program, const std::string& marker) {
  const std::string dir = DirectoryOf(path);
  const std::string name = fs::path(path).filename().string();
  const std::string manifest = dir + "/" + kManifestName;
  std::ifstream in(manifest);
  if (!in) {
    std::error_code error;
    if (fs::exists(dir + "/" + marker, error)) {
      throw InputError(path, 0, 0, "the " + program + " output set in " + dir + " has no " + kManifestName +
                                       ": the run that wrote it did not finish, so its files may come from two "
                                       "runs; run " + program + " again");
    }
    return;  // a table of the user's own
  }
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    const auto fields = internal::SplitCsvLine(line);
    if (fields.size() != 3 || fields[0] != name) continue;
    Fingerprint now;
    if (!Fingerprinted(path, &now)) throw InputError(path, 0, 0, "cannot open the file");
    if (std::to_string(now.bytes) != fields[1] || Hex(now.crc32) != fields[2]) {
      throw InputError(path, 0, 0, "differs from the file " + program + " wrote (" + manifest + " line " +
                                       std::to_string(number) + " lists " + fields[1] + " bytes, CRC-32 " +
                                       fields[2] + "): it was changed, or comes from another run");
    }
    return;
  }
  throw InputError(path, 0, 0, "is not one of the files of the " + program + " run listed in " + manifest);
}

}  // namespace pk
