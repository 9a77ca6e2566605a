// pkfit: fit a compartment model to each subject of a NONMEM-style dataset (parsing and I/O only).
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include <boost/program_options.hpp>

#include "cli.h"
#include "fit_csv.h"
#include "fit_report.h"
#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/estimates.h"
#include "pk/fit_subjects.h"
#include "pk/output.h"
#include "pk/two_stage.h"
#include "pk/units.h"

namespace po = boost::program_options;

namespace {

const char* const kUsage =
    "Usage: pkfit --model NAME --data FILE [options]\n"
    "Fits each subject independently, by least squares (default) or maximum likelihood.\n\n"
    "Examples:\n"
    "  pkfit --model 1cmt_oral --data datasets/theophylline.csv\n"
    "  pkfit --model 2cmt_iv --data datasets/indomethacin.csv --starts 8 --output-dir indo\n"
    "  pkfit --model 1cmt_oral --data d.csv --init ALAG1=0.5 --error combined --optimizer newton\n"
    "  pkfit --model 1cmt_oral --data d.csv --evaluate --init KA=1.2 --gradient adjoint\n";

std::vector<pk::LogNormalPrior> ParsePriors(const std::vector<std::string>& items) {
  std::vector<pk::LogNormalPrior> priors;
  for (const std::string& item : items) {
    const size_t eq = item.find('='), comma = item.find(',');
    if (eq == std::string::npos || comma == std::string::npos || comma < eq) {
      throw pk::InputError("--prior: expected NAME=MEDIAN,SD_LOG, got '" + item + "'");
    }
    const pk::ParameterValues v = pk::cli::ParseAssignments(
        {"m=" + item.substr(eq + 1, comma - eq - 1), "s=" + item.substr(comma + 1)}, "--prior");
    priors.push_back({item.substr(0, eq), v.at("m"), v.at("s")});
  }
  return priors;
}

// The likelihood error models' names, for the help text.
std::string ErrorNames() {
  std::string names;
  for (const std::string& name : pk::ResidualErrorNames()) {
    if (pk::MakeResidualError(name)->is_likelihood()) names += (names.empty() ? "" : ", ") + name;
  }
  return names;
}

// The repeatable options, as given.
struct Lists {
  std::vector<std::string> init, fix, lower, upper, params, priors, subject_ids, ignore, accept;
};

void DeclareOptions(po::options_description* desc, Lists* a) {
  desc->add_options()("help,h", "show this help")("version", "print the version of libpk and exit")("model,m", po::value<std::string>(), "catalogue model, or a model file FILE.pkm (docs/model_language.md)")(
      "data,d", po::value<std::string>(), "NONMEM-style dataset (CSV)")(
      "init", po::value<std::vector<std::string>>(&a->init)->composing(),
      "NAME=VALUE: initial value; the parameter is estimated (also F1, ALAG1, R1, D1, X0_1, K0_1). 'auto': print the "
      "starting values computed from the data (the default for parameters without --init)")(
      "catalogue-init", "start from the catalogue defaults instead of values computed from the data")(
      "init-from", po::value<std::string>(),
      "per-subject starting values from a table with columns ID, PARAMETER, ESTIMATE (an earlier fit's "
      "estimates.csv); they take precedence over --init")(
      "fix", po::value<std::vector<std::string>>(&a->fix)->composing(), "NAME=VALUE: hold at this value")(
      "param", po::value<std::vector<std::string>>(&a->params)->composing(), "same as --fix")(
      "lower", po::value<std::vector<std::string>>(&a->lower)->composing(), "NAME=VALUE: lower bound")(
      "upper", po::value<std::vector<std::string>>(&a->upper)->composing(), "NAME=VALUE: upper bound")(
      "prior", po::value<std::vector<std::string>>(&a->priors)->composing(),
      "NAME=MEDIAN,SD: log-normal prior (SD on the log scale)")(
      "gradient", po::value<std::string>()->default_value("auto"), "auto, forward, adjoint, fd or companion (tf<n>)")(
      "propagator", po::value<std::string>()->default_value("auto"),
      "exact (the Φ/Γ recursion, linear models), ode (CVODES, every model), rk (Dormand-Prince 5(4), "
      "stiff stretches by CVODES) or auto (exact when linear, else rk)")(
      "rtol", po::value<double>()->default_value(1e-8), "ODE propagator: relative tolerance")(
      "atol", po::value<double>()->default_value(1e-10), "ODE propagator: absolute tolerance")(
      "checkpoint-steps", po::value<int>()->default_value(pk::OdeOptions().checkpoint_steps),
      "ODE adjoint: at most this many integration steps between checkpoints (storage against recomputation)")(
      "optimizer", po::value<std::string>()->default_value("lm"), "lm, bfgs, newton or nlopt:NAME")(
      "weighting", po::value<std::string>()->default_value("uniform"), "uniform, dv2, dv or column:NAME")(
      "error", po::value<std::string>(), ("maximum likelihood: " + ErrorNames() + " (exponential: log DV against log PRED)").c_str())(
      "subject", po::value<std::vector<std::string>>(&a->subject_ids)->composing(), "fit only this ID (repeatable)")(
      "starts", po::value<int>()->default_value(1), "starts spread around the initial values; the best is kept")(
      "jobs,j", po::value<int>()->default_value(0), "parallel fits (0 = all cores)")(
      "max-iterations", po::value<int>()->default_value(1000), "iteration / evaluation limit")(
      "linear-scale", "estimate on the natural scale instead of the log scale")(
      "output-dir,o", po::value<std::string>()->default_value("pkfit_out"), "where the results go")(
      "axis", po::value<std::string>()->default_value("auto"),
      "concentration axis of the per-subject plots: auto (log for multi-exponential models), linear, log or both")(
      "log", "same as --axis log")(
      "units", po::value<std::string>(),
      "units of the data, e.g. time=h,amt=mg,conc=mg/L (labels only; a units row in the dataset also gives them)")(
      "population", po::value<std::string>()->default_value("lognormal"),
      "two-stage population estimates over the subjects (STS statistics and GTS): lognormal, normal or none")(
      "omega", po::value<std::string>()->default_value("diagonal"),
      "GTS between-subject covariance: diagonal (variances only) or full")(
      "evaluate", "no fit: print objective and gradient at the given values as CSV")(
      "quiet,q", "no progress bar and no table on stdout");
  pk::cli::AddFilterOptions(desc, &a->ignore, &a->accept);
}

// The model, data, objective and fit options of the request (parameters and subjects follow).
pk::FitSubjectsRequest BaseRequest(const po::variables_map& vm, const Lists& a) {
  pk::FitSubjectsRequest req;
  req.model = pk::MakeModel(vm["model"].as<std::string>());
  req.objective.propagator = pk::cli::ParsePropagator(vm["propagator"].as<std::string>());
  pk::ResolvePropagator(*req.model, req.objective.propagator);  // a clear error for exact + nonlinear
  req.objective.ode.relative_tolerance = vm["rtol"].as<double>();
  req.objective.ode.absolute_tolerance = vm["atol"].as<double>();
  req.objective.ode.checkpoint_steps = vm["checkpoint-steps"].as<int>();
  req.data = std::make_shared<pk::Dataset>(
      pk::ReadDataset(vm["data"].as<std::string>(), pk::cli::ParseFilter(a.ignore, a.accept)));
  req.objective.gradient =
      pk::cli::Parsed("--gradient", [&] { return pk::ParseGradientRoute(vm["gradient"].as<std::string>()); });
  pk::cli::Parsed("--weighting", [&] { pk::ParseWeighting(vm["weighting"].as<std::string>(), &req.objective); return 0; });
  if (vm.count("error")) {
    req.objective.error_model =
        pk::cli::Parsed("--error", [&] { return pk::MakeResidualError(vm["error"].as<std::string>()); });
  } else if (auto declared = pk::DeclaredErrorModel(*req.model)) {  // the model file's $ERROR
    req.objective.error_model = std::move(declared);
  }
  req.priors = ParsePriors(a.priors);
  req.fit.starts = vm["starts"].as<int>();
  req.fit.max_iterations = vm["max-iterations"].as<int>();
  req.fit.log_scale = vm.count("linear-scale") == 0;
  req.jobs = vm["jobs"].as<int>();
  std::string why;
  if (!req.objective.IsValid(&why)) throw pk::InputError(why);
  const std::string optimizer = vm["optimizer"].defaulted() ? "" : vm["optimizer"].as<std::string>();
  req.fit.optimizer = pk::cli::Parsed("--optimizer", [&] { return pk::ChooseOptimizer(req, optimizer); });
  if (!req.fit.IsValid(&why)) throw pk::InputError(why);
  return req;
}

// The subjects and parameters of the request, checked against the data before anything runs.
void CompleteRequest(const po::variables_map& vm, const Lists& a, pk::FitSubjectsRequest* req) {
  std::vector<double> ids;
  for (const std::string& text : a.subject_ids) ids.push_back(pk::cli::ParseAssignments({"id=" + text}, "--subject").at("id"));
  req->subjects = pk::cli::Parsed("--subject", [&] { return pk::SubjectIndices(*req->data, ids); });
  req->initial_from_data = vm.count("catalogue-init") == 0;
  if (vm.count("init-from")) {
    const std::string path = vm["init-from"].as<std::string>();
    pk::CheckOutputSet(path, "pkfit", "fit_details.csv");  // not half of an interrupted run
    req->initial_by_subject = pk::ReadEstimates(path, *req->model);
  }
  pk::ParameterSettings settings;
  std::vector<std::string> init;
  for (const std::string& item : a.init) {
    if (item != "auto") init.push_back(item);
  }
  settings.initial = pk::cli::ParseAssignments(init, "--init");
  settings.fixed = pk::cli::ParseAssignments(a.fix, "--fix");
  for (const auto& kv : pk::cli::ParseAssignments(a.params, "--param")) settings.fixed[kv.first] = kv.second;
  settings.lower = pk::cli::ParseAssignments(a.lower, "--lower");
  settings.upper = pk::cli::ParseAssignments(a.upper, "--upper");
  req->parameters = pk::MakeParameterSpecs(*req, settings);
  for (const std::string& note : pk::CheckSubjects(*req)) std::cerr << "pkfit: note: " << note << "\n";
}

// --evaluate: the objective and gradient at the starting values, as CSV.
int Evaluate(const pk::FitSubjectsRequest& req) {
  std::ostringstream out;
  out << "ID,PARAMETER,VALUE,OBJECTIVE,GRADIENT\n";
  int failed = 0;
  for (const pk::SubjectEvaluation& e : pk::EvaluateSubjects(req)) {
    const std::string id = pk::FormatNumber(e.id);
    if (!e.ok) {
      ++failed;
      std::cerr << "pkfit: ID " << id << ": evaluation failed: " << e.message << "\n";
      continue;
    }
    for (size_t k = 0; k < e.names.size(); ++k) {
      const auto j = static_cast<Eigen::Index>(k);
      out << id << "," << e.names[k] << "," << pk::FormatNumber(e.values(j)) << "," << pk::FormatNumber(e.value) << ","
          << pk::FormatNumber(e.gradient(j)) << "\n";
    }
  }
  std::cout << out.str();
  return failed ? 1 : 0;
}

// The fits, with a progress bar on a terminal.
std::vector<pk::SubjectFit> FitAll(const pk::FitSubjectsRequest& req, bool quiet) {
  const size_t count = pk::SelectedSubjects(req).size();
  const bool bar = !quiet && count >= 8 && ::isatty(2);
  auto progress = [&](int done, int total) {
    if (!bar) return;
    const int width = 30, filled = width * done / total;
    std::fprintf(stderr, "\rfitting [%s%s] %d/%d", std::string(filled, '#').c_str(),
                 std::string(width - filled, ' ').c_str(), done, total);
    if (done == total) std::fprintf(stderr, "\n");
  };
  return pk::FitSubjects(req, progress);
}

// Each subject that failed or did not converge, on stderr; returns how many.
int ReportProblems(const std::vector<pk::SubjectFit>& fits) {
  int bad = 0;
  for (const pk::SubjectFit& f : fits) {
    if (!f.ok) {
      ++bad;
      std::cerr << "pkfit: ID " << pk::FormatNumber(f.id) << ": " << f.error << "\n";
    } else if (!f.summary.converged()) {
      ++bad;
      std::cerr << "pkfit: ID " << pk::FormatNumber(f.id) << ": " << f.summary.message << "\n";
    } else if (!f.summary.identifiable) {
      ++bad;
      std::cerr << "pkfit: ID " << pk::FormatNumber(f.id) << ": not identifiable: " << f.summary.covariance_message
                << "\n";
    }
  }
  return bad;
}

// --axis: auto, linear, log or both (--log is log).
pk::cli::Axis ParseAxis(const po::variables_map& vm) {
  if (vm.count("log") && !vm["axis"].defaulted()) throw pk::InputError("give --axis or --log, not both");
  const std::string axis = vm.count("log") ? "log" : vm["axis"].as<std::string>();
  if (axis == "auto") return pk::cli::Axis::kAuto;
  if (axis == "linear") return pk::cli::Axis::kLinear;
  if (axis == "log") return pk::cli::Axis::kLog;
  if (axis == "both") return pk::cli::Axis::kBoth;
  throw pk::InputError("--axis: expected auto, linear, log or both, got '" + axis + "'");
}

// What the report says of the run besides the fits.
void FillContext(const po::variables_map& vm, const pk::FitSubjectsRequest& req, pk::cli::ReportContext* c) {
  c->model = req.model->name();
  c->model_description = req.model->description();
  c->data = req.data.get();
  const pk::Units given = vm.count("units") ? pk::cli::Parsed("--units", [&] { return pk::ParseUnits(vm["units"].as<std::string>()); })
                                            : pk::Units();
  c->units = pk::ModelUnits(pk::MergeUnits(given, pk::DatasetUnits(*req.data)), *req.model);
  c->axis = ParseAxis(vm);
  c->multi_exponential = req.model->is_linear() && req.model->num_compartments() > 1;
  const pk::ResidualErrorModel& error = *req.objective.error_model;
  c->method = (error.is_likelihood() ? "maximum likelihood, " + pk::DescribeErrorModel(error) + " error"
                                     : "least squares, " + vm["weighting"].as<std::string>() + " weights") +
              "; optimizer " + req.fit.optimizer + ", " + std::to_string(req.fit.starts) + " start" +
              (req.fit.starts > 1 ? "s" : "") + "; parameters on the " + (req.fit.log_scale ? "log" : "natural") +
              " scale";
}

int Main(int argc, char** argv) {
  po::options_description desc("Options");
  Lists lists;
  DeclareOptions(&desc, &lists);
  po::variables_map vm;
  if (!pk::cli::ParseCommandLine(argc, argv, desc, kUsage, &vm)) return 0;
  if (!vm.count("model") || !vm.count("data")) throw pk::InputError("--model and --data are required");
  pk::FitSubjectsRequest req = BaseRequest(vm, lists);
  const std::string population_model = vm["population"].as<std::string>(), omega = vm["omega"].as<std::string>();
  pk::TwoStageOptions two_stage;
  if (population_model != "none") {
    try {
      two_stage.distribution = pk::ParseBetweenSubjectModel(population_model);
    } catch (const pk::InputError&) {
      throw pk::InputError("--population: expected lognormal, normal or none, got '" + population_model + "'");
    }
  }
  if (omega != "diagonal" && omega != "full") {
    throw pk::InputError("--omega: expected diagonal or full, got '" + omega + "'");
  }
  two_stage.diagonal_omega = omega == "diagonal";
  CompleteRequest(vm, lists, &req);
  if (vm.count("evaluate")) return Evaluate(req);

  pk::cli::ReportContext context;  // --axis and --units are checked here, before any fitting
  for (int a = 0; a < argc; ++a) context.command_line += (a ? " " : "") + std::string(argv[a]);
  FillContext(vm, req, &context);
  const bool quiet = vm.count("quiet") > 0;
  const std::vector<pk::SubjectFit> fits = FitAll(req, quiet);
  pk::TwoStageSummary population;  // stage two over the subjects, when there are several
  if (population_model != "none" && fits.size() >= 2) {
    population = pk::EstimateTwoStage(fits, two_stage);
    context.population = &population;
  }
  const std::string dir = vm["output-dir"].as<std::string>();
  pk::cli::WriteFitOutputs(dir, fits, context);
  const int bad = ReportProblems(fits);
  const bool show_initial = std::find(lists.init.begin(), lists.init.end(), "auto") != lists.init.end();
  if (show_initial) std::cout << pk::cli::InitialTable(fits) << "\n";
  if (!quiet) {
    std::cout << pk::cli::EstimatesTable(fits, context.units) << pk::cli::DerivedTable(fits);
    if (context.population) std::cout << pk::cli::PopulationTable(population);
    const std::string route = fits.empty() ? "" : fits.front().summary.gradient;
    std::cout << "\npropagator " << fits.front().summary.propagator << ", gradient " << route << ", optimizer "
              << fits.front().summary.optimizer << "; results in " << dir
              << "/ (report.html, estimates.csv, summary.csv, predictions.csv"
              << (context.population ? ", population.csv" : "") << ")\n";
  }
  if (bad) {
    std::cerr << "pkfit: " << bad << " of " << fits.size() << " subjects failed, did not converge or are not identifiable\n";
  }
  return bad ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  return pk::cli::Run("pkfit", [&] { return Main(argc, argv); });
}
