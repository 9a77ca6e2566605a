#include "fit_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

#include "fit_csv.h"
#include "pk/output.h"
#include "pk/plot.h"

namespace pk {
namespace cli {
namespace {

// A subject in file names and anchors: its ID, and its occurrence when the ID came back ("1_occ2").
std::string Key(const SubjectFit& f) {
  return FormatNumber(f.id) + (f.occurrence > 1 ? "_occ" + std::to_string(f.occurrence) : "");
}
// ... and in text: "1 (occurrence 2)".
std::string Label(const SubjectFit& f) {
  return FormatNumber(f.id) + (f.occurrence > 1 ? " (occurrence " + std::to_string(f.occurrence) + ")" : "");
}

std::string Fmt(double v, const char* f = "%.4g") {
  if (!std::isfinite(v)) return "–";
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

std::string Escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '<') out += "&lt;";
    else if (c == '>') out += "&gt;";
    else if (c == '&') out += "&amp;";
    else out += c;
  }
  return out;
}

// The plot of output `output` (1-based); models with one output have only output 1.
std::string SubjectSvg(const SubjectFit& f, bool log, int output = 1) {
  PlotSeries data{"observed", {}, {}, true}, censored{"censored (at its limit)", {}, {}, true};
  censored.hollow = true;
  for (int k = 0; k < f.dv.size(); ++k) {
    if (!f.sample_output.empty() && f.sample_output[k] != output) continue;
    PlotSeries& to = k < f.censoring.size() && f.censoring(k) != 0 ? censored : data;
    to.x.push_back(f.times[k]);
    to.y.push_back(f.dv(k));
  }
  const bool multi = !f.output_curves.empty();
  PlotSeries curve{"fitted", f.curve_times, multi ? f.output_curves[output - 1] : f.curve, false};
  PlotOptions o;
  o.title = "ID " + FormatNumber(f.id) + (multi ? " " + f.output_names[output - 1] + " (DVID " +
                                                      std::to_string(output) + ")" : "") +
            (f.ok ? "" : " (fit failed)");
  o.log_y = log && (!multi || output == 1);
  if (multi && output > 1) o.y_label = "output " + f.output_names[output - 1];
  if (censored.x.empty()) return RenderSvg({curve, data}, o);
  return RenderSvg({curve, data, censored}, o);
}

int NumPlots(const SubjectFit& f) { return f.output_curves.empty() ? 1 : static_cast<int>(f.output_curves.size()); }

// The usual goodness-of-fit plots over all fitted subjects, for output `output`:
// observed against predicted (with the line of identity; censored samples
// hollow, at their limit), and the weighted residuals against time and against
// the prediction (with the zero line; censored samples have none).
// Empty when no subject has samples of that output.
std::vector<std::pair<std::string, std::string>> GoodnessOfFitSvgs(const std::vector<SubjectFit>& fits, int output,
                                                                   bool several_outputs) {
  PlotSeries dv_pred{"samples", {}, {}, true}, wres_time{"samples", {}, {}, true}, wres_pred{"samples", {}, {}, true};
  PlotSeries censored{"censored (at its limit)", {}, {}, true};
  censored.hollow = true;
  std::string name;
  for (const SubjectFit& f : fits) {
    if (!f.ok) continue;
    if (!f.output_names.empty() && output <= static_cast<int>(f.output_names.size())) name = f.output_names[output - 1];
    for (int k = 0; k < f.pred.size(); ++k) {
      if (!f.sample_output.empty() && f.sample_output[k] != output) continue;
      if (f.sample_output.empty() && output != 1) continue;
      if (k < f.censoring.size() && f.censoring(k) != 0) {
        censored.x.push_back(f.pred(k));
        censored.y.push_back(f.dv(k));
        continue;
      }
      dv_pred.x.push_back(f.pred(k));
      dv_pred.y.push_back(f.dv(k));
      if (k < f.wres.size()) {
        wres_time.x.push_back(f.times[k]);
        wres_time.y.push_back(f.wres(k));
        wres_pred.x.push_back(f.pred(k));
        wres_pred.y.push_back(f.wres(k));
      }
    }
  }
  std::vector<std::pair<std::string, std::string>> svgs;
  if (dv_pred.x.empty() && censored.x.empty()) return svgs;
  const std::string suffix = several_outputs ? " (" + name + ", DVID " + std::to_string(output) + ")" : "";
  auto range = [](const std::vector<double>& v) {  // of the finite values
    double lo = INFINITY, hi = -INFINITY;
    for (double x : v) {
      if (!std::isfinite(x)) continue;
      lo = std::min(lo, x);
      hi = std::max(hi, x);
    }
    return std::make_pair(lo, hi);
  };
  const auto pred = range(dv_pred.x), dv = range(dv_pred.y), cp = range(censored.x), cd = range(censored.y);
  const double lo = std::min({pred.first, dv.first, cp.first, cd.first});
  const double hi = std::max({pred.second, dv.second, cp.second, cd.second});
  PlotSeries identity{"identity", {lo, hi}, {lo, hi}, false};
  PlotOptions o;
  o.title = "observed against predicted" + suffix;
  o.x_label = "predicted (PRED)";
  o.y_label = "observed (DV)";
  svgs.push_back({"dv_pred", censored.x.empty() ? RenderSvg({identity, dv_pred}, o)
                                                 : RenderSvg({identity, dv_pred, censored}, o)});
  if (!wres_time.x.empty()) {
    const auto t = range(wres_time.x), p = range(wres_pred.x);
    o.y_label = "weighted residual (WRES)";
    o.title = "weighted residuals against time" + suffix;
    o.x_label = "time";
    svgs.push_back({"wres_time", RenderSvg({PlotSeries{"zero", {t.first, t.second}, {0, 0}, false}, wres_time}, o)});
    o.title = "weighted residuals against prediction" + suffix;
    o.x_label = "predicted (PRED)";
    svgs.push_back({"wres_pred", RenderSvg({PlotSeries{"zero", {p.first, p.second}, {0, 0}, false}, wres_pred}, o)});
  }
  return svgs;
}

}  // namespace

