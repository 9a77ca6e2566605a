// Reading CSV text line by line, shared by the dataset and estimates readers (not installed).
#ifndef PK_SRC_IO_CSV_LINES_H_
#define PK_SRC_IO_CSV_LINES_H_

#include <string>
#include <utility>
#include <vector>

namespace pk {
namespace internal {

/// (1-based line number, text) of every line.
using NumberedLines = std::vector<std::pair<int, std::string>>;

/// The lines of the file at `path`; throws pk::InputError when it cannot be read.
NumberedLines ReadLines(const std::string& path);
/// The lines of `text`, split as ReadLines splits a file's.
NumberedLines TextLines(const std::string& text, const std::string& source = "text");

/// Splits one CSV line into trimmed fields. Fields may be wrapped in double
/// quotes ("" inside is a quote).
std::vector<std::string> SplitCsvLine(const std::string& line);
/// The same into `fields`, reusing its strings: no allocation per field once they are long enough.
void SplitCsvLine(const std::string& line, std::vector<std::string>* fields);

/// A blank line, or a comment (first non-blank character '#').
bool IsSkippedLine(const std::string& line);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_IO_CSV_LINES_H_
