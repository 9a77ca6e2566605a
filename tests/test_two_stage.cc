// Two-stage population estimates (pk/two_stage.h): STS and GTS against R's
// direct maximisation of the same likelihood (tests/reference/
// make_two_stage_reference.R), against the likelihood's own stationarity, and
// against the truth of a simulated population.
#include <cmath>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/fit_subjects.h"
#include "pk/output.h"
#include "pk/simulate.h"
#include "pk/two_stage.h"
#include "test_util.h"

namespace {

// OMEGA,STATISTIC,ID,PARAMETER,PARAMETER2 -> VALUE
struct Reference {
  std::map<std::string, double> values;
  double Get(const std::string& omega, const std::string& stat, const std::string& id, const std::string& p1,
             const std::string& p2 = "") const {
    const auto it = values.find(omega + "|" + stat + "|" + id + "|" + p1 + "|" + p2);
    REQUIRE(it != values.end());
    return it->second;
  }
};

Reference ReadReference() {
  std::ifstream in(std::string(PK_SOURCE_DIR) + "/tests/reference/two_stage_reference.csv");
  REQUIRE(in);
  std::string line;
  std::getline(in, line);
  Reference r;
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) f.push_back(cell);
    REQUIRE(f.size() == 6);
    r.values[f[0] + "|" + f[1] + "|" + f[2] + "|" + f[3] + "|" + f[4]] = std::stod(f[5]);
  }
  return r;
}

const std::vector<std::string> kNames{"KA", "CL", "V"};

// The GTS log-likelihood, written again here from its definition:
// ℓ = −½ Σ_i [log det Σ_i + rᵀΣ_i⁻¹r + p log 2π], Σ_i = Ω + C_i, r = φ̂_i − μ.
double LogLikelihood(const Eigen::VectorXd& mu, const Eigen::MatrixXd& omega, const std::vector<Eigen::VectorXd>& phi,
                     const std::vector<Eigen::MatrixXd>& c) {
  double l = 0;
  for (size_t i = 0; i < phi.size(); ++i) {
    const Eigen::MatrixXd sigma = omega + c[i];
    const Eigen::VectorXd r = phi[i] - mu;
    l -= 0.5 * (std::log(sigma.determinant()) + r.dot(sigma.inverse() * r) + mu.size() * std::log(2 * M_PI));
  }
  return l;
}

// Random inputs for GTS: φ̂_i = μ + η_i + e_i with η ~ N(0, Ω), e ~ N(0, C_i),
// each C_i a random positive-definite matrix. Returned on the natural scale
// (θ = exp φ) with natural-scale covariances, as EstimateTwoStage takes them.
struct Inputs {
  std::vector<double> ids;
  std::vector<Eigen::VectorXd> theta, phi;
  std::vector<Eigen::MatrixXd> cov, c;
};

Inputs RandomInputs(int n, const Eigen::VectorXd& mu, const Eigen::MatrixXd& omega, double c_scale, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> z(0, 1);
  const int p = static_cast<int>(mu.size());
  const Eigen::MatrixXd lo = omega.llt().matrixL();
  Inputs in;
  for (int i = 0; i < n; ++i) {
    Eigen::MatrixXd a(p, p);
    for (int j = 0; j < p; ++j) {
      for (int k = 0; k < p; ++k) a(j, k) = z(rng);
    }
    const Eigen::MatrixXd ci = c_scale * (a * a.transpose() / p + 0.2 * Eigen::MatrixXd::Identity(p, p));
    const Eigen::MatrixXd lc = ci.llt().matrixL();
    Eigen::VectorXd e1(p), e2(p);
    for (int j = 0; j < p; ++j) {
      e1(j) = z(rng);
      e2(j) = z(rng);
    }
    const Eigen::VectorXd phi = mu + lo * e1 + lc * e2;
    const Eigen::VectorXd theta = phi.array().exp();
    in.ids.push_back(i + 1);
    in.phi.push_back(phi);
    in.theta.push_back(theta);
    in.c.push_back(ci);
    in.cov.push_back(theta.asDiagonal() * ci * theta.asDiagonal());
  }
  return in;
}

}  // namespace

