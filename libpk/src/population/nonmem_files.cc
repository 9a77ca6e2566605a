// NONMEM's .ext and .phi tables of a population fit (pk/nonmem_files.h).
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "pk/nonmem_files.h"
#include "pk/output.h"

namespace pk {
namespace {

constexpr double kNotEstimated = 1e10;  // NONMEM's SE of what is fixed

const char* MethodTitle(PopulationMethod m) {
  switch (m) {
    case PopulationMethod::kFo: return "First Order";
    case PopulationMethod::kFoce: return "First Order Conditional Estimation";
    case PopulationMethod::kFocei: return "First Order Conditional Estimation with Interaction";
    case PopulationMethod::kLaplace: return "Laplacian Conditional Estimation with Interaction";
  }
  return "";
}

// Where each column of the table takes its value in PopulationSummary::estimates (−1: a constant,
// SIGMA(k,k) = 1 or an Ω covariance outside the blocks, 0), and Ω's (i, j) for the OMEGA columns.
struct Column {
  std::string name;
  int estimate = -1;
  double constant = 0;
  int i = -1, j = -1;  // Ω's row and column (OMEGA columns)
};

int EtaIndex(const std::vector<std::string>& etas, const std::string& name) {
  for (size_t k = 0; k < etas.size(); ++k) {
    if (etas[k] == name) return static_cast<int>(k);
  }
  return -1;
}

std::vector<Column> Columns(const PopulationSummary& fit) {
  const auto ntheta = static_cast<int>(fit.parameters.theta.size());
  const auto nsigma = static_cast<int>(fit.parameters.sigma.size());
  const auto nest = static_cast<int>(fit.estimates.size());
  const auto q = static_cast<int>(fit.eta_names.size());
  std::vector<Column> columns;
  for (int k = 0; k < ntheta; ++k) columns.push_back({"THETA" + std::to_string(k + 1), k});
  for (int k = 0; k < nsigma; ++k) columns.push_back({"THETA" + std::to_string(ntheta + k + 1), nest - nsigma + k});
  const int eps = std::max<int>(1, static_cast<int>(fit.epsilon_shrinkage_sd_by_output.size()));
  for (int r = 0; r < eps; ++r) {
    for (int c = 0; c <= r; ++c) {
      columns.push_back({"SIGMA(" + std::to_string(r + 1) + "," + std::to_string(c + 1) + ")", -1, r == c ? 1.0 : 0.0});
    }
  }
  std::vector<int> omega(static_cast<size_t>(q * q), -1);  // Ω's element → its estimate
  for (int e = ntheta; e < nest - nsigma; ++e) {
    const std::string& name = fit.estimates[static_cast<size_t>(e)].name;  // OMEGA(A) or OMEGA(B,A)
    const std::string inside = name.substr(6, name.size() - 7);
    const size_t comma = inside.find(',');
    const int a = EtaIndex(fit.eta_names, inside.substr(0, comma));
    const int b = comma == std::string::npos ? a : EtaIndex(fit.eta_names, inside.substr(comma + 1));
    if (a >= 0 && b >= 0) omega[static_cast<size_t>(a * q + b)] = omega[static_cast<size_t>(b * q + a)] = e;
  }
  for (int r = 0; r < q; ++r) {
    for (int c = 0; c <= r; ++c) {
      columns.push_back({"OMEGA(" + std::to_string(r + 1) + "," + std::to_string(c + 1) + ")",
                         omega[static_cast<size_t>(r * q + c)], 0.0, r, c});
    }
  }
  return columns;
}

std::string Title(const PopulationSummary& fit) {
  return std::string("TABLE NO.     1: ") + MethodTitle(fit.method) +
         ": Goal Function=MINIMUM VALUE OF OBJECTIVE FUNCTION: Problem=1 Subproblem=0 Superproblem1=0 Iteration1=0 "
         "Superproblem2=0 Iteration2=0\n";
}

// A header's name in its 13 columns (a longer one, OMEGA(10,10), takes what it needs).
std::string Name(const std::string& name) {
  return " " + name + std::string(name.size() < 12 ? 12 - name.size() : 0, ' ');
}

// NONMEM's E12.5 in 13 columns, with a space before it whatever its width (−1.50000E-120 has 13).
std::string Value(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%13.5E", v);
  return buffer[0] == ' ' ? std::string(buffer) : " " + std::string(buffer);
}

std::string Row(long long iteration, const std::vector<double>& values, double obj) {
  char head[32];
  std::snprintf(head, sizeof head, "%13lld", iteration);
  std::string line = head;
  for (double v : values) line += Value(v);
  std::string o = FormatNumber(obj);
  line += std::string(o.size() < 21 ? 21 - o.size() : 1, ' ') + o + "\n";
  return line;
}

// The estimates' values (or their SEs) in the columns' order.
std::vector<double> Values(const PopulationSummary& fit, const std::vector<Column>& columns,
                           const Eigen::VectorXd& estimates, bool se) {
  std::vector<double> out;
  for (const Column& c : columns) {
    if (c.estimate < 0) {
      out.push_back(se ? kNotEstimated : c.constant);
      continue;
    }
    const PopulationEstimate& e = fit.estimates[static_cast<size_t>(c.estimate)];
    // An estimated element without an SE (a covariance step that failed for it) writes 0, as
    // NONMEM's row does when $COV did not run.
    out.push_back(se ? (e.fixed ? kNotEstimated : std::isfinite(e.se) ? e.se : 0.0) : estimates(c.estimate));
  }
  return out;
}

// Position of each estimate in the covariance matrix (estimated ones only), or −1.
std::vector<int> CovariancePositions(const PopulationSummary& fit) {
  std::vector<int> at;
  int k = 0;
  for (const PopulationEstimate& e : fit.estimates) at.push_back(e.fixed ? -1 : k++);
  return at;
}

// Ω and Σ as SDs and correlations, and with `se` the SEs of those by the delta method:
// SD ω = √ω², SE = SE(ω²)/(2ω); ρ = ω_ij/√(ω_ii ω_jj), SE² = gᵀ Cov g with
// g = (1/√(ω_ii ω_jj), −ρ/(2ω_ii), −ρ/(2ω_jj)) over (ω_ij, ω_ii, ω_jj).
std::vector<double> StandardDeviationForm(const PopulationSummary& fit, const std::vector<Column>& columns, bool se) {
  const std::vector<int> at = CovariancePositions(fit);
  auto estimate = [&](int e) { return fit.estimates[static_cast<size_t>(e)].estimate; };
  std::vector<int> diagonal(fit.eta_names.size(), -1);
  for (const Column& c : columns) {
    if (c.i >= 0 && c.i == c.j) diagonal[static_cast<size_t>(c.i)] = c.estimate;
  }
  std::vector<double> out;
  for (const Column& c : columns) {
    if (c.name.rfind("THETA", 0) == 0) {
      out.push_back(0);  // as NONMEM writes them
    } else if (c.estimate < 0) {
      out.push_back(se ? kNotEstimated : c.constant);
    } else if (fit.estimates[static_cast<size_t>(c.estimate)].fixed && se) {
      out.push_back(kNotEstimated);
    } else if (c.i == c.j) {
      const double sd = std::sqrt(estimate(c.estimate)), s = fit.estimates[static_cast<size_t>(c.estimate)].se;
      out.push_back(se ? (std::isfinite(s) ? s / (2 * sd) : 0.0) : sd);
    } else {
      const int ii = diagonal[static_cast<size_t>(c.i)], jj = diagonal[static_cast<size_t>(c.j)];
      const double root = std::sqrt(estimate(ii) * estimate(jj)), rho = estimate(c.estimate) / root;
      if (!se) {
        out.push_back(rho);
        continue;
      }
      const int index[3] = {c.estimate, ii, jj};
      const double g[3] = {1 / root, -rho / (2 * estimate(ii)), -rho / (2 * estimate(jj))};
      double variance = 0;
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) {
          const int pa = at[static_cast<size_t>(index[a])], pb = at[static_cast<size_t>(index[b])];
          if (pa >= 0 && pb >= 0) variance += g[a] * g[b] * fit.covariance(pa, pb);
        }
      }
      out.push_back(std::isfinite(variance) ? std::sqrt(std::max(variance, 0.0)) : 0.0);
    }
  }
  return out;
}

