// pksim: simulate a dosing regimen or a NONMEM-style dataset.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <stdexcept>
#include <sstream>
#include <string>
#include <vector>

#include <boost/program_options.hpp>

#include "cli.h"
#include "pk/catalogue.h"
#include "pk/ode_model.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/population_estimates.h"
#include "pk/population_simulation.h"
#include "pk/uncertainty.h"
#include "pk/estimates.h"
#include "pk/exposure.h"
#include "pk/objective.h"
#include "pk/output.h"
#include "pk/plot.h"
#include "pk/units.h"
#include "pk/regimen.h"
#include "pk/simulate.h"
#include "pk/simulation_csv.h"

namespace po = boost::program_options;

namespace {

const char* const kUsage =
    "Usage: pksim --model NAME (--data FILE | --dose AMT ...) [options]\n"
    "Simulates a dataset (NONMEM-style CSV) or a regimen given by flags: exactly for\n"
    "linear models, by Dormand-Prince for nonlinear ones (stiff stretches by CVODES; or\n"
    "--propagator ode: CVODES throughout).\n"
    "Writes one CSV row per EVID 0/2 record (or requested time): ID,TIME,EVID,CP,\n"
    "the model's further outputs (e.g. EFFECT), A1..An; --columns chooses them.\n\n"
    "Examples:\n"
    "  pksim --model 2cmt_oral --dose 500 --ii 12 --doses 14 --times 0:0.5:168 --summary\n"
    "  pksim --model 1cmt_iv --dose 1000 --duration 2 --times 0:0.1:24 --param CL=4 --out sim.csv\n"
    "  pksim --model 1cmt_oral --data datasets/theophylline.csv --param KA=1.5 --times 0:0.25:25\n"
    "  pksim --model 1cmt_oral --estimates pkfit_out/estimates.csv --dose 320 --ii 12 --doses 10 \\\n"
    "        --times 0:1:120 --summary    (each fitted subject on a new regimen)\n"
    "  pksim --model models/pheno_pop.pkm --population pkpop_out --dose 30 --ii 12 --doses 10 \\\n"
    "        --times 0:1:120 --param WT=1.2 --param APGAR=7 --subjects 1000 --seed 7 --out sims.csv\n"
    "        (1000 virtual neonates, each its η from the fit's Ω and residual error from its σ)\n";

// The --summary text of one subject.
// " mg/L" when the unit is known, "" otherwise.
std::string UnitSuffix(const std::string& unit) { return unit.empty() ? "" : " " + unit; }

std::string SummaryText(const pk::Exposure& e, const pk::SubjectSimulation& sim, const pk::Units& units) {
  if (!sim.ok) return "ID " + pk::FormatNumber(e.id) + ": simulation failed: " + sim.message + "\n\n";
  std::string out;
  char line[320];
  const std::string c = UnitSuffix(units.concentration), t = UnitSuffix(units.time), auc_unit = pk::ParameterUnit("AUC", units);
  const std::string auc = UnitSuffix(auc_unit);
  std::snprintf(line, sizeof line, "ID %s: Cmax %.4g%s at t=%.4g%s, Cmin %.4g%s, AUC %.5g%s\n",
                pk::FormatNumber(e.id).c_str(), e.cmax, c.c_str(), e.tmax, t.c_str(), e.cmin, c.c_str(), e.auc,
                auc.c_str());
  out += line;
  if (!e.intervals.empty()) {
    if (!units.time.empty() || !units.concentration.empty()) {
      out += "  (" + (units.time.empty() ? "" : "times in " + units.time) +
             (units.time.empty() || units.concentration.empty() ? "" : ", ") +
             (units.concentration.empty() ? "" : "concentrations in " + units.concentration) +
             (auc_unit.empty() ? "" : ", AUC in " + auc_unit) + ")\n";
    }
    std::snprintf(line, sizeof line, "  %8s %10s %10s %11s %10s %11s %11s %12s\n", "interval", "start", "end", "Cmax",
                  "Tmax", "Cmin", "Ctrough", "AUC");
    out += line;
    for (const pk::IntervalExposure& iv : e.intervals) {
      std::snprintf(line, sizeof line, "  %8d %10.4g %10.4g %11.5g %10.4g %11.5g %11.5g %12.6g\n", iv.index, iv.start,
                    iv.end, iv.cmax, iv.tmax, iv.cmin, iv.ctrough, iv.auc);
      out += line;
    }
  }
  return out + "\n";
}

const char* const kSummaryCsvHeader = "ID,INTERVAL,START,END,CMAX,TMAX,CMIN,CTROUGH,AUC\n";

// The --summary-csv rows of one subject.
std::string SummaryCsvRows(const pk::Exposure& e) {
  std::string out;
  const auto field = [&out](double v) {
    out += ',';
    pk::AppendNumber(&out, v);
  };
  for (const pk::IntervalExposure& iv : e.intervals) {
    pk::AppendNumber(&out, e.id);
    out += ',' + std::to_string(iv.index);
    for (double v : {iv.start, iv.end, iv.cmax, iv.tmax, iv.cmin, iv.ctrough, iv.auc}) field(v);
    out += '\n';
  }
  pk::AppendNumber(&out, e.id);
  out += ",ALL,,";
  for (double v : {e.cmax, e.tmax, e.cmin}) field(v);
  out += ",";
  field(e.auc);
  out += '\n';
  return out;
}

// The repeatable options, as given.
struct Lists {
  std::vector<std::string> params, times, ignore, accept;
};

void DeclareOptions(po::options_description* desc, Lists* a) {
  desc->add_options()("help,h", "show this help")("version", "print the version of libpk and exit")("list-models", "print the model catalogue and exit")(
      "model,m", po::value<std::string>(), "catalogue model, e.g. 2cmt_oral, or a model file FILE.pkm")(
      "data,d", po::value<std::string>(), "NONMEM-style dataset (CSV)")(
      "param,p", po::value<std::vector<std::string>>(&a->params)->composing(),
      "NAME=VALUE for a model parameter or dose modifier (F1, ALAG1, R1, D1, X0_1, K0_1); repeatable")(
      "estimates", po::value<std::string>(),
      "per-subject parameters from a table with columns ID, PARAMETER, ESTIMATE (pkfit's estimates.csv); "
      "--param overrides them. With --data each ID takes its own; with a regimen, every ID in the table gets it")(
      "dose", po::value<double>(), "dose amount (regimen mode)")(
      "cmt", po::value<int>()->default_value(0), "dose compartment (0 = the model's default)")(
      "dose-time", po::value<double>()->default_value(0.0), "time of the first dose")(
      "ii", po::value<double>()->default_value(0.0), "dosing interval")(
      "doses", po::value<int>(), "number of doses (1 + ADDL)")("addl", po::value<int>(), "additional doses")(
      "rate", po::value<double>(), "infusion rate (default: bolus)")(
      "duration", po::value<double>(), "infusion duration (alternative to --rate)")(
      "ss", po::value<int>()->default_value(0), "steady-state flag of the dose (0, 1, 2)")(
      "times,t", po::value<std::vector<std::string>>(&a->times)->composing(),
      "output times FROM:STEP:TO or a,b,c; repeatable")("out,o", po::value<std::string>(),
                                                          "write the simulation CSV here (default: stdout)")(
      "columns", po::value<std::string>(),
      "the CSV's columns, in order, as NONMEM's $TABLE: e.g. ID,TIME,CP (default: ID,TIME,EVID,CP, the "
      "model's further outputs, A1..An)")(
      "summary", "print Cmax, Tmax, Cmin, trough and AUC per subject and dosing interval")(
      "summary-csv", po::value<std::string>(), "write the exposure summary as CSV")(
      "plot", po::value<std::string>(),
      "write concentration against time as SVG; a model with several outputs gets a panel for each")(
      "propagator", po::value<std::string>()->default_value("auto"),
      "exact (Φ/Γ, linear models), ode (CVODES, every model), rk (Dormand-Prince 5(4), stiff "
      "models) or auto")(
      "rtol", po::value<double>()->default_value(1e-8), "ODE propagator: relative tolerance")(
      "atol", po::value<double>()->default_value(1e-10), "ODE propagator: absolute tolerance")(
      "log", "logarithmic concentration axis for --plot")(
      "units", po::value<std::string>(),
      "units for --plot's axes, e.g. time=h,amt=mg,conc=mg/L (a units row in --data also gives them)")(
      "jobs,j", po::value<int>()->default_value(0), "worker threads (0 = all cores); the output does not depend on it")(
      "population", po::value<std::string>(),
      "simulate with variability from a pkpop run (its population_estimates.csv, or its output directory): each "
      "subject's η drawn from Ω, its parameters θ·exp(η) (a model file's η parameters set), and each output "
      "given a residual error from σ (columns DV, DV_<OUTPUT>); the η are columns too")(
      "replicates", po::value<int>()->default_value(1), "--population: the dataset or regimen this many times (REP)")(
      "subjects", po::value<int>(), "--population: simulate the regimen (one subject) for this many subjects, IDs 1..N")(
      "seed", po::value<std::string>()->default_value("1"), "--population: the seed; the output does not depend on -j")(
      "no-residual-error", "--population: no residual error (no DV columns)")(
      "uncertainty", po::value<std::string>(),
      "--population: each replicate's θ, Ω and σ from the estimates' uncertainty: 'covariance' draws them from "
      "N(estimates, the run's covariance.csv), truncated to the parameter space; a bootstrap.csv (or the directory of "
      "a pkpop --bootstrap run) takes its USED rows in turn");
  pk::cli::AddFilterOptions(desc, &a->ignore, &a->accept);
}

void ListModels() {
  for (const std::string& name : pk::CatalogueModelNames()) {
    const auto model = pk::MakeModel(name);
    std::string ps;
    for (const std::string& p : model->parameter_names()) ps += (ps.empty() ? "" : ", ") + p;
    std::printf("%-17s (%s)  %s\n", name.c_str(), ps.c_str(), model->description().c_str());
  }
}

// The regimen the dose flags give, with output records at `grid`.
pk::Dataset RegimenFromFlags(const po::variables_map& vm, const std::vector<double>& grid) {
  pk::Dose dose;
  dose.amount = vm["dose"].as<double>();
  dose.cmt = vm["cmt"].as<int>();
  dose.time = vm["dose-time"].as<double>();
  dose.ii = vm["ii"].as<double>();
  dose.ss = vm["ss"].as<int>();
  if (vm.count("doses") && vm.count("addl")) throw pk::InputError("give --doses or --addl, not both");
  if (vm.count("doses")) dose.addl = vm["doses"].as<int>() - 1;
  if (vm.count("addl")) dose.addl = vm["addl"].as<int>();
  if (vm.count("rate") && vm.count("duration")) throw pk::InputError("give --rate or --duration, not both");
  if (vm.count("rate")) dose.rate = vm["rate"].as<double>();
  if (vm.count("duration")) {
    dose.duration = vm["duration"].as<double>();
    if (dose.duration <= 0) throw pk::InputError("--duration must be positive");
  }
  if (grid.empty()) throw pk::InputError("a regimen needs output times (--times FROM:STEP:TO)");
  pk::Regimen regimen;
  regimen.doses.push_back(dose);
  regimen.times = grid;
  pk::Dataset data = pk::cli::Parsed("--dose", [&] { return pk::RegimenToDataset(regimen); });
  data.source = "command-line regimen";
  return data;
}

// --plot draws the first kPlotSubjects subjects, each line at most kPlotPoints points (a peak kept
// exactly): its memory and the SVG's size are bounded, however many rows the simulation writes.
constexpr int kPlotSubjects = 100;
constexpr int kPlotPoints = 4000;

// One subject's lines for --plot: the central concentration and, for a model with several
// outputs (an effect, a metabolite), each further output, for a panel of its own.
std::vector<pk::PlotSeries> PlotLines(const pk::SubjectSimulation& s) {
  const Eigen::Index outputs = std::max<Eigen::Index>(1, s.outputs.rows());
  std::vector<pk::PlotSeries> lines(static_cast<size_t>(outputs));
  for (Eigen::Index k = 0; k < outputs; ++k) {
    pk::PlotSeries& line = lines[static_cast<size_t>(k)];
    line.label = "ID " + pk::FormatNumber(s.id);
    for (size_t i = 0; i < s.rows.size(); ++i) {
      line.x.push_back(s.rows[i].time);
      line.y.push_back(k == 0 ? s.rows[i].cp : s.outputs(k, static_cast<Eigen::Index>(i)));
    }
    line = pk::DecimateLine(line, kPlotPoints);
  }
  return lines;
}

// plot[k]: every subject's line of output k. One panel a output, stacked on a shared time axis,
// as mrgsolve plots a simulation's outputs; --log applies to the concentration's.
std::string PlotSvg(const pk::Model& model, const std::vector<std::vector<pk::PlotSeries>>& plot, bool log,
                    const pk::Units& units, int subjects) {
  std::vector<pk::PlotOptions> panels(std::max<size_t>(1, plot.size()));
  const std::vector<std::string>& names = model.output_names();
  const size_t drawn = plot.empty() ? 0 : plot[0].size();
  for (size_t k = 0; k < panels.size(); ++k) {
    pk::PlotOptions& o = panels[k];
    o.title = k > 0 ? "" : "pksim: " + model.name();
    if (k == 0 && static_cast<size_t>(subjects) > drawn) {
      o.title += " (the first " + std::to_string(drawn) + " of " + std::to_string(subjects) + " subjects)";
    }
    o.log_y = log && k == 0;
    o.x_label = pk::WithUnit("time", units.time);
    o.y_label = k == 0 ? pk::WithUnit(panels.size() > 1 && !names.empty() ? names[0] : "concentration",
                                      units.concentration)
                       : (k < names.size() ? names[k] : "output " + std::to_string(k + 1));
    if (panels.size() > 1) o.height = 400;
  }
  if (panels.size() == 1) return pk::RenderSvg(plot.empty() ? std::vector<pk::PlotSeries>() : plot[0], panels[0]);
  return pk::RenderPanelsSvg(plot, panels);
}

// Says on stderr which of the model's parameters neither --param nor a data column gives: those
// take the catalogue's defaults, which a user should not mistake for their own values.
void NoteDefaults(const pk::Model& model, const pk::Dataset& data, const pk::ParameterValues& values) {
  const pk::ParameterLayout layout(model);
  std::vector<bool> given(static_cast<size_t>(model.num_parameters()), false);
  for (const auto& kv : values) {
    const int i = layout.Index(kv.first);
    if (i >= 0 && i < model.num_parameters()) given[static_cast<size_t>(i)] = true;
  }
  std::string defaults;
  for (int i = 0; i < model.num_parameters(); ++i) {
    if (given[static_cast<size_t>(i)] || data.ExtraColumn(model.parameter_names()[i]) >= 0) continue;
    defaults += (defaults.empty() ? "" : ", ") + model.parameter_names()[i] + "=" +
                pk::FormatNumber(model.default_parameters()(i));
  }
  if (!defaults.empty()) {
    std::cerr << "pksim: note: the " << (model.declarations().source.empty() ? "catalogue's" : "model file's")
              << " defaults for what --param and the data do not give: " << defaults << "\n";
  }
}

// --population and its options.
struct Variability {
  pk::PopulationEstimates estimates;
  pk::VariabilityOptions options;
  std::vector<std::string> labels;  // the η columns' names
};

// --uncertainty: the run's covariance.csv (beside `estimates`, population_estimates.csv), or a bootstrap.csv.
void Uncertainty(const std::string& source, const std::string& estimates, const pk::Model& model, Variability* v) {
  std::vector<pk::PopulationEstimates>& sets = v->options.parameter_sets;
  if (source == "covariance") {
    const std::string path = std::filesystem::path(estimates).replace_filename("covariance.csv").string();
    pk::CheckOutputSet(path, "pkpop", "pkpop.ext");
    int redrawn = 0;
    try {
      sets = pk::DrawFromCovariance(v->estimates, pk::ReadEstimatesCovariance(path), model, v->options.replicates,
                                    v->options.seed, &redrawn);
    } catch (const pk::InputError& e) {
      throw pk::InputError(e.message().rfind(path, 0) == 0 ? e.message() : path + ": " + e.message());
    }
    std::cerr << "pksim: note: each replicate's θ, Ω and σ drawn from N(estimates, " << path << ")"
              << (redrawn > 0 ? "; " + std::to_string(redrawn) + " draws outside the parameter space drawn again" : "")
              << "\n";
    const double rejected = static_cast<double>(redrawn) / (redrawn + v->options.replicates);
    if (rejected > 0.05) {
      std::cerr << "pksim: warning: " << pk::FormatNumber(std::round(1000 * rejected) / 10)
                << "% of the draws fell outside the parameter space: the truncated normal's means differ from the "
                   "estimates (a variance or θ whose SE is large beside it); a bootstrap's replicates "
                   "(--uncertainty BOOT) describe such uncertainty better\n";
    }
    return;
  }
  std::string path = source;
  if (std::filesystem::is_directory(path)) {
    path += "/bootstrap.csv";
    if (!std::filesystem::exists(path)) {
      throw pk::InputError("--uncertainty " + source + ": the run has no bootstrap.csv (run pkpop --bootstrap N), or "
                           "give 'covariance'");
    }
  }
  pk::CheckOutputSet(path, "pkpop", "pkpop.ext");
  sets = pk::ReadParameterSets(path, v->estimates, model);
  std::cerr << "pksim: note: each replicate's θ, Ω and σ from one of the " << sets.size() << " used replicates of "
            << path << (static_cast<size_t>(v->options.replicates) > sets.size() ? ", in turn (some used more than once)" : "")
            << "\n";
}

std::optional<Variability> ParseVariability(const po::variables_map& vm, const pk::Model& model) {
  const bool given = !vm["replicates"].defaulted() || vm.count("subjects") || !vm["seed"].defaulted() ||
                     vm.count("no-residual-error") || vm.count("uncertainty");
  if (!vm.count("population")) {
    if (given) {
      throw pk::InputError("--replicates, --subjects, --seed, --no-residual-error and --uncertainty need --population");
    }
    return std::nullopt;
  }
  if (vm.count("estimates")) throw pk::InputError("give --population or --estimates, not both");
  std::string path = vm["population"].as<std::string>();
  if (std::filesystem::is_directory(path)) path += "/population_estimates.csv";
  pk::CheckOutputSet(path, "pkpop", "pkpop.ext");  // not half of an interrupted run
  Variability v;
  v.estimates = pk::ReadPopulationEstimates(path, model);
  v.options.replicates = vm["replicates"].as<int>();
  if (v.options.replicates < 1 || v.options.replicates > 100000) throw pk::InputError("--replicates: expected 1 to 100000");
  if (vm.count("subjects")) {
    v.options.subjects = vm["subjects"].as<int>();
    if (v.options.subjects < 1 || v.options.subjects > 10000000) throw pk::InputError("--subjects: expected 1 to 10000000");
  }
  v.options.seed = pk::cli::ParseSeed(vm["seed"].as<std::string>());
  v.options.residual_error = !vm.count("no-residual-error");
  for (const std::string& e : v.estimates.etas) v.labels.push_back(pk::cli::EtaLabel(e));
  if (vm.count("uncertainty")) Uncertainty(vm["uncertainty"].as<std::string>(), path, model, &v);
  return v;
}

// Where the rows go as subjects finish: a file written whole or not at all, or standard output.
class Output {
 public:
  explicit Output(const std::string& path) {
    if (!path.empty()) file_ = std::make_unique<pk::AtomicFile>(path);
  }
  void Write(const std::string& text) {
    if (file_) {
      file_->Write(text);
    } else if (std::fwrite(text.data(), 1, text.size(), stdout) != text.size()) {
      throw std::runtime_error("standard output: write failed");
    }
  }
  void Commit() {
    if (file_) file_->Commit();
    if (!file_ && std::fflush(stdout) != 0) throw std::runtime_error("standard output: write failed");
  }

