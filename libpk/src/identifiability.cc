#include "identifiability.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include "internal_text.h"

namespace pk {
namespace internal {
namespace {

std::string Proportion(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2g", v);
  return buf;
}

}  // namespace

// Among the parameters with information, the `nullity` eigenvectors of the
// information scaled to a unit diagonal (so that units do not matter) with the
// smallest eigenvalues are the combinations that leave the fit unchanged to
// first order: J v ≈ 0.
std::string Unidentified(const Eigen::MatrixXd& info, int nullity, const std::vector<std::string>& names,
                         const Eigen::VectorXd& ds_dphi, bool log_scale) {
  const int n = static_cast<int>(info.rows());
  const double largest = n > 0 ? info.diagonal().maxCoeff() : 0.0;
  // "A", "A and B", "A, B and C".
  auto list = [](const std::vector<std::string>& items) {
    if (items.size() < 2) return internal::Join(items, "");
    return internal::Join(std::vector<std::string>(items.begin(), items.end() - 1), ", ") + " and " + items.back();
  };
  std::vector<int> some;
  std::vector<std::string> none, parts;
  for (int j = 0; j < n; ++j) {
    if (info(j, j) > 1e-14 * largest) {
      some.push_back(j);
    } else {
      none.push_back(names[j]);
    }
  }
  if (!none.empty()) {
    parts.push_back(list(none) + (none.size() > 1 ? " do" : " does") +
                    " not affect the predictions");
  }
  const int k = static_cast<int>(some.size());
  const int directions = std::min(k, nullity - static_cast<int>(none.size()));
  if (directions > 0) {
    Eigen::VectorXd scale(k);
    for (int a = 0; a < k; ++a) scale(a) = std::sqrt(info(some[a], some[a]));
    Eigen::MatrixXd c(k, k);
    for (int a = 0; a < k; ++a) {
      for (int b = 0; b < k; ++b) c(a, b) = info(some[a], some[b]) / (scale(a) * scale(b));
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(c);
    // The null directions: u in the unit-free scaling, v on the estimation scale s. Who takes part is judged
    // where it is free of units: by v on the log scale, by u on the natural scale.
    const Eigen::MatrixXd u = eig.eigenvectors().leftCols(directions);
    Eigen::MatrixXd v(k, directions);
    for (int a = 0; a < k; ++a) v.row(a) = u.row(a) / scale(a) * ds_dphi(some[a]);
    const Eigen::MatrixXd& judge = log_scale ? v : u;
    const Eigen::VectorXd weight = judge.rowwise().norm();
    std::vector<int> part;
    for (int a = 0; a < k; ++a) {
      if (weight(a) >= 0.05 * weight.maxCoeff()) part.push_back(a);
    }
    std::vector<std::string> who, scaled;
    for (int a : part) {
      who.push_back(names[some[a]]);
      scaled.push_back((log_scale ? "log " : "") + names[some[a]]);
    }
    if (who.size() < 2) {
      parts.push_back(list(who) + " is not determined by these data");
    } else if (directions > 1) {
      parts.push_back(list(who) + " are not determined separately: " + std::to_string(directions) +
                      " combinations of them leave the fit unchanged");
    } else {
      // One direction: its proportions, relative to the largest.
      int top = part[0];
      for (int a : part) {
        if (std::fabs(v(a, 0)) > std::fabs(v(top, 0))) top = a;
      }
      std::vector<std::string> ratio;
      for (int a : part) ratio.push_back(Proportion(v(a, 0) / v(top, 0)));
      parts.push_back(list(who) + " are not determined separately: changing " + list(scaled) +
                      " in the proportions " + internal::Join(ratio, " : ") + " leaves the fit unchanged");
    }
  }
  return internal::Join(parts, "; ");
}

int NullCoordinate(const Eigen::MatrixXd& jacobian, double threshold, double* ratio) {
  const Eigen::Index n = jacobian.cols();
  if (ratio) *ratio = 1;
  if (n == 0 || jacobian.rows() == 0) return -1;
  const Eigen::VectorXd norms = jacobian.colwise().norm().transpose();
  for (Eigen::Index j = n - 1; j >= 0; --j) {
    if (norms(j) == 0) {
      if (ratio) *ratio = 0;
      return static_cast<int>(j);
    }
  }
  const Eigen::MatrixXd scaled = jacobian * norms.cwiseInverse().asDiagonal();
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(scaled, Eigen::ComputeFullV);
  const Eigen::VectorXd& sigma = svd.singularValues();
  // Fewer rows than columns: the missing singular values are 0.
  const double smallest = jacobian.rows() < n ? 0.0 : sigma(n - 1);
  if (ratio) *ratio = smallest / sigma(0);
  if (!(smallest <= threshold * sigma(0))) return -1;
  // The null vector of the scaled problem, back on the optimiser's scale.
  const Eigen::VectorXd v = norms.cwiseInverse().cwiseProduct(svd.matrixV().col(n - 1)).cwiseAbs();
  const double largest = v.maxCoeff();
  for (Eigen::Index j = n - 1; j >= 0; --j) {
    if (v(j) >= (1 - 1e-6) * largest) return static_cast<int>(j);
  }
  return -1;
}

}  // namespace internal
}  // namespace pk