// Whether the summary holds a fit's estimates (θ, Ω's elements and σ): a fit that stopped at its
// starting point (no subject's mode found) has none.
bool HasEstimates(const PopulationSummary& fit) {
  const auto q = fit.parameters.omega.rows();
  const auto least = static_cast<size_t>(fit.parameters.theta.size() + fit.parameters.sigma.size() + q);
  if (fit.estimates.size() < least || !std::isfinite(fit.ofv)) return false;
  for (const PopulationIteration& it : fit.history) {
    if (it.values.size() != static_cast<Eigen::Index>(fit.estimates.size())) return false;
  }
  return true;
}

}  // namespace

std::string NonmemExtTable(const PopulationSummary& fit) {
  std::string out = Title(fit) + " ITERATION   ";
  if (!HasEstimates(fit)) return out + " OBJ\n";  // the header alone: there are no estimates to list
  const std::vector<Column> columns = Columns(fit);
  for (const Column& c : columns) out += Name(c.name);
  out += " OBJ\n";
  double best = HUGE_VAL;
  for (const PopulationIteration& it : fit.history) {
    if (!(it.ofv < best)) continue;
    best = it.ofv;
    out += Row(it.evaluation - 1, Values(fit, columns, it.values, false), it.ofv);
  }
  Eigen::VectorXd final_values(static_cast<Eigen::Index>(fit.estimates.size()));
  for (size_t k = 0; k < fit.estimates.size(); ++k) final_values(static_cast<Eigen::Index>(k)) = fit.estimates[k].estimate;
  out += Row(-1000000000, Values(fit, columns, final_values, false), fit.ofv);
  const bool have_se = fit.covariance.size() > 0;
  if (have_se) out += Row(-1000000001, Values(fit, columns, final_values, true), 0);
  out += Row(-1000000004, StandardDeviationForm(fit, columns, false), 0);
  if (have_se) out += Row(-1000000005, StandardDeviationForm(fit, columns, true), 0);
  std::vector<double> fixed;
  for (const Column& c : columns) {
    fixed.push_back(c.estimate < 0 || fit.estimates[static_cast<size_t>(c.estimate)].fixed ? 1 : 0);
  }
  out += Row(-1000000006, fixed, 0);
  return out;
}

