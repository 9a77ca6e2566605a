// Reproducible standard normal numbers for simulations (not installed): one stream per (seed,
// replicate, subject, kind), so that a simulation's numbers depend on neither threads nor order.
#ifndef PK_SRC_SIMULATION_NORMAL_STREAM_H_
#define PK_SRC_SIMULATION_NORMAL_STREAM_H_

#include <cmath>
#include <cstdint>

#include <Eigen/Core>

namespace pk {
namespace internal {

// SplitMix64 (Steele, Lea & Flood, OOPSLA 2014): one step of its sequence from state z.
inline std::uint64_t SplitMix(std::uint64_t* z) {
  std::uint64_t x = (*z += 0x9e3779b97f4a7c15ULL);
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

// Standard normal numbers from a stream of its own: xoshiro256** (Blackman & Vigna 2018), seeded
// by SplitMix64 from (seed, replicate, subject, kind), through Box–Muller. Both are fixed
// arithmetic on 64-bit integers, so a seed gives the same numbers on every platform (up to the
// last bits of log, sin and cos); its state is four words, so a stream costs nothing to start. A
// stream is named by 64 bits: two of 10⁹ subjects share one with probability about 3·10⁻², so
// simulations of that size should not rely on their subjects' independence to the last digit.
class NormalStream {
 public:
  NormalStream(std::uint64_t seed, int replicate, int subject, int kind) {
    std::uint64_t z = seed;
    z = SplitMix(&z) ^ static_cast<std::uint64_t>(replicate);
    z = SplitMix(&z) ^ (static_cast<std::uint64_t>(subject) << 1 | static_cast<std::uint64_t>(kind & 1));
    // Kinds beyond η and ε (the bootstrap's draws) mix in one more round, so that (subject, kind 2)
    // is not (subject + 1, kind 0), and the first two kinds' streams stay as they were.
    if (kind >= 2) z = SplitMix(&z) ^ static_cast<std::uint64_t>(kind);
    for (std::uint64_t& word : s_) word = SplitMix(&z);
  }
  double Next() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double r = std::sqrt(-2 * std::log(Uniform())), angle = 6.283185307179586477 * Uniform();
    spare_ = r * std::sin(angle);
    has_spare_ = true;
    return r * std::cos(angle);
  }
  /// A uniform number in (0, 1) from the same stream (the bootstrap's draws of subjects).
  double NextUniform() { return Uniform(); }

 private:
  static std::uint64_t Rotate(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  std::uint64_t Bits() {
    const std::uint64_t result = Rotate(s_[1] * 5, 7) * 9, t = s_[1] << 17;
    s_[2] ^= s_[0];
    s_[3] ^= s_[1];
    s_[1] ^= s_[2];
    s_[0] ^= s_[3];
    s_[2] ^= t;
    s_[3] = Rotate(s_[3], 45);
    return result;
  }
  // In (0, 1): the top 52 bits, centred in their interval (k + 0.5 is exact below 2⁵²), so that log
  // never sees 0 nor 1.
  double Uniform() { return (static_cast<double>(Bits() >> 12) + 0.5) * 0x1p-52; }
  std::uint64_t s_[4];
  double spare_ = 0;
  bool has_spare_ = false;
};

/// The streams of a simulated subject: its η and its residual errors ε; a bootstrap replicate's
/// draws of subjects (subject 0); a replicate's draw of θ, Ω and σ from their uncertainty (subject 0).
enum StreamKind { kEtaStream = 0, kEpsilonStream = 1, kBootstrapStream = 2, kUncertaintyStream = 3 };

/// F with FFᵀ = Ω (η = Fz): the Cholesky factor, or for a singular Ω (a variance fixed at 0) the
/// pivoted LDLᵀ one, PᵀL√D. Throws pk::InputError when Ω is not symmetric positive semi-definite.
/// (population/simulation.cc)
Eigen::MatrixXd OmegaFactor(const Eigen::MatrixXd& omega);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_SIMULATION_NORMAL_STREAM_H_
