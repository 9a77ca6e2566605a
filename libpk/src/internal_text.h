// Small text helpers shared by the library's sources (not installed).
#ifndef PK_SRC_INTERNAL_TEXT_H_
#define PK_SRC_INTERNAL_TEXT_H_

#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace pk {
namespace internal {

/// A value not computed; the tables write it as missing.
inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// A letter a–z in upper case; any other byte as it is.
inline char AsciiUpper(char c) { return c >= 'a' && c <= 'z' ? static_cast<char>(c - 'a' + 'A') : c; }
/// Character classes of ASCII, whatever the C locale (<cctype>'s follow it: under a Latin-1 or
/// Latin-5 locale isalpha accepts 'é', so a model text or a filter would read differently).
inline bool AsciiAlpha(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z'); }
inline bool AsciiDigit(char c) { return c >= '0' && c <= '9'; }
inline bool AsciiAlnum(char c) { return AsciiAlpha(c) || AsciiDigit(c); }
/// Space, tab, newline, vertical tab, form feed, carriage return.
inline bool AsciiSpace(char c) { return c == ' ' || (c >= '\t' && c <= '\r'); }
/// Upper and lower case of ASCII letters (other bytes unchanged, whatever the C locale).
std::string ToUpper(std::string s);
std::string ToLower(std::string s);
/// The text with control characters and bytes that are not UTF-8 written as \xNN, for messages
/// that quote input.
std::string Printable(const std::string& text);
std::string Trim(const std::string& s);
/// Parses the whole of `text` as a finite double; false if it is not one.
bool ParseDouble(const std::string& text, double* value);
std::string Join(const std::vector<std::string>& items, const std::string& separator);
/// `v` printed with the printf format `fmt`.
std::string Num(double v, const char* fmt = "%.6g");
/// A table cell of `width` columns, right-aligned; "–" when v is not finite.
std::string Cell(double v, const char* fmt, int width);
/// The lower triangle of a correlation matrix, a row per name (names left-aligned
/// in `name_width` columns, indented by two spaces), three decimals.
std::string LowerTriangle(const std::vector<std::string>& names, const Eigen::MatrixXd& m, int name_width);

/// A name of Ω's elements as pkpop tables them (upper case): "OMEGA(A)" → {A}, "OMEGA(A,B)" → {A, B};
/// empty for any other name.
std::vector<std::string> OmegaArguments(const std::string& upper);

/// pk::FormatNumber's text written to `out`, which has room for 48 characters (the text has at most
/// 24; fixed-length copies may write past it); returns its end.
char* WriteNumber(double value, char* out);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_INTERNAL_TEXT_H_