TEST_CASE("two-stage on R's stage one: the same STS statistics and GTS optimum as R's direct maximisation",
          "[two_stage][reference]") {
  const Reference ref = ReadReference();
  std::vector<double> ids;
  std::vector<Eigen::VectorXd> theta;
  std::vector<Eigen::MatrixXd> cov;
  for (int id = 1; id <= 12; ++id) {
    const std::string s = std::to_string(id);
    Eigen::VectorXd t(3);
    Eigen::MatrixXd c(3, 3);
    for (int j = 0; j < 3; ++j) {
      t(j) = ref.Get("", "estimate", s, kNames[j]);
      for (int k = 0; k < 3; ++k) c(j, k) = ref.Get("", "cov_log", s, kNames[j], kNames[k]);
    }
    ids.push_back(id);
    theta.push_back(t);
    cov.push_back(t.asDiagonal() * c * t.asDiagonal());  // natural scale, as fits report it
  }
  for (const bool diagonal : {false, true}) {
    const std::string label = diagonal ? "diagonal" : "full";
    INFO(label << " Ω");
    pk::TwoStageOptions options;
    options.diagonal_omega = diagonal;
    const pk::TwoStageSummary s = pk::EstimateTwoStage(kNames, ids, theta, cov, options);
    INFO(s.FullReport());
    REQUIRE(s.gts_ok);
    CHECK(s.gts_converged);
    CHECK(s.excluded.empty());
    CHECK(s.gts_ids.size() == 12);
    // R's optimum is found by optim to about 1e-9 in −2LL; EM's is tighter, so
    // libpk's may only be lower.
    const double r_m2ll = ref.Get(label, "minus2ll", "", "");
    CHECK(s.minus2ll <= r_m2ll + 1e-9);
    CHECK(s.minus2ll >= r_m2ll - 1e-6);
    for (int j = 0; j < 3; ++j) {
      INFO(kNames[j]);
      const pk::DescriptiveStatistics& d = s.descriptive[j];
      CHECK(d.n == 12);
      CHECK(d.mean == Approx(ref.Get("", "sts_mean", "", kNames[j])).epsilon(1e-12));
      CHECK(d.sd == Approx(ref.Get("", "sts_sd", "", kNames[j])).epsilon(1e-12));
      CHECK(d.cv_pct == Approx(ref.Get("", "sts_cv_pct", "", kNames[j])).epsilon(1e-12));
      CHECK(d.geometric_mean == Approx(ref.Get("", "sts_geometric_mean", "", kNames[j])).epsilon(1e-12));
      CHECK(d.geometric_cv_pct == Approx(ref.Get("", "sts_geometric_cv_pct", "", kNames[j])).epsilon(1e-12));
      CHECK(d.median == Approx(ref.Get("", "sts_median", "", kNames[j])).epsilon(1e-12));
      CHECK(d.min == Approx(ref.Get("", "sts_min", "", kNames[j])).epsilon(1e-12));
      CHECK(d.max == Approx(ref.Get("", "sts_max", "", kNames[j])).epsilon(1e-12));
      // The optimum: to the precision of R's optim (about 1e-5 in the Ω entries).
      CHECK(s.mu(j) == Approx(ref.Get(label, "mu", "", kNames[j])).margin(1e-5));
      const pk::PopulationParameter& q = s.population[j];
      CHECK(q.typical == Approx(ref.Get(label, "typical", "", kNames[j])).epsilon(1e-5));
      CHECK(q.typical_se == Approx(ref.Get(label, "typical_se", "", kNames[j])).epsilon(1e-4));
      CHECK(q.bsv_cv_pct == Approx(ref.Get(label, "bsv_cv_pct", "", kNames[j])).epsilon(1e-4));
      CHECK(q.typical_rse_pct == Approx(100 * q.typical_se / q.typical).epsilon(1e-12));
      CHECK(q.omega2_rse_pct == Approx(100 * q.omega2_se / q.omega2).epsilon(1e-12));
      for (int k = 0; k <= j; ++k) {
        if (diagonal && k != j) continue;
        INFO(kNames[k]);
        const double r_omega = ref.Get(label, "omega", "", kNames[j], kNames[k]);
        CHECK(s.omega(j, k) == Approx(r_omega).margin(1e-5));
        CHECK(s.omega_se(j, k) == Approx(ref.Get(label, "omega_se", "", kNames[j], kNames[k])).epsilon(1e-3));
        const double r_corr = r_omega / std::sqrt(ref.Get(label, "omega", "", kNames[j], kNames[j]) *
                                                  ref.Get(label, "omega", "", kNames[k], kNames[k]));
        CHECK(s.omega_correlation(j, k) == Approx(r_corr).margin(1e-4));
      }
    }
    if (diagonal) CHECK(s.omega(1, 0) == 0);
  }
}

