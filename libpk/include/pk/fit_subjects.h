// libpk: fitting every subject of a dataset independently, in parallel.
#ifndef PK_FIT_SUBJECTS_H_
#define PK_FIT_SUBJECTS_H_

#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pk/conversion.h"
#include "pk/estimates.h"
#include "pk/fit.h"
#include "pk/initial_estimates.h"
#include "pk/objective.h"

namespace pk {

struct SubjectFit {
  double id = 0;
  int occurrence = 1;          ///< Subject::occurrence: 2, 3, ... for an ID that came back
  int subject = 0;             ///< index into Dataset::subjects
  bool ok = false;             ///< the fit ran (it may still not have converged)
  std::string error;           ///< why the subject could not be fitted, when !ok
  FitSummary summary;
  std::vector<double> times;   ///< sample times
  std::vector<int> sample_records;  ///< per sample, its record in the subject's Subject::records
  Eigen::VectorXd dv;          ///< observations (a censored sample's limit)
  Eigen::VectorXi censoring;   ///< per sample: 0, or 1 / -1 for a value below / above DV (CENS)
  Eigen::VectorXd ipred;       ///< individual predictions at the estimate (NONMEM's IPRED)
  /// Individual weighted residuals (NONMEM's IWRES): least squares √W(DV − PRED)/σ̂ with σ̂² = 2V/(N − p);
  /// maximum likelihood (DV − PRED)/σ_k, or (log DV − log PRED)/SIGMA_LOG for
  /// the exponential error. NaN for a censored sample.
  Eigen::VectorXd iwres;
  /// Where the starting values came from: "data (...)" or "catalogue defaults (...)".
  std::string initial_method;
  ParameterValues initial;     ///< the starting values of the estimated parameters
  /// Linear models, with delta-method SEs (pk/conversion.h): the exponents and
  /// half-lives of the unit-dose response ("exponents"); for tf<n> models also
  /// the equivalent IV and oral compartmental parameters ("iv", "oral").
  std::vector<TransferFunctionReading> derived;
  /// The fitted curve on a fine grid (for plots): times and central concentrations.
  std::vector<double> curve_times;
  std::vector<double> curve;
  /// Models with several outputs (DVID): the output each sample measures, and
  /// per output k (1-based: output_curves[k-1], the first equal to `curve`)
  /// its name and fitted curve. Empty for single-output models.
  std::vector<int> sample_output;
  std::vector<std::string> output_names;
  std::vector<std::vector<double>> output_curves;
};

/// Specification shared by all subjects.
struct FitSubjectsRequest {
  std::shared_ptr<const Model> model;
  std::shared_ptr<const Dataset> data;
  std::vector<int> subjects;           ///< indices into data->subjects; empty = all
  ObjectiveOptions objective;
  std::vector<LogNormalPrior> priors;
  std::vector<ParameterSpec> parameters;  ///< an empty name list is not allowed
  FitOptions fit;
  /// Start parameters whose ParameterSpec::initial is NaN from values computed
  /// from each subject's data (pk/initial_estimates.h) instead of the catalogue
  /// defaults; where that fails, the defaults are used and the reason recorded.
  bool initial_from_data = true;
  /// Starting values per subject ID, e.g. an earlier fit's estimates. For the
  /// parameters estimated here they take the place of ParameterSpec::initial
  /// and of the values from the data; other names are ignored. A subject
  /// without an entry starts as if this were empty.
  std::vector<SubjectEstimates> initial_by_subject;
  int jobs = 0;                        ///< worker threads; 0 = all cores
  int curve_points = 400;              ///< grid size of the fitted curve
};

/// The parameter settings a user gives by name (pkfit's --init, --fix, --lower and --upper).
struct ParameterSettings {
  ParameterValues initial, fixed, lower, upper;
};

/// The parameters a request fits: every model parameter that no data column supplies, then the
/// error model's σ, then every other name in `settings` (dose modifiers such as F1 or ALAG1),
/// with the initial values (NaN where none is given: from the data or the defaults), fixes and
/// bounds of `settings`. Throws pk::InputError naming the model's parameters for a name it does
/// not have, and for settings that cannot make a fit: bounds the wrong way round, an initial value
/// outside its bounds or not positive on the log scale (request.fit.log_scale), or a value of zero or
/// below for a parameter the model requires positive (Model::must_be_positive).
std::vector<ParameterSpec> MakeParameterSpecs(const FitSubjectsRequest& request, const ParameterSettings& settings);

/// The optimiser for `request`: `requested` ("lm", "bfgs", "newton" or "nlopt:NAME") when the
/// data allow it, else the default: Levenberg–Marquardt for least squares, Newton for maximum
/// likelihood, BFGS where continuous records (CONT=1) leave no residual vector. A requested
/// optimiser that cannot work (LM with maximum likelihood, LM or Newton with continuous records)
/// is a pk::InputError. An empty `requested` asks for the default.
std::string ChooseOptimizer(const FitSubjectsRequest& request, const std::string& requested);

/// The indices into data.subjects of the subjects with these IDs, every occurrence of a repeated
/// ID, in the order given. Throws pk::InputError for an ID the data do not have.
std::vector<int> SubjectIndices(const Dataset& data, const std::vector<double>& ids);

/// request.subjects, or every subject when it is empty.
std::vector<int> SelectedSubjects(const FitSubjectsRequest& request);

/// Binds every selected subject to the model and options before anything runs, so that data the
/// model cannot take, or a dose that needs a modifier no value or column supplies (R1 for RATE=-1,
/// say), is a pk::InputError naming file, line and column. Returns notes for the user:
/// observations of a linear model outside its central compartment (legitimate in NONMEM's meaning
/// of CMT, but most often a dataset written for another model).
std::vector<std::string> CheckSubjects(const FitSubjectsRequest& request);

/// The objective and its gradient at the starting values, with no fit.
struct SubjectEvaluation {
  double id = 0;
  bool ok = false;
  std::string message;             ///< why the evaluation failed, when !ok
  std::vector<std::string> names;  ///< request.parameters' names, as the model spells them
  Eigen::VectorXd values;          ///< their values
  double value = 0;                ///< the objective V
  Eigen::VectorXd gradient;        ///< ∂V over each of them
};
/// Per selected subject, at ParameterSpec::initial (NaN: the objective's default). Throws
/// pk::InputError for values a dose cannot take; a failed evaluation is reported in its entry.
std::vector<SubjectEvaluation> EvaluateSubjects(const FitSubjectsRequest& request);

/// Fits each subject on its own. Invalid or incompatible options throw
/// pk::InputError before anything runs. A subject that cannot be fitted is reported
/// in its SubjectFit; the others still run. `progress(done, total)` is called
/// from the worker threads (serialised) as subjects finish.
std::vector<SubjectFit> FitSubjects(const FitSubjectsRequest& request,
                                    const std::function<void(int, int)>& progress = nullptr);

}  // namespace pk

#endif  // PK_FIT_SUBJECTS_H_
