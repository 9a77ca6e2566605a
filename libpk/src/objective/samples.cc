// The samples of one subject as the loss sees them: observations, least-squares weights,
// censoring and continuous records, read from the prepared records.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "censoring.h"
#include "internal_text.h"
#include "objective/objective_state.h"
#include "pk/error.h"
#include "pk/ode_model.h"
#include "pk/output.h"

namespace pk {
namespace internal {
namespace {

// A nonlinear model's outputs are g(x, θ), chosen by DVID; a CMT that names another compartment
// would otherwise be ignored without a word.
void CheckOutputCmt(const ObjectiveState& d, const OdeModel* ode_model, const Record& r, int dvid_col) {
  if (!ode_model || r.cmt <= 0 || r.cmt == ode_model->central_compartment() ||
      (dvid_col >= 0 && !std::isnan(r.extra[dvid_col]))) {
    return;
  }
  std::string outputs;
  for (int k = 0; k < ode_model->num_outputs(); ++k) {
    outputs += (k ? ", " : "") + std::to_string(k + 1) + "=" + ode_model->output_names()[k];
  }
  throw InputError(d.data->source, r.line, d.data->ColumnNumber("CMT"),
                   "CMT " + std::to_string(r.cmt) + " on an observation: model " + ode_model->name() +
                       " predicts its outputs (" + outputs + "), chosen by DVID, not a compartment's amount; give " +
                       "CMT 0 or " + std::to_string(ode_model->central_compartment()) +
                       " (the central compartment), or a DVID");
}

void CheckContinuous(const ObjectiveState& d, const Record& r, int censored) {
  if (censored != 0) {
    throw InputError(d.data->source, r.line, d.data->ColumnNumber("CENS"),
                     "a continuous record (CONT=1) cannot be censored");
  }
  if (!IntegratesOde(d.propagator)) {
    throw InputError(d.data->source, r.line, d.data->ColumnNumber("CONT"),
                     "continuous records (CONT=1) need the ODE propagator (--propagator ode)");
  }
  if (d.likelihood()) {
    throw InputError(d.data->source, r.line, d.data->ColumnNumber("CONT"),
                     "continuous records (CONT=1) are fitted by least squares, not maximum likelihood");
  }
}

// The least-squares weight of sample `r`.
double Weight(const ObjectiveState& d, const Record& r, int weight_col) {
  const ObjectiveOptions& options = d.options;
  const auto bad = [&](const std::string& what) {
    throw InputError(d.data->source, r.line, d.data->ColumnNumber(what == "weight" ? options.weight_column : "DV"),
                     std::string("weighting ") + ToString(options.weighting) + " needs " +
                         (what == "weight" ? "a finite weight >= 0" : "DV != 0") + " on every sample");
  };
  double w = 1;
  switch (options.weighting) {
    case Weighting::kUniform: break;
    case Weighting::kInverseDvSquared:
      if (r.dv == 0) bad("DV");
      w = 1 / (r.dv * r.dv);
      break;
    case Weighting::kInverseDv:
      if (r.dv == 0) bad("DV");
      w = 1 / std::fabs(r.dv);
      break;
    case Weighting::kColumn:
      w = r.extra[weight_col];
      if (!std::isfinite(w) || w < 0) bad("weight");
      break;
  }
  return w;
}

void AddContinuous(ObjectiveState* d, const Record& r, int key, double w) {
  auto& series = d->ode.continuous.series;
  auto it = std::find_if(series.begin(), series.end(), [&](const auto& x) { return x.key == key; });
  if (it == series.end()) {
    series.push_back({});
    series.back().key = key;
    it = series.end() - 1;
  }
  if (!it->t.empty() && !(r.time > it->t.back())) {
    throw InputError(d->data->source, r.line, d->data->ColumnNumber("TIME"),
                     "continuous records (CONT=1) of one output need increasing times");
  }
  it->t.push_back(r.time);
  it->y.push_back(r.dv);
  it->w.push_back(w);
}

void BindPriors(ObjectiveState* d, const std::vector<LogNormalPrior>& priors) {
  for (const LogNormalPrior& p : priors) {
    const std::string upper = ToUpper(p.parameter);
    const auto it = std::find(d->names.begin(), d->names.end(), upper);
    if (it == d->names.end()) throw InputError("prior: " + d->model->UnknownParameter(p.parameter, d->names));
    if (!(p.median > 0) || !(p.sd_log > 0)) {
      throw InputError("prior on " + p.parameter + " needs median > 0 and sd > 0");
    }
    d->priors.push_back({static_cast<int>(it - d->names.begin()), std::log(p.median), p.sd_log});
  }
}

}  // namespace

void BindSamples(ObjectiveState* d, const std::vector<LogNormalPrior>& priors) {
  const int cont_col = d->data->ExtraColumn("CONT");
  const int dvid_col = d->data->ExtraColumn("DVID");
  const int cens_col = d->data->ExtraColumn("CENS");
  const auto* ode_model = dynamic_cast<const OdeModel*>(d->model.get());
  const int weight_col =
      d->options.weighting == Weighting::kColumn ? d->data->ExtraColumn(d->options.weight_column) : -1;
  if (d->options.weighting == Weighting::kColumn && weight_col < 0) {
    throw InputError(d->data->source, 0, 0, "no weight column '" + d->options.weight_column + "'");
  }
  std::vector<double> ys, ws;
  std::vector<int> cs, os;
  const std::vector<Record>& records = d->prepared.records();
  d->ode.key_of_record.assign(records.size(), 0);
  d->ode.sample_of_record.assign(records.size(), -1);
  for (size_t ri = 0; ri < records.size(); ++ri) {
    const Record& r = records[ri];
    d->ode.key_of_record[ri] = ode_model ? OutputOfRecord(*ode_model, *d->data, r, dvid_col) : d->prepared.cmt[ri] + 1;
    if (!r.IsSample()) continue;
    CheckOutputCmt(*d, ode_model, r, dvid_col);
    const bool continuous = cont_col >= 0 && r.extra[cont_col] == 1;
    const int censored = CheckedCensoring(*d->data, r, cens_col, d->likelihood() || d->options.keep_censored);
    if (continuous) CheckContinuous(*d, r, censored);
    const double w = Weight(*d, r, weight_col);
    if (continuous) {
      AddContinuous(d, r, d->ode.key_of_record[ri], w);
      continue;
    }
    // The output the sample measures, and its error model (each output its own, or one for all).
    const int output = OutputOfKey(*d->model, d->ode.key_of_record[ri]);
    int first_sigma = 0;
    const ResidualErrorModel* error = d->error;
    try {
      error = &d->error->ForOutput(output, &first_sigma);
    } catch (const InputError& e) {
      throw InputError(d->data->source, r.line, dvid_col >= 0 ? d->data->ColumnNumber("DVID") : 0, e.message());
    }
    if (error->log_transformed() && !(r.dv > 0)) {
      throw InputError(d->data->source, r.line, d->data->ColumnNumber("DV"),
                       std::string("the ") + error->name() +
                           " error model compares log DV with log PRED, so DV must be > 0, not " + FormatNumber(r.dv) +
                           (censored != 0 ? " (a censored sample's limit)" : "") +
                           "; give a sample below the limit of quantification CENS=1 and DV = the limit, or MDV=1");
    }
    d->ode.sample_of_record[ri] = static_cast<int>(ys.size());
    ys.push_back(r.dv);
    ws.push_back(w);
    cs.push_back(censored);
    os.push_back(output);
    d->times.push_back(r.time);
  }
  d->ode.num_samples = static_cast<int>(ys.size());
  d->y = Eigen::Map<Eigen::VectorXd>(ys.data(), static_cast<Eigen::Index>(ys.size()));
  d->w = Eigen::Map<Eigen::VectorXd>(ws.data(), static_cast<Eigen::Index>(ws.size()));
  d->cens = Eigen::Map<Eigen::VectorXi>(cs.data(), static_cast<Eigen::Index>(cs.size()));
  d->outputs = Eigen::Map<Eigen::VectorXi>(os.data(), static_cast<Eigen::Index>(os.size()));
  BindPriors(d, priors);
}

}  // namespace internal
}  // namespace pk