TEST_CASE("two-stage from libpk's own fits of theophylline: R's population estimates, to stage one's precision",
          "[two_stage][reference]") {
  const Reference ref = ReadReference();
  pk::FitSubjectsRequest req;
  req.model = pk::MakeModel("1cmt_oral");
  req.data = std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/theophylline.csv"));
  for (const std::string& name : kNames) req.parameters.push_back({name, NAN});
  req.jobs = 2;
  const std::vector<pk::SubjectFit> fits = pk::FitSubjects(req);
  // Stage one: libpk's estimates and log-scale SEs against R's nls (which stops
  // at a relative offset of 1e-7 to 1e-8; the estimates differ by up to 1.3e-7).
  for (const pk::SubjectFit& f : fits) {
    REQUIRE(f.ok);
    REQUIRE(f.summary.converged());
    const std::string id = pk::FormatNumber(f.id);
    for (int j = 0; j < 3; ++j) {
      INFO("ID " << id << " " << kNames[j]);
      CHECK(f.summary.estimates[j].estimate == Approx(ref.Get("", "estimate", id, kNames[j])).epsilon(1e-6));
      const double se_log = f.summary.estimates[j].se / f.summary.estimates[j].estimate;
      CHECK(se_log == Approx(std::sqrt(ref.Get("", "cov_log", id, kNames[j], kNames[j]))).epsilon(1e-5));
    }
  }
  for (const bool diagonal : {false, true}) {
    const std::string label = diagonal ? "diagonal" : "full";
    pk::TwoStageOptions options;
    options.diagonal_omega = diagonal;
    const pk::TwoStageSummary s = pk::EstimateTwoStage(fits, options);
    INFO(label << " Ω\n" << s.FullReport());
    REQUIRE(s.gts_ok);
    CHECK(s.gts_converged);
    CHECK(s.minus2ll == Approx(ref.Get(label, "minus2ll", "", "")).margin(1e-7));
    for (int j = 0; j < 3; ++j) {
      INFO(kNames[j]);
      CHECK(s.descriptive[j].mean == Approx(ref.Get("", "sts_mean", "", kNames[j])).epsilon(1e-6));
      CHECK(s.descriptive[j].geometric_cv_pct == Approx(ref.Get("", "sts_geometric_cv_pct", "", kNames[j])).epsilon(1e-6));
      CHECK(s.population[j].typical == Approx(ref.Get(label, "typical", "", kNames[j])).epsilon(1e-6));
      CHECK(s.population[j].typical_se == Approx(ref.Get(label, "typical_se", "", kNames[j])).epsilon(1e-5));
      CHECK(s.omega(j, j) == Approx(ref.Get(label, "omega", "", kNames[j], kNames[j])).epsilon(1e-6));
    }
  }
}

