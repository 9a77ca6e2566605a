// pkpop: population (mixed-effects) estimation by FO, FOCE, FOCEI or Laplace (parsing and I/O only).
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <functional>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <boost/program_options.hpp>

#include "cli.h"
#include "pop_html.h"
#include "pop_simulation.h"
#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/nonmem_files.h"
#include "pk/population.h"
#include "pk/population_estimates.h"
#ifdef PK_HAVE_MPI
#include "pk/mpi.h"
#endif
#include "pk/residual_error.h"

namespace po = boost::program_options;

namespace {

const char* const kUsage =
    "Usage: pkpop --model NAME --data FILE [options]\n"
    "Estimates a population model (NONMEM's FO, FOCE, FOCEI or Laplace): typical values θ, between-subject\n"
    "variances Ω of the random effects η and residual-error σ. η are a model file's own ($OMEGA, written\n"
    "into $PK) or log-normal on a parameter (CL_i = CL·exp(η_CL)).\n\n"
    "Examples:\n"
    "  pkpop --model 1cmt_iv --data datasets/phenobarbital.csv --eta CL,V --error proportional\n"
    "  pkpop --model 1cmt_oral --data datasets/theophylline.csv --eta KA,CL,V --block CL,V --error combined\n"
    "  pkpop --model models/1cmt_iv.pkm --data d.csv --method laplace --theta CL=0.005 --omega CL=0.2 --fix V\n"
    "  pkpop --model models/pheno_pop.pkm --data datasets/phenobarbital.csv -j 2\n";

struct Lists {
  std::vector<std::string> eta, block, theta, omega, sigma, fix, ignore, accept;
};

void DeclareOptions(po::options_description* desc, Lists* a) {
  desc->add_options()("help,h", "show this help")("version", "print the version of libpk and exit")(
      "model,m", po::value<std::string>(), "catalogue model, or a model file FILE.pkm")(
      "data,d", po::value<std::string>(), "NONMEM-style dataset (CSV)")(
      "method", po::value<std::string>()->default_value("focei"), "fo (METHOD=ZERO; η̂ post hoc), foce, focei (INTER) or laplace (LAPLACIAN INTER)")(
      "eta", po::value<std::vector<std::string>>(&a->eta)->composing(),
      "the η, comma-separated, in Ω's order: a model file's own (ETA_CL), or a parameter NAME for a log-normal "
      "η on it (default: the file's η, else every estimable parameter)")(
      "block", po::value<std::vector<std::string>>(&a->block)->composing(),
      "η that form a full Ω block, comma-separated and consecutive in --eta (repeatable); others are diagonal")(
      "error", po::value<std::string>(), "additive, proportional, combined or exponential (default: the model "
                                         "file's $ERROR, else combined)")(
      "theta", po::value<std::vector<std::string>>(&a->theta)->composing(), "NAME=VALUE: initial θ (default: the model's)")(
      "omega", po::value<std::vector<std::string>>(&a->omega)->composing(),
      "NAME=VALUE: initial variance of η NAME (default: a model file's $OMEGA, else 0.1); A:B=VALUE an initial "
      "covariance in a block")(
      "sigma", po::value<std::vector<std::string>>(&a->sigma)->composing(), "NAME=VALUE: initial σ (SIGMA_ADD, ...)")(
      "fix", po::value<std::vector<std::string>>(&a->fix)->composing(),
      "hold at its initial value: a θ or σ name, or OMEGA(NAME) for the Ω block of η_NAME (comma-separated)")(
      "propagator", po::value<std::string>()->default_value("auto"), "exact, ode, rk or auto (as pkfit)")(
      "gradient", po::value<std::string>()->default_value("auto"),
      "the outer gradient: implicit (the modes' implicit function theorem, exact second- and, for Laplace, "
      "third-order sensitivities), fd (central differences of the OFV, as NONMEM) or auto (implicit, and fd "
      "from a point where the exact derivatives do not reach)")(
      "conditional-hessian", po::value<std::string>()->default_value("exact"),
      "½∇²l of each subject's conditional objective (Laplace's H; Newton's matrix on the ODE propagator): exact "
      "(from the second-order sensitivities) or differences (of the exact gradient, as NONMEM; a check)")(
      "rtol", po::value<double>()->default_value(1e-9),
      "ODE propagator: relative tolerance (pkfit's is 1e-8; the outer line search needs the OFV closer to the "
      "one whose gradient it is given)")(
      "atol", po::value<double>()->default_value(1e-11), "ODE propagator: absolute tolerance")(
      "threads,j", po::value<int>()->default_value(1), "subjects' inner problems on this many threads")(
      "max-evaluations", po::value<int>()->default_value(1000),
      "outer objective evaluations, at most; 0: no estimation, the OFV, tables, covariance step and any VPC at the "
      "initial estimates (NONMEM's MAXEVAL=0)")(
      "init-from", po::value<std::string>(),
      "start from a pkpop run's estimates (its output directory or population_estimates.csv); --theta, --omega and "
      "--sigma override them. With --max-evaluations 0: a VPC or simulation of that run without fitting again")(
      "no-covariance", "skip the covariance step (no standard errors)")(
      "cov-matrix", po::value<std::string>()->default_value("sandwich"),
      "the covariance step's matrix, as NONMEM's $COVARIANCE MATRIX=: sandwich (R⁻¹SR⁻¹, the default), r (2R⁻¹) "
      "or s (4S⁻¹)")(
      "output-dir,o", po::value<std::string>()->default_value("pkpop_out"), "where the results go")(
      "quiet,q", "no progress line and no table on stdout");
  pk::cli::AddPopulationSimulationOptions(desc);
  pk::cli::AddFilterOptions(desc, &a->ignore, &a->accept);
}

std::vector<std::string> SplitCommas(const std::vector<std::string>& items) {
  std::vector<std::string> out;
  for (const std::string& item : items) {
    std::stringstream ss(item);
    for (std::string f; std::getline(ss, f, ',');) {
      if (!f.empty()) out.push_back(f);
    }
  }
  return out;
}

// ASCII letters in upper case, whatever the C locale, as the library compares names.
std::string Upper(std::string s) {
  for (char& c : s) {
    if (c >= 'a' && c <= 'z') c = static_cast<char>(c - 'a' + 'A');
  }
  return s;
}

int Position(const std::vector<std::string>& names, const std::string& name) {
  for (size_t i = 0; i < names.size(); ++i) {
    if (Upper(names[i]) == Upper(name)) return static_cast<int>(i);
  }
  return -1;
}

int Required(const std::vector<std::string>& names, const std::string& name, const std::string& option) {
  const int k = Position(names, name);
  if (k < 0) throw pk::InputError(option + ": unknown name '" + name + "'");
  return k;
}

// Ω's blocks from --block: each a run of consecutive η; the others are blocks of one.
// A flag of the declared blocks (blocks of `declared_sizes`) carried to a regrouping into `sizes`: a
// block keeps its flag where it keeps its place and size, and for a SAME tie (`tie`) the block before
// it must too.
std::vector<bool> KeptFlags(const std::vector<int>& declared_sizes, const std::vector<bool>& declared,
                            const std::vector<int>& sizes, bool tie) {
  std::map<int, size_t> declared_at;  // a declared block's first η → its index
  for (size_t b = 0, start = 0; b < declared_sizes.size(); start += static_cast<size_t>(declared_sizes[b++])) {
    declared_at[static_cast<int>(start)] = b;
  }
  std::vector<bool> kept(sizes.size(), false);
  for (size_t b = 0, start = 0; b < sizes.size(); start += static_cast<size_t>(sizes[b++])) {
    const auto it = declared_at.find(static_cast<int>(start));
    if (it == declared_at.end() || it->second >= declared.size() || !declared[it->second]) continue;
    const size_t d = it->second;
    kept[b] = declared_sizes[d] == sizes[b] && (!tie || (b > 0 && d > 0 && declared_sizes[d - 1] == sizes[b - 1]));
  }
  return kept;
}

// --block: Ω's blocks from the η lists (the others diagonal), in place of the model file's. Its FIX
// flags stay where --block leaves a block as it was, its SAME ties where it leaves a tied block and
// its source as they were (an occasion's η, say, while CL and V become a block).
void Blocks(const std::vector<std::string>& etas, const std::vector<std::string>& specs, pk::PopulationStructure* s) {
  std::vector<int> block_of(etas.size(), -1);
  std::vector<int> sizes;
  for (const std::string& spec : specs) {
    const std::vector<std::string> names = SplitCommas({spec});
    std::vector<int> at;
    for (const std::string& n : names) at.push_back(Required(etas, n, "--block"));
    std::sort(at.begin(), at.end());
    for (size_t k = 1; k < at.size(); ++k) {
      if (at[k] != at[k - 1] + 1) throw pk::InputError("--block " + spec + ": the η must be consecutive in --eta");
    }
    for (int k : at) {
      if (block_of[static_cast<size_t>(k)] >= 0) throw pk::InputError("--block: η_" + etas[static_cast<size_t>(k)] + " is in two blocks");
      block_of[static_cast<size_t>(k)] = at.front();
    }
  }
  for (size_t k = 0; k < etas.size();) {
    size_t size = 1;
    while (block_of[k] >= 0 && k + size < etas.size() && block_of[k + size] == block_of[k]) ++size;
    sizes.push_back(static_cast<int>(size));
    k += size;
  }
  const std::vector<bool> same = KeptFlags(s->omega_blocks, s->omega_block_same, sizes, true);
  const std::vector<bool> fixed = KeptFlags(s->omega_blocks, s->omega_block_fixed, sizes, false);
  const auto count = [](const std::vector<bool>& v) { return std::count(v.begin(), v.end(), true); };
  // The declared blocks whose flag the regrouping drops, by their first η.
  const auto dropped = [&](const std::vector<bool>& declared, const std::vector<bool>& kept) {
    std::set<size_t> kept_at;
    for (size_t b = 0, start = 0; b < sizes.size(); start += static_cast<size_t>(sizes[b++])) {
      if (kept[b]) kept_at.insert(start);
    }
    std::string names;
    for (size_t d = 0, start = 0; d < s->omega_blocks.size(); start += static_cast<size_t>(s->omega_blocks[d++])) {
      if (d < declared.size() && declared[d] && !kept_at.count(start)) names += (names.empty() ? "" : ", ") + etas[start];
    }
    return names;
  };
  if (count(same) < count(s->omega_block_same)) {
    std::cerr << "pkpop: note: --block regroups Ω: the model file's SAME ties of " << dropped(s->omega_block_same, same)
              << " are dropped, those η estimated as --block groups them" << (count(same) > 0 ? " (the other ties stay)" : "")
              << "\n";
  }
  if (count(fixed) < count(s->omega_block_fixed)) {
    std::cerr << "pkpop: note: --block regroups Ω: the model file's FIX blocks of " << dropped(s->omega_block_fixed, fixed)
              << " are estimated (FIX stays with a block --block leaves as it was)\n";
  }
  s->omega_blocks = sizes;
  s->omega_block_fixed = count(fixed) > 0 ? fixed : std::vector<bool>();
  s->omega_block_same = count(same) > 0 ? same : std::vector<bool>();
}

// Initial values and FIX flags from --theta, --omega, --sigma and --fix.
// A pkpop run's estimates (its population_estimates.csv, or its directory) as the start: its θ, its
// Ω over the η this problem has, and its σ. A name of the run that this problem lacks is an error.
void StartFrom(std::string path, const pk::PopulationProblem& problem, pk::PopulationParameters* p) {
  if (std::filesystem::is_directory(path)) path += "/population_estimates.csv";
  pk::CheckOutputSet(path, "pkpop", "pkpop.ext");  // not half of an interrupted run
  const pk::PopulationEstimates run = pk::ReadPopulationEstimates(path, problem.model());
  const auto position = [&](const std::vector<std::string>& names, const std::string& name, const char* what) {
    const int k = Position(names, name);
    if (k < 0) throw pk::InputError("--init-from " + path + ": " + name + " is not " + what + " of this problem");
    return k;
  };
  for (const auto& [name, value] : run.theta) p->theta(position(problem.theta_names(), name, "a θ")) = value;
  std::vector<int> at;
  for (const std::string& eta : run.etas) at.push_back(position(problem.eta_names(), eta, "an η"));
  for (size_t r = 0; r < at.size(); ++r) {
    for (size_t c = 0; c < at.size(); ++c) {
      p->omega(at[r], at[c]) = run.omega(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(c));
    }
  }
  for (size_t k = 0; k < run.sigma_names.size(); ++k) {
    p->sigma(position(problem.sigma_names(), run.sigma_names[k], "a σ")) = run.sigma(static_cast<Eigen::Index>(k));
  }
}

pk::PopulationParameters Initial(const pk::PopulationProblem& problem, const Lists& a, const std::string& init_from,
                                 pk::PopulationStructure* s) {
  pk::PopulationParameters p = problem.DefaultParameters();
  if (!init_from.empty()) StartFrom(init_from, problem, &p);
  for (const auto& [name, value] : pk::cli::ParseAssignments(SplitCommas(a.theta), "--theta")) {
    p.theta(Required(problem.theta_names(), name, "--theta")) = value;
  }
  for (const auto& [name, value] : pk::cli::ParseAssignments(SplitCommas(a.sigma), "--sigma")) {
    p.sigma(Required(problem.sigma_names(), name, "--sigma")) = value;
  }
  std::vector<std::pair<int, int>> given;  // covariances from --omega A:B
  for (const auto& [name, value] : pk::cli::ParseAssignments(SplitCommas(a.omega), "--omega")) {
    const size_t colon = name.find(':');
    const int r = Required(problem.eta_names(), name.substr(0, colon), "--omega");
    const int c = colon == std::string::npos ? r : Required(problem.eta_names(), name.substr(colon + 1), "--omega");
    p.omega(r, c) = p.omega(c, r) = value;
    if (r != c) given.emplace_back(r, c);
    int first = 0;  // a SAME block takes its source's values: a value of its own would be dropped
    for (size_t b = 0; b < s->omega_blocks.size(); first += s->omega_blocks[b++]) {
      if (r >= first && r < first + s->omega_blocks[b] && b < s->omega_block_same.size() && s->omega_block_same[b]) {
        throw pk::InputError("--omega " + name + ": that Ω block is SAME as the block before it, whose values it takes: "
                             "give them to that one");
      }
    }
  }
  s->theta_fixed.assign(problem.theta_names().size(), false);
  s->sigma_fixed.assign(problem.sigma_names().size(), false);
  if (s->omega_block_fixed.size() != s->omega_blocks.size()) s->omega_block_fixed.assign(s->omega_blocks.size(), false);
  for (const std::string& name : SplitCommas(a.fix)) {
    const std::string u = Upper(name);
    if (u.rfind("OMEGA(", 0) == 0 && u.back() == ')') {
      const int k = Required(problem.eta_names(), u.substr(6, u.size() - 7), "--fix");
      int first = 0;
      for (size_t b = 0; b < s->omega_blocks.size(); first += s->omega_blocks[b++]) {
        if (k < first || k >= first + s->omega_blocks[b]) continue;
        if (b < s->omega_block_same.size() && s->omega_block_same[b]) {
          throw pk::InputError("--fix " + name + ": that Ω block is SAME as the block before it, and follows it: fix that one");
        }
        s->omega_block_fixed[b] = true;
      }
    } else if (Position(problem.theta_names(), name) >= 0) {
      s->theta_fixed[static_cast<size_t>(Position(problem.theta_names(), name))] = true;
    } else {
      s->sigma_fixed[static_cast<size_t>(Required(problem.sigma_names(), name, "--fix"))] = true;
    }
  }
  // Covariances between η of different blocks: an error when --omega gave one, else 0 (a file's
  // $OMEGA block that --block splits).
  std::vector<int> block_of;
  for (size_t b = 0; b < s->omega_blocks.size(); ++b) {
    block_of.insert(block_of.end(), static_cast<size_t>(s->omega_blocks[b]), static_cast<int>(b));
  }
  for (const auto& [r, c] : given) {
    if (block_of[static_cast<size_t>(r)] != block_of[static_cast<size_t>(c)]) {
      throw pk::InputError("--omega " + problem.eta_names()[static_cast<size_t>(r)] + ":" +
                           problem.eta_names()[static_cast<size_t>(c)] + ": the two η are not in one Ω block (--block)");
    }
  }
  for (Eigen::Index r = 0; r < p.omega.rows(); ++r) {
    for (Eigen::Index c = 0; c < p.omega.cols(); ++c) {
      if (block_of[static_cast<size_t>(r)] != block_of[static_cast<size_t>(c)]) p.omega(r, c) = 0;
    }
  }
  return p;
}

std::string EstimatesCsv(const pk::PopulationSummary& fit) {
  std::string out = "PARAMETER,ESTIMATE,SE,RSE_PCT,FIXED,AT_BOUNDARY\n";
  for (const auto& e : fit.estimates) {
    out += pk::cli::Quote(e.name) + "," + pk::FormatNumber(e.estimate) + "," + (std::isfinite(e.se) ? pk::FormatNumber(e.se) : "") +
           "," + (std::isfinite(e.rse_pct) ? pk::FormatNumber(e.rse_pct) : "") + "," + (e.fixed ? "1" : "0") + "," +
           (e.at_boundary ? "1" : "0") + "\n";
  }
  out += "OFV," + pk::FormatNumber(fit.ofv) + ",,,,\n";
  return out;
}

// With censored samples (M3) a CENS column follows, and their residuals are empty.
std::string SdtabCsv(const pk::PopulationSummary& fit, bool censoring) {
  std::string out = std::string("ID,TIME,DVID,DV,PRED,IPRED,RES,WRES,CWRES,IWRES") + (censoring ? ",CENS\n" : "\n");
  for (const auto& r : fit.rows) {
    for (double v : {r.id, r.time, static_cast<double>(r.dvid), r.dv, r.pred, r.ipred, r.res, r.wres, r.cwres}) {
      out += (std::isfinite(v) ? pk::FormatNumber(v) : "") + ",";
    }
    out += (std::isfinite(r.iwres) ? pk::FormatNumber(r.iwres) : "");
    out += censoring ? "," + std::to_string(r.censored) + "\n" : "\n";
  }
  return out;
}

// Xpose's patab: per sample row, the subject's η̂ and its individual parameters. For a model file
// these are its $PK definitions at the row's record (a time-varying covariate changes them); for a
// catalogue model, the subject's parameters.
std::string PatabCsv(const pk::PopulationProblem& problem, const pk::PopulationSummary& fit) {
  const std::vector<std::string>& defined = problem.model().declarations().pk_definitions;
  std::string out = "ID,TIME";
  for (const auto& n : problem.eta_names()) out += "," + pk::cli::EtaLabel(n);
  for (const auto& n : defined.empty() ? problem.theta_names() : defined) out += "," + n;
  out += "\n";
  const auto number = [](double v) { return std::isfinite(v) ? pk::FormatNumber(v) : std::string(); };
  // A row's subject by its position in the data (an ID that comes back is another subject).
  const size_t count = problem.data().subjects.size();
  std::vector<const pk::PopulationSubject*> by_position(count, nullptr);
  for (const auto& s : fit.subjects) {
    if (s.subject >= 0 && static_cast<size_t>(s.subject) < count) by_position[static_cast<size_t>(s.subject)] = &s;
  }
  for (const auto& r : fit.rows) {
    const pk::PopulationSubject* found =
        r.subject >= 0 && static_cast<size_t>(r.subject) < count ? by_position[static_cast<size_t>(r.subject)] : nullptr;
    if (found == nullptr || !found->ok) continue;
    const pk::PopulationSubject& s = *found;
    out += number(r.id) + "," + number(r.time);
    for (Eigen::Index k = 0; k < s.eta.size(); ++k) out += "," + number(s.eta(k));
    const Eigen::VectorXd& values = defined.empty() ? s.parameters : r.definitions;
    for (Eigen::Index k = 0; k < values.size(); ++k) out += "," + number(values(k));
    out += "\n";
  }
  return out;
}

std::string SubjectsCsv(const pk::PopulationProblem& problem, const pk::PopulationSummary& fit) {
  std::string out = "ID,OK,OFV";
  for (const auto& n : problem.eta_names()) out += "," + pk::cli::EtaLabel(n);
  for (const auto& n : problem.theta_names()) out += "," + n;
  // A model file's individual parameters as its $PK defines them (CL, V, …), at the first record.
  const std::vector<std::string>& defined = problem.model().declarations().pk_definitions;
  for (const auto& n : defined) out += "," + n;
  out += ",MESSAGE\n";
  for (const auto& s : fit.subjects) {
    out += pk::FormatNumber(s.id) + "," + (s.ok ? "1" : "0") + "," + (s.ok ? pk::FormatNumber(s.ofv) : "");
    for (Eigen::Index k = 0; k < static_cast<Eigen::Index>(problem.eta_names().size()); ++k) {
      out += "," + (s.ok ? pk::FormatNumber(s.eta(k)) : "");
    }
    for (Eigen::Index k = 0; k < static_cast<Eigen::Index>(problem.theta_names().size()); ++k) {
      out += "," + (s.ok ? pk::FormatNumber(s.parameters(k)) : "");
    }
    for (Eigen::Index k = 0; k < static_cast<Eigen::Index>(defined.size()); ++k) {
      out += "," + (s.ok && k < s.definitions.size() ? pk::FormatNumber(s.definitions(k)) : "");
    }
    std::string m = s.message;
    std::replace(m.begin(), m.end(), '"', '\'');
    out += ",\"" + m + "\"\n";
  }
  return out;
}

std::string IterationsCsv(const pk::PopulationSummary& fit) {
  std::string out = "EVALUATION,OFV,GRADIENT_NORM";
  for (const auto& e : fit.estimates) out += "," + pk::cli::Quote(e.name);
  out += "\n";
  for (const auto& it : fit.history) {
    out += std::to_string(it.evaluation) + "," + pk::FormatNumber(it.ofv) + "," + pk::FormatNumber(it.gradient_norm);
    for (Eigen::Index k = 0; k < it.values.size(); ++k) out += "," + pk::FormatNumber(it.values(k));
    out += "\n";
  }
  return out;
}

std::string CovarianceCsv(const pk::PopulationSummary& fit) {
  std::vector<std::string> names;
  for (const auto& e : fit.estimates) {
    if (!e.fixed) names.push_back(e.name);
  }
  std::string out = "PARAMETER";
  for (const auto& n : names) out += "," + pk::cli::Quote(n);
  out += "\n";
  for (Eigen::Index r = 0; r < fit.covariance.rows(); ++r) {
    out += pk::cli::Quote(names[static_cast<size_t>(r)]);
    for (Eigen::Index c = 0; c < fit.covariance.cols(); ++c) out += "," + pk::FormatNumber(fit.covariance(r, c));
    out += "\n";
  }
  return out;
}

// report.txt: the fit's table, then the bootstrap's and the NPDE's when there are some.
std::string ReportText(const pk::PopulationSummary& fit, const pk::cli::PopulationReportContext& context) {
  return fit.FullReport() + (context.bootstrap ? "\n" + context.bootstrap->FullReport() : "") +
         (context.npde ? "\n" + context.npde->FullReport() : "");
}

// The output set, whole or not at all. Its contents are built before the first file is written, and
// simtab.csv (the longest to write) is simulated before it too. Until the new MANIFEST, the set written
// before (the fit's own, Main) vouches for its files this write has not changed: the estimates, tables
// and .ext stay readable if pkpop is stopped during it. A failed simulation is returned (the other
// results are written); anything else throws.
std::string WriteOutputs(const std::string& dir, const pk::PopulationProblem& problem, const pk::PopulationSummary& fit,
                         const pk::cli::PopulationReportContext& context,
                         const pk::cli::PopulationSimulationRequest& simulation) {
  std::filesystem::create_directories(dir);
  pk::RemoveStaleTemporaries(dir);
  std::vector<std::pair<std::string, std::string>> files = {
      {"population_estimates.csv", EstimatesCsv(fit)}, {"sdtab.csv", SdtabCsv(fit, problem.num_censored() > 0)},
      {"patab.csv", PatabCsv(problem, fit)},
      {"subjects.csv", SubjectsCsv(problem, fit)},     {"iterations.csv", IterationsCsv(fit)},
      {"covariance.csv", CovarianceCsv(fit)},          {"report.txt", ReportText(fit, context)},
      {"pkpop.ext", pk::NonmemExtTable(fit)},          {"pkpop.phi", pk::NonmemPhiTable(fit)}};
  const auto report = pk::cli::PopulationReport(problem, fit, context);
  files.insert(files.end(), report.begin(), report.end());
  if (context.vpc) {
    files.push_back({"vpc.csv", pk::VpcCsv(*context.vpc)});
    files.push_back({"vpc.svg", pk::cli::VpcSvg(*context.vpc, problem.model())});
  }
  if (context.bootstrap) files.push_back({"bootstrap.csv", pk::BootstrapCsv(*context.bootstrap)});
  if (context.npde) {
    files.push_back({"npde.csv", pk::NpdeCsv(*context.npde)});
    files.push_back({"npde.svg", pk::cli::NpdeSvg(*context.npde)});
  }
  std::string failure;
  if (simulation.simulate > 0) {
    try {
      const int failed = pk::cli::WriteSimtab(dir + "/simtab.csv", problem, fit.parameters, simulation);
      if (failed > 0) {
        std::cerr << "pkpop: note: " << failed << " subject-replicates could not be simulated and are not in simtab.csv\n";
      }
    } catch (const std::exception& e) {
      failure = std::string("the simulation for simtab.csv failed (the other results are written): ") + e.what();
    }
  }
  std::vector<std::string> names;
  for (const auto& [name, text] : files) {
    pk::WriteFileAtomically(dir + "/" + name, text);
    names.push_back(name);
  }
  if (simulation.simulate > 0 && failure.empty()) names.push_back("simtab.csv");
  pk::CompleteOutputSet(dir, names, "pkpop");
  return failure;
}

// Without --eta: a model file's own η (its $OMEGA), else an η on every estimable parameter.
std::vector<std::string> DefaultEtas(const pk::Model& model) {
  std::vector<std::string> file, every;
  for (int i = 0; i < model.num_parameters(); ++i) {
    const std::string& name = model.parameter_names()[static_cast<size_t>(i)];
    if (model.is_eta(i)) file.push_back(name);
    if (!model.is_covariate(i) && !model.is_eta(i)) every.push_back(name);
  }
  return file.empty() ? every : file;
}

// This process's place when pkpop runs under mpirun (one process otherwise).
struct Process {
  int rank = 0;
  std::shared_ptr<const pk::SubjectDistribution> distribution;  ///< null: one process
  /// Under mpirun with more than one process: pk::MpiSession::AllReady. Called once, with true just
  /// before the fit, or with false by main when this process failed before it got there.
  std::function<bool(bool)> all_ready;
  bool asked = false;  ///< all_ready was called
};

// `run` for one analysis after the fit: its failure (a throw, or the message it returns) as "the <what>
// failed: …" in *failures.
void Attempt(const char* what, const std::function<std::string()>& run, std::vector<std::string>* failures) {
  std::string why;
  try {
    why = run();
  } catch (const std::exception& e) {
    why = e.what();
  }
  if (!why.empty()) failures->push_back(std::string("the ") + what + " failed: " + why);
}

// The VPC, the NPDE and the bootstrap at the estimates, into the report's context; their failures.
std::vector<std::string> Analyses(const pk::PopulationProblem& problem, const pk::PopulationSummary& fit,
                                  const pk::PopulationOptions& options,
                                  const pk::cli::PopulationSimulationRequest& simulation, bool quiet,
                                  pk::cli::PopulationReportContext* context) {
  std::vector<std::string> failures;
  if (simulation.vpc) {
    Attempt("VPC", [&] {
      context->vpc = pk::ComputeVpc(problem, fit.parameters, *simulation.vpc);
      return std::string();
    }, &failures);
  }
  if (simulation.npde) {
    Attempt("NPDE", [&] {
      context->npde = pk::ComputeNpde(problem, fit.parameters, *simulation.npde);
      if (context->npde->npde.count > 0) return std::string();
      return "no sample has an NPDE" +
             (context->npde->notes.empty() ? std::string() : " (" + context->npde->notes.front() + ")");
    }, &failures);
  }
  if (simulation.bootstrap == 0) return failures;
  pk::BootstrapOptions b;
  b.replicates = simulation.bootstrap;
  b.seed = simulation.seed;
  b.threads = simulation.threads;
  b.fit = options;
  b.stratify = simulation.bootstrap_stratify;
  if (!quiet) {
    b.progress = [n = b.replicates](int done) {
      std::cerr << "\r  bootstrap: " << done << " of " << n << " replicates fitted" << (done == n ? "\n" : "") << std::flush;
    };
  }
  Attempt("bootstrap", [&] {
    context->bootstrap = pk::BootstrapPopulation(problem, fit, b);
    return context->bootstrap->converged == 0 ? std::string("no replicate's fit converged") : std::string();
  }, &failures);
  return failures;
}

int Main(int argc, char** argv, Process* p) {
  const Process& process = *p;
  po::options_description desc("Options");
  Lists a;
  DeclareOptions(&desc, &a);
  po::variables_map vm;
  if (!pk::cli::ParseCommandLine(argc, argv, desc, kUsage, &vm)) return 0;
  if (!vm.count("model") || !vm.count("data")) throw pk::InputError("--model and --data are required");
  // A model file's η (its $OMEGA) are the population model's random effects.
  const auto model = pk::MakeModel(vm["model"].as<std::string>(), pk::RandomEffects::kParameters);
  const auto data = std::make_shared<pk::Dataset>(
      pk::ReadDataset(vm["data"].as<std::string>(), pk::cli::ParseFilter(a.ignore, a.accept)));
  pk::ObjectiveOptions objective;
  objective.propagator = pk::cli::ParsePropagator(vm["propagator"].as<std::string>());
  objective.ode.relative_tolerance = vm["rtol"].as<double>();
  objective.ode.absolute_tolerance = vm["atol"].as<double>();
  // --error, else the model file's $ERROR (one model, or one per output), else combined.
  objective.error_model = pk::DeclaredErrorModel(*model);
  if (vm.count("error") || !objective.error_model) {
    const std::string error = vm.count("error") ? vm["error"].as<std::string>() : "combined";
    objective.error_model = pk::cli::Parsed("--error", [&] { return pk::MakeResidualError(error); });
  }
  std::vector<std::string> etas = SplitCommas(a.eta);
  if (etas.empty()) etas = DefaultEtas(*model);
  const pk::PopulationProblem problem(model, data, etas, objective);
  pk::PopulationOptions options;
  options.method = pk::cli::Parsed("--method", [&] { return pk::ParsePopulationMethod(vm["method"].as<std::string>()); });
  options.gradient =
      pk::cli::Parsed("--gradient", [&] { return pk::ParsePopulationGradient(vm["gradient"].as<std::string>()); });
  const std::string hessian = vm["conditional-hessian"].as<std::string>();
  if (hessian != "exact" && hessian != "differences") {
    throw pk::InputError("--conditional-hessian: expected exact or differences, not '" + hessian + "'");
  }
  options.exact_conditional_hessian = hessian == "exact";
  options.threads = vm["threads"].as<int>();
  options.distribution = process.distribution;
  options.max_iterations = vm["max-evaluations"].as<int>();
  options.covariance = !vm.count("no-covariance");
  options.covariance_matrix = pk::cli::Parsed(
      "--cov-matrix", [&] { return pk::ParseCovarianceMatrix(vm["cov-matrix"].as<std::string>()); });
  // --block replaces the blocks a model file's $OMEGA declares (Blocks keeps the SAME ties it leaves).
  options.structure = problem.DeclaredStructure();
  if (!a.block.empty()) Blocks(problem.eta_names(), a.block, &options.structure);
  const pk::PopulationParameters initial =
      Initial(problem, a, vm.count("init-from") ? vm["init-from"].as<std::string>() : "", &options.structure);
  const pk::cli::PopulationSimulationRequest simulation = pk::cli::ParsePopulationSimulation(vm, options.threads);
  if (simulation.bootstrap > 0 && options.max_iterations == 0) {
    throw pk::InputError("--bootstrap needs estimation: with --max-evaluations 0 every replicate would stay at the "
                         "estimates");
  }
  if (simulation.vpc) pk::CheckVpcOptions(problem, *simulation.vpc);  // before the fit, not after it
  if (!simulation.bootstrap_stratify.empty()) pk::BootstrapStrata(problem.data(), simulation.bootstrap_stratify);
  const bool quiet = vm.count("quiet") > 0 || process.rank > 0;  // process 0 alone speaks and writes
  if (!quiet) {
    options.progress = [](int evaluation, double ofv, double gradient) {
      std::cerr << "\r  evaluation " << evaluation << "  OFV " << pk::FormatNumber(std::round(ofv * 1e6) / 1e6)
                << "  |gradient| " << pk::FormatNumber(std::round(gradient * 1e4) / 1e4) << "        " << std::flush;
    };
  }
  if (process.all_ready) {  // every process got this far: else each stops here rather than wait for it
    p->asked = true;
    if (!process.all_ready(true)) {
      throw pk::InputError("another MPI process stopped before the fit (see its message); nothing was fitted");
    }
  }
  const pk::PopulationSummary fit = pk::FitPopulation(problem, initial, options);
  if (!quiet) std::cerr << "\n";
  const std::string dir = vm["output-dir"].as<std::string>();
  pk::cli::PopulationReportContext context;
  context.model = vm["model"].as<std::string>();
  context.error = pk::DescribeErrorModel(*objective.error_model);
  context.dataset_path = vm["data"].as<std::string>();
  for (int k = 0; k < argc; ++k) context.command_line += (k ? " " : "") + std::string(argv[k]);
  // The analyses at the estimates (process 0 alone); a failure of one loses nothing of the fit, nor
  // does stopping one (a bootstrap may take hours): the fit's own set is written whole first.
  const bool analyses = simulation.vpc || simulation.npde || simulation.bootstrap > 0 || simulation.simulate > 0;
  if (process.rank == 0 && analyses) {
    WriteOutputs(dir, problem, fit, context, pk::cli::PopulationSimulationRequest());
    if (!quiet) std::cerr << "  the fit's results are in " << dir << "/; the analyses after it follow\n";
  }
  std::vector<std::string> failures =
      process.rank == 0 ? Analyses(problem, fit, options, simulation, quiet, &context) : std::vector<std::string>();
  if (process.rank == 0) {
    const std::string simtab = WriteOutputs(dir, problem, fit, context, simulation);
    if (!simtab.empty()) failures.push_back(simtab);
  }
  if (!quiet) {
    std::cout << fit.FullReport() << "\nresults in " << dir
              << "/ (report.html with its plots, population_estimates.csv, sdtab.csv, patab.csv, subjects.csv, iterations.csv, "
                 "covariance.csv, report.txt, pkpop.ext and pkpop.phi: NONMEM's .ext and .phi"
              << (context.vpc ? "; vpc.csv and vpc.svg" : "") << (context.npde ? "; npde.csv and npde.svg" : "")
              << (context.bootstrap ? "; bootstrap.csv" : "")
              << (simulation.simulate > 0 ? "; simtab.csv" : "") << ")\n";
  }
  if (context.vpc && !quiet) std::cout << "\n" << context.vpc->BriefReport();
  if (context.bootstrap && !quiet) std::cout << "\n" << context.bootstrap->FullReport();
  if (context.npde && !quiet) std::cout << "\n" << context.npde->FullReport();
  if (!fit.converged && process.rank == 0) std::cerr << "pkpop: " << fit.message << "\n";
  for (const std::string& f : failures) std::cerr << "pkpop: " << f << "\n";
  return fit.converged && failures.empty() ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  Process process;
#ifdef PK_HAVE_MPI
  // Under mpirun the subjects are split across the processes; alone, this is one process of one.
  std::unique_ptr<pk::MpiSession> mpi;
  if (pk::LaunchedByMpi()) {
    mpi = std::make_unique<pk::MpiSession>(&argc, &argv);
    process.rank = mpi->rank();
    if (mpi->size() > 1) {
      process.distribution = mpi->Distribution();
      process.all_ready = [&mpi](bool ready) { return mpi->AllReady(ready); };
    }
  }
#endif
  const int code = pk::cli::Run("pkpop", [&] { return Main(argc, argv, &process); });
  // This process stopped before the fit (bad input, --help): tell the others, which wait for it there.
  if (process.all_ready && !process.asked) process.all_ready(false);
  return code;
}
