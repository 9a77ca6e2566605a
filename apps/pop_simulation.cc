// pkpop's simulations at the estimates (pop_simulation.h).
#include "pop_simulation.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>

#include "cli.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/plot.h"
#include "pk/population_simulation.h"

namespace po = boost::program_options;

namespace pk {
namespace cli {
namespace {

std::vector<std::string> Commas(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream ss(text);
  for (std::string item; std::getline(ss, item, ',');) out.push_back(item);
  return out;
}

double Number(const std::string& option, const std::string& text) {
  double v = 0;
  if (!ParseNumber(text, &v)) throw InputError(option + ": '" + text + "' is not a number");
  return v;
}

// --vpc-bins: auto, a count, or edges.
void ParseBins(const std::string& text, VpcOptions* o) {
  if (text == "auto") return;
  const std::vector<std::string> items = Commas(text);
  if (items.size() == 1) {
    const double count = Number("--vpc-bins", items[0]);
    if (!(count >= 1 && count <= 1000 && count == std::floor(count))) {
      throw InputError("--vpc-bins: a count of bins is a whole number from 1 to 1000, not '" + text + "'");
    }
    o->max_bins = static_cast<int>(count);
    return;
  }
  for (const std::string& item : items) o->bin_edges.push_back(Number("--vpc-bins", item));
}

std::string Ordinal(double p) {
  const std::string n = FormatNumber(p);
  const long whole = std::lround(p);
  if (p != static_cast<double>(whole)) return n + "th";
  const long last = whole % 10, tens = whole % 100;
  return n + (tens >= 11 && tens <= 13 ? "th" : last == 1 ? "st" : last == 2 ? "nd" : last == 3 ? "rd" : "th");
}

}  // namespace

void AddPopulationSimulationOptions(po::options_description* desc) {
  desc->add_options()(
      "vpc", po::value<int>()->default_value(0),
      "after the fit, a visual predictive check from this many replicates of the data simulated at the estimates "
      "(vpc.csv, vpc.svg and a section of report.html); 0: none")(
      "vpc-bins", po::value<std::string>()->default_value("auto"),
      "the VPC's time bins: auto (each distinct time up to 10 a DVID, else Jenks' natural breaks into 10), a "
      "count N (the same with N), or edges T0,T1,...")(
      "vpc-min-bin", po::value<int>()->default_value(5),
      "automatic bins: one with fewer values joins its neighbour across the smaller gap in time (1: never)")(
      "vpc-percentiles", po::value<std::string>()->default_value("5,50,95"), "the percentiles the VPC compares")(
      "vpc-interval", po::value<double>()->default_value(90), "the simulated percentiles' interval, %")(
      "pcvpc", "prediction-corrected VPC (Bergstrand et al. 2011): each value scaled by its bin's median PRED over its own")(
      "pvcvpc",
      "prediction- and variability-corrected VPC (PsN's -varcorr): a pcVPC whose values' deviations from the bin's "
      "median PRED are also scaled by the bin's median spread over their own (simulates the replicates twice)")(
      "vpc-lower-bound", po::value<double>()->default_value(0), "pcVPC: the data's lower bound")(
      "vpc-stratify", po::value<std::string>(),
      "a data column to stratify the VPC by (a panel for each of its values, at most 20), e.g. DOSE or STUDY")(
      "vpc-lloq", po::value<double>(),
      "a limit of quantification for every DVID: observed and simulated values below it count as censored (default: "
      "the limits of the data's CENS=1 rows)")(
      "simulate", po::value<int>()->default_value(0),
      "after the fit, this many replicates of the data simulated at the estimates into simtab.csv (REP, ID, TIME, "
      "DVID, DV, IPRED, PRED and the drawn η), as NONMEM's $SIMULATION")(
      "npde", po::value<int>()->default_value(0),
      "after the fit, normalised prediction distribution errors (NPDE, NPD) of every sample from this many simulations "
      "of each subject at the estimates (npde.csv, npde.svg and a section of report.html), as NONMEM's $TABLE NPDE "
      "and the npde package; 0: none, else at least 2 (1000 is usual)")(
      "bootstrap", po::value<int>()->default_value(0),
      "after the fit, a nonparametric bootstrap of this many replicates (subjects drawn with replacement, the model "
      "fitted again from the estimates, as PsN's bootstrap): bootstrap.csv, each parameter's median, SE and 95% "
      "interval in report.txt and report.html; 0: none")(
      "bootstrap-stratify", po::value<std::string>(),
      "draw each bootstrap replicate's subjects within the strata of this data column (its value on each subject's "
      "first record), keeping each stratum's size, as PsN's -stratify_on")(
      "seed", po::value<std::string>()->default_value("1"),
      "the seed of the simulations and of the bootstrap's draws (an integer up to 2^64 − 1)");
}

PopulationSimulationRequest ParsePopulationSimulation(const po::variables_map& vm, int threads) {
  PopulationSimulationRequest r;
  r.seed = ParseSeed(vm["seed"].as<std::string>());
  r.threads = std::max(1, threads);
  r.simulate = vm["simulate"].as<int>();
  if (r.simulate < 0 || r.simulate > 100000) throw InputError("--simulate: expected 0 to 100000 replicates");
  r.bootstrap = vm["bootstrap"].as<int>();
  if (r.bootstrap < 0 || r.bootstrap > 100000) throw InputError("--bootstrap: expected 0 to 100000 replicates");
  if (vm.count("bootstrap-stratify")) {
    if (r.bootstrap == 0) throw InputError("--bootstrap-stratify needs --bootstrap N");
    r.bootstrap_stratify = vm["bootstrap-stratify"].as<std::string>();
  }
  const int npde = vm["npde"].as<int>();
  if (npde < 0 || npde == 1 || npde > 100000) throw InputError("--npde: expected 0 (none) or 2 to 100000 simulations");
  if (npde > 0) {
    NpdeOptions o;
    o.simulations = npde;
    o.seed = r.seed;
    o.threads = r.threads;
    r.npde = o;
  }
  const int replicates = vm["vpc"].as<int>();
  if (replicates < 0 || replicates > 100000) throw InputError("--vpc: expected 0 to 100000 replicates");
  const bool vpc_only = !vm["vpc-bins"].defaulted() || !vm["vpc-percentiles"].defaulted() || !vm["vpc-min-bin"].defaulted() ||
                        !vm["vpc-interval"].defaulted() || vm.count("pcvpc") || vm.count("pvcvpc") ||
                        !vm["vpc-lower-bound"].defaulted() ||
                        vm.count("vpc-lloq") || vm.count("vpc-stratify");
  if (replicates == 0) {
    if (vpc_only) {
      throw InputError("--vpc-bins, --vpc-min-bin, --vpc-percentiles, --vpc-interval, --pcvpc, --pvcvpc, --vpc-lower-bound, "
                       "--vpc-lloq and --vpc-stratify need --vpc N");
    }
    if (r.simulate == 0 && npde == 0 && r.bootstrap == 0 && !vm["seed"].defaulted()) {
      throw InputError("--seed needs --vpc N, --npde N, --simulate N or --bootstrap N");
    }
    return r;
  }
  VpcOptions o;
  o.replicates = replicates;
  o.seed = r.seed;
  o.threads = std::max(1, threads);
  ParseBins(vm["vpc-bins"].as<std::string>(), &o);
  o.percentiles.clear();
  for (const std::string& p : Commas(vm["vpc-percentiles"].as<std::string>())) o.percentiles.push_back(Number("--vpc-percentiles", p));
  o.interval = vm["vpc-interval"].as<double>();
  o.min_bin_count = vm["vpc-min-bin"].as<int>();
  o.variability_corrected = vm.count("pvcvpc") > 0;
  o.prediction_corrected = vm.count("pcvpc") > 0 || o.variability_corrected;  // --pvcvpc implies it
  o.lower_bound = vm["vpc-lower-bound"].as<double>();
  if (vm.count("vpc-lloq")) o.lloq = vm["vpc-lloq"].as<double>();
  if (vm.count("vpc-stratify")) o.stratify = vm["vpc-stratify"].as<std::string>();
  std::string why;
  if (!o.IsValid(&why)) throw InputError("--vpc: " + why);
  r.vpc = o;
  return r;
}

int WriteSimtab(const std::string& path, const PopulationProblem& problem, const PopulationParameters& parameters,
                const PopulationSimulationRequest& request) {
  const SimulationDesign design = MakeSimulationDesign(problem, parameters);
  AtomicFile file(path);
  std::string header = "REP,ID,TIME,DVID,DV,IPRED,PRED";
  for (const std::string& n : problem.eta_names()) header += "," + EtaLabel(n);
  file.Write(header + "\n");
  PopulationSimulationOptions options;
  options.replicates = request.simulate;
  options.seed = request.seed;
  options.threads = request.threads;
  int failed = 0;
  const auto number = [](double v) { return std::isfinite(v) ? FormatNumber(v) : std::string(); };
  SimulatePopulation(problem, parameters, options, [&](const SimulatedReplicate& r) {
    std::string text;
    const std::string rep = std::to_string(r.replicate + 1);
    for (size_t i = 0; i < r.subjects.size(); ++i) {
      const SimulatedSubject& s = r.subjects[i];
      const SimulationDesign::Subject& d = design.subjects[i];
      if (!s.ok) {
        ++failed;
        continue;
      }
      std::string etas;
      for (Eigen::Index k = 0; k < s.eta.size(); ++k) etas += "," + number(s.eta(k));
      for (size_t j = 0; j < d.time.size(); ++j) {
        const auto jj = static_cast<Eigen::Index>(j);
        text += rep + "," + number(d.id) + "," + number(d.time[j]) + "," + std::to_string(d.dvid[j]) + "," +
                number(s.dv(jj)) + "," + number(s.ipred(jj)) + "," + number(d.pred(jj)) + etas + "\n";
      }
    }
    file.Write(text);
  });
  file.Commit();
  return failed;
}

std::string NpdeSvg(const NpdeSummary& npde) {
  PlotSeries time{"NPDE", {}, {}, true}, epred{"NPDE", {}, {}, true};
  std::vector<double> sorted;
  double t0 = INFINITY, t1 = -INFINITY, e0 = INFINITY, e1 = -INFINITY;
  for (const NpdeRow& r : npde.rows) {
    if (!std::isfinite(r.npde)) continue;
    time.x.push_back(r.time), time.y.push_back(r.npde);
    epred.x.push_back(r.epred), epred.y.push_back(r.npde);
    sorted.push_back(r.npde);
    t0 = std::min(t0, r.time), t1 = std::max(t1, r.time), e0 = std::min(e0, r.epred), e1 = std::max(e1, r.epred);
  }
  std::sort(sorted.begin(), sorted.end());
  time.colour = epred.colour = "#1f77b4";
  // N(0, 1)'s 2.5th, 50th and 97.5th percentiles across each panel.
  const auto lines = [](double x0, double x1) {
    std::vector<PlotSeries> out;
    for (const auto& [label, z] : {std::pair<const char*, double>{"+1.96 (97.5%)", 1.959963984540054},
                                   {"0 (median)", 0.0}, {"−1.96 (2.5%)", -1.959963984540054}}) {
      PlotSeries l{label, {x0, x1}, {z, z}};
      l.reference = true;
      out.push_back(l);
    }
    return out;
  };
  PlotSeries qq{"NPDE", {}, sorted, true}, identity{"identity", {}, {}};
  qq.colour = "#1f77b4";
  identity.reference = true;
  const double n = static_cast<double>(sorted.size());
  for (size_t k = 0; k < sorted.size(); ++k) qq.x.push_back(NormalQuantile((static_cast<double>(k) + 0.5) / n));
  if (!sorted.empty()) {
    const double lo = std::min(qq.x.front(), sorted.front()), hi = std::max(qq.x.back(), sorted.back());
    identity.x = {lo, hi}, identity.y = {lo, hi};
  }
  std::vector<std::vector<PlotSeries>> panels(3);
  std::vector<PlotOptions> options(3);
  panels[0] = lines(t0, t1);
  panels[0].push_back(time);
  panels[1] = lines(e0, e1);
  panels[1].push_back(epred);
  panels[2] = {identity, qq};
  const std::string of = " · " + std::to_string(npde.npde.count) + " samples, " + std::to_string(npde.simulations) +
                         " simulations";
  options[0].title = "NPDE against time" + of;
  options[1].title = "NPDE against EPRED (the simulations' mean)";
  options[1].x_label = "EPRED";
  options[2].title = "NPDE quantiles against N(0, 1)'s";
  options[2].x_label = "N(0, 1) quantile";
  for (PlotOptions& o : options) o.width = 900, o.height = 420;
  options[0].y_label = options[1].y_label = options[2].y_label = "NPDE";
  return RenderPanelsSvg(panels, options);
}

std::string VpcSvg(const VpcSummary& vpc, const Model& model) {
  std::map<std::pair<double, int>, std::vector<const VpcBin*>> panels;  // (stratum, DVID)
  for (const VpcBin& b : vpc.bins) panels[{b.stratum, b.dvid}].push_back(&b);
  std::set<int> dvids;
  for (const VpcBin& b : vpc.bins) dvids.insert(b.dvid);
  std::vector<std::vector<PlotSeries>> all;
  std::vector<PlotOptions> options;
  const std::string interval = FormatNumber(vpc.interval) + "% PI";
  for (const auto& [panel, bins] : panels) {
    const double stratum = panel.first;
    const int dvid = panel.second;
    std::vector<PlotSeries> series;
    PlotSeries points{"observed", {}, {}, true};
    points.hollow = true;
    points.colour = "#9a9a9a";
    for (const VpcObservation& o : vpc.observations) {
      const VpcBin& bin = vpc.bins[static_cast<size_t>(o.bin)];
      if (bin.dvid == dvid && bin.stratum == stratum) points.x.push_back(o.time), points.y.push_back(o.value);
    }
    for (size_t k = 0; k < vpc.percentiles.size(); ++k) {
      const bool median = vpc.percentiles[k] == 50;
      PlotSeries band{"sim. " + Ordinal(vpc.percentiles[k]) + " (" + interval + ")", {}, {}};
      PlotSeries observed{"obs. " + Ordinal(vpc.percentiles[k]), {}, {}};
      band.colour = median ? "#d62728" : "#1f77b4";
      observed.colour = "#111111";
      observed.dashed = !median;
      for (const VpcBin* b : bins) {
        band.x.push_back(b->time);
        band.y.push_back(b->simulated_lower[k]);
        band.upper.push_back(b->simulated_upper[k]);
        observed.x.push_back(b->time);
        observed.y.push_back(b->observed[k]);
      }
      series.insert(series.begin() + static_cast<std::ptrdiff_t>(k), band);  // bands beneath the lines and points
      series.push_back(observed);
    }
    series.insert(series.begin() + static_cast<std::ptrdiff_t>(vpc.percentiles.size()), points);
    PlotOptions o;
    const std::vector<std::string>& names = model.output_names();
    const std::string name = dvid >= 1 && static_cast<size_t>(dvid) <= names.size() ? names[static_cast<size_t>(dvid - 1)] : "";
    const std::string where = (vpc.stratify.empty() ? "" : " · " + vpc.stratify + " = " + FormatNumber(stratum)) +
                              (dvids.size() > 1 ? " · DVID " + std::to_string(dvid) + (name.empty() ? "" : " (" + name + ")") : "");
    o.title = vpc.Kind() + where + " · " +
              std::to_string(vpc.replicates) + " replicates";
    o.y_label = vpc.variability_corrected ? "prediction- and variability-corrected DV"
                : vpc.prediction_corrected  ? "prediction-corrected DV"
                                            : "DV";
    o.width = 900;
    all.push_back(std::move(series));
    options.push_back(o);
    if (!vpc.limits) continue;
    // Censored data: the fraction of each bin below the limit, observed against simulated (PsN's BLQ panel).
    PlotSeries band{"sim. (" + interval + ")", {}, {}}, observed{"observed", {}, {}};
    band.colour = "#1f77b4";
    observed.colour = "#111111";
    for (const VpcBin* b : bins) {
      band.x.push_back(b->time);
      band.y.push_back(b->censored_lower);
      band.upper.push_back(b->censored_upper);
      observed.x.push_back(b->time);
      observed.y.push_back(b->censored_observed);
    }
    PlotOptions f = o;
    f.title = "Fraction below the limit of quantification" + where;
    f.y_label = "fraction BLQ";
    f.height = 300;
    all.push_back({band, observed});
    options.push_back(f);
  }
  return RenderPanelsSvg(all, options);
}

}  // namespace cli
}  // namespace pk
