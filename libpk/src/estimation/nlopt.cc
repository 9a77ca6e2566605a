#include "estimation/nlopt.h"

#include <new>
#include <stdexcept>

#include <nlopt.h>

namespace pk {
namespace internal {
namespace {

nlopt_opt Opt(void* p) { return static_cast<nlopt_opt>(p); }

struct Call {
  const NloptFunction* f;
  nlopt_opt opt;
  std::string error;  // what the function threw, if it did
};

// An exception must not unwind through NLopt's C frames: it is kept, NLopt is stopped, and the
// outcome is a failure with its message (as NLopt's own C++ interface reports it).
double Trampoline(unsigned, const double* x, double* gradient, void* data) {
  Call* call = static_cast<Call*>(data);
  try {
    return (*call->f)(x, gradient);
  } catch (const std::exception& e) {
    call->error = e.what();
  } catch (...) {
    call->error = "unknown exception";
  }
  nlopt_force_stop(call->opt);
  return 0;
}

}  // namespace

bool Nlopt::Knows(const std::string& algorithm) { return nlopt_algorithm_from_string(algorithm.c_str()) >= 0; }

Nlopt::Nlopt(const std::string& algorithm, int n) {
  const int code = nlopt_algorithm_from_string(algorithm.c_str());
  if (code < 0) throw std::invalid_argument("unknown NLopt algorithm '" + algorithm + "'");
  opt_ = nlopt_create(static_cast<nlopt_algorithm>(code), static_cast<unsigned>(n));
  if (opt_ == nullptr) throw std::bad_alloc();
}

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
  Call call{&f, Opt(opt_), ""};
  nlopt_set_min_objective(Opt(opt_), Trampoline, &call);
  const nlopt_result result = nlopt_optimize(Opt(opt_), x->data(), &out.value);
  if (!call.error.empty()) {
    out.evaluations = nlopt_get_numevals(Opt(opt_));
    out.result = nlopt_result_to_string(result);
    out.kind = Outcome::kFailure;
    out.error = call.error;
    return out;
  }
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