std::string InitialTable(const std::vector<SubjectFit>& fits) {
  std::ostringstream out;
  out << "ID,PARAMETER,INITIAL,SOURCE\n";
  for (const SubjectFit& f : fits) {
    for (const auto& kv : f.initial) {
      out << FormatNumber(f.id) << "," << kv.first << "," << Csv(kv.second) << "," << Quote(f.initial_method) << "\n";
    }
  }
  return out.str();
}

std::string DerivedTable(const std::vector<SubjectFit>& fits) {
  std::ostringstream out;
  char buf[160];
  for (const char* reading : {"exponents", "iv", "oral"}) {
    bool header = false;
    for (const SubjectFit& f : fits) {
      for (const TransferFunctionReading& r : f.derived) {
        if (r.reading != reading) continue;
        if (!header) {
          out << "\n" << (r.reading == "exponents" ? "exponents and half-lives"
                                                    : (r.reading == "iv" ? "as an IV compartment model"
                                                                         : "as an oral compartment model (fastest rate = KA)"))
              << ", value (RSE%):\n";
          header = true;
        }
        std::snprintf(buf, sizeof buf, "%-6s", FormatNumber(f.id).c_str());
        out << buf;
        if (!r.ok) {
          out << " " << r.message << "\n";
          continue;
        }
        for (const DerivedParameter& d : r.parameters) {
          if (d.name.rfind("AMP", 0) == 0) continue;  // amplitudes: in derived.csv
          std::snprintf(buf, sizeof buf, " %s %s (%s)", d.name.c_str(), Fmt(d.value).c_str(), Fmt(d.rse_pct, "%.3g").c_str());
          out << buf;
        }
        if (!r.message.empty()) out << " (" << r.message << ")";
        out << "\n";
      }
    }
  }
  return out.str();
}

std::string PopulationTable(const TwoStageSummary& population) {
  std::ostringstream out;
  out << "\npopulation: " << population.FullReport();
  return out.str();
}