TEST_CASE("GTS ends where the marginal likelihood is stationary, for a full and a diagonal Omega", "[two_stage]") {
  Eigen::VectorXd mu(3);
  mu << std::log(1.5), std::log(3.0), std::log(30.0);
  Eigen::MatrixXd omega(3, 3);
  omega << 0.20, 0.03, 0.02, 0.03, 0.08, 0.04, 0.02, 0.04, 0.05;
  const double c_scale = GENERATE(0.01, 0.1, 1.0);  // estimation error small, like Ω, and dominant
  const bool diagonal = GENERATE(false, true);
  INFO("C scale " << c_scale << (diagonal ? ", diagonal Ω" : ", full Ω"));
  const Inputs in = RandomInputs(25, mu, omega, c_scale, 11);
  pk::TwoStageOptions options;
  options.diagonal_omega = diagonal;
  const pk::TwoStageSummary s = pk::EstimateTwoStage(kNames, in.ids, in.theta, in.cov, options);
  INFO(s.FullReport());
  REQUIRE(s.gts_ok);
  CHECK(s.gts_converged);
  const double l = LogLikelihood(s.mu, s.omega, in.phi, in.c);
  CHECK(s.minus2ll == Approx(-2 * l).epsilon(1e-12));
  // At the optimum μ is the mean of the shrunken estimates (the M-step's fixed point).
  REQUIRE(s.shrunken.rows() == 25);
  for (int j = 0; j < 3; ++j) {
    CHECK(s.shrunken.col(j).array().log().mean() == Approx(s.mu(j)).margin(1e-6 * std::sqrt(s.mu_covariance(j, j))));
  }
  // ℓ is maximised over μ and positive semi-definite Ω = SSᵀ. Its derivatives in μ
  // and in the entries of Ω's symmetric square root S (the diagonal of S for a
  // diagonal Ω) by central differences vanish, also where Ω is singular.
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(s.omega);
  const Eigen::MatrixXd root =
      eig.eigenvectors() * eig.eigenvalues().cwiseMax(0).cwiseSqrt().asDiagonal() * eig.eigenvectors().transpose();
  auto l_at = [&](const Eigen::VectorXd& m, const Eigen::MatrixXd& sq) {
    return LogLikelihood(m, sq * sq.transpose(), in.phi, in.c);
  };
  const double h = 1e-5;
  for (int j = 0; j < 3; ++j) {
    Eigen::VectorXd up = s.mu, down = s.mu;
    up(j) += h;
    down(j) -= h;
    const double g = (l_at(up, root) - l_at(down, root)) / (2 * h);
    CHECK(std::fabs(g) * std::sqrt(s.mu_covariance(j, j)) < 1e-6);
    for (int k = 0; k < 3; ++k) {
      if (diagonal && k != j) continue;
      Eigen::MatrixXd r_up = root, r_down = root;
      r_up(j, k) += h;
      r_down(j, k) -= h;
      INFO("S " << j << "," << k);
      CHECK(std::fabs((l_at(s.mu, r_up) - l_at(s.mu, r_down)) / (2 * h)) < 1e-6);
    }
  }
  // No point of a small random neighbourhood does better.
  std::mt19937 rng(3);
  std::normal_distribution<double> z(0, 1);
  for (int t = 0; t < 50; ++t) {
    Eigen::VectorXd m = s.mu;
    for (int j = 0; j < 3; ++j) m(j) += 1e-3 * z(rng) * std::sqrt(s.mu_covariance(j, j));
    Eigen::MatrixXd sq = root;
    for (int j = 0; j < 3; ++j) {
      for (int k = 0; k < 3; ++k) {
        if (!diagonal || j == k) sq(j, k) += 1e-3 * z(rng) * std::sqrt(s.omega(j, j) + 1e-4);
      }
    }
    CHECK(l_at(m, sq) <= l + 1e-12);
  }
}

