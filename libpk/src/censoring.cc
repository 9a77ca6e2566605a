#include "censoring.h"

#include <cmath>
#include <limits>
#include <string>

#include "pk/error.h"
#include "pk/output.h"

namespace pk {
namespace internal {
namespace {

constexpr double kLogSqrt2Pi = 0.91893853320467274178;  // ½ log 2π

double NormalDensity(double z) { return std::exp(-0.5 * z * z - kLogSqrt2Pi); }

// Φ(−x)/φ(x) for x ≥ 5 by its continued fraction 1/(x + 1/(x + 2/(x + 3/(x + …)))),
// evaluated from the tail; 60 terms reach rounding at x = 5 (the tests compare
// with erfcl) and far fewer would do beyond.
double MillsRatio(double x) {
  double t = x;
  for (int k = 60; k >= 1; --k) t = x + k / t;
  return 1 / t;
}

}  // namespace

int CheckedCensoring(const Dataset& data, const Record& r, int cens_col, bool likelihood) {
  if (cens_col < 0 || std::isnan(r.extra[static_cast<size_t>(cens_col)])) return 0;
  const double c = r.extra[static_cast<size_t>(cens_col)];
  const int column = data.ColumnNumber("CENS");
  if (c != 0 && c != 1 && c != -1) {
    throw InputError(data.source, r.line, column,
                     "CENS is " + FormatNumber(c) + ": it must be 0 (a value), 1 (DV is the limit the value lies " +
                         "below, e.g. BLQ) or -1 (DV is the limit it lies above)");
  }
  if (c == 0) return 0;
  if (!likelihood) {
    throw InputError(data.source, r.line, column,
                     "a censored sample (CENS=" + FormatNumber(c) + ") needs maximum likelihood (--error additive, " +
                         "proportional, combined or exponential; Beal's M3): least squares has no term for a value known only " +
                         "to lie beyond a limit. To leave it out instead (M1), give it MDV=1");
  }
  const int limit = data.ExtraColumn("LIMIT");
  if (limit >= 0 && !std::isnan(r.extra[static_cast<size_t>(limit)])) {
    throw InputError(data.source, r.line, data.ColumnNumber("LIMIT"),
                     "LIMIT (a censoring interval, Beal's M4) is not supported: a censored sample lies anywhere "
                     "beyond its DV; leave LIMIT empty ('.') on censored rows");
  }
  return static_cast<int>(c);
}

void LogNormalCdf(double z, double* log_cdf, double* mills) {
  if (z == std::numeric_limits<double>::infinity()) {
    *log_cdf = 0;
    *mills = 0;
  } else if (z >= -5) {
    // Φ(z) = ½ erfc(−z/√2); for z > 0, log Φ = log1p(−Q) keeps Q's digits.
    const double cdf = 0.5 * std::erfc(-z * M_SQRT1_2);
    *log_cdf = z > 0 ? std::log1p(-0.5 * std::erfc(z * M_SQRT1_2)) : std::log(cdf);
    *mills = NormalDensity(z) / cdf;
  } else {
    const double r = MillsRatio(-z);  // Φ(z)/φ(z)
    *log_cdf = -0.5 * z * z - kLogSqrt2Pi + std::log(r);
    *mills = 1 / r;
  }
}

void CensoredInformation(double z, int s, double* i_mm, double* i_ms, double* i_ss) {
  if (std::isinf(z)) {
    *i_mm = z > 0 ? 0.0 : 1.0;
    *i_ms = 0;
    *i_ss = z > 0 ? 0.0 : 2.0;
    return;
  }
  double log_cdf, h;
  LogNormalCdf(z, &log_cdf, &h);
  const double phi = NormalDensity(z);
  const double q = 0.5 * std::erfc(z * M_SQRT1_2);  // 1 − Φ(z)
  *i_mm = phi * h + q + z * phi;
  *i_ss = z * z * phi * h + 2 * q + (z * z * z + z) * phi;
  *i_ms = s * (z * phi * h + (z * z + 1) * phi);
}

}  // namespace internal
}  // namespace pk
