// The text of a number as libpk writes it (pk::FormatNumber). {fmt} is sealed in this file.
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include <fmt/format.h>

#include "../internal_text.h"

namespace pk {
namespace internal {
namespace {

const char* DigitPair(unsigned k) {  // k < 100: its two decimal digits
  static const char kPairs[] =
      "00010203040506070809101112131415161718192021222324252627282930313233343536373839"
      "40414243444546474849505152535455565758596061626364656667686970717273747576777879"
      "8081828384858687888990919293949596979899";
  return kPairs + 2 * k;
}

// Exactly eight digits of v < 10⁸ at p: four pairs from two independent halves, not a chain of
// dependent divisions (a digit a division was a good part of the time).
void WriteEightDigits(std::uint32_t v, char* p) {
  const std::uint32_t high = v / 10000, low = v % 10000;
  std::copy_n(DigitPair(high / 100), 2, p);
  std::copy_n(DigitPair(high % 100), 2, p + 2);
  std::copy_n(DigitPair(low / 100), 2, p + 4);
  std::copy_n(DigitPair(low % 100), 2, p + 6);
}

// The shortest decimal that reads back as |value| (a normal double): its digits (into buffer; the
// result points at the first) and the exponent of the first, value = ±d₁.d₂…d_n × 10^exponent.
// {fmt}'s Dragonbox gives the digits as an integer below 10¹⁷ in about 14 ns; libstdc++'s
// std::to_chars (Ryū) takes about 60. Dragonbox sits in {fmt}'s detail namespace (Debian 12: fmt 9.1;
// fmt 10 and 11 keep it); FormatNumber's test against the printf definition on 400 000 doubles guards
// the use. All 17 places are written and the leading zeros skipped; '0's follow the digits to the
// buffer's end (48 bytes), so the layout below copies fixed lengths.
const char* ShortestDigits(double value, char (&buffer)[48], int* count, int* exponent) {
  static const std::uint64_t kPowers[18] = {1,
                                            10,
                                            100,
                                            1000,
                                            10000,
                                            100000,
                                            1000000,
                                            10000000,
                                            100000000,
                                            1000000000,
                                            10000000000,
                                            100000000000,
                                            1000000000000,
                                            10000000000000,
                                            100000000000000,
                                            1000000000000000,
                                            10000000000000000,
                                            100000000000000000};
  const auto decimal = fmt::detail::dragonbox::to_decimal(std::fabs(value));
  const std::uint64_t m = decimal.significand;  // 0 < m < 10¹⁷
  buffer[0] = static_cast<char>('0' + m / 10000000000000000u);
  WriteEightDigits(static_cast<std::uint32_t>(m / 100000000 % 100000000), buffer + 1);
  WriteEightDigits(static_cast<std::uint32_t>(m % 100000000), buffer + 9);
  std::memset(buffer + 17, '0', sizeof buffer - 17);
  // Digits of m without a loop: log10 from the bit length (1233/4096 ≈ log10 2), corrected once.
  const int t = ((64 - __builtin_clzll(m)) * 1233) >> 12;
  *count = t + (m >= kPowers[t] ? 1 : 0);
  *exponent = decimal.exponent + *count - 1;
  return buffer + 17 - *count;
}

}  // namespace

// printf's %.Ng and strtod follow the C locale (a program that embeds libpk and sets a German one
// would write and read 0,25); this does not.
//
// The text is printf's %.Pg with the least P >= 6 that reads back. That P is the digit count d of
// the shortest round-trip form when d > 6, and 6 otherwise; and the digits are the shortest form's,
// since a double's rounding interval (about 1e-16 wide) holds at most one decimal of d <= 17
// digits that is nearest, for normal numbers whose interval is symmetric, that is all but the
// powers of two (see FormatNumber's test against that definition, every power of two included). So
// the shortest digits and their exponent give the text, in %g's layout.
char* WriteNumber(double value, char* out) {
  if (!std::isfinite(value)) return std::to_chars(out, out + 40, value).ptr;
  std::uint64_t bits = 0;
  std::memcpy(&bits, &value, sizeof bits);
  const bool power_of_two = value != 0 && (bits & ((std::uint64_t{1} << 52) - 1)) == 0;
  if (value != 0 && (std::fabs(value) < std::numeric_limits<double>::min() || power_of_two)) {
    // A subnormal's rounding interval is wide: several 6-digit decimals may read back, and %.6g
    // takes the nearest, not the shortest. A power of two's is lopsided (the gap below is half the
    // gap above): the shortest decimal may lie in the wide half, where the correctly rounded one of
    // as many digits does not read back (2⁻²⁴ needs 17 digits, not 16). The definition itself, then.
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
  char buffer[48];
  int d = 0, exponent = 0;
  const char* const digits = ShortestDigits(value, buffer, &d, &exponent);
  const int precision = std::max(6, d);
  // Fixed-length copies (the caller's 48 bytes of room allow them), each followed by the true length:
  // copies of varying length branch unpredictably, and were half of this function's time.
  if (exponent < -4 || exponent >= precision) {  // %g's scientific form: d.ddde±XX
    *o++ = digits[0];
    if (d > 1) {
      *o++ = '.';
      std::memcpy(o, digits + 1, 16);
      o += d - 1;
    }
    *o++ = 'e';
    *o++ = exponent < 0 ? '-' : '+';
    const int e = std::abs(exponent);
    if (e >= 100) *o++ = static_cast<char>('0' + e / 100);
    std::memcpy(o, DigitPair(static_cast<unsigned>(e % 100)), 2);
    return o + 2;
  }
  if (exponent < 0) {  // 0.000ddd
    std::memcpy(o, "0.000", 5);
    o += 1 - exponent;
    std::memcpy(o, digits, 17);
    return o + d;
  }
  std::memcpy(o, digits, 17);  // the integer part, the buffer's '0's past the last digit
  o += exponent + 1;
  if (d > exponent + 1) {
    *o++ = '.';
    std::memcpy(o, digits + exponent + 1, 16);
    o += d - exponent - 1;
  }
  return o;
}

}  // namespace internal
}  // namespace pk
