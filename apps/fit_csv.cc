#include "fit_csv.h"

#include <cmath>
#include <sstream>

#include "cli.h"
#include "pk/output.h"

namespace pk {
namespace cli {

std::string Csv(double v) { return std::isfinite(v) ? FormatNumber(v) : ""; }

std::string FitStatus(const SubjectFit& f) {
  if (!f.ok) return "failed";
  switch (f.summary.termination) {
    case TerminationType::kConvergence:
      if (!f.summary.identifiable) return "not identifiable";
      return "converged";
    case TerminationType::kNoConvergence: return "not converged";
    case TerminationType::kFailure: return "failed";
    case TerminationType::kUnbounded: return "unbounded";
  }
  return "?";
}

std::string EstimatesCsv(const std::vector<SubjectFit>& fits, const Units& units) {
  std::ostringstream est;
  est << "ID,PARAMETER,ESTIMATE,SE,RSE_PCT,UNIT\n";
  for (const SubjectFit& f : fits) {
    if (!f.ok) continue;
    for (const ParameterEstimate& e : f.summary.estimates) {
      est << FormatNumber(f.id) << "," << e.name << "," << Csv(e.estimate) << "," << (e.fixed ? "" : Csv(e.se)) << ","
          << (e.fixed ? "" : Csv(e.rse_pct)) << "," << Quote(ParameterUnit(e.name, units)) << "\n";
    }
  }
  return est.str();
}

std::string SummaryCsv(const std::vector<SubjectFit>& fits) {
  std::ostringstream sum;
  // OBJECTIVE is the minimised V (½·RSS, or −log L); OFV (maximum likelihood) and RSS (least squares)
  // are what a NONMEM user compares.
  sum << "ID,NOBS,OBJECTIVE,OFV,RSS,AIC,BIC,ITERATIONS,CONVERGED,GRADIENT,OPTIMIZER,SECONDS,PROPAGATOR,NCENS\n";
  for (const SubjectFit& f : fits) {
    const FitSummary& s = f.summary;
    sum << FormatNumber(f.id) << "," << f.dv.size() << "," << (f.ok ? Csv(s.objective) : "") << ","
        << (f.ok ? Csv(s.ofv) : "") << "," << (f.ok ? Csv(s.rss) : "") << "," << (f.ok ? Csv(s.aic) : "") << ","
        << (f.ok ? Csv(s.bic) : "") << "," << s.iterations << "," << (f.ok && s.converged() ? 1 : 0) << ","
        << s.gradient << "," << s.optimizer << "," << Csv(s.seconds) << "," << s.propagator << ","
        << f.censoring.cwiseAbs().sum() << "\n";
  }
  return sum.str();
}

std::string PredictionsCsv(const std::vector<SubjectFit>& fits, const Dataset& data) {
  // The dataset's other columns follow, as NONMEM's $TABLE carries covariates (CENS is one of ours).
  std::vector<int> carried;
  std::ostringstream pred;
  pred << "ID,TIME,DV,IPRED,IRES,IWRES,CENS";
  for (size_t c = 0; c < data.extra_columns.size(); ++c) {
    if (data.extra_columns[c] == "CENS") continue;
    carried.push_back(static_cast<int>(c));
    pred << "," << data.extra_columns[c];
  }
  pred << "\n";
  for (const SubjectFit& f : fits) {
    if (!f.ok) continue;
    const std::string id = FormatNumber(f.id);
    const std::vector<Record>& records = data.subjects[static_cast<size_t>(f.subject)].records;
    for (int k = 0; k < f.ipred.size(); ++k) {
      // A censored sample's DV is its limit: it has no residual.
      const int cens = k < f.censoring.size() ? f.censoring(k) : 0;
      pred << id << "," << Csv(f.times[k]) << "," << Csv(f.dv(k)) << "," << Csv(f.ipred(k)) << ","
           << (cens != 0 ? "" : Csv(f.dv(k) - f.ipred(k))) << "," << (k < f.iwres.size() ? Csv(f.iwres(k)) : "") << ","
           << cens;
      const Record* record = k < static_cast<int>(f.sample_records.size())
                                 ? &records[static_cast<size_t>(f.sample_records[static_cast<size_t>(k)])]
                                 : nullptr;
      for (int c : carried) pred << "," << (record ? Csv(record->extra[static_cast<size_t>(c)]) : "");
      pred << "\n";
    }
  }
  return pred.str();
}

std::string FitDetailsCsv(const std::vector<SubjectFit>& fits) {
  std::ostringstream det;
  det << "ID,STATUS,MESSAGE,INITIAL_OBJECTIVE,EVALUATIONS,BEST_START,MINUS2LL,AIC,BIC,INITIAL_VALUES,COVARIANCE\n";
  for (const SubjectFit& f : fits) {
    const FitSummary& s = f.summary;
    det << FormatNumber(f.id) << "," << Quote(FitStatus(f)) << "," << Quote(f.ok ? s.message : f.error) << ","
        << Csv(s.initial_objective) << "," << s.evaluations << "," << s.best_start << "," << Csv(s.minus2ll) << ","
        << Csv(s.aic) << "," << Csv(s.bic) << "," << Quote(f.initial_method) << ","
        << Quote(f.ok ? s.covariance_message : "") << "\n";
  }
  return det.str();
}

std::string DerivedCsv(const std::vector<SubjectFit>& fits, const Units& units) {
  std::ostringstream derived;
  bool any = false;
  derived << "ID,READING,PARAMETER,VALUE,SE,RSE_PCT,NOTE,UNIT\n";
  for (const SubjectFit& f : fits) {
    if (!f.ok) continue;
    const std::string id = FormatNumber(f.id);
    for (const TransferFunctionReading& r : f.derived) {
      any = true;
      if (!r.ok) derived << id << "," << r.reading << ",,,,," << Quote(r.message) << ",\n";
      for (const DerivedParameter& d : r.parameters) {
        derived << id << "," << r.reading << "," << d.name << "," << Csv(d.value) << "," << Csv(d.se) << ","
                << Csv(d.rse_pct) << "," << Quote(r.message) << "," << Quote(ParameterUnit(d.name, units)) << "\n";
      }
    }
  }
  return any ? derived.str() : "";
}

std::string PopulationCsv(const TwoStageSummary& pop, const Units& units) {
  std::ostringstream population;
  population << "PARAMETER,N,MEAN,SD,CV_PCT,GEOMEAN,GEOCV_PCT,MEDIAN,MIN,MAX,GTS_N,TYPICAL,TYPICAL_SE,TYPICAL_RSE_PCT,"
                "OMEGA2,OMEGA2_SE,OMEGA2_RSE_PCT,BSV_CV_PCT,UNIT\n";
  for (size_t j = 0; j < pop.descriptive.size(); ++j) {
    const DescriptiveStatistics& d = pop.descriptive[j];
    population << d.name << "," << d.n << "," << Csv(d.mean) << "," << Csv(d.sd) << "," << Csv(d.cv_pct) << ","
               << Csv(d.geometric_mean) << "," << Csv(d.geometric_cv_pct) << "," << Csv(d.median) << "," << Csv(d.min)
               << "," << Csv(d.max);
    if (pop.gts_ok) {
      const PopulationParameter& q = pop.population[j];
      population << "," << pop.gts_ids.size() << "," << Csv(q.typical) << "," << Csv(q.typical_se) << ","
                 << Csv(q.typical_rse_pct) << "," << Csv(q.omega2) << "," << Csv(q.omega2_se) << ","
                 << Csv(q.omega2_rse_pct) << "," << Csv(q.bsv_cv_pct) << "," << Quote(ParameterUnit(d.name, units)) << "\n";
    } else {
      population << ",0,,,,,,,," << Quote(ParameterUnit(d.name, units)) << "\n";
    }
  }
  return population.str();
}

std::string PopulationOmegaCsv(const TwoStageSummary& pop) {
  std::ostringstream omega;
  omega << "PARAMETER1,PARAMETER2,OMEGA,SE,CORRELATION\n";
  for (size_t j = 0; pop.gts_ok && j < pop.parameters.size(); ++j) {
    for (size_t k = 0; k <= j; ++k) {
      if (pop.diagonal_omega && k != j) continue;
      const auto a = static_cast<Eigen::Index>(j), b = static_cast<Eigen::Index>(k);
      omega << pop.parameters[j] << "," << pop.parameters[k] << "," << Csv(pop.omega(a, b)) << ","
            << Csv(pop.omega_se(a, b)) << "," << Csv(pop.omega_correlation(a, b)) << "\n";
    }
  }
  return omega.str();
}

}  // namespace cli
}  // namespace pk