std::string EstimatesTable(const std::vector<SubjectFit>& fits) {
  std::ostringstream out;
  const SubjectFit* first = nullptr;
  for (const SubjectFit& f : fits) {
    if (f.ok) {
      first = &f;
      break;
    }
  }
  char buf[128];
  std::snprintf(buf, sizeof buf, "%-6s %5s %12s  %-13s", "ID", "NOBS", "OBJECTIVE", "STATUS");
  out << buf;
  if (first) {
    for (const ParameterEstimate& e : first->summary.estimates) {
      std::snprintf(buf, sizeof buf, " %20s", (e.name + (e.fixed ? " (fixed)" : " (RSE%)")).c_str());
      out << buf;
    }
  }
  out << "\n";
  for (const SubjectFit& f : fits) {
    std::snprintf(buf, sizeof buf, "%-6s %5d %12s  %-13s", FormatNumber(f.id).c_str(), static_cast<int>(f.dv.size()),
                  f.ok ? Fmt(f.summary.objective, "%.6g").c_str() : "–", FitStatus(f).c_str());
    out << buf;
    if (!f.ok) {
      out << " " << f.error << "\n";
      continue;
    }
    for (const ParameterEstimate& e : f.summary.estimates) {
      const std::string cell = e.fixed ? Fmt(e.estimate) : Fmt(e.estimate) + " (" + Fmt(e.rse_pct, "%.3g") + ")";
      std::snprintf(buf, sizeof buf, " %20s", cell.c_str());
      out << buf;
    }
    out << "\n";
  }
  // Censored samples, then why standard errors are missing, under the table.
  std::string censored;
  for (const SubjectFit& f : fits) {
    const int c = f.censoring.cwiseAbs().sum();
    if (c > 0) censored += (censored.empty() ? "" : ", ") + FormatNumber(f.id) + ": " + std::to_string(c);
  }
  if (!censored.empty()) out << "censored samples (CENS, Beal's M3) per ID: " << censored << "\n";
  for (const SubjectFit& f : fits) {
    if (f.ok && !f.summary.covariance_message.empty()) {
      out << "ID " << FormatNumber(f.id) << ": " << f.summary.CovarianceNote() << "\n";
    }
  }
  return out.str();
}

