#include "estimation/nlopt.h"

#include <nlopt.h>

namespace pk {
namespace internal {
namespace {

nlopt_opt Opt(void* p) { return static_cast<nlopt_opt>(p); }

double Trampoline(unsigned n, const double* x, double* gradient, void* data) {
  (void)n;
  return (*static_cast<const NloptFunction*>(data))(x, gradient);
}

}  // namespace

bool Nlopt::Knows(const std::string& algorithm) { return nlopt_algorithm_from_string(algorithm.c_str()) >= 0; }

Nlopt::Nlopt(const std::string& algorithm, int n)
    : opt_(nlopt_create(nlopt_algorithm_from_string(algorithm.c_str()), static_cast<unsigned>(n))), n_(n) {}

Nlopt::~Nlopt() { nlopt_destroy(Opt(opt_)); }

void Nlopt::SetBounds(const std::vector<double>& lower, const std::vector<double>& upper) {
  nlopt_set_lower_bounds(Opt(opt_), lower.data());
  nlopt_set_upper_bounds(Opt(opt_), upper.data());
}

void Nlopt::SetRelativeTolerances(double function, double parameter) {
  nlopt_set_ftol_rel(Opt(opt_), function);
  nlopt_set_xtol_rel(Opt(opt_), parameter);
}

void Nlopt::SetMaxEvaluations(int evaluations) { nlopt_set_maxeval(Opt(opt_), evaluations); }

Nlopt::Outcome Nlopt::Minimize(const NloptFunction& f, std::vector<double>* x) {
  Outcome out;
  nlopt_set_min_objective(Opt(opt_), Trampoline, const_cast<NloptFunction*>(&f));
  const nlopt_result result = nlopt_optimize(Opt(opt_), x->data(), &out.value);
  out.evaluations = nlopt_get_numevals(Opt(opt_));
  out.result = nlopt_result_to_string(result);
  switch (result) {
    case NLOPT_SUCCESS:
    case NLOPT_STOPVAL_REACHED:
    case NLOPT_FTOL_REACHED:
    case NLOPT_XTOL_REACHED:
      out.kind = Outcome::kConverged;
      break;
    case NLOPT_MAXEVAL_REACHED:
    case NLOPT_MAXTIME_REACHED:
      out.kind = Outcome::kLimit;
      break;
    case NLOPT_ROUNDOFF_LIMITED:
      out.kind = Outcome::kRoundoff;
      break;
    default: {
      // The words of NLopt's own C++ interface for these results.
      const char* message = nlopt_get_errmsg(Opt(opt_));
      out.kind = Outcome::kFailure;
      if (result == NLOPT_OUT_OF_MEMORY) {
        out.error = "std::bad_alloc";
      } else if (result == NLOPT_FORCED_STOP) {
        out.error = "nlopt forced stop";
      } else {
        out.error = message ? message : result == NLOPT_INVALID_ARGS ? "nlopt invalid argument" : "nlopt failure";
      }
    }
  }
  return out;
}

std::string Nlopt::algorithm_name() const { return nlopt_algorithm_name(nlopt_get_algorithm(Opt(opt_))); }

}  // namespace internal
}  // namespace pk
