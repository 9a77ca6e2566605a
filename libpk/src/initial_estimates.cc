#include "pk/initial_estimates.h"

#include "pk/conversion.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Dense>

namespace pk {
namespace {

struct DoseInput {
  double time;
  double amount;
  double duration;  // 0 for a bolus
};

// Response at time t (after dose time) of the kernel e^{−λs} to one dose, and
// with first-order absorption at rate ka when ka > 0.
double KernelResponse(const DoseInput& d, double t, double lambda, double ka) {
  const double s = t - d.time;
  if (s <= 0) return 0;
  if (ka > 0) {
    // D·ka (e^{−λs} − e^{−ka s})/(ka − λ)
    return d.amount * ka * (std::exp(-lambda * s) - std::exp(-ka * s)) / (ka - lambda);
  }
  if (d.duration <= 0) return d.amount * std::exp(-lambda * s);
  const double rate = d.amount / d.duration;
  if (s <= d.duration) return rate * (1 - std::exp(-lambda * s)) / lambda;
  return rate * (std::exp(-lambda * (s - d.duration)) - std::exp(-lambda * s)) / lambda;
}

struct Candidate {
  double cost = std::numeric_limits<double>::infinity();
  std::vector<double> rates;
  double ka = 0;
  Eigen::VectorXd amplitudes;
};

// The weighted kernel columns x_k = Σ_d K(d, t_k; λ, ka)/c_k of the grid search,
// each computed on first use and kept: a column depends on (λ, ka) alone, and the
// search meets each pair in many combinations.
class KernelColumns {
 public:
  KernelColumns(const std::vector<DoseInput>& doses, const std::vector<double>& t, const std::vector<double>& c,
                const std::vector<double>& rates)
      : doses_(doses), t_(t), c_(c), rates_(rates), grid_(static_cast<int>(rates.size())),
        columns_(static_cast<size_t>(grid_) * (grid_ + 1)) {}

  // Rate index i; absorption rate index j (-1: none).
  const Eigen::VectorXd& Get(int i, int j) {
    Eigen::VectorXd& col = columns_[static_cast<size_t>(i) * (grid_ + 1) + (j + 1)];
    if (col.size() == 0) {
      const int n = static_cast<int>(t_.size());
      const double ka = j < 0 ? 0.0 : rates_[j];
      col.resize(n);
      for (int k = 0; k < n; ++k) {
        const double w = 1 / c_[k];
        double sum = 0;
        for (const DoseInput& d : doses_) sum += KernelResponse(d, t_[k], rates_[i], ka);
        col(k) = sum * w;
      }
    }
    return col;
  }

 private:
  const std::vector<DoseInput>& doses_;
  const std::vector<double>& t_;
  const std::vector<double>& c_;
  const std::vector<double>& rates_;
  const int grid_;
  std::vector<Eigen::VectorXd> columns_;
};

// Weighted linear least squares for the amplitudes at fixed rates (the columns
// of x); false for non-positive amplitudes. The work space is reused from call
// to call.
struct AmplitudeSolver {
  Eigen::MatrixXd x;
  Eigen::VectorXd y, a;
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr;

