#include "pk/initial_estimates.h"

#include "pk/catalogue.h"

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

}  // namespace

bool ExponentialsToMammillary(const Exponentials& e, std::vector<double>* p, std::string* why) {
  const int m = static_cast<int>(e.rate.size());
  auto fail = [&](const std::string& w) {
    if (why) *why = w;
    return false;
  };
  double b0 = 0;
  for (double a : e.amplitude) b0 += a;
  if (!(b0 > 0)) return fail("the amplitudes do not sum to a positive concentration");
  const double v1 = 1 / b0;
  p->clear();
  if (m == 1) {
    *p = {e.rate[0] * v1, v1};
    return true;
  }
  if (m == 2) {
    const double a1 = e.amplitude[0], a2 = e.amplitude[1], l1 = e.rate[0], l2 = e.rate[1];
    const double k21 = (a1 * l2 + a2 * l1) / (a1 + a2);
    const double k10 = l1 * l2 / k21;
    const double k12 = l1 + l2 - k21 - k10;
    if (!(k21 > 0 && k10 > 0 && k12 > 0)) return fail("the exponentials give a negative micro-constant");
    *p = {k10 * v1, v1, k12 * v1, k12 * v1 / k21};
    return true;
  }
  if (m == 3) {
    // A(s) = Π(s + λ_i) = s³ + a1 s² + a2 s + a3; B(s) = Σ a_i Π_{j≠i}(s + λ_j) = b0 s² + b1 s + b2.
    const double l1 = e.rate[0], l2 = e.rate[1], l3 = e.rate[2];
    const double a1 = l1 + l2 + l3, a2 = l1 * l2 + l1 * l3 + l2 * l3, a3 = l1 * l2 * l3;
    double b1 = 0, b2 = 0;
    for (int i = 0; i < 3; ++i) {
      const double lj = e.rate[(i + 1) % 3], lk = e.rate[(i + 2) % 3];
      b1 += e.amplitude[i] * (lj + lk);
      b2 += e.amplitude[i] * lj * lk;
    }
    // B(s)/b0 = (s + k21)(s + k31).
    const double sum = b1 / b0, prod = b2 / b0, disc = sum * sum - 4 * prod;
    if (!(disc >= 0) || !(prod > 0)) return fail("the peripheral rates are complex (no mammillary model fits)");
    const double k21 = (sum + std::sqrt(disc)) / 2, k31 = (sum - std::sqrt(disc)) / 2;
    if (!(k31 > 0)) return fail("a peripheral rate is not positive");
    const double k10 = a3 / (k21 * k31);
    const double s1 = a1 - k10 - k21 - k31;
    const double s2 = a2 - k10 * (k21 + k31) - k21 * k31;
    if (std::fabs(k21 - k31) < 1e-12 * k21) return fail("the peripheral rates coincide: the labelling is not identifiable");
    // k12 k31 + k13 k21 = s2, k12 + k13 = s1.
    const double k12 = (s2 - s1 * k21) / (k31 - k21), k13 = s1 - k12;
    if (!(k10 > 0 && k12 > 0 && k13 > 0)) return fail("the exponentials give a negative micro-constant");
    *p = {k10 * v1, v1, k12 * v1, k12 * v1 / k21, k13 * v1, k13 * v1 / k31};
    return true;
  }
  return fail("only 1, 2 or 3 exponentials are supported");
}

void ExponentialsToTransferFunction(const Exponentials& e, std::vector<double>* coefficients) {
  const int n = static_cast<int>(e.rate.size());
  // Polynomial products, highest power first: {1} · (s + λ).
  auto product = [&](int skip) {
    std::vector<double> p{1.0};
    for (int i = 0; i < n; ++i) {
      if (i == skip) continue;
      std::vector<double> q(p.size() + 1, 0.0);
      for (size_t k = 0; k < p.size(); ++k) {
        q[k] += p[k];
        q[k + 1] += p[k] * e.rate[i];
      }
      p = q;
    }
    return p;
  };
  const std::vector<double> a = product(-1);  // size n+1, a[0] = 1
  std::vector<double> b(n, 0.0);
  for (int i = 0; i < n; ++i) {
    const std::vector<double> p = product(i);  // size n
    for (int k = 0; k < n; ++k) b[k] += e.amplitude[i] * p[k];
  }
  coefficients->assign(a.begin() + 1, a.end());
  coefficients->insert(coefficients->end(), b.begin(), b.end());
}

namespace {

// A measured concentration: a sample that is not censored (a censored one's DV is its limit).
bool Measured(const Record& r, int cens_col) {
  return r.IsSample() && (cens_col < 0 || std::isnan(r.extra[static_cast<size_t>(cens_col)]) ||
                          r.extra[static_cast<size_t>(cens_col)] == 0);
}

}  // namespace

