// What a singular information matrix leaves undetermined, in words (not installed).
#ifndef PK_SRC_IDENTIFIABILITY_H_
#define PK_SRC_IDENTIFIABILITY_H_

#include <string>
#include <vector>

#include <Eigen/Core>

namespace pk {
namespace internal {

/// `info` is the information matrix on the optimiser's scale φ, singular with
/// `nullity` null directions; `names` its parameters; ds_dphi maps φ to the
/// estimation scale s (log θ when `log_scale`, else θ), on which directions are
/// shown. Says which parameters do not affect the predictions (a zero diagonal
/// entry) and which are not determined separately: one null direction with its
/// proportions, several by the parameters they involve (any basis of them is as
/// good). Empty when there is nothing to name.
std::string Unidentified(const Eigen::MatrixXd& info, int nullity, const std::vector<std::string>& names,
                         const Eigen::VectorXd& ds_dphi, bool log_scale);

/// The coordinate that dominates a null direction of a residual Jacobian J
/// (m×n), or -1 when J is regular. J counts as singular when a column is zero or
/// when, its columns scaled to unit norm, σ_min ≤ `threshold`·σ_max. The
/// coordinate is the one with the largest share |v_j| of the null vector v on
/// the optimiser's scale; among shares within 1e-6 of each other, the last.
int NullCoordinate(const Eigen::MatrixXd& jacobian, double threshold, double* ratio = nullptr);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_IDENTIFIABILITY_H_