  bool Solve(double* cost) {
    y.setOnes(x.rows());  // c_k·w_k
    qr.compute(x);
    a = qr.solve(y);
    if (!a.allFinite() || (a.array() <= 0).any()) return false;
    *cost = (x * a - y).squaredNorm();
    return *cost < std::numeric_limits<double>::infinity();
  }
};

// Terminal-phase log-linear regression, as in non-compartmental analysis: over
// the last k points after the peak (k = 3, 4, …), the slope of log c against
// t with the best adjusted R². Returns λz > 0, or 0 when there is none.
double TerminalRate(const std::vector<double>& t, const std::vector<double>& c) {
  const int n = static_cast<int>(t.size());
  const int peak = static_cast<int>(std::max_element(c.begin(), c.end()) - c.begin());
  double best_r2 = -1, best_rate = 0;
  for (int k = 3; k <= n - peak - 1 && k <= n; ++k) {
    double st = 0, sy = 0, stt = 0, sty = 0, syy = 0;
    for (int i = n - k; i < n; ++i) {
      const double y = std::log(c[i]);
      st += t[i];
      sy += y;
      stt += t[i] * t[i];
      sty += t[i] * y;
      syy += y * y;
    }
    const double sxx = stt - st * st / k, sxy = sty - st * sy / k, syy_c = syy - sy * sy / k;
    if (!(sxx > 0) || !(syy_c > 0)) continue;
    const double slope = sxy / sxx, r2 = sxy * sxy / (sxx * syy_c);
    const double adjusted = 1 - (1 - r2) * (k - 1) / (k - 2);
    if (slope < 0 && adjusted > best_r2 - 1e-4) {  // prefer more points at (nearly) equal fit
      best_r2 = std::max(best_r2, adjusted);
      best_rate = -slope;
    }
  }
  return best_rate;
}

// All increasing m-tuples of grid indices.
void Combinations(int grid, int m, int start, std::vector<int>* current, std::vector<std::vector<int>>* out) {
  if (static_cast<int>(current->size()) == m) {
    out->push_back(*current);
    return;
  }
  for (int i = start; i < grid; ++i) {
    current->push_back(i);
    Combinations(grid, m, i + 1, current, out);
    current->pop_back();
  }
}

// A measured concentration: a sample that is not censored (a censored one's DV is its limit).
bool Measured(const Record& r, int cens_col) {
  return r.IsSample() && (cens_col < 0 || std::isnan(r.extra[static_cast<size_t>(cens_col)]) ||
                          r.extra[static_cast<size_t>(cens_col)] == 0);
}

// The subject's doses (ADDL expanded up to its last record) and the positive samples after the
// first dose. Returns "" or why the method does not apply.
std::string Inputs(const Model& model, const InitialStructure& structure, const Dataset& data, int subject,
                   std::vector<DoseInput>* doses, std::vector<double>* ts, std::vector<double>* cs) {
  const int cens_col = data.ExtraColumn("CENS");
  const bool tf = structure.kind == InitialStructure::Kind::kTransferFunction;
  const Subject& s = data.subjects[subject];
  std::vector<double> t, c;
  double end_time = -INFINITY;  // implied doses after the last record do not matter
  for (const Record& r : s.records) end_time = std::max(end_time, r.time);
  for (const Record& r : s.records) {
    if (r.evid == Evid::kReset || r.evid == Evid::kResetDose || r.ss != 0 || r.rate < 0) {
      return "steady-state doses, resets and modelled rates are not handled";
    }
    if (r.IsDose()) {
      if (r.cmt != 0 && r.cmt != model.default_dose_compartment()) {
        return "doses into a compartment other than the default are not handled";
      }
      const double duration = r.rate > 0 ? r.amt / r.rate : 0.0;
      if (structure.depot && duration > 0) return "infusions into the depot are not handled";
      for (int k = 0; k <= r.addl && (k == 0 || r.time + k * r.ii <= end_time); ++k) {
        doses->push_back({r.time + k * r.ii, r.amt, duration});
      }
    } else if (Measured(r, cens_col) && r.dv > 0 && (tf || r.cmt == 0 || r.cmt == model.central_compartment())) {
      t.push_back(r.time);
      c.push_back(r.dv);
    }
  }
  if (doses->empty()) return "no dose";
  for (size_t k = 0; k < t.size(); ++k) {
    if (t[k] > doses->front().time) {
      ts->push_back(t[k]);
      cs->push_back(c[k]);
    }
  }
  const int unknowns = structure.order + (structure.depot ? 1 : 0);
  if (static_cast<int>(ts->size()) < unknowns + 1) return "too few positive samples after the dose";
  return "";
}

// The candidate rates: a log-spaced grid from about 1/20 of the observed time span to about 20/first
// sample time, joined by the terminal rate from log-linear regression, so that the slowest phase can
// be matched exactly rather than to the grid's resolution.
std::vector<double> RateGrid(int phases, const std::vector<double>& ts, const std::vector<double>& cs, double t0) {
  const double first = ts.front() - t0, span = ts.back() - t0;
  const double lo = 0.05 / span, hi = 20 / first;
  const int grid = phases == 1 ? 40 : (phases == 2 ? 28 : (phases == 3 ? 16 : 11));
  std::vector<double> rates(grid);
  for (int i = 0; i < grid; ++i) rates[i] = lo * std::pow(hi / lo, static_cast<double>(i) / (grid - 1));
  const double lambda_z = TerminalRate(ts, cs);
  if (lambda_z > 0) {
    rates.push_back(lambda_z);
    std::sort(rates.begin(), rates.end());
  }
  return rates;
}

// The best few rate combinations, in order of cost, so an infeasible conversion can fall back to the next.
std::vector<Candidate> GridSearch(const InitialStructure& structure, const std::vector<DoseInput>& doses,
                                  const std::vector<double>& ts, const std::vector<double>& cs) {
  const int phases = structure.order;
  const std::vector<double> rates = RateGrid(phases, ts, cs, doses.front().time);
  const int grid_size = static_cast<int>(rates.size());
  std::vector<std::vector<int>> combos;
  std::vector<int> current;
  Combinations(grid_size, phases, 0, &current, &combos);
  const size_t kKeep = 20;
  std::vector<Candidate> best;
  KernelColumns columns(doses, ts, cs, rates);
  AmplitudeSolver solver;
  solver.x.resize(static_cast<Eigen::Index>(ts.size()), phases);
  auto consider = [&](const std::vector<int>& idx, int ka_index) {
    for (int i = 0; i < phases; ++i) solver.x.col(i) = columns.Get(idx[i], ka_index);
    double cost;
    if (!solver.Solve(&cost)) return;
    if (best.size() == kKeep && !(cost < best.back().cost)) return;
    const auto at = std::upper_bound(best.begin(), best.end(), cost,
                                     [](double c, const Candidate& b) { return c < b.cost; });
    Candidate cand;
    cand.cost = cost;
    for (int i : idx) cand.rates.push_back(rates[i]);
    cand.ka = ka_index < 0 ? 0.0 : rates[ka_index];
    cand.amplitudes = solver.a;
    best.insert(at, std::move(cand));
    if (best.size() > kKeep) best.pop_back();
  };
  for (const std::vector<int>& idx : combos) {
    if (!structure.depot) {
      consider(idx, -1);
    } else {
      // Absorption faster than every disposition rate (the usual, non-flip-flop branch).
      for (int j = idx.back() + 1; j < grid_size; ++j) consider(idx, j);
    }
  }
  return best;
}

// The first candidate that converts into the model's parameters.
void Convert(const InitialStructure& structure, const std::vector<Candidate>& best, InitialEstimate* out) {
  for (const Candidate& cand : best) {
    Exponentials e;
    e.rate = cand.rates;
    for (int i = 0; i < cand.amplitudes.size(); ++i) e.amplitude.push_back(cand.amplitudes(i));
    std::vector<double> p;
    std::string why;
    if (structure.kind == InitialStructure::Kind::kTransferFunction) {
      ExponentialsToTransferFunction(e, &p);
    } else if (!ExponentialsToMammillary(e, &p, &why)) {
      out->message = why;
      continue;
    } else if (structure.depot) {
      p.insert(p.begin(), cand.ka);
    }
    for (size_t k = 0; k < p.size() && k < structure.names.size(); ++k) out->values[structure.names[k]] = p[k];
    out->ok = true;
    out->message.clear();
    return;
  }
  if (out->message.empty()) out->message = "no candidate with positive amplitudes";
}

// Saturable elimination: the linear block's clearance CL at the median observed concentration C̃,
// with KM = C̃ (half-saturated there): VMAX·C̃/(KM + C̃) = CL·C̃ gives VMAX = CL·(KM + C̃).
void Saturable(const InitialStructure& structure, const Dataset& data, int subject, InitialEstimate* out) {
  const int cens_col = data.ExtraColumn("CENS");
  std::vector<double> c;
  for (const Record& r : data.subjects[subject].records) {
    if (Measured(r, cens_col) && r.dv > 0) c.push_back(r.dv);
  }
  std::sort(c.begin(), c.end());
  const double median = c[c.size() / 2];
  const std::string& clearance = structure.names[structure.depot ? 1 : 0];
  const double cl = out->values.at(clearance);
  out->values.erase(clearance);
  out->values[structure.km] = median;
  out->values[structure.vmax] = cl * 2 * median;
  out->method += " on the linear model; KM = median concentration, VMAX = CL (KM + median)";
}

}  // namespace

InitialEstimate EstimateInitialValues(const Model& model, const Dataset& data, int subject) {
  const InitialStructure& structure = model.initial_structure();
  InitialEstimate out;
  out.method = "terminal log-linear regression, exponential grid with linear amplitudes";
  if (structure.kind == InitialStructure::Kind::kNone || structure.order < 1) {
    out.message = "model " + model.name() + " declares no structure for starting values from the data";
    return out;
  }
  std::vector<DoseInput> doses;
  std::vector<double> ts, cs;
  out.message = Inputs(model, structure, data, subject, &doses, &ts, &cs);
  if (!out.message.empty()) return out;
  Convert(structure, GridSearch(structure, doses, ts, cs), &out);
  if (out.ok && !structure.vmax.empty()) Saturable(structure, data, subject, &out);
  return out;
}

}  // namespace pk