TEST_CASE("GTS with estimation errors of nearly 0 is the sample mean and the covariance with divisor N",
          "[two_stage]") {
  Eigen::VectorXd mu(3);
  mu << 0.4, 1.1, 3.4;
  Eigen::MatrixXd omega(3, 3);
  omega << 0.30, 0.05, 0.02, 0.05, 0.10, 0.03, 0.02, 0.03, 0.04;
  const Inputs in = RandomInputs(15, mu, omega, 1e-12, 5);
  const pk::TwoStageSummary s = pk::EstimateTwoStage(kNames, in.ids, in.theta, in.cov, pk::TwoStageOptions());
  INFO(s.FullReport());
  REQUIRE(s.gts_ok);
  CHECK(s.gts_converged);
  Eigen::VectorXd mean = Eigen::VectorXd::Zero(3);
  for (const auto& p : in.phi) mean += p / 15;
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(3, 3);
  for (const auto& p : in.phi) cov += (p - mean) * (p - mean).transpose() / 15;
  for (int j = 0; j < 3; ++j) {
    CHECK(s.mu(j) == Approx(mean(j)).margin(1e-9));
    CHECK(s.population[j].typical == Approx(std::exp(mean(j))).epsilon(1e-9));
    // STS's geometric CV% uses divisor N − 1, GTS's BSV CV% divisor N.
    CHECK(s.population[j].bsv_cv_pct == Approx(100 * std::sqrt(std::expm1(cov(j, j)))).epsilon(1e-8));
    CHECK(s.descriptive[j].geometric_cv_pct == Approx(100 * std::sqrt(std::expm1(cov(j, j) * 15 / 14))).epsilon(1e-12));
    for (int k = 0; k < 3; ++k) CHECK(s.omega(j, k) == Approx(cov(j, k)).margin(1e-9));
    // Nothing to shrink: the shrunken estimates are the estimates.
    for (int i = 0; i < 15; ++i) CHECK(s.shrunken(i, j) == Approx(in.theta[i](j)).epsilon(1e-9));
    // With C_i = 0: Cov(μ̂) = Ω/N, Var(ω̂_jj) = 2ω_jj²/N.
    CHECK(s.mu_covariance(j, j) == Approx(cov(j, j) / 15).epsilon(1e-8));
    CHECK(s.omega_se(j, j) == Approx(std::sqrt(2.0 / 15) * cov(j, j)).epsilon(1e-6));
  }
}

TEST_CASE("GTS takes an Omega variance to its bound of 0 when the estimates vary no more than their errors",
          "[two_stage]") {
  Eigen::VectorXd mu(3);
  mu << 0.4, 1.1, 3.4;
  Eigen::MatrixXd omega = Eigen::MatrixXd::Zero(3, 3);
  omega(0, 0) = 0.2;
  omega(1, 1) = 1e-14;  // no variability in CL: only estimation error
  omega(2, 2) = 0.05;
  Inputs in = RandomInputs(40, mu, omega, 0.05, 8);
  pk::TwoStageOptions options;
  options.diagonal_omega = true;
  const pk::TwoStageSummary s = pk::EstimateTwoStage(kNames, in.ids, in.theta, in.cov, options);
  INFO(s.FullReport());
  REQUIRE(s.gts_ok);
  CHECK(s.gts_converged);
  CHECK(s.gts_iterations < 500);  // EM alone creeps towards a bound
  if (s.omega(1, 1) < 1e-6) {
    CHECK(s.gts_message.find("between-subject variance of CL is at its bound of 0") != std::string::npos);
    CHECK(std::isnan(s.population[1].omega2_rse_pct));
    CHECK(std::isfinite(s.population[0].omega2_rse_pct));
    CHECK(s.population[1].omega2_at_bound);
    CHECK(!s.population[0].omega2_at_bound);
    // Printed as 0 at its bound, not as 1e-22.
    const std::string report = s.FullReport();
    const size_t row = report.rfind("\n  CL ") + 1;  // the GTS table comes last
    REQUIRE(row > 0);
    CHECK(report.substr(row, report.find('\n', row) - row).find("0 (bound)") != std::string::npos);
  } else {
    CHECK(!s.population[1].omega2_at_bound);
  }
  // Whether it reached 0 or stopped above: the profile likelihood in Ω_CL,CL falls from there.
  const double l = LogLikelihood(s.mu, s.omega, in.phi, in.c);
  Eigen::MatrixXd more = s.omega;
  more(1, 1) += 1e-4;
  CHECK(LogLikelihood(s.mu, more, in.phi, in.c) < l);
  CHECK(s.omega(1, 1) < 0.2 * 0.05 * 0.2);  // far below the estimation error's variance
}

