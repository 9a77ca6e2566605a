// The likelihood of a censored sample (Beal's M3), in the standard normal's
// terms (not installed). docs/fitting.md derives what is used here.
#ifndef PK_SRC_CENSORING_H_
#define PK_SRC_CENSORING_H_

#include "pk/dataset.h"

namespace pk {
namespace internal {

/// The censoring of sample `r` from the CENS column (index `cens_col` into
/// Record::extra, or -1 without one): 0 (a value, also for a missing entry), 1
/// (DV is an upper limit: the value lies below it, e.g. BLQ) or -1 (DV is a
/// lower limit). Throws pk::InputError, naming the line and column, for another
/// value; for a censored sample when `likelihood` is false (least squares has
/// no term for it); and for a LIMIT column's value on a censored sample
/// (interval censoring is not supported).
int CheckedCensoring(const Dataset& data, const Record& r, int cens_col, bool likelihood);

/// log Φ(z) and the inverse Mills ratio h(z) = φ(z)/Φ(z) = d log Φ(z)/dz, with
/// full relative accuracy for every finite z: from erfc where Φ(z) is not tiny,
/// and from the continued fraction of Φ(z)/φ(z) below z = −5, where Φ(z)
/// underflows long before log Φ(z) does. At z = +∞, log Φ = 0 and h = 0.
void LogNormalCdf(double z, double* log_cdf, double* mills);

/// The expected Fisher information of one sample that is censored at a limit L
/// when it falls beyond it (the Tobit model): y ~ N(μ, σ²), observed when
/// s·(L − y) < 0 and otherwise only known to lie beyond L. With z = s(L − μ)/σ,
/// this is σ² times the 2×2 information in (μ, σ):
///   i_mm = φh + Q + zφ,  i_ss = z²φh + 2Q + (z³ + z)φ,  i_ms = s[zφh + (z² + 1)φ],
/// with φ = φ(z), h = φ(z)/Φ(z) and Q = 1 − Φ(z), the probability of a value.
/// It tends to (1, 2, 0) as z → −∞ (never censored) and to 0 as z → +∞.
void CensoredInformation(double z, int s, double* i_mm, double* i_ms, double* i_ss);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_CENSORING_H_
