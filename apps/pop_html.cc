// pkpop's report.html (pop_html.h): estimates, goodness-of-fit plots as Xpose draws them, η against
// covariates and the individual fits, rendered from templates/pop_report.html.mustache.
#include "pop_html.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>

#include <kainjow/mustache.hpp>

#include "cli.h"
#include "pk/output.h"
#include "pk/plot.h"
#include "pk/simulate.h"
#include "pk/version.h"
#include "pop_report_template.h"
#include "pop_simulation.h"

namespace pk {
namespace cli {
namespace {

using kainjow::mustache::data;
using kainjow::mustache::list;
using kainjow::mustache::object;
using Files = std::vector<std::pair<std::string, std::string>>;

const char* const kObserved = "#1f77b4";
const char* const kIpred = "#333333";
const char* const kPred = "#2ca02c";
constexpr size_t kMaxPanels = 100;

data Text(const std::string& s) { return data(s); }

PlotOptions Small(const std::string& title, const std::string& x, const std::string& y) {
  PlotOptions o;
  o.title = title;
  o.x_label = x;
  o.y_label = y;
  o.width = 420;
  o.height = 320;
  o.legend = false;
  return o;
}

// Points against a reference line (identity from the data's range, or zero) with a smoother.
std::string Gof(const std::vector<double>& x, const std::vector<double>& y, bool identity, const PlotOptions& o) {
  PlotSeries points{"samples", x, y, true};
  points.colour = kObserved;
  double lo = HUGE_VAL, hi = -HUGE_VAL;
  for (const auto* v : {&x, &y}) {
    for (double e : *v) {
      if (std::isfinite(e)) lo = std::min(lo, e), hi = std::max(hi, e);
    }
  }
  if (!(lo <= hi)) lo = 0, hi = 1;
  PlotSeries reference = identity ? PlotSeries{"identity", {lo, hi}, {lo, hi}}
                                  : PlotSeries{"zero", {*std::min_element(x.begin(), x.end()),
                                                        *std::max_element(x.begin(), x.end())}, {0, 0}};
  reference.reference = true;
  return RenderGofSvg(points, reference, o);
}

// The plots of one output's rows (every row's when `dvid` is 0); `suffix` names its files and titles.
void GoodnessOfFit(const PopulationSummary& fit, int dvid, const std::string& title, const std::string& suffix,
                   list* svgs, Files* files) {
  std::map<std::string, std::vector<double>> c;
  for (const PopulationRow& r : fit.rows) {
    if (r.censored != 0) continue;  // DV is a limit (M3), not a value to plot against a prediction
    if (dvid != 0 && r.dvid != dvid) continue;
    for (const auto& [name, v] : std::map<std::string, double>{{"DV", r.dv}, {"PRED", r.pred}, {"IPRED", r.ipred},
                                                                {"TIME", r.time}, {"CWRES", r.cwres}, {"IWRES", r.iwres}}) {
      c[name].push_back(v);
    }
  }
  const struct {
    const char *file, *x, *y;
    bool identity;
  } plots[] = {{"dv_pred", "PRED", "DV", true},       {"dv_ipred", "IPRED", "DV", true},
               {"cwres_time", "TIME", "CWRES", false}, {"cwres_pred", "PRED", "CWRES", false},
               {"iwres_ipred", "IPRED", "IWRES", false}};
  for (const auto& p : plots) {
    const std::string svg =
        Gof(c[p.x], c[p.y], p.identity, Small(std::string(p.y) + " against " + p.x + title, p.x, p.y));
    svgs->push_back(object{{"svg", svg}});
    files->push_back({std::string("gof_") + p.file + suffix + ".svg", svg});
  }
}

// DV against PRED and IPRED, CWRES and IWRES: one set for the rows of each output (DVID) when there
// are several, as Xpose facets them: a concentration and an effect share no axis.
void GoodnessOfFit(const PopulationProblem& problem, const PopulationSummary& fit, list* svgs, Files* files) {
  if (fit.rows.empty()) return;
  std::set<int> dvids;
  for (const PopulationRow& r : fit.rows) dvids.insert(r.dvid);
  if (dvids.size() == 1) {
    GoodnessOfFit(fit, 0, "", "", svgs, files);
    return;
  }
  // As pkfit names them: output 1's files unsuffixed, DVID k's with _k; titles "(EFFECT, DVID 2)".
  const Model& model = problem.model();
  for (int dvid : dvids) {
    const bool named = dvid >= 1 && dvid <= model.num_outputs();
    const std::string title =
        " (" + (named ? model.output_names()[static_cast<size_t>(dvid - 1)] + ", " : "") + "DVID " + std::to_string(dvid) + ")";
    GoodnessOfFit(fit, dvid, title, dvid <= 1 ? "" : "_" + std::to_string(dvid), svgs, files);
  }
}

// η̂ against each covariate column's first value per subject (columns with one value only are left out).
void Covariates(const PopulationProblem& problem, const PopulationSummary& fit, list* svgs, Files* files) {
  const Dataset& data = problem.data();
  for (size_t col = 0; col < data.extra_columns.size(); ++col) {
    std::vector<double> x;
    std::vector<std::vector<double>> y(problem.eta_names().size());
    for (const PopulationSubject& s : fit.subjects) {
      if (!s.ok) continue;
      if (s.subject < 0 || static_cast<size_t>(s.subject) >= data.subjects.size()) continue;
      const auto it = data.subjects.begin() + s.subject;
      if (it->records.empty() || !std::isfinite(it->records.front().extra[col])) continue;
      x.push_back(it->records.front().extra[col]);
      for (size_t k = 0; k < y.size(); ++k) y[k].push_back(s.eta(static_cast<Eigen::Index>(k)));
    }
    if (x.size() < 3 || *std::min_element(x.begin(), x.end()) == *std::max_element(x.begin(), x.end())) continue;
    const std::string& cov = data.extra_columns[col];
    for (size_t k = 0; k < y.size(); ++k) {
      const std::string eta = EtaLabel(problem.eta_names()[k]);
      const std::string svg = Gof(x, y[k], false, Small(eta + " against " + cov, cov, eta));
      svgs->push_back(object{{"svg", svg}});
      files->push_back({"eta_" + problem.eta_names()[k] + "_" + cov + ".svg", svg});
    }
  }
}

// A subject's prediction curves from time 0 to its last record, one per output (1 = CP): at φ (IPRED)
// or θ (PRED). A model file's η are parameters of its own (ETA_CL): IPRED sets them to η̂; a
// catalogue model's individual parameters already hold exp(η̂).
std::vector<PlotSeries> Curves(const PopulationProblem& problem, int subject, const Eigen::VectorXd& values,
                               const Eigen::VectorXd& eta, const std::string& label, int outputs) {
  const auto& records = problem.data().subjects[static_cast<size_t>(subject)].records;
  SimulationOptions options;
  options.check_values = false;  // estimates may sit at the edge of their range
  const double last = records.empty() ? 0 : records.back().time;
  for (int k = 0; k <= 240; ++k) options.output_times.push_back(last * k / 240.0);
  ParameterValues p;
  for (size_t k = 0; k < problem.theta_names().size(); ++k) p[problem.theta_names()[k]] = values(static_cast<Eigen::Index>(k));
  const Model& model = problem.model();
  for (size_t k = 0; k < problem.eta_names().size() && static_cast<Eigen::Index>(k) < eta.size(); ++k) {
    const int i = model.ParameterIndex(problem.eta_names()[k]);
    if (i >= 0 && model.is_eta(i)) p[problem.eta_names()[k]] = eta(static_cast<Eigen::Index>(k));
  }
  std::vector<PlotSeries> curves(static_cast<size_t>(outputs), PlotSeries{label, {}, {}});
  const SubjectSimulation sim = SimulateSubject(model, problem.data(), subject, p, options);
  // Each output by its own column (an added output time copies its neighbour's CMT and DVID, which
  // may name a dose compartment or another output).
  for (size_t i = 0; i < sim.rows.size(); ++i) {
    const SimulatedRecord& r = sim.rows[i];
    if (r.evid != Evid::kOther) continue;
    for (int k = 0; k < outputs; ++k) {
      curves[static_cast<size_t>(k)].x.push_back(r.time);
      curves[static_cast<size_t>(k)].y.push_back(k == 0 ? r.cp : sim.outputs(k, static_cast<Eigen::Index>(i)));
    }
  }
  return curves;
}

// The outputs the report's subject panels show: those the data observe, up to the model's last.
int PanelOutputs(const PopulationProblem& problem, const PopulationSummary& fit) {
  int outputs = 1;
  for (const PopulationRow& r : fit.rows) outputs = std::max(outputs, r.dvid);
  return std::min(outputs, std::max(1, problem.model().num_outputs()));
}

// Each subject's DV with its IPRED and PRED curves, in dataset order (the first kMaxPanels), a panel
// per observed output.
list Panels(const PopulationProblem& problem, const PopulationSummary& fit) {
  // By the subject's position in the data: an ID that comes back is another subject.
  std::map<int, std::vector<const PopulationRow*>> rows;
  for (const PopulationRow& r : fit.rows) rows[r.subject].push_back(&r);
  const int outputs = PanelOutputs(problem, fit);
  list panels;
  size_t shown = 0;
  for (const PopulationSubject& s : fit.subjects) {
    if (!s.ok || shown == kMaxPanels) continue;
    if (s.subject < 0 || static_cast<size_t>(s.subject) >= problem.data().subjects.size()) continue;
    const Eigen::VectorXd zero = Eigen::VectorXd::Zero(s.eta.size());
    std::vector<PlotSeries> ipred = Curves(problem, s.subject, s.parameters, s.eta, "IPRED", outputs),
                            pred = Curves(problem, s.subject, fit.parameters.theta, zero, "PRED", outputs);
    list figures;  // side by side, a subject's outputs stay on one row
    for (int k = 1; k <= outputs; ++k) {
      PlotSeries dv{"DV", {}, {}, true};
      for (const PopulationRow* r : rows[s.subject]) {
        if (r->censored == 0 && std::max(r->dvid, 1) == k) dv.x.push_back(r->time), dv.y.push_back(r->dv);
      }
      PlotSeries& i = ipred[static_cast<size_t>(k - 1)];
      PlotSeries& p = pred[static_cast<size_t>(k - 1)];
      dv.colour = kObserved, i.colour = kIpred, p.colour = kPred;
      const std::string name = outputs > 1 ? problem.model().output_names()[static_cast<size_t>(k - 1)] : "";
      figures.push_back(object{{"caption", Text("ID " + FormatNumber(s.id) + (name.empty() ? "" : " · " + name))},
                               {"svg", RenderSvg({p, i, dv}, Small("", "time", k == 1 ? "concentration" : name))}});
    }
    panels.push_back(object{{"span", std::to_string(outputs)}, {"figures", figures}});
    ++shown;
  }
  return panels;
}

list Estimates(const PopulationProblem& problem, const PopulationSummary& fit) {
  list rows;
  for (const PopulationEstimate& e : fit.estimates) {
    std::string cv = std::isfinite(e.cv_pct) ? Sig(e.cv_pct, 3) : "", shrinkage;
    for (size_t k = 0; k < problem.eta_names().size(); ++k) {
      if (e.name != "OMEGA(" + problem.eta_names()[k] + ")") continue;
      if (static_cast<Eigen::Index>(k) < fit.eta_shrinkage_sd.size()) {
        shrinkage = Sig(100 * fit.eta_shrinkage_sd(static_cast<Eigen::Index>(k)), 3) + "%";
      }
    }
    const std::string flag = e.same ? "SAME: the block before it" : e.fixed ? "fixed" : e.at_boundary ? "at its boundary" : "";
    rows.push_back(object{{"name", Text(e.name)}, {"estimate", Sig(e.estimate, 4)}, {"se", Sig(e.se, 3)},
                          {"rse", Sig(e.rse_pct, 3)}, {"cv", Text(cv)}, {"shrinkage", Text(shrinkage)},
                          {"flag", Text(flag)}, {"class", Text(e.at_boundary ? "bad" : "")}});
  }
  // NONMEM's $SIGMA holds variances: each σ² with SE(σ²) = 2σ·SE(σ) and twice the RSE, as report.txt.
  for (const PopulationEstimate& e : fit.estimates) {
    if (e.name.rfind("SIGMA_", 0) != 0) continue;
    rows.push_back(object{{"name", Text(e.name + "²")},
                          {"estimate", Sig(e.estimate * e.estimate, 4)},
                          {"se", Sig(2 * e.estimate * e.se, 3)},
                          {"rse", Sig(2 * e.rse_pct, 3)},
                          {"cv", Text("")},
                          {"shrinkage", Text("")},
                          {"flag", Text(std::string(e.fixed ? "fixed; " : "") + "as NONMEM's $SIGMA, a variance")},
                          {"class", Text("")}});
  }
  return rows;
}

// The bootstrap's table: each parameter's estimate and SE beside the replicates' median, mean, bias, SE
// and interval.
void Bootstrap(const BootstrapSummary& b, const PopulationSummary& fit, object* page) {
  list rows;
  for (size_t k = 0; k < b.parameters.size() && k < fit.estimates.size(); ++k) {
    const BootstrapParameter& p = b.parameters[k];
    const bool shown = !p.fixed && std::isfinite(p.lower);
    rows.push_back(object{{"name", Text(p.name)},
                          {"estimate", Sig(p.estimate, 4)},
                          {"se", Sig(fit.estimates[k].se, 3)},
                          {"median", Sig(p.fixed ? NAN : p.median, 4)},
                          {"mean", Sig(p.fixed ? NAN : p.mean, 4)},
                          {"bias", Sig(p.fixed ? NAN : p.bias, 3)},
                          {"bse", Sig(p.fixed ? NAN : p.se, 3)},
                          {"interval", Text(shown ? Sig(p.lower, 4) + " to " + Sig(p.upper, 4) : p.fixed ? "fixed" : "")}});
  }
  (*page)["bootstrap"] = rows;
  (*page)["bootstrap_interval"] = Text(FormatNumber(b.interval) + "% interval");
  (*page)["bootstrap_note"] = Text(b.BriefReport());
}

}  // namespace

Files PopulationReport(const PopulationProblem& problem, const PopulationSummary& fit,
                       const PopulationReportContext& c) {
  Files files;
  object page;
  page["model"] = c.model;
  page["dataset"] = c.dataset_path.substr(c.dataset_path.find_last_of('/') + 1);
  page["dataset_path"] = c.dataset_path;
  page["num_subjects"] = std::to_string(problem.num_subjects());
  page["num_samples"] = std::to_string(problem.num_observations());
  std::string etas;
  for (const auto& n : problem.eta_names()) etas += (etas.empty() ? "" : ", ") + n;
  page["etas"] = etas;
  page["error"] = c.error;
  page["method"] = Text(std::string(ToString(fit.method)) + " (NONMEM's " +
                        (fit.method == PopulationMethod::kFo      ? "METHOD=ZERO"
                         : fit.method == PopulationMethod::kFoce  ? "METHOD=COND"
                         : fit.method == PopulationMethod::kFocei ? "METHOD=COND INTER"
                                                                  : "METHOD=COND LAPLACIAN INTER") + ")");
  page["date"] = Today();
  page["version"] = Text(Version());
  page["command"] = c.command_line;
  page["ofv"] = Sig(fit.ofv, 10);
  page["converged"] = data(fit.converged);
  page["status"] = Text(fit.converged ? "converged" : "not converged");
  if (fit.failed_subjects > 0) page["num_failed"] = std::to_string(fit.failed_subjects);
  page["evaluations"] = std::to_string(fit.evaluations);
  page["seconds"] = Sig(fit.seconds, 3);
  page["message"] = Text("The outer optimiser ended: " + fit.message + ".");
  page["covariance"] = Text(fit.covariance_message.empty()
                                ? std::string(Describe(fit.covariance_matrix)) +
                                      (fit.covariance_derivatives.empty() ? "" : "; " + fit.covariance_derivatives)
                                : "none");
  page["estimates"] = Estimates(problem, fit);
  std::string eps = Sig(100 * fit.epsilon_shrinkage_sd, 3) + "%";
  for (size_t k = 0; k < fit.epsilon_shrinkage_sd_by_output.size(); ++k) {
    eps += (k == 0 ? " (DVID 1: " : ", DVID " + std::to_string(k + 1) + ": ") +
           Sig(100 * fit.epsilon_shrinkage_sd_by_output[k], 3) + "%" +
           (k + 1 == fit.epsilon_shrinkage_sd_by_output.size() ? ")" : "");
  }
  page["epsilon_shrinkage"] = eps;
  page["gradient"] = fit.gradient;
  if (!fit.eta_estimates.empty()) page["eta_estimates"] = fit.eta_estimates;
  list notes;
  if (!fit.covariance_message.empty()) notes.push_back(Text("No standard errors: " + fit.covariance_message));
  for (const std::string& w : fit.CovarianceWarnings()) notes.push_back(Text("Covariance step: " + w + "."));
  for (const PopulationSubject& s : fit.subjects) {
    if (!s.ok) notes.push_back(Text("Subject " + FormatNumber(s.id) + ": " + s.message));
  }
  page["has_notes"] = data(!notes.empty());
  page["notes"] = notes;
  list gof, covariates;
  GoodnessOfFit(problem, fit, &gof, &files);
  Covariates(problem, fit, &covariates, &files);
  page["gof"] = gof;
  page["has_vpc"] = data(c.vpc.has_value());
  if (c.vpc) {
    page["vpc_svg"] = Text(VpcSvg(*c.vpc, problem.model()));
    page["vpc_note"] = Text(c.vpc->BriefReport());
  }
  page["has_bootstrap"] = data(c.bootstrap.has_value());
  if (c.bootstrap) Bootstrap(*c.bootstrap, fit, &page);
  page["has_npde"] = data(c.npde.has_value());
  if (c.npde) {
    page["npde_svg"] = Text(NpdeSvg(*c.npde));
    std::string note = c.npde->BriefReport();
    const size_t shown = std::min<size_t>(c.npde->notes.size(), 10);
    for (size_t k = 0; k < shown; ++k) note += " " + c.npde->notes[k] + ".";
    if (shown < c.npde->notes.size()) note += " " + std::to_string(c.npde->notes.size() - shown) + " more in report.txt.";
    page["npde_note"] = Text(note);
  }
  page["has_covariates"] = data(!covariates.empty());
  page["covariate_plots"] = covariates;
  page["panels"] = Panels(problem, fit);
  const size_t subjects = fit.subjects.size();
  const bool outputs = PanelOutputs(problem, fit) > 1;
  page["panels_note"] = Text((subjects > kMaxPanels ? "The first " + std::to_string(kMaxPanels) + " of " +
                                                          std::to_string(subjects) + " subjects. "
                                                    : "") +
                             (outputs ? "A panel per output the data observe (DVID)." : ""));
  kainjow::mustache::mustache tmpl(PopulationReportTemplate());
  files.insert(files.begin(), {"report.html", tmpl.render(page)});
  return files;
}

}  // namespace cli
}  // namespace pk