TEST_CASE("GTS names a singular full Omega: random effects that move together", "[two_stage]") {
  // log CL and log V vary together exactly (V = 10·CL in every subject), KA on its own.
  std::mt19937 rng(4);
  std::normal_distribution<double> z(0, 1);
  std::vector<double> ids;
  std::vector<Eigen::VectorXd> theta;
  std::vector<Eigen::MatrixXd> cov;
  for (int i = 0; i < 30; ++i) {
    const double eta = 0.3 * z(rng);
    Eigen::VectorXd t(3);
    t << std::exp(0.4 + 0.4 * z(rng)), std::exp(1.1 + eta), std::exp(3.4 + eta);
    ids.push_back(i + 1);
    theta.push_back(t);
    cov.push_back(1e-3 * t.asDiagonal() * Eigen::MatrixXd::Identity(3, 3) * t.asDiagonal());
  }
  pk::TwoStageOptions options;
  const pk::TwoStageSummary s = pk::EstimateTwoStage(kNames, ids, theta, cov, options);
  INFO(s.FullReport());
  REQUIRE(s.gts_ok);
  CHECK(s.gts_converged);
  CHECK(s.omega_correlation(2, 1) == Approx(1).margin(1e-6));
  CHECK(s.gts_message.find("Ω is singular") != std::string::npos);
  options.diagonal_omega = true;
  CHECK(pk::EstimateTwoStage(kNames, ids, theta, cov, options).gts_message.empty());
}

TEST_CASE("a simulated population: GTS recovers the truth, where STS's variances hold the estimation error",
          "[two_stage]") {
  // 1cmt_oral, 320 mg, 11 samples per subject, 10% exponential error (σ fixed at
  // its truth); log-normal KA, CL, V, Ω diagonal. (With sparser data GTS is
  // biased: docs/fitting.md.)
  const int n = 60;
  const double truth_mu[3] = {std::log(1.5), std::log(2.8), std::log(32.0)};
  const double truth_omega2[3] = {0.16, 0.09, 0.04};
  const std::vector<double> times{0.25, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 12, 24};
  std::mt19937 rng(20261124);
  std::normal_distribution<double> z(0, 1);
  std::ostringstream csv;
  csv.precision(17);
  csv << "ID,TIME,AMT,RATE,II,ADDL,SS,EVID,DV\n";
  // The realised mean and variance (divisor n) of the subjects' true log θ.
  double sum[3] = {0, 0, 0}, sum_sq[3] = {0, 0, 0};
  for (int i = 1; i <= n; ++i) {
    pk::ParameterValues theta;
    for (int j = 0; j < 3; ++j) {
      const double eta = truth_mu[j] + std::sqrt(truth_omega2[j]) * z(rng);
      theta[kNames[j]] = std::exp(eta);
      sum[j] += eta;
      sum_sq[j] += eta * eta;
    }
    std::ostringstream grid;
    grid << "ID,TIME,AMT,RATE,II,ADDL,SS,EVID,DV\n1,0,320,0,0,0,0,1,.\n";
    for (double t : times) grid << "1," << t << ",0,0,0,0,0,2,.\n";
    const auto sim = pk_test::SimulateText("1cmt_oral", grid.str(), theta);
    REQUIRE(sim.ok);
    csv << i << ",0,320,0,0,0,0,1,.\n";
    for (const auto& row : sim.rows) {
      csv << i << "," << row.time << ",0,0,0,0,0,0," << row.cp * std::exp(0.1 * z(rng)) << "\n";
    }
  }
  pk::FitSubjectsRequest req;
  req.model = pk::MakeModel("1cmt_oral");
  req.data = std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "population.csv"));
  req.objective.error_model = pk::MakeResidualError("exponential");
  for (const std::string& name : kNames) req.parameters.push_back({name, NAN});
  pk::ParameterSpec sigma;
  sigma.name = "SIGMA_LOG";
  sigma.initial = 0.1;
  sigma.fixed = true;
  req.parameters.push_back(sigma);
  req.fit.optimizer = "newton";
  req.fit.starts = 3;
  const std::vector<pk::SubjectFit> fits = pk::FitSubjects(req);
  pk::TwoStageOptions options;
  options.diagonal_omega = true;
  const pk::TwoStageSummary s = pk::EstimateTwoStage(fits, options);
  INFO(s.FullReport());
  REQUIRE(s.gts_ok);
  CHECK(s.gts_converged);
  CHECK(s.gts_ids.size() == n);
  for (int j = 0; j < 3; ++j) {
    INFO(kNames[j]);
    const double realised_mean = sum[j] / n, realised_var = sum_sq[j] / n - realised_mean * realised_mean;
    // GTS: within three standard errors of the population's truth and of the
    // realised values.
    CHECK(std::fabs(s.mu(j) - truth_mu[j]) < 3 * std::sqrt(s.mu_covariance(j, j)));
    CHECK(std::fabs(s.omega(j, j) - truth_omega2[j]) < 3 * s.omega_se(j, j));
    CHECK(std::fabs(s.mu(j) - realised_mean) < 3 * std::sqrt(s.mu_covariance(j, j)));
    CHECK(std::fabs(s.omega(j, j) - realised_var) < 3 * s.omega_se(j, j));
    // STS: the variance of the log estimates also holds their estimation error.
    const double sts_var = std::log1p(std::pow(s.descriptive[j].geometric_cv_pct / 100, 2));
    CHECK(sts_var > s.omega(j, j));
    CHECK(s.population[j].bsv_cv_pct < s.descriptive[j].geometric_cv_pct);
  }
}

