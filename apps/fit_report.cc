#include "fit_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

#include "fit_csv.h"
#include "pk/output.h"

namespace pk {
namespace cli {

std::string SubjectKey(const SubjectFit& f) {
  return FormatNumber(f.id) + (f.occurrence > 1 ? "_occ" + std::to_string(f.occurrence) : "");
}

std::string SubjectLabel(const SubjectFit& f) {
  return FormatNumber(f.id) + (f.occurrence > 1 ? " (occurrence " + std::to_string(f.occurrence) + ")" : "");
}

std::string EstimateText(const ParameterEstimate& e) { return e.at_bound ? "0 (bound)" : Sig(e.estimate, 4); }

std::string RseText(const ParameterEstimate& e) { return e.fixed ? "fixed" : Sig(e.rse_pct, 3); }

std::string ObjectiveName(const std::vector<SubjectFit>& fits) {
  for (const SubjectFit& f : fits) {
    if (f.ok) return std::isnan(f.summary.ofv) ? "RSS" : "OFV";
  }
  return "OFV";
}

double ReportedObjective(const FitSummary& s) { return std::isnan(s.ofv) ? s.rss : s.ofv; }

std::string ObjectiveNote(const std::vector<SubjectFit>& fits) {
  if (ObjectiveName(fits) == "RSS") {
    return "RSS: the (weighted) residual sum of squares at the estimate. AIC and BIC use the Gaussian likelihood "
           "with the residual variance profiled out, which counts as one more parameter.";
  }
  return "OFV: −2 log-likelihood without the constant N·log(2π) of the N uncensored samples, as NONMEM's "
         "OBJECTIVE FUNCTION VALUE WITHOUT CONSTANT; fit_details.csv has −2LL with it (MINUS2LL). "
         "AIC = −2LL + 2p, BIC = −2LL + p·log N.";
}

bool Trusted(const SubjectFit& f) { return f.ok && f.summary.converged() && f.summary.identifiable; }

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
          out << "\n" << (r.reading == "exponents" ? "exponents and half-lives (_ABS: absorption)"
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
          out << " " << d.name << " " << Sig(d.value, 4) << " (" << Sig(d.rse_pct, 3) << ")";
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

std::string EstimatesTable(const std::vector<SubjectFit>& fits, const Units& units) {
  std::ostringstream out;
  const SubjectFit* first = nullptr;
  for (const SubjectFit& f : fits) {
    if (f.ok && !first) first = &f;
  }
  char buf[160];
  std::snprintf(buf, sizeof buf, "%-6s %5s %11s %10s %10s  %-16s", "ID", "NOBS", ObjectiveName(fits).c_str(), "AIC",
                "BIC", "STATUS");
  out << buf;
  if (first) {
    for (const ParameterEstimate& e : first->summary.estimates) {
      const std::string head = WithUnit(e.name, ParameterUnit(e.name, units)) + (e.fixed ? " fixed" : " (RSE%)");
      std::snprintf(buf, sizeof buf, " %22s", head.c_str());
      out << buf;
    }
  }
  out << "\n";
  for (const SubjectFit& f : fits) {
    const FitSummary& s = f.summary;
    std::snprintf(buf, sizeof buf, "%-6s %5d %11s %10s %10s  %-16s", FormatNumber(f.id).c_str(),
                  static_cast<int>(f.dv.size()), f.ok ? Sig(ReportedObjective(s), 6).c_str() : "–",
                  f.ok ? Sig(s.aic, 5).c_str() : "–", f.ok ? Sig(s.bic, 5).c_str() : "–", FitStatus(f).c_str());
    out << buf;
    if (!f.ok) {
      out << " " << f.error << "\n";
      continue;
    }
    for (const ParameterEstimate& e : s.estimates) {
      const std::string cell = EstimateText(e) + (e.fixed || e.at_bound ? "" : " (" + RseText(e) + ")");
      std::snprintf(buf, sizeof buf, " %22s", cell.c_str());
      out << buf;
    }
    out << "\n";
  }
  out << ObjectiveNote(fits) << "\n";
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
  std::vector<std::pair<std::string, std::string>> svgs;
  const std::string html = HtmlReport(fits, context, &svgs);

  // The set is complete when its manifest is written, last; until then the last run's manifest
  // vouches for the files this run has not changed (untouched, or rewritten byte for byte).
  std::vector<std::string> written;
  const auto write = [&](const std::string& name, const std::string& contents) {
    WriteFileAtomically(dir + "/" + name, contents);
    written.push_back(name);
  };
  write("estimates.csv", EstimatesCsv(fits, context.units));
  write("summary.csv", SummaryCsv(fits));
  write("predictions.csv", PredictionsCsv(fits, *context.data));
  write("fit_details.csv", FitDetailsCsv(fits));
  const std::string derived = DerivedCsv(fits, context.units);
  if (!derived.empty()) write("derived.csv", derived);
  if (context.population) {
    write("population.csv", PopulationCsv(*context.population, context.units));
    write("population_omega.csv", PopulationOmegaCsv(*context.population));
  }
  for (const auto& file : svgs) write(file.first, file.second);
  write("summary.json", JsonSummary(fits, context));
  write("report.html", html);
  CompleteOutputSet(dir, written, "pkfit");
}

}  // namespace cli
}  // namespace pk
