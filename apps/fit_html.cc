// report.html: the template apps/templates/report.html.mustache filled with the fits, and the
// plots it shows. kainjow::mustache is used in this file only.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>

#include <kainjow/mustache.hpp>

#include "fit_csv.h"
#include "fit_report.h"
#include "pk/output.h"
#include "pk/plot.h"
#include "pk/version.h"
#include "report_template.h"

namespace pk {
namespace cli {
namespace {

using kainjow::mustache::data;
using kainjow::mustache::list;
using kainjow::mustache::object;

const char* const kObserved = "#1f77b4";
const char* const kFitted = "#333333";

// Text as mustache data. (A bare const char* would become a bool: data has a constructor from bool.)
data Text(const std::string& s) { return data(s); }
// Text for a {{#section}} that is left out when the text is empty (an empty string is not false).
data Maybe(const std::string& s) { return s.empty() ? data(false) : data(s); }

std::string ConcentrationLabel(const Units& u) { return WithUnit("concentration", u.concentration); }
std::string TimeLabel(const Units& u) { return WithUnit("time", u.time); }

// One panel of a subject's fit: observed (censored hollow, at their limit) and the fitted curve.
std::string SubjectSvg(const SubjectFit& f, const ReportContext& c, bool log, int output, bool panel) {
  PlotSeries data{"observed", {}, {}, true}, censored{"censored (at its limit)", {}, {}, true};
  censored.hollow = true;
  data.colour = censored.colour = kObserved;
  for (int k = 0; k < f.dv.size(); ++k) {
    if (!f.sample_output.empty() && f.sample_output[static_cast<size_t>(k)] != output) continue;
    PlotSeries& to = k < f.censoring.size() && f.censoring(k) != 0 ? censored : data;
    to.x.push_back(f.times[static_cast<size_t>(k)]);
    to.y.push_back(f.dv(k));
  }
  const bool multi = !f.output_curves.empty();
  PlotSeries curve{"fitted (IPRED)", f.curve_times, multi ? f.output_curves[static_cast<size_t>(output - 1)] : f.curve, false};
  curve.colour = kFitted;
  PlotOptions o;
  o.title = panel ? "" : "ID " + SubjectLabel(f);
  if (multi) o.title += (o.title.empty() ? "" : " ") + f.output_names[static_cast<size_t>(output - 1)];
  o.x_label = TimeLabel(c.units);
  o.y_label = multi && output > 1 ? "output " + f.output_names[static_cast<size_t>(output - 1)] : ConcentrationLabel(c.units);
  o.log_y = log && (!multi || output == 1);
  o.legend = !panel;
  if (panel) {
    o.width = 420;
    o.height = 300;
  }
  std::vector<PlotSeries> series{curve, data};
  if (!censored.x.empty()) series.push_back(censored);
  return RenderSvg(series, o);
}

int NumOutputs(const SubjectFit& f) { return f.output_curves.empty() ? 1 : static_cast<int>(f.output_curves.size()); }

// The axes the subject panels are drawn with.
std::vector<bool> PanelAxes(const ReportContext& c) {
  switch (c.axis) {
    case Axis::kLinear: return {false};
    case Axis::kLog: return {true};
    case Axis::kBoth: return {false, true};
    case Axis::kAuto: break;
  }
  return {c.multi_exponential};
}

// The samples of one output, all subjects together, for the goodness-of-fit plots.
struct GofPoints {
  std::vector<double> ipred, dv, time, iwres, cens_ipred, cens_dv;
  std::string name;
};

GofPoints CollectGof(const std::vector<SubjectFit>& fits, int output) {
  GofPoints g;
  for (const SubjectFit& f : fits) {
    if (!f.ok) continue;
    if (!f.output_names.empty() && output <= static_cast<int>(f.output_names.size())) {
      g.name = f.output_names[static_cast<size_t>(output - 1)];
    }
    for (int k = 0; k < f.ipred.size(); ++k) {
      if (f.sample_output.empty() ? output != 1 : f.sample_output[static_cast<size_t>(k)] != output) continue;
      if (k < f.censoring.size() && f.censoring(k) != 0) {
        g.cens_ipred.push_back(f.ipred(k));
        g.cens_dv.push_back(f.dv(k));
        continue;
      }
      g.ipred.push_back(f.ipred(k));
      g.dv.push_back(f.dv(k));
      g.time.push_back(f.times[static_cast<size_t>(k)]);
      g.iwres.push_back(k < f.iwres.size() ? f.iwres(k) : NAN);
    }
  }
  return g;
}

// For the log-log plot: the samples whose IPRED is 0 to rounding (below 1e-9 of the largest, as an
// oral dose's prediction at its own time, ±1e-15) are left out with the zeros, or the axis would
// reach down to them.
GofPoints WithoutRoundingZeros(const GofPoints& g) {
  double top = 0;
  for (double v : g.ipred) top = std::max(top, std::fabs(v));
  for (double v : g.cens_ipred) top = std::max(top, std::fabs(v));
  const auto keep = [top](const std::vector<double>& ipred, const std::vector<double>& dv, std::vector<double>* to_ipred,
                         std::vector<double>* to_dv) {
    for (size_t i = 0; i < ipred.size(); ++i) {
      if (!(ipred[i] > 1e-9 * top)) continue;
      to_ipred->push_back(ipred[i]);
      to_dv->push_back(dv[i]);
    }
  };
  GofPoints out;
  out.name = g.name;
  keep(g.ipred, g.dv, &out.ipred, &out.dv);
  keep(g.cens_ipred, g.cens_dv, &out.cens_ipred, &out.cens_dv);
  return out;
}

std::pair<double, double> Range(const std::vector<double>& a, const std::vector<double>& b, bool positive) {
  double lo = INFINITY, hi = -INFINITY;
  for (const auto* v : {&a, &b}) {
    for (double x : *v) {
      if (!std::isfinite(x) || (positive && x <= 0)) continue;
      lo = std::min(lo, x);
      hi = std::max(hi, x);
    }
  }
  return {lo, hi};
}

// Points with a reference line and a LOWESS smoother.
std::string GofSvg(const std::vector<double>& x, const std::vector<double>& y, const PlotSeries& reference,
                   const PlotOptions& o, const GofPoints* censored) {
  PlotSeries points{"samples", x, y, true};
  points.colour = kObserved;
  std::vector<PlotSeries> extra;
  if (censored && !censored->cens_ipred.empty()) {
    PlotSeries c{"censored (at its limit)", censored->cens_ipred, censored->cens_dv, true};
    c.hollow = true;
    c.colour = kObserved;
    extra.push_back(c);
  }
  return RenderGofSvg(points, reference, o, extra);
}

// The goodness-of-fit plots of one output: DV against IPRED (linear and log-log, with the line of
// identity) and IWRES against time and against IPRED (with the zero line); files gof_<plot>[_k].svg.
void GoodnessOfFit(const std::vector<SubjectFit>& fits, const ReportContext& c, int output, bool several,
                   list* svgs, std::vector<std::pair<std::string, std::string>>* files) {
  const GofPoints g = CollectGof(fits, output);
  if (g.dv.empty() && g.cens_dv.empty()) return;
  const std::string suffix = several ? " (" + g.name + ", DVID " + std::to_string(output) + ")" : "";
  const std::string file_suffix = output > 1 ? "_" + std::to_string(output) : "";
  PlotOptions o;
  o.width = 420;
  o.height = 320;
  o.legend = false;
  const auto add = [&](const std::string& name, const std::string& svg) {
    svgs->push_back(object{{"svg", svg}});
    files->push_back({"gof_" + name + file_suffix + ".svg", svg});
  };
  const std::string conc = output > 1 ? g.name : ConcentrationLabel(c.units);
  for (bool log : {false, true}) {
    const GofPoints shown = log ? WithoutRoundingZeros(g) : g;
    const auto r = Range(shown.ipred, shown.dv, log);
    if (!std::isfinite(r.first)) continue;
    PlotSeries identity{"identity", {r.first, r.second}, {r.first, r.second}, false};
    identity.reference = true;
    o.title = std::string("DV against IPRED") + (log ? ", log–log" : "") + suffix;
    o.x_label = "individual prediction IPRED, " + conc;
    o.y_label = "observed DV";
    o.log_x = o.log_y = log;
    add(log ? "dv_ipred_log" : "dv_ipred", GofSvg(shown.ipred, shown.dv, identity, o, &shown));
  }
  o.log_x = o.log_y = false;
  o.y_label = "IWRES";
  for (const bool against_time : {true, false}) {
    const std::vector<double>& x = against_time ? g.time : g.ipred;
    const auto r = Range(x, {}, false);
    if (!std::isfinite(r.first)) continue;
    PlotSeries zero{"zero", {r.first, r.second}, {0, 0}, false};
    zero.reference = true;
    o.title = std::string("IWRES against ") + (against_time ? "time" : "IPRED") + suffix;
    o.x_label = against_time ? TimeLabel(c.units) : "IPRED, " + conc;
    add(against_time ? "iwres_time" : "iwres_ipred", GofSvg(x, g.iwres, zero, o, nullptr));
  }
}

list Cells(const std::vector<std::string>& texts, const std::vector<std::string>& classes) {
  list cells;
  for (size_t i = 0; i < texts.size(); ++i) cells.push_back(object{{"text", texts[i]}, {"class", classes[i]}});
  return cells;
}

// The estimates table: a row per subject with its objective, AIC, BIC, status and estimates.
void Estimates(const std::vector<SubjectFit>& fits, const ReportContext& c, data* page) {
  const SubjectFit* first = nullptr;
  for (const SubjectFit& f : fits) {
    if (f.ok && !first) first = &f;
  }
  std::vector<std::string> head{"ID", "NOBS", ObjectiveName(fits), "AIC", "BIC", "status"};
  std::vector<std::string> head_class{"l", "", "", "", "", "l"};
  if (first) {
    for (const ParameterEstimate& e : first->summary.estimates) {
      head.push_back(WithUnit(e.name, ParameterUnit(e.name, c.units)) + (e.fixed ? "" : " (RSE%)"));
      head_class.push_back("");
    }
  }
  list rows;
  for (const SubjectFit& f : fits) {
    list cells;
    cells.push_back(object{{"text", SubjectLabel(f)}, {"class", Text("l")}, {"link", Text("id" + SubjectKey(f))}});
    const std::string bad = Trusted(f) ? "l" : "l bad";
    std::vector<std::string> texts{std::to_string(f.dv.size()), f.ok ? Sig(ReportedObjective(f.summary), 6) : "–",
                                   f.ok ? Sig(f.summary.aic, 5) : "–", f.ok ? Sig(f.summary.bic, 5) : "–",
                                   FitStatus(f) + (f.ok ? "" : ": " + f.error)};
    std::vector<std::string> classes{"", "", "", "", bad};
    for (const ParameterEstimate& e : f.ok ? f.summary.estimates : std::vector<ParameterEstimate>{}) {
      texts.push_back(EstimateText(e) + (e.fixed ? " (fixed)" : e.at_bound ? "" : " (" + RseText(e) + ")"));
      classes.push_back("");
    }
    for (const data& cell : Cells(texts, classes)) cells.push_back(cell);
    rows.push_back(object{{"cells", cells}});
  }
  (*page)["estimate_header"] = Cells(head, head_class);
  (*page)["estimate_rows"] = rows;
}

data Population(const TwoStageSummary& pop) {
  std::vector<std::string> head{"parameter", "N", "mean", "SD", "CV%", "geo. mean", "geo. CV%", "median", "min", "max"};
  if (pop.gts_ok) {
    for (const char* h : {"GTS typical (RSE%)", "ω² (RSE%)", "BSV CV%"}) head.push_back(h);
  }
  std::vector<std::string> head_class(head.size(), "");
  head_class[0] = "l";
  list rows;
  for (size_t j = 0; j < pop.descriptive.size(); ++j) {
    const DescriptiveStatistics& d = pop.descriptive[j];
    std::vector<std::string> t{d.name, std::to_string(d.n), Sig(d.mean, 4), Sig(d.sd, 3), Sig(d.cv_pct, 3),
                               Sig(d.geometric_mean, 4), Sig(d.geometric_cv_pct, 3), Sig(d.median, 4), Sig(d.min, 4),
                               Sig(d.max, 4)};
    if (pop.gts_ok) {
      const PopulationParameter& q = pop.population[j];
      t.push_back(Sig(q.typical, 4) + " (" + Sig(q.typical_rse_pct, 3) + ")");
      t.push_back(q.omega2_at_bound ? "0 (bound)" : Sig(q.omega2, 4) + " (" + Sig(q.omega2_rse_pct, 3) + ")");
      t.push_back(q.omega2_at_bound ? "0" : Sig(q.bsv_cv_pct, 3));
    }
    rows.push_back(object{{"cells", Cells(t, head_class)}});
  }
  list excluded;
  for (const auto& e : pop.excluded) excluded.push_back(data("ID " + FormatNumber(e.first) + " left out: " + e.second));
  return object{{"brief", pop.BriefReport()},
                {"distribution", ToString(pop.distribution)},
                {"header", Cells(head, head_class)},
                {"rows", rows},
                {"has_excluded", data(!pop.excluded.empty())},
                {"excluded", excluded}};
}

// The panel grid: one figure per subject (and output, and axis when both are drawn).
void Panels(const std::vector<SubjectFit>& fits, const ReportContext& c, data* page,
            std::vector<std::pair<std::string, std::string>>* files) {
  list panels;
  const std::vector<bool> axes = PanelAxes(c);
  for (const SubjectFit& f : fits) {
    bool first = true;
    for (int k = 1; k <= NumOutputs(f); ++k) {
      for (bool log : axes) {
        const std::string caption = "ID " + SubjectLabel(f) + (NumOutputs(f) > 1 ? " " + f.output_names[static_cast<size_t>(k - 1)] : "") +
                                    (axes.size() > 1 ? (log ? " (log)" : " (linear)") : "") + (f.ok ? "" : ": fit failed");
        panels.push_back(object{{"anchor", Maybe(first ? "id" + SubjectKey(f) : "")},
                                {"class", Text(Trusted(f) ? "" : "bad")},
                                {"caption", caption},
                                {"svg", SubjectSvg(f, c, log, k, true)}});
        first = false;
      }
      // The full-size plot of each subject as a file of its own (the first axis).
      const std::string name = "fit_ID" + SubjectKey(f) + (k > 1 ? "_" + f.output_names[static_cast<size_t>(k - 1)] : "");
      files->push_back({name + ".svg", SubjectSvg(f, c, axes.front(), k, false)});
    }
  }
  (*page)["panels"] = panels;
  (*page)["legend"] = list{object{{"colour", Text(kObserved)}, {"label", Text("observed (hollow: censored, at its limit)")}},
                           object{{"colour", Text(kFitted)}, {"label", Text("fitted (IPRED)")}}};
  (*page)["axis_note"] = Text(axes.size() > 1 ? "Each subject on a linear and on a log axis."
                              : axes.front()  ? "Log concentration axis (--axis linear for a linear one)."
                                              : "Linear concentration axis (--axis log for a log one).");
}

data DerivedSection(const TransferFunctionReading& r, const Units& units) {
  const char* title = r.reading == "exponents" ? "Exponents and half-lives (_ABS: absorption)"
                      : r.reading == "iv"      ? "As an IV compartment model"
                                               : "As an oral compartment model (fastest rate = KA)";
  list rows;
  for (const DerivedParameter& d : r.parameters) {
    rows.push_back(object{{"name", WithUnit(d.name, ParameterUnit(d.name, units))}, {"value", Sig(d.value, 4)}, {"se", Sig(d.se, 3)}, {"rse", Sig(d.rse_pct, 3)}});
  }
  return object{{"title", Text(title)}, {"message", Maybe(r.message)}, {"has_rows", data(r.ok && !r.parameters.empty())}, {"rows", rows}};
}

void Details(const std::vector<SubjectFit>& fits, const Units& units, data* page) {
  list details;
  for (const SubjectFit& f : fits) {
    std::string initial;
    for (const auto& kv : f.initial) initial += (initial.empty() ? "" : ", ") + kv.first + " = " + Sig(kv.second, 4);
    list derived;
    for (const TransferFunctionReading& r : f.derived) derived.push_back(DerivedSection(r, units));
    const std::string status = FitStatus(f);
    details.push_back(object{{"label", SubjectLabel(f)},
                             {"status", status},
                             {"class", Text(Trusted(f) ? "" : "bad")},
                             {"error", Maybe(f.ok ? "" : f.error)},
                             {"initial", Maybe(f.ok ? f.initial_method + ": " + initial : "")},
                             {"report", Maybe(f.ok ? f.summary.FullReport() : "")},
                             {"derived", derived}});
  }
  (*page)["details"] = details;
}

std::string UnitsText(const Units& u) {
  if (u.empty()) return "none given (--units time=h,amt=mg,conc=mg/L, or a units row in the dataset)";
  const auto or_dash = [](const std::string& s) { return s.empty() ? std::string("–") : s; };
  return "time " + or_dash(u.time) + ", amount " + or_dash(u.amount) + ", concentration " + or_dash(u.concentration);
}

// The notes under the estimates: each distinct note on the standard errors once, with the IDs it
// concerns, then the censored samples per ID in one line.
list Notes(const std::vector<SubjectFit>& fits) {
  std::vector<std::pair<std::string, std::string>> by_note;  // note, IDs (in the subjects' order)
  std::string censored;
  for (const SubjectFit& f : fits) {
    if (f.ok && !f.summary.covariance_message.empty()) {
      const std::string note = f.summary.CovarianceNote();
      auto it = std::find_if(by_note.begin(), by_note.end(), [&](const auto& n) { return n.first == note; });
      if (it == by_note.end()) it = by_note.insert(by_note.end(), {note, ""});
      it->second += (it->second.empty() ? "" : ", ") + SubjectLabel(f);
    }
    const int c = f.censoring.cwiseAbs().sum();
    if (c > 0) censored += (censored.empty() ? "" : ", ") + SubjectLabel(f) + ": " + std::to_string(c);
  }
  list notes;
  for (const auto& n : by_note) notes.push_back(Text((n.second.find(',') == std::string::npos ? "ID " : "IDs ") +
                                                     n.second + ": " + n.first));
  if (!censored.empty()) {
    notes.push_back(Text("Censored samples (CENS) per ID, " + censored +
                         ", enter by their probability of lying beyond their limit (Beal's M3); the plots show them "
                         "hollow, at their limit."));
  }
  return notes;
}

// The header, the summary cards and the notes.
void Header(const std::vector<SubjectFit>& fits, const ReportContext& c, data* page) {
  int ok = 0, samples = 0;
  double objective = 0, aic = 0, bic = 0;
  for (const SubjectFit& f : fits) {
    samples += static_cast<int>(f.dv.size());
    ok += Trusted(f) ? 1 : 0;
    if (!f.ok) continue;
    objective += ReportedObjective(f.summary);
    aic += f.summary.aic;
    bic += f.summary.bic;
  }
  const std::string path = c.data ? c.data->source : "";
  (*page)["dataset"] = std::filesystem::path(path).filename().string();
  (*page)["dataset_path"] = path;
  (*page)["model"] = c.model;
  (*page)["model_description"] = c.model_description;
  (*page)["method"] = c.method;
  (*page)["units"] = UnitsText(c.units);
  (*page)["date"] = Today();
  (*page)["version"] = Text(Version());
  (*page)["command"] = c.command_line;
  (*page)["num_subjects"] = std::to_string(fits.size());
  (*page)["num_samples"] = std::to_string(samples);
  (*page)["num_ok"] = std::to_string(ok);
  if (ok < static_cast<int>(fits.size())) (*page)["num_bad"] = std::to_string(fits.size() - static_cast<size_t>(ok));
  (*page)["objective_name"] = ObjectiveName(fits);
  (*page)["objective_total"] = Sig(objective, 7);
  (*page)["aic_total"] = Sig(aic, 6);
  (*page)["bic_total"] = Sig(bic, 6);
  (*page)["objective_note"] = ObjectiveNote(fits);
  (*page)["notes"] = Notes(fits);
  (*page)["has_notes"] = data(!(*page)["notes"].is_empty_list());
}

}  // namespace

std::string HtmlReport(const std::vector<SubjectFit>& fits, const ReportContext& context,
                       std::vector<std::pair<std::string, std::string>>* files) {
  data page;
  Header(fits, context, &page);
  Estimates(fits, context, &page);
  if (context.population) page["population"] = Population(*context.population);
  int outputs = 1;
  for (const SubjectFit& f : fits) outputs = std::max(outputs, f.ok ? NumOutputs(f) : 1);
  list gof;
  std::vector<std::pair<std::string, std::string>> gof_files;
  for (int k = 1; k <= outputs; ++k) GoodnessOfFit(fits, context, k, outputs > 1, &gof, &gof_files);
  page["has_gof"] = data(!gof.empty());
  page["gof"] = gof;
  Panels(fits, context, &page, files);
  files->insert(files->end(), gof_files.begin(), gof_files.end());
  Details(fits, context.units, &page);
  kainjow::mustache::mustache tmpl(ReportTemplate());
  if (!tmpl.is_valid()) throw std::logic_error("report template: " + tmpl.error_message());
  const std::string html = tmpl.render(page);
  if (!tmpl.is_valid()) throw std::logic_error("report template: " + tmpl.error_message());
  return html;
}

}  // namespace cli
}  // namespace pk