TEST_CASE("two-stage leaves out what it cannot use and says why", "[two_stage]") {
  Eigen::VectorXd mu(3);
  mu << 0.4, 1.1, 3.4;
  const Eigen::MatrixXd omega = 0.1 * Eigen::MatrixXd::Identity(3, 3);
  Inputs in = RandomInputs(5, mu, omega, 0.05, 2);
  in.cov[1] = Eigen::MatrixXd();                     // no covariance: STS only
  in.theta[2](1) = -1;                               // not positive: STS only under the log-normal model
  in.theta[3](0) = std::numeric_limits<double>::quiet_NaN();  // left out of both
  const pk::TwoStageSummary s = pk::EstimateTwoStage(kNames, in.ids, in.theta, in.cov, pk::TwoStageOptions());
  INFO(s.FullReport());
  CHECK(s.sts_ids == std::vector<double>{1, 2, 3, 5});
  CHECK(s.gts_ids == std::vector<double>{1, 5});
  REQUIRE(s.excluded.size() == 3);
  CHECK(s.excluded[0].first == 2);
  CHECK(s.excluded[0].second == "GTS: no covariance of the estimates");
  CHECK(s.excluded[1].first == 3);
  CHECK(s.excluded[1].second == "GTS: CL = -1 is not positive (log-normal model)");
  CHECK(s.excluded[2].first == 4);
  CHECK(std::isnan(s.descriptive[1].geometric_mean));  // CL has a negative value
  CHECK(s.descriptive[1].n == 4);
  CHECK(s.gts_ok);
  // The normal model takes the negative value.
  pk::TwoStageOptions normal;
  normal.distribution = pk::BetweenSubjectModel::kNormal;
  const pk::TwoStageSummary t = pk::EstimateTwoStage(kNames, in.ids, in.theta, in.cov, normal);
  CHECK(t.gts_ids == std::vector<double>{1, 3, 5});
  // One subject with a covariance is too few.
  in.cov[4] = Eigen::MatrixXd();
  const pk::TwoStageSummary u = pk::EstimateTwoStage(kNames, in.ids, in.theta, in.cov, pk::TwoStageOptions());
  CHECK_FALSE(u.gts_ok);
  CHECK(u.gts_message == "GTS needs at least two subjects with covariances; there is 1");
  CHECK(u.descriptive[0].n == 4);
  // Bad options and inconsistent sizes are input errors.
  pk::TwoStageOptions bad;
  bad.tolerance = 0;
  std::string why;
  CHECK_FALSE(bad.IsValid(&why));
  CHECK(why == "tolerance must be positive and finite");
  CHECK_THROWS_AS(pk::EstimateTwoStage(kNames, in.ids, in.theta, in.cov, bad), pk::InputError);
  in.theta[0] = Eigen::VectorXd::Ones(2);
  CHECK_THROWS_AS(pk::EstimateTwoStage(kNames, in.ids, in.theta, in.cov, pk::TwoStageOptions()), pk::InputError);
}
