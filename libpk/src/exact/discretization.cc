#include "discretization.h"

#include <cmath>
#include <stdexcept>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <unsupported/Eigen/MatrixFunctions>

#include "jet_exponential.h"
#include "numerical_failure.h"

namespace pk {
namespace internal {
namespace {

template <typename T>
T* Find(std::vector<std::pair<double, T>>& cache, double h) {
  for (auto& entry : cache) {
    if (entry.first == h) return &entry.second;
  }
  return nullptr;
}

}  // namespace

double Sinhc(double d) {
  if (std::fabs(d) < 1e-3) return 1 + d * d / 6 * (1 + d * d / 20);
  return std::sinh(d) / d;
}

Discretization::Discretization(Eigen::MatrixXd a, int n_in, bool allow_eigen, std::shared_ptr<const JetProducts> jet)
    : a_(std::move(a)), n_(static_cast<int>(a_.rows())), n_in_(n_in), allow_eigen_(allow_eigen), jet_(std::move(jet)) {
  if (jet_ && n_ != jet_->parts * n_in_) throw std::logic_error("a jet matrix's parts have n_in states each");
}

// The parts of exp(hA), with Van Loan's [[A, I],[0, 0]] for Γ (inputs enter part 0 alone), written
// out as the stacked Φ (block (t, b) = part a for each entry (t, a, b)) and Γ (block t = Γ's part t).
// A's part a is the stacked block (a, 0): the unit's entry (a, a, 0) puts it there.
void Discretization::JetStep(double h, bool with_gamma, Step* step) {
  const int parts = jet_->parts, b = n_in_, w = with_gamma ? 2 * b : b;
  thread_local Jet e;  // hA, then its exponential; kept so that a step allocates no parts
  e.resize(static_cast<size_t>(parts));
  for (int s = 0; s < parts; ++s) {
    e[static_cast<size_t>(s)].setZero(w, w);
    e[static_cast<size_t>(s)].topLeftCorner(b, b) = a_.block(s * b, 0, b, b) * h;
  }
  if (with_gamma) e[0].topRightCorner(b, b) = Eigen::MatrixXd::Identity(b, b) * h;
  JetExponential(*jet_, &e);
  ++exponentials_;
  step->phi = Eigen::MatrixXd::Zero(n_, n_);
  for (const auto& [t, a, c] : jet_->entries) step->phi.block(t * b, c * b, b, b) = e[static_cast<size_t>(a)].topLeftCorner(b, b);
  if (!with_gamma) return;
  step->gamma.resize(n_, b);
  for (int s = 0; s < parts; ++s) step->gamma.middleRows(s * b, b) = e[static_cast<size_t>(s)].topRightCorner(b, b);
}

void Discretization::Decompose() {
  if (decomposed_) return;
  decomposed_ = true;
  if (!allow_eigen_) return;
  Eigen::VectorXd t;
  if (SymmetrizingDiagonal(a_, &t)) {
    // A = T Q Λ Qᵀ T⁻¹ from the symmetric S = T⁻¹AT: real eigenvalues, orthogonal Q.
    Eigen::MatrixXd sym = t.cwiseInverse().asDiagonal() * a_ * t.asDiagonal();
    sym = 0.5 * (sym + sym.transpose());
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(sym);
    if (es.info() != Eigen::Success) return;
    lambda_ = es.eigenvalues();
    v_ = t.asDiagonal() * es.eigenvectors();
    w_ = es.eigenvectors().transpose() * t.cwiseInverse().asDiagonal();
  } else {
    const Eigen::EigenSolver<Eigen::MatrixXd> es(a_);
    if (es.info() != Eigen::Success) return;
    const double scale = std::max(a_.cwiseAbs().maxCoeff(), 1e-300);
    if (es.eigenvalues().imag().cwiseAbs().maxCoeff() > 1e-12 * scale) return;
    lambda_ = es.eigenvalues().real();
    v_ = es.eigenvectors().real();
    const Eigen::PartialPivLU<Eigen::MatrixXd> lu(v_);
    w_ = lu.inverse();
  }
  const double kappa = v_.cwiseAbs().colwise().sum().maxCoeff() * w_.cwiseAbs().colwise().sum().maxCoeff();
  // The derivative contractions carry errors of about κ²ε; κ ≤ 1e3 keeps them near 1e-10.
  if (!(kappa <= 1e3) || !w_.allFinite()) return;
  eigen_ = true;
  z_ = Eigen::MatrixXd::Zero(n_, n_);
}

bool Discretization::eigen_path() {
  Decompose();
  return eigen_;
}

const Discretization::Step& Discretization::Get(double h, bool with_gamma) {
  Step* step = Find(steps_, h);
  if (jet_) {
    if (step == nullptr) {
      steps_.emplace_back(h, Step());
      step = &steps_.back().second;
    }
    if (step->phi.size() == 0 || (with_gamma && step->gamma.size() == 0)) JetStep(h, with_gamma, step);
    return *step;
  }
  if (step == nullptr) {
    steps_.emplace_back(h, Step());
    step = &steps_.back().second;
    if (!with_gamma) {
      step->phi = (a_ * h).exp();
      ++exponentials_;
    }
  }
  if (with_gamma && step->gamma.size() == 0) {
    // Van Loan: exp([[A, B],[0, 0]] h) = [[Φ, Γ],[0, I]].
    Eigen::MatrixXd m = Eigen::MatrixXd::Zero(n_ + n_in_, n_ + n_in_);
    m.topLeftCorner(n_, n_) = a_ * h;
    m.block(0, n_, n_in_, n_in_) = Eigen::MatrixXd::Identity(n_in_, n_in_) * h;
    const Eigen::MatrixXd e = m.exp();
    ++exponentials_;
    step->phi = e.topLeftCorner(n_, n_);
    step->gamma = e.topRightCorner(n_, n_in_);
  }
  return *step;
}

const Discretization::Step& Discretization::GetNearby(double h, bool with_gamma, double* at) {
  if (a_norm_ < 0) a_norm_ = a_.cwiseAbs().colwise().sum().maxCoeff();
  *at = h;
  for (const auto& entry : steps_) {
    if (entry.first == h) break;
    if (a_norm_ * std::fabs(h - entry.first) <= 0x1p-30) {
      *at = entry.first;
      break;
    }
  }
  return Get(*at, with_gamma);
}

const Eigen::MatrixXd& Discretization::DividedDifferences(double h) {
  if (Eigen::MatrixXd* f = Find(divided_, h)) return *f;
  Eigen::MatrixXd f(n_, n_);
  for (int i = 0; i < n_; ++i) {
    for (int k = 0; k < n_; ++k) {
      const double d = (lambda_(i) - lambda_(k)) * h / 2;
      f(i, k) = h * std::exp((lambda_(i) + lambda_(k)) * h / 2) * Sinhc(d);
    }
  }
  divided_.emplace_back(h, std::move(f));
  return divided_.back().second;
}

Discretization::Sensitivity Discretization::BlockSensitivity(double h, const std::vector<Eigen::MatrixXd>& da_list) {
  // exp([[Mh, 0],[M_j h, Mh]]): the lower-left block is ∂exp(Mh)/∂θ_j (seed 5.4/5.7).
  const int k = n_ + n_in_;
  Eigen::MatrixXd big = Eigen::MatrixXd::Zero(2 * k, 2 * k);
  big.topLeftCorner(n_, n_) = a_ * h;
  big.block(0, n_, n_in_, n_in_) = Eigen::MatrixXd::Identity(n_in_, n_in_) * h;
  big.bottomRightCorner(k, k) = big.topLeftCorner(k, k);
  Sensitivity s;
  for (const Eigen::MatrixXd& da : da_list) {
    // L(X, E) is linear in E: exponentiate with a unit-norm direction so that
    // scaling and squaring is chosen by X alone, then scale back.
    const double norm = da.norm() * h;
    if (norm == 0) {
      s.dphi.push_back(Eigen::MatrixXd::Zero(n_, n_));
      s.dgamma.push_back(Eigen::MatrixXd::Zero(n_, n_in_));
      continue;
    }
    big.block(k, 0, n_, n_) = da * (h / norm);
    const Eigen::MatrixXd e = big.exp();
    ++exponentials_;
    s.dphi.push_back(e.block(k, 0, n_, n_) * norm);
    s.dgamma.push_back(e.block(k, n_, n_, n_in_) * norm);
  }
  return s;
}

const Discretization::Sensitivity& Discretization::GetSensitivity(double h, bool with_gamma,
                                                                  const std::vector<Eigen::MatrixXd>& da_list) {
  Decompose();
  if (with_gamma || !eigen_) {
    if (Sensitivity* s = Find(sens_gamma_, h)) return *s;
    sens_gamma_.emplace_back(h, BlockSensitivity(h, da_list));
    return sens_gamma_.back().second;
  }
  if (Sensitivity* s = Find(sens_, h)) return *s;
  const Eigen::MatrixXd& f = DividedDifferences(h);
  Sensitivity s;
  for (const Eigen::MatrixXd& da : da_list) s.dphi.push_back(v_ * (f.cwiseProduct(w_ * da * v_)) * w_);
  sens_.emplace_back(h, std::move(s));
  return sens_.back().second;
}

void Discretization::AccumulateAdjoint(double h, const Eigen::VectorXd& lambda_after, const Eigen::VectorXd& x_before,
                                       const Eigen::VectorXd& u) {
  Decompose();
  const bool input = u.size() > 0 && !u.isZero(0.0);
  if (eigen_ && !input) {
    const Eigen::MatrixXd& f = DividedDifferences(h);
    z_.noalias() += f.cwiseProduct((v_.transpose() * lambda_after) * (w_ * x_before).transpose());
    return;
  }
  Eigen::MatrixXd* acc = Find(frechet_, h);
  if (acc == nullptr) {
    frechet_.emplace_back(h, Eigen::MatrixXd::Zero(n_ + n_in_, n_ + n_in_));
    acc = &frechet_.back().second;
  }
  // W += [λ; 0][x; u]ᵀ (only the top rows are non-zero).
  acc->topLeftCorner(n_, n_).noalias() += lambda_after * x_before.transpose();
  if (input) acc->topRightCorner(n_, n_in_).noalias() += lambda_after * u.transpose();
}

Eigen::MatrixXd Discretization::FinishAdjoint() {
  Eigen::MatrixXd g = Eigen::MatrixXd::Zero(n_, n_);
  if (eigen_ && !z_.isZero(0.0)) {
    g = w_.transpose() * z_ * v_.transpose();
    z_.setZero();
  }
  const int k = n_ + n_in_;
  for (const auto& entry : frechet_) {
    const double h = entry.first;
    // λ̃ᵀ L(Mh, hM_j) x̃ = h ⟨L(hMᵀ, W), M_j⟩; L(X, E) is the upper-right block of exp([[X, E],[0, X]]).
    Eigen::MatrixXd mt = Eigen::MatrixXd::Zero(k, k);
    mt.topLeftCorner(n_, n_) = a_.transpose() * h;
    mt.block(n_, 0, n_in_, n_in_) = Eigen::MatrixXd::Identity(n_in_, n_in_) * h;
    Eigen::MatrixXd big = Eigen::MatrixXd::Zero(2 * k, 2 * k);
    big.topLeftCorner(k, k) = mt;
    big.bottomRightCorner(k, k) = mt;
    // L is linear in its direction: a unit-norm W keeps the exponential's accuracy set by hMᵀ.
    const double norm = entry.second.norm();
    if (norm == 0) continue;
    big.topRightCorner(k, k) = entry.second / norm;
    const Eigen::MatrixXd e = big.exp();
    ++exponentials_;
    g += (h * norm) * e.topRightCorner(k, k).topLeftCorner(n_, n_);
  }
  frechet_.clear();
  return g;
}

PeriodicSteadyState SolvePeriodicSteadyState(Discretization* d, int n, const Eigen::VectorXd& bolus,
                                             const std::vector<std::pair<double, Eigen::VectorXd>>& segments) {
  PeriodicSteadyState ss;
  ss.m = Eigen::MatrixXd::Identity(n, n);
  Eigen::VectorXd p0 = bolus;  // P(0) = M b + w
  for (const auto& seg : segments) {
    const bool input = !seg.second.isZero(0.0);
    const Discretization::Step& st = d->Get(seg.first, input);
    const Eigen::MatrixXd phi = st.phi.topLeftCorner(n, n);
    ss.m = phi * ss.m;
    p0 = phi * p0;
    if (input) p0 += st.gamma.topRows(n) * seg.second;
  }
  ss.lu.compute(Eigen::MatrixXd::Identity(n, n) - ss.m);
  if (!(ss.lu.rcond() > 1e-13)) {
    throw NumericalFailure(
        "no steady state: the dosing-interval map has an eigenvalue at 1 (is drug eliminated from every "
        "compartment it reaches?)");
  }
  ss.x_star = ss.lu.solve(p0);
  return ss;
}

}  // namespace internal
}  // namespace pk
