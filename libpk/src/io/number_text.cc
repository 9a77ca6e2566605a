// The text of a number as libpk writes it (pk::FormatNumber). {fmt} is sealed in this file.
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <limits>

#include <fmt/format.h>

#include "../internal_text.h"

namespace pk {
namespace internal {
namespace {

// The shortest decimal that reads back as |value| (a normal double): its digits and the exponent of
// the first, value = ±d₁.d₂…d_n × 10^exponent. {fmt}'s Dragonbox gives the digits as an integer in
// about 14 ns; libstdc++'s std::to_chars (Ryū) takes about 60. Dragonbox sits in {fmt}'s detail
// namespace (Debian 12: fmt 9.1; fmt 10 and 11 keep it); FormatNumber's test against the printf
// definition on 400 000 doubles guards the use.
const char* DigitPair(unsigned k) {  // k < 100: its two decimal digits
  static const char kPairs[] =
      "00010203040506070809101112131415161718192021222324252627282930313233343536373839"
      "40414243444546474849505152535455565758596061626364656667686970717273747576777879"
      "8081828384858687888990919293949596979899";
  return kPairs + 2 * k;
}

// The decimal digits of m, written to end back; returns their start. Two digits a step, and a
// significand of up to 17 digits in two independent halves: a digit a division is a chain of
// dependent multiplications that dominated the time.
char* WriteDigitsBackward(std::uint64_t m, char* end) {
  char* p = end;
  std::uint32_t high;
  if (m >= 100000000) {
    auto low = static_cast<std::uint32_t>(m % 100000000);
    high = static_cast<std::uint32_t>(m / 100000000);
    for (int k = 0; k < 4; ++k, low /= 100) {
      p -= 2;
      std::copy_n(DigitPair(low % 100), 2, p);
    }
  } else {
    high = static_cast<std::uint32_t>(m);
  }
  for (; high >= 100; high /= 100) {
    p -= 2;
    std::copy_n(DigitPair(high % 100), 2, p);
  }
  if (high >= 10) {
    p -= 2;
    std::copy_n(DigitPair(high), 2, p);
  } else if (high > 0 || p == end) {
    *--p = static_cast<char>('0' + high);
  }
  return p;
}

// The shortest decimal that reads back as |value| (a normal double): its digits and the exponent of
// the first, value = ±d₁.d₂…d_n × 10^exponent. {fmt}'s Dragonbox gives the digits as an integer in
// about 14 ns; libstdc++'s std::to_chars (Ryū) takes about 60. Dragonbox sits in {fmt}'s detail
// namespace (Debian 12: fmt 9.1; fmt 10 and 11 keep it); FormatNumber's test against the printf
// definition on 400 000 doubles guards the use.
const char* ShortestDigits(double value, char (&buffer)[24], int* count, int* exponent) {
  const auto decimal = fmt::detail::dragonbox::to_decimal(std::fabs(value));
  char* const end = buffer + sizeof buffer;
  const char* const start = WriteDigitsBackward(decimal.significand, end);
  *count = static_cast<int>(end - start);
  *exponent = decimal.exponent + *count - 1;
  return start;
}

}  // namespace

// printf's %.Ng and strtod follow the C locale (a program that embeds libpk and sets a German one
// would write and read 0,25); this does not.
//
// The text is printf's %.Pg with the least P >= 6 that reads back. That P is the digit count d of
// the shortest round-trip form when d > 6, and 6 otherwise; and the digits are the shortest form's,
// since a double's rounding interval (about 1e-16 wide) holds at most one decimal of d <= 17
// digits that is nearest, for normal numbers (see FormatNumber's test against that definition). So
// the shortest digits and their exponent give the text, in %g's layout.
char* WriteNumber(double value, char* out) {
  if (!std::isfinite(value)) return std::to_chars(out, out + 40, value).ptr;
  if (value != 0 && std::fabs(value) < std::numeric_limits<double>::min()) {
    // A subnormal's rounding interval is wide: several 6-digit decimals may read back, and %.6g
    // takes the nearest, not the shortest. The definition itself, then.
    for (int precision = 6;; ++precision) {
      char* const end = std::to_chars(out, out + 40, value, std::chars_format::general, precision).ptr;
      double back = 0;
      std::from_chars(out, end, back);
      if (back == value || precision == 17) return end;
    }
  }
  char* o = out;
  if (std::signbit(value)) *o++ = '-';
  if (value == 0) {
    *o++ = '0';
    return o;
  }
  char buffer[24];
  int d = 0, exponent = 0;
  const char* const digits = ShortestDigits(value, buffer, &d, &exponent);
  const int precision = std::max(6, d);
  if (exponent < -4 || exponent >= precision) {  // %g's scientific form: d.ddde±XX
    *o++ = digits[0];
    if (d > 1) {
      *o++ = '.';
      o = std::copy(digits + 1, digits + d, o);
    }
    *o++ = 'e';
    *o++ = exponent < 0 ? '-' : '+';
    const int e = std::abs(exponent);
    if (e >= 100) *o++ = static_cast<char>('0' + e / 100);
    *o++ = static_cast<char>('0' + e / 10 % 10);
    *o++ = static_cast<char>('0' + e % 10);
    return o;
  }
  if (exponent < 0) {
    *o++ = '0';
    *o++ = '.';
    for (int k = 0; k < -exponent - 1; ++k) *o++ = '0';
    return std::copy(digits, digits + d, o);
  }
  for (int k = 0; k <= exponent; ++k) *o++ = k < d ? digits[k] : '0';
  if (d > exponent + 1) {
    *o++ = '.';
    o = std::copy(digits + exponent + 1, digits + d, o);
  }
  return o;
}

}  // namespace internal
}  // namespace pk
