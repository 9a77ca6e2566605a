// The population objective over all subjects (not installed): every subject's mode from a
// warm start, in parallel, summed in subject order so that the result does not depend on the
// number of threads.
#ifndef PK_SRC_POPULATION_ENGINE_H_
#define PK_SRC_POPULATION_ENGINE_H_

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "population/conditional.h"
#include "population/packing.h"
#include "pk/population.h"

namespace pk {
namespace internal {

class PopulationEngine {
 public:
  /// `distribution` (may be null) splits the subjects across processes (pk/population.h).
  PopulationEngine(const PopulationProblem& problem, PopulationMethod method, int threads,
                   std::shared_ptr<const SubjectDistribution> distribution = nullptr);

  /// The subjects taking part (those that failed at the initial estimates are left out).
  const std::vector<bool>& included() const { return included_; }
  void Exclude(int subject) { included_[static_cast<size_t>(subject)] = false; }

  struct Result {
    bool ok = false;
    std::string message;             ///< the first failing subject and why
    double ofv = 0;
    Eigen::VectorXd per_subject;     ///< OFV_i (0 for a subject left out)
    std::vector<SubjectMode> modes;  ///< when asked for
  };
  /// OFV at p with each subject's search starting from `starts` (η̂ of a nearby point). Across
  /// processes every mode's ok, OFV_i, η̂_i and failure message are shared, but the rest of a
  /// SubjectMode (at_mode) only where it was found; `here` solves every subject in this process.
  Result Evaluate(const PopulationParameters& p, const std::vector<Eigen::VectorXd>& starts, bool keep_modes,
                  bool here = false) const;

  /// ∇OFV at x from the modes of Evaluate(packing.Unpack(x), ..., true), by the implicit
  /// function theorem on the modes (outer_gradient.h; FO's at η = 0, which does not move). Row i of *per_subject (n×size, when
  /// non-null) is ∇OFV_i, 0 for a subject left out. False with `why` naming the first subject
  /// whose gradient cannot be formed.
  /// How many subjects' second derivatives were differences of the exact first ones, and why (the
  /// first such subject of this process).
  struct Differenced {
    int subjects = 0;
    std::string reason;
  };
  bool Gradient(const Packing& packing, const Eigen::VectorXd& x, const std::vector<SubjectMode>& modes,
                Eigen::VectorXd* gradient, Eigen::MatrixXd* per_subject, std::string* why,
                Differenced* differenced = nullptr) const;

  const PopulationProblem& problem() const { return problem_; }
  PopulationMethod method() const { return method_; }
  /// PopulationOptions::exact_conditional_hessian (default true).
  void set_exact_hessian(bool exact) { exact_hessian_ = exact; }
  bool exact_hessian() const { return exact_hessian_; }
  int threads() const { return threads_; }

 private:
  const PopulationProblem& problem_;
  PopulationMethod method_;
  bool exact_hessian_ = true;
  int threads_;
  std::shared_ptr<const SubjectDistribution> distribution_;
  std::vector<bool> included_;

  bool Owns(int subject) const {
    return !distribution_ || subject % distribution_->size() == distribution_->rank();
  }
  int Owner(int subject) const { return distribution_ ? subject % distribution_->size() : 0; }
  void Share(std::vector<SubjectMode>* modes) const;
  std::vector<int> Work(bool shared) const;
};

/// The covariance step at the estimate (covariance.cc): R = ∇²OFV over the estimated natural
/// parameters, S = Σ_i ∇OFV_i ∇OFV_iᵀ, and the sandwich R⁻¹SR⁻¹; SEs, RSE%, correlations and the
/// condition number into `summary`. With `exact_gradient` (any method's implicit gradient) S is formed from the exact
/// per-subject gradients and R from central differences of the exact gradient; otherwise both
/// from central differences of the OFV. `matrix` chooses R⁻¹SR⁻¹, 2R⁻¹ or 4S⁻¹ (NONMEM's MATRIX=).
void PopulationCovariance(const PopulationEngine& engine, const Packing& packing,
                          const std::vector<Eigen::VectorXd>& starts, bool exact_gradient, CovarianceMatrix matrix,
                          PopulationSummary* summary);

/// PRED, IPRED, RES, WRES, CWRES and IWRES per sample, and the shrinkages (diagnostics.cc).
void PopulationDiagnostics(const PopulationEngine& engine, const PopulationParameters& p,
                           const std::vector<SubjectMode>& modes, PopulationSummary* summary);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_ENGINE_H_
