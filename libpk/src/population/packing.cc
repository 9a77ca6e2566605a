// The population parameters as one vector (packing.h).
#include "population/packing.h"

#include <cmath>
#include <numeric>

#include <Eigen/Cholesky>

#include "internal_text.h"
#include "pk/error.h"
#include "population/problem_impl.h"

namespace pk {
namespace internal {
namespace {

std::vector<bool> Flags(const std::vector<bool>& given, size_t n, const char* what) {
  if (given.empty()) return std::vector<bool>(n, false);
  if (given.size() != n) throw InputError(std::string("expected ") + std::to_string(n) + " " + what + " flags");
  return given;
}

}  // namespace

Packing::Packing(const PopulationProblem& problem, const PopulationStructure& s, const PopulationParameters& initial)
    : initial_(initial) {
  const auto& d = problem.impl();
  const size_t nt = d.theta_names.size(), q = d.eta_names.size(), ns = d.sigma_names.size();
  theta_fixed_ = Flags(s.theta_fixed, nt, "θ fixed");
  sigma_fixed_ = Flags(s.sigma_fixed, ns, "σ fixed");
  std::vector<int> sizes = s.omega_blocks.empty() ? std::vector<int>(q, 1) : s.omega_blocks;
  if (std::accumulate(sizes.begin(), sizes.end(), 0) != static_cast<int>(q)) {
    throw InputError("the Ω blocks' sizes must add up to the number of η (" + std::to_string(q) + ")");
  }
  const std::vector<bool> block_fixed = Flags(s.omega_block_fixed, sizes.size(), "Ω block fixed");
  const std::vector<bool> block_same = Flags(s.omega_block_same, sizes.size(), "Ω block SAME");
  for (size_t k = 0; k < nt; ++k) {
    const double v = initial.theta(static_cast<Eigen::Index>(k));
    theta_log_.push_back(d.model->must_be_positive(d.theta_model_index[k]));
    if (!std::isfinite(v) || (theta_log_.back() && !(v > 0))) {
      throw InputError("the initial " + d.theta_names[k] + " must be positive, got " + Num(v));
    }
    const auto& declared = d.model->declarations().parameters;
    const size_t i = static_cast<size_t>(d.theta_model_index[k]);
    theta_lower_.push_back(i < declared.size() ? declared[i].lower : -HUGE_VAL);
    theta_upper_.push_back(i < declared.size() ? declared[i].upper : HUGE_VAL);
    if (theta_log_.back() && !(theta_lower_.back() > 0)) {
      // A positive parameter bounded below by 0 (or not at all): log θ, or the logit on (0, hi).
      theta_lower_.back() = std::isfinite(theta_upper_.back()) ? 0.0 : -HUGE_VAL;
    }
    if (!theta_fixed_[k] && !(v > theta_lower_.back() && v < theta_upper_.back())) {
      throw InputError("the initial " + d.theta_names[k] + " (" + Num(v) + ") must lie strictly within its bounds (" +
                       Num(theta_lower_.back()) + ", " + Num(theta_upper_.back()) + ") from the model file");
    }
    names_.push_back(d.theta_names[k]);
    fixed_.push_back(theta_fixed_[k]);
    size_ += theta_fixed_[k] ? 0 : 1;
  }
  same_.assign(names_.size(), false);
  int first = 0;
  for (size_t b = 0; b < sizes.size(); ++b) {
    Block block{first, sizes[b], block_fixed[b]};
    block.natural = static_cast<int>(names_.size());
    if (block_same[b]) SameAsBefore(problem, sizes, &block);
    const Eigen::MatrixXd w = initial_.omega.block(first, first, block.size, block.size);
    if (Eigen::LLT<Eigen::MatrixXd>(w).info() != Eigen::Success || !(w.diagonal().array() > 0).all()) {
      throw InputError("the initial Ω block of " + d.eta_names[static_cast<size_t>(first)] +
                       " is not positive definite");
    }
    for (int r = 0; r < block.size; ++r) {
      for (int c = 0; c <= r; ++c) {
        const std::string& a = d.eta_names[static_cast<size_t>(first + r)];
        names_.push_back(r == c ? "OMEGA(" + a + ")" : "OMEGA(" + a + "," + d.eta_names[static_cast<size_t>(first + c)] + ")");
        fixed_.push_back(block.fixed || block.same >= 0);
        same_.push_back(block.same >= 0);
        size_ += block.fixed || block.same >= 0 ? 0 : 1;
      }
    }
    blocks_.push_back(block);
    first += block.size;
  }
  Eigen::MatrixXd off = initial.omega;
  for (const Block& b : blocks_) off.block(b.first, b.first, b.size, b.size).setZero();
  if (off.cwiseAbs().maxCoeff() > 0) throw InputError("Ω has covariances outside its blocks");
  for (size_t j = 0; j < ns; ++j) {
    const double v = initial.sigma(static_cast<Eigen::Index>(j));
    if (!(v > 0) || !std::isfinite(v)) throw InputError("the initial " + d.sigma_names[j] + " must be positive");
    names_.push_back(d.sigma_names[j]);
    fixed_.push_back(sigma_fixed_[j]);
    same_.push_back(false);
    size_ += sigma_fixed_[j] ? 0 : 1;
  }
}

// A SAME block repeats the block before it (of its size), whose source it takes; it is fixed with
// that source, and starts from its values (NONMEM takes a SAME block's values from the block before).
void Packing::SameAsBefore(const PopulationProblem& problem, const std::vector<int>& sizes, Block* block) {
  const std::string& name = problem.impl().eta_names[static_cast<size_t>(block->first)];
  const size_t b = blocks_.size();
  if (b == 0 || sizes[b - 1] != block->size) {
    throw InputError("the Ω block of " + name + " is SAME as the block before it, which " +
                     (b == 0 ? std::string("does not exist") : "has " + std::to_string(sizes[b - 1]) + " η, not " +
                                                                std::to_string(block->size)));
  }
  const Block& before = blocks_[b - 1];
  block->same = before.same >= 0 ? before.same : static_cast<int>(b - 1);
  const Block& source = blocks_[static_cast<size_t>(block->same)];
  block->fixed = source.fixed;
  initial_.omega.block(block->first, block->first, block->size, block->size) =
      initial_.omega.block(source.first, source.first, source.size, source.size);
}

bool Packing::NearThetaBound(size_t k, double theta) const {
  const double lo = theta_lower_[k], hi = theta_upper_[k];
  // With one bound the scale is the larger of θ, the bound and the initial value: relative to θ
  // alone, an estimate that runs into a bound of 0 (θ → 0) would never be near it.
  const double bound = std::isfinite(lo) ? lo : hi, initial = initial_.theta(static_cast<Eigen::Index>(k));
  const double scale = std::max({std::fabs(theta), std::fabs(bound), std::fabs(initial), 1e-8});
  const double tol = std::isfinite(lo) && std::isfinite(hi) ? 1e-3 * (hi - lo) : 1e-3 * scale;
  return (std::isfinite(lo) && theta - lo <= tol) || (std::isfinite(hi) && hi - theta <= tol);
}

double Packing::XOf(size_t k, double theta) const {
  const double lo = theta_lower_[k], hi = theta_upper_[k];
  if (std::isfinite(lo) && std::isfinite(hi)) return std::log((theta - lo) / (hi - theta));
  if (std::isfinite(lo)) return std::log(theta - lo);
  if (std::isfinite(hi)) return std::log(hi - theta);
  return theta_log_[k] ? std::log(theta) : theta;
}

Eigen::VectorXd Packing::Pack(const PopulationParameters& p) const {
  Eigen::VectorXd x(size_);
  int at = 0;
  for (size_t k = 0; k < theta_fixed_.size(); ++k) {
    const double v = p.theta(static_cast<Eigen::Index>(k));
    if (!theta_fixed_[k]) x(at++) = XOf(k, v);
  }
  for (const Block& b : blocks_) {
    if (b.fixed || b.same >= 0) continue;
    const Eigen::MatrixXd l = p.omega.block(b.first, b.first, b.size, b.size).llt().matrixL();
    for (int r = 0; r < b.size; ++r) {
      for (int c = 0; c <= r; ++c) x(at++) = r == c ? std::log(l(r, r)) : l(r, c);
    }
  }
  for (size_t j = 0; j < sigma_fixed_.size(); ++j) {
    if (!sigma_fixed_[j]) x(at++) = std::log(p.sigma(static_cast<Eigen::Index>(j)));
  }
  return x;
}

PopulationParameters Packing::Unpack(const Eigen::VectorXd& x) const {
  PopulationParameters p = initial_;
  int at = 0;
  for (size_t k = 0; k < theta_fixed_.size(); ++k) {
    if (!theta_fixed_[k]) p.theta(static_cast<Eigen::Index>(k)) = ThetaOf(k, x(at++), [](double c) { return c; });
  }
  for (const Block& b : blocks_) {
    if (b.same >= 0) {  // its source's values, set before it
      const Block& source = blocks_[static_cast<size_t>(b.same)];
      p.omega.block(b.first, b.first, b.size, b.size) = p.omega.block(source.first, source.first, b.size, b.size);
      continue;
    }
    if (b.fixed) continue;
    Eigen::MatrixXd l = Eigen::MatrixXd::Zero(b.size, b.size);
    for (int r = 0; r < b.size; ++r) {
      for (int c = 0; c <= r; ++c) l(r, c) = r == c ? std::exp(x(at++)) : x(at++);
    }
    p.omega.block(b.first, b.first, b.size, b.size) = l * l.transpose();
  }
  for (size_t j = 0; j < sigma_fixed_.size(); ++j) {
    if (!sigma_fixed_[j]) p.sigma(static_cast<Eigen::Index>(j)) = std::exp(x(at++));
  }
  return p;
}

Eigen::VectorXd Packing::Natural(const PopulationParameters& p) const {
  Eigen::VectorXd z(static_cast<Eigen::Index>(names_.size()));
  Eigen::Index at = 0;
  for (Eigen::Index k = 0; k < p.theta.size(); ++k) z(at++) = p.theta(k);
  for (const Block& b : blocks_) {
    for (int r = 0; r < b.size; ++r) {
      for (int c = 0; c <= r; ++c) z(at++) = p.omega(b.first + r, b.first + c);
    }
  }
  for (Eigen::Index j = 0; j < p.sigma.size(); ++j) z(at++) = p.sigma(j);
  return z;
}

PopulationParameters Packing::FromNatural(const Eigen::VectorXd& z) const {
  PopulationParameters p = initial_;
  Eigen::Index at = 0;
  for (Eigen::Index k = 0; k < p.theta.size(); ++k) p.theta(k) = z(at++);
  for (const Block& b : blocks_) {
    // A SAME block reads its source's entries: moving those moves both (the covariance step's differences).
    Eigen::Index from = b.same < 0 ? at : blocks_[static_cast<size_t>(b.same)].natural;
    for (int r = 0; r < b.size; ++r) {
      for (int c = 0; c <= r; ++c, ++at, ++from) {
        p.omega(b.first + r, b.first + c) = z(from);
        p.omega(b.first + c, b.first + r) = z(from);
      }
    }
  }
  for (Eigen::Index j = 0; j < p.sigma.size(); ++j) p.sigma(j) = z(at++);
  return p;
}

int Packing::NaturalSource(size_t k) const {
  for (const Block& b : blocks_) {
    const int count = b.size * (b.size + 1) / 2, at = static_cast<int>(k) - b.natural;
    if (b.same >= 0 && at >= 0 && at < count) return blocks_[static_cast<size_t>(b.same)].natural + at;
  }
  return static_cast<int>(k);
}

std::vector<int> Packing::variance_positions() const {
  std::vector<int> out;
  int at = static_cast<int>(theta_fixed_.size());
  for (const Block& b : blocks_) {
    for (int r = 0; r < b.size; ++r) {
      for (int c = 0; c <= r; ++c, ++at) {
        if (r == c) out.push_back(at);
      }
    }
  }
  return out;
}

}  // namespace internal
}  // namespace pk
