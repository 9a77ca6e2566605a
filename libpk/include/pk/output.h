// libpk: writing results whole or not at all.
#ifndef PK_OUTPUT_H_
#define PK_OUTPUT_H_

#include <string>

namespace pk {

/// Writes `contents` to a temporary file beside `path`, then renames it over
/// `path`, so a reader never sees a partial file. Throws std::runtime_error
/// naming the path on failure.
void WriteFileAtomically(const std::string& path, const std::string& contents);

/// Removes the "<name>.tmp.<pid>" files that WriteFileAtomically left in `directory` when its
/// process was killed between writing and renaming (the process is gone).
void RemoveStaleTemporaries(const std::string& directory);

/// Shortest decimal text that reads back as the same double ("%.17g" trimmed), in the
/// same form whatever the C locale.
std::string FormatNumber(double value);

/// A finite decimal number (surrounding spaces and one leading '+' allowed), read the same
/// whatever the C locale; false for anything else, hexadecimal, infinities and NaN included.
bool ParseNumber(const std::string& text, double* value);

}  // namespace pk

#endif  // PK_OUTPUT_H_
