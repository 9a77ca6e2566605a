// pkfit: fit a compartment model to each subject of a NONMEM-style dataset.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <iostream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <boost/program_options.hpp>

#include "cli.h"
#include "fit_report.h"
#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/estimates.h"
#include "pk/fit_subjects.h"
#include "pk/ode_model.h"
#include "pk/output.h"
#include "pk/two_stage.h"

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

std::string Upper(std::string s) {
  for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

int Main(int argc, char** argv) {
  po::options_description desc("Options");
  std::vector<std::string> init, fix, lower, upper, params, priors, subject_ids, ignore, accept;
  desc.add_options()("help,h", "show this help")("model,m", po::value<std::string>(), "catalogue model")(
      "data,d", po::value<std::string>(), "NONMEM-style dataset (CSV)")(
      "init", po::value<std::vector<std::string>>(&init)->composing(),
      "NAME=VALUE: initial value; the parameter is estimated (also F1, ALAG1, R1, D1). 'auto': print the "
      "starting values computed from the data (the default for parameters without --init)")(
      "catalogue-init", "start from the catalogue defaults instead of values computed from the data")(
      "init-from", po::value<std::string>(),
      "per-subject starting values from a table with columns ID, PARAMETER, ESTIMATE (an earlier fit's "
      "estimates.csv); they take precedence over --init")(
      "fix", po::value<std::vector<std::string>>(&fix)->composing(), "NAME=VALUE: hold at this value")(
      "param", po::value<std::vector<std::string>>(&params)->composing(), "same as --fix")(
      "lower", po::value<std::vector<std::string>>(&lower)->composing(), "NAME=VALUE: lower bound")(
      "upper", po::value<std::vector<std::string>>(&upper)->composing(), "NAME=VALUE: upper bound")(
      "prior", po::value<std::vector<std::string>>(&priors)->composing(),
      "NAME=MEDIAN,SD: log-normal prior (SD on the log scale)")(
      "gradient", po::value<std::string>()->default_value("auto"), "auto, forward, adjoint, fd or companion (tf<n>)")(
      "propagator", po::value<std::string>()->default_value("auto"),
      "exact (the Φ/Γ recursion, linear models), ode (CVODES, every model) or auto (exact when linear)")(
      "rtol", po::value<double>()->default_value(1e-8), "ODE propagator: relative tolerance")(
      "atol", po::value<double>()->default_value(1e-10), "ODE propagator: absolute tolerance")(
      "checkpoint-steps", po::value<int>()->default_value(pk::OdeOptions().checkpoint_steps),
      "ODE adjoint: at most this many integration steps between checkpoints (storage against recomputation)")(
      "optimizer", po::value<std::string>()->default_value("lm"), "lm, bfgs, newton or nlopt:NAME")(
      "weighting", po::value<std::string>()->default_value("uniform"), "uniform, dv2, dv or column:NAME")(
      "error", po::value<std::string>(), "maximum likelihood: additive, proportional, combined or exponential (log DV against log PRED)")(
      "subject", po::value<std::vector<std::string>>(&subject_ids)->composing(), "fit only this ID (repeatable)")(
      "starts", po::value<int>()->default_value(1), "starts spread around the initial values; the best is kept")(
      "jobs,j", po::value<int>()->default_value(0), "parallel fits (0 = all cores)")(
      "max-iterations", po::value<int>()->default_value(1000), "iteration / evaluation limit")(
      "linear-scale", "estimate on the natural scale instead of the log scale")(
      "output-dir,o", po::value<std::string>()->default_value("pkfit_out"), "where the results go")(
      "log", "logarithmic concentration axis in the plots")(
      "population", po::value<std::string>()->default_value("lognormal"),
      "two-stage population estimates over the subjects (STS statistics and GTS): lognormal, normal or none")(
      "omega", po::value<std::string>()->default_value("diagonal"),
      "GTS between-subject covariance: diagonal (variances only) or full")(
      "evaluate", "no fit: print objective and gradient at the given values as CSV")(
      "quiet,q", "no progress bar and no table on stdout");
  pk::cli::AddFilterOptions(&desc, &ignore, &accept);
  po::variables_map vm;
  if (!pk::cli::ParseCommandLine(argc, argv, desc, kUsage, &vm)) return 0;
  if (!vm.count("model") || !vm.count("data")) throw pk::InputError("--model and --data are required");
  pk::FitSubjectsRequest req;
  req.model = pk::MakeModel(vm["model"].as<std::string>());
  req.objective.propagator = pk::cli::ParsePropagator(vm["propagator"].as<std::string>());
  pk::ResolvePropagator(*req.model, req.objective.propagator);  // a clear error for exact + nonlinear
  req.objective.ode.relative_tolerance = vm["rtol"].as<double>();
  req.objective.ode.absolute_tolerance = vm["atol"].as<double>();
  req.objective.ode.checkpoint_steps = vm["checkpoint-steps"].as<int>();
  req.data = std::make_shared<pk::Dataset>(
      pk::ReadDataset(vm["data"].as<std::string>(), pk::cli::ParseFilter(ignore, accept)));
  req.objective.gradient =
      pk::cli::Parsed("--gradient", [&] { return pk::ParseGradientRoute(vm["gradient"].as<std::string>()); });
  pk::cli::Parsed("--weighting", [&] { pk::ParseWeighting(vm["weighting"].as<std::string>(), &req.objective); return 0; });
  if (vm.count("error")) {
    req.objective.error_model =
        pk::cli::Parsed("--error", [&] { return pk::MakeResidualError(vm["error"].as<std::string>()); });
  }
  req.priors = ParsePriors(priors);
  req.fit.optimizer = vm["optimizer"].as<std::string>();
  req.fit.starts = vm["starts"].as<int>();
  req.fit.max_iterations = vm["max-iterations"].as<int>();
  req.fit.log_scale = vm.count("linear-scale") == 0;
  req.jobs = vm["jobs"].as<int>();
  const std::string population_model = vm["population"].as<std::string>(), omega = vm["omega"].as<std::string>();
  pk::TwoStageOptions two_stage;
  if (population_model == "normal") {
    two_stage.distribution = pk::BetweenSubjectModel::kNormal;
  } else if (population_model != "lognormal" && population_model != "none") {
    throw pk::InputError("--population: expected lognormal, normal or none, got '" + population_model + "'");
  }
  if (omega != "diagonal" && omega != "full") {
    throw pk::InputError("--omega: expected diagonal or full, got '" + omega + "'");
  }
  two_stage.diagonal_omega = omega == "diagonal";
  std::string why;
  if (!req.objective.IsValid(&why) || !req.fit.IsValid(&why)) throw pk::InputError(why);
  if (req.fit.optimizer == "lm" && req.objective.error_model->is_likelihood() && !vm["optimizer"].defaulted()) {
    throw pk::InputError("--optimizer lm minimises a sum of squares; with --error use bfgs, newton or nlopt:NAME");
  }
  if (req.fit.optimizer == "lm" && req.objective.error_model->is_likelihood()) {
    req.fit.optimizer = "newton";  // the default optimiser for maximum likelihood
  }
  // Continuous records (CONT=1) give a loss without residuals: LM cannot take them.
  const int cont_col = req.data->ExtraColumn("CONT");
  bool continuous = false;
  for (const pk::Subject& s : req.data->subjects) {
    for (const pk::Record& r : s.records) continuous = continuous || (cont_col >= 0 && r.extra[cont_col] == 1);
  }
  if (continuous && (req.fit.optimizer == "lm" || req.fit.optimizer == "newton")) {
    if (!vm["optimizer"].defaulted()) {
      throw pk::InputError("continuous records (CONT=1) have no residual vector: use --optimizer bfgs or "
                                     "nlopt:NAME");
    }
    req.fit.optimizer = "bfgs";
  }

  // Subjects.
  if (!subject_ids.empty()) {
    for (const std::string& text : subject_ids) {
      const double id = pk::cli::ParseAssignments({"id=" + text}, "--subject").at("id");
      bool found = false;
      for (int i = 0; i < static_cast<int>(req.data->subjects.size()); ++i) {
        if (req.data->subjects[i].id == id) {
          req.subjects.push_back(i);
          found = true;
        }
      }
      if (!found) throw pk::InputError("--subject: no ID " + text + " in " + req.data->source);
    }
  }

  // Parameters: every model parameter not supplied by a data column, plus σ for ML, plus --init.
  const pk::Objective probe(req.model, req.data, req.subjects.empty() ? 0 : req.subjects[0], req.objective, req.priors);
  bool show_initial = false;
  for (auto it = init.begin(); it != init.end();) {
    if (*it == "auto") {
      show_initial = true;
      it = init.erase(it);
    } else {
      ++it;
    }
  }
  req.initial_from_data = vm.count("catalogue-init") == 0;
  if (vm.count("init-from")) req.initial_by_subject = pk::ReadEstimates(vm["init-from"].as<std::string>(), *req.model);
  const pk::ParameterValues inits = pk::cli::ParseAssignments(init, "--init");
  pk::ParameterValues fixes = pk::cli::ParseAssignments(fix, "--fix");
  for (const auto& kv : pk::cli::ParseAssignments(params, "--param")) fixes[kv.first] = kv.second;
  const pk::ParameterValues lows = pk::cli::ParseAssignments(lower, "--lower");
  const pk::ParameterValues highs = pk::cli::ParseAssignments(upper, "--upper");
  for (const pk::ParameterValues* group : {&inits, static_cast<const pk::ParameterValues*>(&fixes), &lows, &highs}) {
    for (const auto& kv : *group) {
      if (probe.ParameterIndex(kv.first) < 0) {
        std::string names;
        for (const std::string& n : probe.parameter_names()) names += (names.empty() ? "" : ", ") + n;
        throw pk::InputError("unknown parameter '" + kv.first + "'; this model has " + names);
      }
    }
  }
  std::map<std::string, pk::ParameterSpec> specs;
  std::vector<std::string> order;
  auto add = [&](const std::string& name) {
    if (!specs.count(name)) {
      pk::ParameterSpec s;
      s.name = name;
      s.initial = NAN;
      specs[name] = s;
      order.push_back(name);
    }
    return &specs[name];
  };
  for (int i = 0; i < req.model->num_parameters(); ++i) {
    const std::string& name = probe.parameter_names()[i];
    if (req.data->ExtraColumn(name) >= 0) continue;  // the data supplies it
    add(name);
  }
  for (const char* name : {pk::kSigmaAdd, pk::kSigmaProp, pk::kSigmaLog}) {
    if (probe.ParameterIndex(name) >= 0) add(name);
  }
  for (const auto& kv : inits) add(Upper(kv.first))->initial = kv.second;
  for (const auto& kv : fixes) {
    pk::ParameterSpec* s = add(Upper(kv.first));
    s->initial = kv.second;
    s->fixed = true;
  }
  for (const auto& kv : lows) add(Upper(kv.first))->lower = kv.second;
  for (const auto& kv : highs) add(Upper(kv.first))->upper = kv.second;
  for (const std::string& name : order) req.parameters.push_back(specs[name]);

  // Every selected subject must be usable with this model before anything runs.
  std::vector<int> all = req.subjects;
  if (all.empty()) {
    for (int i = 0; i < static_cast<int>(req.data->subjects.size()); ++i) all.push_back(i);
  }
  for (int i : all) pk::Objective(req.model, req.data, i, req.objective, req.priors);
  // Observations outside the central compartment of a linear model are legitimate (NONMEM's meaning of CMT),
  // but most often a dataset written for another model: say which compartment they measure. A nonlinear
  // model's observations measure the output their DVID names, whatever their CMT.
  std::map<int, int> elsewhere;
  const bool by_dvid = dynamic_cast<const pk::OdeModel*>(req.model.get()) != nullptr;
  for (int i : by_dvid ? std::vector<int>() : all) {
    for (const pk::Record& r : req.data->subjects[static_cast<size_t>(i)].records) {
      if (r.IsSample() && r.cmt > 0 && r.cmt != req.model->central_compartment()) ++elsewhere[r.cmt];
    }
  }
  for (const auto& kv : elsewhere) {
    std::cerr << "pkfit: note: " << kv.second << " observation" << (kv.second > 1 ? "s" : "") << " with CMT " << kv.first
              << " measure " << req.model->compartment_names()[static_cast<size_t>(kv.first - 1)] << ", not "
              << req.model->compartment_names()[static_cast<size_t>(req.model->central_compartment() - 1)]
              << " (CMT " << req.model->central_compartment() << ") of " << req.model->name() << "\n";
  }

  if (vm.count("evaluate")) {
    std::ostringstream out;
    out << "ID,PARAMETER,VALUE,OBJECTIVE,GRADIENT\n";
    int failed = 0;
    for (int i : all) {
      const pk::Objective objective(req.model, req.data, i, req.objective, req.priors);
      Eigen::VectorXd values = objective.DefaultValues();
      std::vector<int> free;
      for (const pk::ParameterSpec& s : req.parameters) {
        const int k = objective.ParameterIndex(s.name);
        if (!std::isnan(s.initial)) values(k) = s.initial;
        free.push_back(k);
      }
      objective.CheckValues(values);
      const auto ev = objective.Evaluate(values, free, pk::Objective::Need::kGradient);
      const std::string id = pk::FormatNumber(objective.subject_id());
      if (!ev.ok) {
        ++failed;
        std::cerr << "pkfit: ID " << id << ": evaluation failed: " << ev.message << "\n";
        continue;
      }
      for (size_t k = 0; k < free.size(); ++k) {
        out << id << "," << objective.parameter_names()[free[k]] << "," << pk::FormatNumber(values(free[k])) << ","
            << pk::FormatNumber(ev.value) << "," << pk::FormatNumber(ev.gradient(static_cast<Eigen::Index>(k)))
            << "\n";
      }
    }
    std::cout << out.str();
    return failed ? 1 : 0;
  }

  const bool quiet = vm.count("quiet") > 0;
  const bool bar = !quiet && all.size() >= 8 && ::isatty(2);
  auto progress = [&](int done, int total) {
    if (!bar) return;
    const int width = 30, filled = width * done / total;
    std::fprintf(stderr, "\rfitting [%s%s] %d/%d", std::string(filled, '#').c_str(),
                 std::string(width - filled, ' ').c_str(), done, total);
    if (done == total) std::fprintf(stderr, "\n");
  };
  const std::vector<pk::SubjectFit> fits = pk::FitSubjects(req, progress);

  pk::cli::ReportContext context;
  context.model = req.model->name();
  context.data = req.data->source;
  for (int a = 0; a < argc; ++a) context.command_line += (a ? " " : "") + std::string(argv[a]);
  context.log_plots = vm.count("log") > 0;
  // Stage two over the subjects, when there are several.
  pk::TwoStageSummary population;
  if (population_model != "none" && fits.size() >= 2) {
    population = pk::EstimateTwoStage(fits, two_stage);
    context.population = &population;
  }
  const std::string dir = vm["output-dir"].as<std::string>();
  pk::cli::WriteFitOutputs(dir, fits, context);

  int bad = 0;
  for (const pk::SubjectFit& f : fits) {
    if (!f.ok) {
      ++bad;
      std::cerr << "pkfit: ID " << pk::FormatNumber(f.id) << ": " << f.error << "\n";
    } else if (!f.summary.converged()) {
      ++bad;
      std::cerr << "pkfit: ID " << pk::FormatNumber(f.id) << ": " << f.summary.message << "\n";
    }
  }
  if (show_initial) std::cout << pk::cli::InitialTable(fits) << "\n";
  if (!quiet) {
    std::cout << pk::cli::EstimatesTable(fits) << pk::cli::DerivedTable(fits);
    if (context.population) std::cout << pk::cli::PopulationTable(population);
    const std::string route = fits.empty() ? "" : fits.front().summary.gradient;
    std::cout << "\npropagator " << fits.front().summary.propagator << ", gradient " << route << ", optimizer " << fits.front().summary.optimizer
              << "; results in " << dir << "/ (report.html, estimates.csv, summary.csv, predictions.csv"
              << (context.population ? ", population.csv" : "") << ")\n";
  }
  if (bad) std::cerr << "pkfit: " << bad << " of " << fits.size() << " subjects failed or did not converge\n";
  return bad ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  return pk::cli::Run("pkfit", [&] { return Main(argc, argv); });
}