 private:
  std::unique_ptr<pk::AtomicFile> file_;
};

// The dataset: --data, or the regimen the dose flags give.
pk::Dataset Data(const po::variables_map& vm, const Lists& lists, const std::vector<double>& grid) {
  if (vm.count("data")) {
    if (vm.count("dose")) throw pk::InputError("give either --data or --dose, not both");
    return pk::ReadDataset(vm["data"].as<std::string>(), pk::cli::ParseFilter(lists.ignore, lists.accept));
  }
  if (!vm.count("dose")) throw pk::InputError("give --data FILE or a regimen (--dose AMT ...)");
  return RegimenFromFlags(vm, grid);
}

pk::SimulationOptions SimulationOptions(const po::variables_map& vm, const std::vector<double>& grid) {
  pk::SimulationOptions o;
  o.propagator = pk::cli::ParsePropagator(vm["propagator"].as<std::string>());
  o.ode.relative_tolerance = vm["rtol"].as<double>();
  o.ode.absolute_tolerance = vm["atol"].as<double>();
  o.jobs = vm["jobs"].as<int>();
  // The AUC is a state of its own, integrated only for the exposure metrics (and an extra state keeps
  // a one-step integrator from continuing through the output times).
  o.track_auc = vm.count("summary") > 0 || vm.count("summary-csv") > 0;
  if (vm.count("data")) o.output_times = grid;  // a regimen has them already
  std::string why;
  if (!o.IsValid(&why)) throw pk::InputError(why);
  return o;
}

// --columns, or with --population every column of a simulation with variability; none: the default table.
std::optional<pk::SimulationColumns> Columns(const po::variables_map& vm, const pk::Model& model,
                                             const std::optional<Variability>& variability) {
  std::optional<pk::SimulationColumns> columns;
  if (variability) {
    const bool dv = variability->options.residual_error, reps = variability->options.replicates > 1;
    columns.emplace(model,
                    vm.count("columns") ? vm["columns"].as<std::string>()
                                        : pk::SimulationColumns::DefaultList(model, variability->labels, dv, reps),
                    variability->labels, dv);
  } else if (vm.count("columns")) {
    columns.emplace(model, vm["columns"].as<std::string>());
  }
  return columns;
}

// Every subject to `sink`: with a population's variability, per-subject estimates, or `values`.
void SimulateAll(const po::variables_map& vm, const pk::Model& model, const pk::Dataset& data,
                 const pk::ParameterValues& values, const std::optional<Variability>& variability,
                 const pk::SimulationOptions& options, const pk::SimulationSink& sink) {
  if (variability) {
    pk::SimulateEachWithVariability(model, data, variability->estimates, values, options, variability->options, sink);
    return;
  }
  if (!vm.count("estimates")) {
    NoteDefaults(model, data, values);
    pk::SimulateEach(model, data, values, options, sink);
    return;
  }
  const std::string path = vm["estimates"].as<std::string>();
  pk::CheckOutputSet(path, "pkfit", "fit_details.csv");  // not half of an interrupted run
  const auto estimates = pk::ReadEstimates(path, model);
  // With a regimen, every ID of the table gets it.
  const auto match = vm.count("data") ? pk::EstimatesMatch::kById : pk::EstimatesMatch::kEveryId;
  pk::SimulateEachWithEstimates(model, data, estimates, values, match, options, path, sink);
}

int Main(int argc, char** argv) {
  po::options_description desc("Options");
  Lists lists;
  DeclareOptions(&desc, &lists);
  po::variables_map vm;
  if (!pk::cli::ParseCommandLine(argc, argv, desc, kUsage, &vm)) return 0;
  if (vm.count("list-models")) {
    ListModels();
    return 0;
  }
  if (!vm.count("model")) throw pk::InputError("--model is required (see --list-models)");
  // With --population a model file's η are parameters, which each subject's draw sets.
  const bool population = vm.count("population") > 0;
  const auto model = pk::MakeModel(vm["model"].as<std::string>(),
                                   population ? pk::RandomEffects::kParameters : pk::RandomEffects::kZero);
  const std::optional<Variability> variability = ParseVariability(vm, *model);
  const pk::ParameterValues values = pk::cli::ParseAssignments(lists.params, "--param");
  pk::ParameterLayout(*model).Resolve(values);  // an unknown name is an error before anything runs
  const std::vector<double> grid = pk::cli::ParseTimes(lists.times);
  const pk::Dataset data = Data(vm, lists, grid);
  const pk::Units units = pk::ModelUnits(
      pk::MergeUnits(
          vm.count("units") ? pk::cli::Parsed("--units", [&] { return pk::ParseUnits(vm["units"].as<std::string>()); })
                            : pk::Units(),
          pk::DatasetUnits(data)),
      *model);
  const pk::SimulationOptions sim_options = SimulationOptions(vm, grid);

  // Rows are written as subjects finish, in the dataset's order: memory holds a few subjects.
  const bool rows_wanted = vm.count("out") || !vm.count("summary");
  std::optional<Output> rows, summary_csv;
  if (rows_wanted) rows.emplace(vm.count("out") ? vm["out"].as<std::string>() : std::string());
  if (vm.count("summary-csv")) summary_csv.emplace(vm["summary-csv"].as<std::string>());
  // The headers go out with the first subject, so that a run the library refuses writes nothing.
  bool started = false;
  const std::optional<pk::SimulationColumns> columns = Columns(vm, *model, variability);
  const auto start = [&] {
    if (started) return;
    started = true;
    if (rows) rows->Write(columns ? columns->Header() : pk::SimulationCsvHeader(*model));
    if (summary_csv) summary_csv->Write(kSummaryCsvHeader);
  };
  std::vector<std::vector<pk::PlotSeries>> plot;  // per output, a line per subject (the first kPlotSubjects)
  int simulated = 0;
  int failed = 0;
  pk::SimulationSink sink;
  if (rows) {
    sink.render = [&columns](const pk::SubjectSimulation& s) {
      std::string text;
      if (columns) {
        columns->Append(s, &text);
      } else {
        pk::AppendSimulationCsv(s, &text);
      }
      return text;
    };
  }
  sink.consume = [&](pk::SubjectSimulation&& s, std::string&& text) {
    start();
    if (!s.ok) {
      ++failed;
      std::cerr << "pksim: ID " << pk::FormatNumber(s.id) << ": simulation failed: " << s.message << "\n";
    }
    if (rows) rows->Write(text);
    if (vm.count("summary") || summary_csv) {  // the exposure metrics only when asked for
      const pk::Exposure e = pk::ComputeExposure(s);
      if (vm.count("summary")) std::cout << SummaryText(e, s, units);
      if (summary_csv) summary_csv->Write(SummaryCsvRows(e));
    }
    if (s.ok) ++simulated;  // what the plot could draw
    if (vm.count("plot") && s.ok && (plot.empty() || plot[0].size() < kPlotSubjects)) {
      std::vector<pk::PlotSeries> lines = PlotLines(s);
      plot.resize(std::max(plot.size(), lines.size()));
      for (size_t k = 0; k < lines.size(); ++k) plot[k].push_back(std::move(lines[k]));
    }
  };
  SimulateAll(vm, *model, data, values, variability, sim_options, sink);
  start();
  if (rows) rows->Commit();
  if (summary_csv) summary_csv->Commit();
  if (vm.count("plot")) {
    const size_t drawn = plot.empty() ? 0 : plot[0].size();
    if (static_cast<size_t>(simulated) > drawn) {
      std::cerr << "pksim: note: --plot draws the first " << drawn << " of " << simulated << " subjects simulated\n";
    }
    pk::WriteFileAtomically(vm["plot"].as<std::string>(), PlotSvg(*model, plot, vm.count("log") > 0, units, simulated));
  }
  return failed > 0 ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  return pk::cli::Run("pksim", [&] { return Main(argc, argv); });
}