namespace {

void HtmlHeader(const std::vector<SubjectFit>& fits, const ReportContext& context, std::ostringstream& html) {
  html << "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>pkfit report</title>\n"
       << "<style>body{font-family:sans-serif;margin:2em;max-width:1100px}table{border-collapse:collapse;margin:1em 0}"
       << "td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}th{background:#f3f3f3}"
       << "td.l,th.l{text-align:left}.bad{color:#b00}</style></head><body>\n"
       << "<h1>pkfit report</h1>\n<p>Model <b>" << Escape(context.model) << "</b>, data <code>" << Escape(context.data)
       << "</code>.<br>Command: <code>" << Escape(context.command_line) << "</code></p>\n";
  int failed = 0;
  for (const SubjectFit& f : fits) failed += f.ok && f.summary.converged() && f.summary.identifiable ? 0 : 1;
  html << "<p>" << fits.size() << " subjects, " << fits.size() - failed << " converged and identifiable";
  if (failed) html << ", <span class=\"bad\">" << failed << " failed, not converged or not identifiable</span>";
  int censored = 0;
  for (const SubjectFit& f : fits) censored += f.censoring.cwiseAbs().sum();
  if (censored > 0) {
    html << " " << censored << " censored samples (CENS) enter by their probability of lying beyond their limit "
         << "(Beal's M3); the plots show them hollow, at their limit";
  }
  html << ".</p>\n";
}

void HtmlEstimates(const std::vector<SubjectFit>& fits, std::ostringstream& html) {
  html << "<h2>Estimates</h2>\n<table><tr><th class=\"l\">ID</th><th>NOBS</th><th>objective</th><th class=\"l\">status</th>";
  const SubjectFit* first = nullptr;
  for (const SubjectFit& f : fits) {
    if (f.ok && !first) first = &f;
  }
  if (first) {
    for (const ParameterEstimate& e : first->summary.estimates) html << "<th>" << Escape(e.name) << " (RSE%)</th>";
  }
  html << "<th>-2LL</th><th>AIC</th><th>time (ms)</th></tr>\n";
  for (const SubjectFit& f : fits) {
    html << "<tr><td class=\"l\"><a href=\"#id" << Key(f) << "\">" << Label(f) << "</a></td><td>"
         << f.dv.size() << "</td><td>" << (f.ok ? Fmt(f.summary.objective, "%.6g") : "–") << "</td><td class=\"l"
         << (f.ok && f.summary.converged() && f.summary.identifiable ? "" : " bad") << "\">" << FitStatus(f) << "</td>";
    if (f.ok) {
      for (const ParameterEstimate& e : f.summary.estimates) {
        html << "<td>" << Fmt(e.estimate) << (e.fixed ? " (fixed)" : " (" + Fmt(e.rse_pct, "%.3g") + ")") << "</td>";
      }
      html << "<td>" << Fmt(f.summary.minus2ll) << "</td><td>" << Fmt(f.summary.aic) << "</td><td>"
           << Fmt(f.summary.seconds * 1e3, "%.3g") << "</td>";
    } else {
      html << "<td class=\"l bad\" colspan=\"99\">" << Escape(f.error) << "</td>";
    }
    html << "</tr>\n";
  }
  html << "</table>\n";
}

void HtmlPopulation(const TwoStageSummary& pop, std::ostringstream& html) {
  html << "<h2>Population (two-stage)</h2>\n<p>" << Escape(pop.BriefReport()) << ".</p>\n"
       << "<p>STS: statistics of the individual estimates of the " << pop.sts_ids.size()
       << " converged fits; their spread includes each fit's estimation error. GTS: maximum likelihood of the "
       << ToString(pop.distribution) << " population model given each fit's estimate and covariance "
       << "(the typical value is exp(μ) for the log-normal model; BSV CV% = 100·√(exp(ω²) − 1)).</p>\n"
       << "<table><tr><th class=\"l\">parameter</th><th>N</th><th>mean</th><th>SD</th><th>CV%</th>"
       << "<th>geo. mean</th><th>geo. CV%</th><th>median</th><th>min</th><th>max</th>";
  if (pop.gts_ok) html << "<th>GTS typical (RSE%)</th><th>ω² (RSE%)</th><th>BSV CV%</th>";
  html << "</tr>\n";
  for (size_t j = 0; j < pop.descriptive.size(); ++j) {
    const DescriptiveStatistics& d = pop.descriptive[j];
    html << "<tr><td class=\"l\">" << Escape(d.name) << "</td><td>" << d.n << "</td><td>" << Fmt(d.mean) << "</td><td>"
         << Fmt(d.sd) << "</td><td>" << Fmt(d.cv_pct, "%.3g") << "</td><td>" << Fmt(d.geometric_mean) << "</td><td>"
         << Fmt(d.geometric_cv_pct, "%.3g") << "</td><td>" << Fmt(d.median) << "</td><td>" << Fmt(d.min)
         << "</td><td>" << Fmt(d.max) << "</td>";
    if (pop.gts_ok) {
      const PopulationParameter& q = pop.population[j];
      html << "<td>" << Fmt(q.typical) << " (" << Fmt(q.typical_rse_pct, "%.3g") << ")</td><td>" << Fmt(q.omega2)
           << " (" << Fmt(q.omega2_rse_pct, "%.3g") << ")</td><td>" << Fmt(q.bsv_cv_pct, "%.3g") << "</td>";
    }
    html << "</tr>\n";
  }
  html << "</table>\n";
  if (!pop.excluded.empty()) {
    html << "<ul>";
    for (const auto& e : pop.excluded) {
      html << "<li>ID " << FormatNumber(e.first) << " left out: " << Escape(e.second) << "</li>";
    }
    html << "</ul>\n";
  }
}

// Goodness of fit, per output, into the report; returns the files gof_<plot>.svg
// (gof_<plot>_<output>.svg beyond output 1) with their contents.
std::vector<std::pair<std::string, std::string>> HtmlGoodnessOfFit(const std::vector<SubjectFit>& fits,
                                                                   std::ostringstream& html) {
  std::vector<std::pair<std::string, std::string>> gof_files;
  int outputs = 1;
  for (const SubjectFit& f : fits) outputs = std::max(outputs, f.ok ? NumPlots(f) : 1);
  for (int k = 1; k <= outputs; ++k) {
    for (auto& plot : GoodnessOfFitSvgs(fits, k, outputs > 1)) {
      if (gof_files.empty()) {
        html << "<h2>Goodness of fit</h2>\n<p>All subjects together. PRED is each subject's own fitted prediction; "
             << "WRES = √W·(DV − PRED)/σ̂ (least squares) or (DV − PRED)/σ (maximum likelihood).</p>\n";
      }
      html << plot.second << "\n";
      gof_files.push_back({"gof_" + plot.first + (k > 1 ? "_" + std::to_string(k) : "") + ".svg", plot.second});
    }
  }
  return gof_files;
}

void HtmlDerived(const TransferFunctionReading& r, std::ostringstream& html) {
  const char* title = r.reading == "exponents" ? "Exponents and half-lives" :
                      (r.reading == "iv" ? "As an IV compartment model" : "As an oral compartment model (fastest rate = KA)");
  html << "<h4>" << title << "</h4>\n";
  if (!r.ok) {
    html << "<p class=\"bad\">" << Escape(r.message) << "</p>\n";
    return;
  }
  html << "<table><tr><th class=\"l\">parameter</th><th>value</th><th>SE</th><th>RSE%</th></tr>\n";
  for (const DerivedParameter& d : r.parameters) {
    html << "<tr><td class=\"l\">" << Escape(d.name) << "</td><td>" << Fmt(d.value) << "</td><td>" << Fmt(d.se)
         << "</td><td>" << Fmt(d.rse_pct, "%.3g") << "</td></tr>\n";
  }
  html << "</table>\n";
  if (!r.message.empty()) html << "<p>" << Escape(r.message) << ".</p>\n";
}

void HtmlSubjects(const std::vector<SubjectFit>& fits, bool log_plots, std::ostringstream& html) {
  html << "<h2>Subjects</h2>\n";
  for (const SubjectFit& f : fits) {
    html << "<h3 id=\"id" << Key(f) << "\">ID " << Label(f) << "</h3>\n";
    if (!f.ok) {
      html << "<p class=\"bad\">" << Escape(f.error) << "</p>\n";
      continue;
    }
    html << "<p>Starting values from " << Escape(f.initial_method) << ":";
    for (const auto& kv : f.initial) html << " " << Escape(kv.first) << " = " << Fmt(kv.second);
    html << ".</p>\n<pre>" << Escape(f.summary.FullReport()) << "</pre>\n";
    for (const TransferFunctionReading& r : f.derived) HtmlDerived(r, html);
    for (int k = 1; k <= NumPlots(f); ++k) html << SubjectSvg(f, log_plots, k) << "\n";
  }
}

void CreateDirectory(const std::string& dir) {
  std::error_code error;
  std::filesystem::create_directories(dir, error);  // with its parents, like mkdir -p
  if (!std::filesystem::is_directory(dir)) {
    throw std::runtime_error(dir + ": cannot create the output directory" + (error ? " (" + error.message() + ")" : ""));
  }
}

}  // namespace

