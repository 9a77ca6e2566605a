// Small text helpers shared by the library's sources (not installed).
#ifndef PK_SRC_INTERNAL_TEXT_H_
#define PK_SRC_INTERNAL_TEXT_H_

#include <string>
#include <vector>

namespace pk {
namespace internal {

std::string ToUpper(std::string s);
std::string Trim(const std::string& s);
/// Parses the whole of `text` as a finite double; false if it is not one.
bool ParseDouble(const std::string& text, double* value);
std::string Join(const std::vector<std::string>& items, const std::string& separator);
/// `v` printed with the printf format `fmt`.
std::string Num(double v, const char* fmt = "%.6g");
/// A table cell of `width` columns, right-aligned; "–" when v is not finite.
std::string Cell(double v, const char* fmt, int width);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_INTERNAL_TEXT_H_