std::string NonmemPhiTable(const PopulationSummary& fit) {
  const auto q = static_cast<Eigen::Index>(fit.eta_names.size());
  std::string out = Title(fit) + " SUBJECT_NO   ID          ";
  for (Eigen::Index k = 0; k < q; ++k) out += Name("ETA(" + std::to_string(k + 1) + ")");
  for (Eigen::Index r = 0; r < q; ++r) {
    for (Eigen::Index c = 0; c <= r; ++c) out += Name("ETC(" + std::to_string(r + 1) + "," + std::to_string(c + 1) + ")");
  }
  out += " OBJ\n";
  for (const PopulationSubject& s : fit.subjects) {
    if (!s.ok || s.eta.size() != q || s.eta_covariance.rows() != q || !std::isfinite(s.ofv)) continue;
    char head[64];
    std::snprintf(head, sizeof head, "%13d", s.subject + 1);
    const std::string id = FormatNumber(s.id);
    std::vector<double> values(s.eta.data(), s.eta.data() + q);
    for (Eigen::Index r = 0; r < q; ++r) {
      for (Eigen::Index c = 0; c <= r; ++c) values.push_back(s.eta_covariance(r, c));
    }
    const std::string row = Row(0, values, s.ofv);  // its ITERATION field replaced below
    out += head + std::string(id.size() < 13 ? 13 - id.size() : 1, ' ') + id + row.substr(13);
  }
  return out;
}

}  // namespace pk