void WriteFitOutputs(const std::string& dir, const std::vector<SubjectFit>& fits, const ReportContext& context) {
  CreateDirectory(dir);
  RemoveStaleTemporaries(dir);
  // The report: a run header, the summary and estimates tables, and one section per subject.
  std::ostringstream html;
  HtmlHeader(fits, context, html);
  HtmlEstimates(fits, html);
  if (context.population) HtmlPopulation(*context.population, html);
  const auto gof_files = HtmlGoodnessOfFit(fits, html);
  HtmlSubjects(fits, context.log_plots, html);
  html << "</body></html>\n";

  // The set is complete when its manifest is written, last; until then it has none.
  BeginOutputSet(dir);
  std::vector<std::string> written;
  const auto write = [&](const std::string& name, const std::string& contents) {
    WriteFileAtomically(dir + "/" + name, contents);
    written.push_back(name);
  };
  write("estimates.csv", EstimatesCsv(fits));
  write("summary.csv", SummaryCsv(fits));
  write("predictions.csv", PredictionsCsv(fits));
  write("fit_details.csv", FitDetailsCsv(fits));
  const std::string derived = DerivedCsv(fits);
  if (!derived.empty()) write("derived.csv", derived);
  if (context.population) {
    write("population.csv", PopulationCsv(*context.population));
    write("population_omega.csv", PopulationOmegaCsv(*context.population));
  }
  for (const SubjectFit& f : fits) {
    write("fit_ID" + Key(f) + ".svg", SubjectSvg(f, context.log_plots));
    for (int k = 2; k <= NumPlots(f); ++k) {
      write("fit_ID" + Key(f) + "_" + f.output_names[k - 1] + ".svg", SubjectSvg(f, context.log_plots, k));
    }
  }
  for (const auto& file : gof_files) write(file.first, file.second);
  write("report.html", html.str());
  CompleteOutputSet(dir, written, "pkfit");
}

}  // namespace cli
}  // namespace pk
