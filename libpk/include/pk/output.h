// libpk: writing results whole or not at all, and numbers as text.
#ifndef PK_OUTPUT_H_
#define PK_OUTPUT_H_

#include <string>
#include <vector>

namespace pk {

/// A file written whole or not at all, in pieces: the text goes to a temporary file
/// "<path>.tmp.<pid>" as it is written (so memory does not grow with the file), and Commit()
/// syncs it to disk, renames it over `path` and syncs the directory. Destroyed without Commit()
/// (an error, an exception), it removes the temporary and leaves any earlier file at `path`
/// untouched. A `path` that is a device or a pipe (/dev/null, /dev/stdout) is written in place.
/// Failures throw std::runtime_error naming `path`.
class AtomicFile {
 public:
  explicit AtomicFile(std::string path);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  void Write(const char* data, size_t size);
  void Write(const std::string& text) { Write(text.data(), text.size()); }
  void Commit();
  const std::string& path() const { return path_; }

 private:
  std::string path_, temporary_;
  int fd_ = -1;
  size_t written_ = 0, flushing_ = 0;  // bytes written; bytes whose writeback has been started
};

/// Writes `contents` to `path` through an AtomicFile, so a reader never sees a partial file.
void WriteFileAtomically(const std::string& path, const std::string& contents);

/// Removes the "<name>.tmp.<pid>" files that an AtomicFile left in `directory` when its
/// process was killed between writing and renaming (the process is gone).
void RemoveStaleTemporaries(const std::string& directory);

// ---- Output sets.
//
// A program that writes several files that belong together (pkfit's estimates, details,
// predictions and report) marks the set complete with a manifest, written last: MANIFEST in
// the directory lists each file of the run with its size and CRC-32, and a reader accepts a
// file only as the manifest lists it. A new run writes its files over the last run's and then
// its own manifest over the last one, so while it runs (or if it is killed half-way) a file it
// has rewritten is refused, and one it has not yet touched, or rewrote byte for byte (pkpop's
// estimates when it writes its set again with a VPC), stays readable as the last complete set's:
// a killed run loses none of the last set's files it had not rewritten. A directory whose first
// run was killed has no manifest; readers refuse it by a marker file of the program's
// (CheckOutputSet). Not handled: two programs writing one directory at once (there is no lock), a
// reader that checks two files while a run completes its set between the checks (it could pair
// files of two runs), and a killed run's new files, which no manifest lists and nothing removes
// (readers refuse them).

/// The manifest's file name, "MANIFEST".
extern const char* const kManifestName;

/// Writes `directory`'s manifest for `files` (names within the directory, already written),
/// with a line naming `program`, in place of the last run's; then removes the files the last
/// manifest listed that `files` do not (they must not stay beside the new set). Other files of
/// the directory are left alone.
void CompleteOutputSet(const std::string& directory, const std::vector<std::string>& files,
                       const std::string& program);

/// Checks that `path` belongs to a complete output set: when its directory has a manifest, the
/// file must be listed with the size and CRC-32 it has now; when it has none, the directory
/// must not look like an output set of `program` (a `marker` file, such as pkfit's
/// fit_details.csv, beside it). Throws pk::InputError naming the file and what is wrong; a
/// table written by hand in a directory of its own passes.
void CheckOutputSet(const std::string& path, const std::string& program, const std::string& marker);

// ---- Numbers as text.

/// Shortest decimal text that reads back as the same double ("%.17g" trimmed: %.Pg with the
/// least P ≥ 6 that reads back), in the same form whatever the C locale.
std::string FormatNumber(double value);

/// Appends FormatNumber(value) to `out` without a temporary string.
void AppendNumber(std::string* out, double value);

/// A finite decimal number (surrounding spaces and one leading '+' allowed), read the same
/// whatever the C locale; false for anything else, hexadecimal, infinities and NaN included.
bool ParseNumber(const std::string& text, double* value);

}  // namespace pk

#endif  // PK_OUTPUT_H_
