// libpk: errors for bad input at the API boundary.
//
// Bad input (a malformed dataset, an unknown model or parameter name, an
// event the model cannot take) throws pk::InputError. It names where the
// problem is: the file, the 1-based line and column, and the offending text,
// so an application can print one clear line and exit non-zero.
//
// Numerical trouble is *not* an InputError: routines that compute report it
// through their result or summary structs instead of throwing.
#ifndef PK_ERROR_H_
#define PK_ERROR_H_

#include <stdexcept>
#include <string>
#include <vector>

namespace pk {

class InputError : public std::runtime_error {
 public:
  /// `file` may be empty (input that did not come from a file); `line` and
  /// `column` are 1-based, 0 when unknown.
  InputError(std::string file, int line, int column, std::string message);
  /// An error with no place: a bad option or an inconsistent request.
  explicit InputError(std::string message);

  const std::string& file() const { return file_; }
  int line() const { return line_; }
  int column() const { return column_; }
  /// The message without the location prefix.
  const std::string& message() const { return message_; }

 private:
  std::string file_;
  int line_;
  int column_;
  std::string message_;
};

/// The candidate closest to a mistyped `name` (case-insensitive edit distance at most 2, or a
/// third of the name's length), or "" when none is close: for "did you mean …?" in messages.
std::string ClosestName(const std::string& name, const std::vector<std::string>& candidates);

}  // namespace pk

#endif  // PK_ERROR_H_
