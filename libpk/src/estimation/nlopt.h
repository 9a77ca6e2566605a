// NLopt, sealed (not installed): the one file that includes NLopt's API. An RAII handle on one
// optimisation; outcomes are returned, never thrown.
#ifndef PK_SRC_ESTIMATION_NLOPT_H_
#define PK_SRC_ESTIMATION_NLOPT_H_

#include <functional>
#include <string>
#include <vector>

namespace pk {
namespace internal {

/// The value at x; `gradient` (n entries) is null for derivative-free algorithms.
using NloptFunction = std::function<double(const double* x, double* gradient)>;

class Nlopt {
 public:
  /// Whether NLopt knows the algorithm (by NLopt's name, e.g. "LD_LBFGS").
  static bool Knows(const std::string& algorithm);

  /// Throws std::invalid_argument for an algorithm NLopt does not know (see Knows).
  Nlopt(const std::string& algorithm, int n);
  ~Nlopt();
  Nlopt(const Nlopt&) = delete;
  Nlopt& operator=(const Nlopt&) = delete;

  void SetBounds(const std::vector<double>& lower, const std::vector<double>& upper);
  void SetRelativeTolerances(double function, double parameter);
  void SetMaxEvaluations(int evaluations);

  struct Outcome {
    enum Kind { kConverged, kLimit, kRoundoff, kFailure };
    Kind kind = kFailure;
    std::string result;  ///< NLopt's name of its result, e.g. "FTOL_REACHED"
    std::string error;   ///< for kFailure: NLopt's error message
    int evaluations = 0;
    double value = 0;
  };
  /// Minimises `f` from *x, leaving the best point found in *x.
  Outcome Minimize(const NloptFunction& f, std::vector<double>* x);
  /// NLopt's description of the algorithm.
  std::string algorithm_name() const;

 private:
  void* opt_ = nullptr;  // nlopt_opt
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ESTIMATION_NLOPT_H_