InitialEstimate EstimateInitialValues(const Model& model, const Dataset& data, int subject) {
  const int cens_col = data.ExtraColumn("CENS");
  const std::string& model_name = model.name();
  if (model_name.size() > 3 && model_name.compare(model_name.size() - 3, 3, "_mm") == 0) {
    // Michaelis-Menten: the linear counterpart's clearance CL at the median
    // observed concentration C̃, with KM = C̃ (half-saturated there):
    // VMAX·C̃/(KM + C̃) = CL·C̃ gives VMAX = CL·(KM + C̃).
    InitialEstimate out = EstimateInitialValues(*MakeModel(model_name.substr(0, model_name.size() - 3)), data, subject);
    if (!out.ok) return out;
    std::vector<double> c;
    for (const Record& r : data.subjects[subject].records) {
      if (Measured(r, cens_col) && r.dv > 0) c.push_back(r.dv);
    }
    std::sort(c.begin(), c.end());
    const double median = c[c.size() / 2];
    const double cl = out.values.at("CL");
    out.values.erase("CL");
    out.values["KM"] = median;
    out.values["VMAX"] = cl * 2 * median;
    out.method += " on the linear model; KM = median concentration, VMAX = CL (KM + median)";
    return out;
  }
  InitialEstimate out;
  out.method = "terminal log-linear regression, exponential grid with linear amplitudes";
  const std::string& name = model.name();
  int phases = 0;
  if (name.rfind("1cmt", 0) == 0) phases = 1;
  if (name.rfind("2cmt", 0) == 0) phases = 2;
  if (name.rfind("3cmt", 0) == 0) phases = 3;
  const bool tf = name.size() == 3 && name.rfind("tf", 0) == 0;
  if (tf) phases = name[2] - '0';
  const bool oral = name.find("oral") != std::string::npos;
  if (phases == 0 || !model.is_linear()) {
    out.message = "automatic initial values cover the 1-3 compartment catalogue models";
    return out;
  }
  // The dose history and the samples.
  const Subject& s = data.subjects[subject];
  std::vector<DoseInput> doses;
  std::vector<double> t, c;
  double end_time = -INFINITY;  // implied doses after the last record do not matter
  for (const Record& r : s.records) end_time = std::max(end_time, r.time);
  for (const Record& r : s.records) {
    if (r.evid == Evid::kReset || r.evid == Evid::kResetDose || r.ss != 0 || r.rate < 0) {
      out.message = "steady-state doses, resets and modelled rates are not handled";
      return out;
    }
    if (r.IsDose()) {
      if (r.cmt != 0 && r.cmt != model.default_dose_compartment()) {
        out.message = "doses into a compartment other than the default are not handled";
        return out;
      }
      const double duration = r.rate > 0 ? r.amt / r.rate : 0.0;
      if (oral && duration > 0) {
        out.message = "infusions into the depot are not handled";
        return out;
      }
      for (int k = 0; k <= r.addl && (k == 0 || r.time + k * r.ii <= end_time); ++k) {
        doses.push_back({r.time + k * r.ii, r.amt, duration});
      }
    } else if (Measured(r, cens_col) && r.dv > 0 && (tf || r.cmt == 0 || r.cmt == model.central_compartment())) {
      t.push_back(r.time);
      c.push_back(r.dv);
    }
  }
  if (doses.empty()) {
    out.message = "no dose";
    return out;
  }
  // Samples after the first dose only.
  std::vector<double> ts, cs;
  for (size_t k = 0; k < t.size(); ++k) {
    if (t[k] > doses.front().time) {
      ts.push_back(t[k]);
      cs.push_back(c[k]);
    }
  }
  const int unknowns = phases + (oral ? 1 : 0);
  if (static_cast<int>(ts.size()) < unknowns + 1) {
    out.message = "too few positive samples after the dose";
    return out;
  }
  const double first = ts.front() - doses.front().time, span = ts.back() - doses.front().time;
  const double lo = 0.05 / span, hi = 20 / first;
  const int grid = phases == 1 ? 40 : (phases == 2 ? 28 : (phases == 3 ? 16 : 11));
  std::vector<double> rates(grid);
  for (int i = 0; i < grid; ++i) rates[i] = lo * std::pow(hi / lo, static_cast<double>(i) / (grid - 1));
  // The terminal rate from log-linear regression joins the grid, so the slowest
  // phase can be matched exactly rather than to the grid's resolution.
  const double lambda_z = TerminalRate(ts, cs);
  if (lambda_z > 0) {
    rates.push_back(lambda_z);
    std::sort(rates.begin(), rates.end());
  }
  const int grid_size = static_cast<int>(rates.size());
  std::vector<std::vector<int>> combos;
  std::vector<int> current;
  Combinations(grid_size, phases, 0, &current, &combos);

  // Keep the best few candidates, in order of cost, so an infeasible conversion can fall back to the next.
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
    if (!oral) {
      consider(idx, -1);
    } else {
      // Absorption faster than every disposition rate (the usual, non-flip-flop branch).
      for (int j = idx.back() + 1; j < grid_size; ++j) consider(idx, j);
    }
  }
  for (const Candidate& cand : best) {
    Exponentials e;
    e.rate = cand.rates;
    for (int i = 0; i < cand.amplitudes.size(); ++i) e.amplitude.push_back(cand.amplitudes(i));
    std::vector<double> p;
    std::string why;
    if (tf) {
      ExponentialsToTransferFunction(e, &p);
      for (size_t k = 0; k < p.size(); ++k) out.values[model.parameter_names()[k]] = p[k];
      out.ok = true;
      out.message.clear();
      return out;
    }
    if (!ExponentialsToMammillary(e, &p, &why)) {
      out.message = why;
      continue;
    }
    // Catalogue order: [KA,] then the disposition parameters.
    int k = 0;
    if (oral) out.values[model.parameter_names()[k++]] = cand.ka;
    for (double v : p) out.values[model.parameter_names()[k++]] = v;
    out.ok = true;
    out.message.clear();
    return out;
  }
  if (out.message.empty()) out.message = "no candidate with positive amplitudes";
  return out;
}

}  // namespace pk
