#include "pk/error.h"

#include <utility>

namespace pk {
namespace {

std::string Locate(const std::string& file, int line, int column, const std::string& message) {
  std::string where = file;
  if (line > 0) where += (where.empty() ? "line " : ":") + std::to_string(line);
  if (column > 0) where += (line > 0 ? ":" : (where.empty() ? "column " : ":")) + std::to_string(column);
  return where.empty() ? message : where + ": " + message;
}

}  // namespace

InputError::InputError(std::string file, int line, int column, std::string message)
    : std::runtime_error(Locate(file, line, column, message)),
      file_(std::move(file)),
      line_(line),
      column_(column),
      message_(std::move(message)) {}

InputError::InputError(std::string message) : InputError("", 0, 0, std::move(message)) {}

}  // namespace pk
