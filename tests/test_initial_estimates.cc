// Starting values from the data: the exponential ↔ compartmental conversion,
// and fits started from them reaching the known optimum.
#include <cmath>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/conversion.h"
#include "pk/fit_subjects.h"
#include "pk/initial_estimates.h"
#include "pk/linear_model.h"
#include "pk/simulate.h"

namespace {

// Unit-dose IV response of a disposition model, from an independent eigendecomposition.
pk::Exponentials ResponseOf(const std::string& iv_model, const Eigen::VectorXd& theta) {
  const auto model = pk::MakeModel(iv_model);
  const auto& lin = dynamic_cast<const pk::LinearModel&>(*model);
  const Eigen::MatrixXd a = lin.SystemMatrix<double>(theta);
  Eigen::EigenSolver<Eigen::MatrixXd> es(a);
  const Eigen::MatrixXd v = es.eigenvectors().real();
  const Eigen::MatrixXd w = v.inverse();
  pk::Exponentials e;
  for (int i = 0; i < a.rows(); ++i) {
    e.rate.push_back(-es.eigenvalues()(i).real());
    e.amplitude.push_back(v(0, i) * w(i, 0) / theta(1));  // V1 is parameter 1 (after CL)
  }
  return e;
}

std::shared_ptr<pk::Dataset> Synthetic(const std::string& model, const pk::ParameterValues& truth,
                                       const std::string& dose_row) {
  const std::vector<double> times{0.1, 0.25, 0.5, 0.75, 1, 1.5, 2, 3, 4, 6, 8, 12, 16, 24, 36, 48, 72};
  std::ostringstream csv;
  csv.precision(17);
  csv << "ID,TIME,AMT,RATE,EVID,DV\n" << dose_row;
  for (double t : times) csv << "1," << t << ",0,0,2,.\n";
  const auto sim = pk::SimulateSubject(*pk::MakeModel(model), pk::ParseDataset(csv.str(), "s"), 0, truth);
  std::ostringstream out;
  out.precision(17);
  out << "ID,TIME,AMT,RATE,EVID,DV\n" << dose_row;
  for (const auto& row : sim.rows) out << "1," << row.time << ",0,0,0," << row.cp << "\n";
  return std::make_shared<pk::Dataset>(pk::ParseDataset(out.str(), "synthetic"));
}

}  // namespace

TEST_CASE("sums of exponentials convert back to the compartmental parameters", "[initial]") {
  struct Case {
    std::string model;
    std::vector<double> theta;
  };
  for (const Case& c : std::vector<Case>{{"1cmt_iv", {2.5, 30}},
                                         {"2cmt_iv", {4, 12, 7, 40}},
                                         {"3cmt_iv", {3, 10, 8, 20, 1, 60}}}) {
    INFO(c.model);
    const Eigen::VectorXd theta = Eigen::Map<const Eigen::VectorXd>(c.theta.data(), c.theta.size());
    std::vector<double> back;
    std::string why;
    REQUIRE(pk::ExponentialsToMammillary(ResponseOf(c.model, theta), &back, &why));
    REQUIRE(back.size() == c.theta.size());
    for (size_t i = 0; i < back.size(); ++i) CHECK(back[i] == Approx(c.theta[i]).epsilon(1e-9));
  }
  // Infeasible input is reported, not converted.
  std::vector<double> p;
  std::string why;
  CHECK(!pk::ExponentialsToMammillary({{1.0, -0.9}, {2.0, 0.1}}, &p, &why));
  CHECK(!why.empty());
}

TEST_CASE("fits started from the data recover the truth of 2- and 3-compartment models", "[initial]") {
  struct Case {
    std::string model;
    pk::ParameterValues truth;
    std::string dose;
  };
  const std::vector<Case> cases = {
      {"2cmt_iv", {{"CL", 4}, {"V1", 12}, {"Q", 7}, {"V2", 40}}, "1,0,500,0,1,.\n"},
      {"2cmt_iv", {{"CL", 4}, {"V1", 12}, {"Q", 7}, {"V2", 40}}, "1,0,500,250,1,.\n"},  // 2 h infusion
      {"3cmt_iv", {{"CL", 3}, {"V1", 10}, {"Q2", 8}, {"V2", 20}, {"Q3", 1}, {"V3", 60}}, "1,0,500,0,1,.\n"},
      {"2cmt_oral", {{"KA", 1.3}, {"CL", 4}, {"V2", 12}, {"Q", 7}, {"V3", 40}}, "1,0,500,0,1,.\n"},
      {"3cmt_oral",
       {{"KA", 2.5}, {"CL", 3}, {"V2", 10}, {"Q3", 8}, {"V3", 20}, {"Q4", 1}, {"V4", 60}},
       "1,0,500,0,1,.\n"},
  };
  for (const Case& c : cases) {
    INFO(c.model << " " << c.dose);
    pk::FitSubjectsRequest req;
    req.model = pk::MakeModel(c.model);
    req.data = Synthetic(c.model, c.truth, c.dose);
    for (const std::string& p : req.model->parameter_names()) req.parameters.push_back({p, NAN});
    req.fit.max_iterations = 5000;
    req.fit.function_tolerance = 1e-15;
    req.fit.parameter_tolerance = 1e-13;
    req.jobs = 1;
    const pk::SubjectFit fit = pk::FitSubjects(req).at(0);
    INFO(fit.initial_method << "\n" << fit.summary.FullReport());
    REQUIRE(fit.ok);
    CHECK(fit.initial_method.rfind("data", 0) == 0);
    for (const pk::ParameterEstimate& e : fit.summary.estimates) {
      CHECK(e.estimate == Approx(c.truth.at(e.name)).epsilon(1e-5));
    }
  }
}

TEST_CASE("starting values from the data are reported, and designs they cannot use fall back", "[initial]") {
  const auto model = pk::MakeModel("1cmt_iv");
  const pk::Dataset ss = pk::ParseDataset("ID,TIME,AMT,II,SS,EVID,DV\n1,0,100,12,1,1,.\n1,2,0,0,0,0,3\n1,6,0,0,0,0,2\n", "x");
  const pk::InitialEstimate e = pk::EstimateInitialValues(*model, ss, 0);
  CHECK(!e.ok);
  CHECK_THAT(e.message, Catch::Contains("steady-state"));
}

TEST_CASE("transfer functions: the same fit as the compartmental model, and conversions agree", "[initial][companion]") {
  // tf2 and 2cmt_iv describe the same family after an IV bolus: equal optimum on indomethacin.
  pk::FitSubjectsRequest req;
  req.data = std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/indomethacin.csv"));
  req.jobs = 1;
  auto fit_with = [&](const std::string& model) {
    req.model = pk::MakeModel(model);
    req.parameters.clear();
    for (const std::string& p : req.model->parameter_names()) req.parameters.push_back({p, NAN});
    return pk::FitSubjects(req);
  };
  const auto cmt = fit_with("2cmt_iv");
  const auto tf = fit_with("tf2");
  for (size_t k = 0; k < cmt.size(); ++k) {
    INFO("ID " << cmt[k].id);
    REQUIRE(tf[k].ok);
    CHECK(tf[k].summary.objective == Approx(cmt[k].summary.objective).epsilon(1e-7));
    // b1 is the initial concentration per unit dose: 1/V1 of the compartmental fit.
    const double b1 = tf[k].summary.estimates[2].estimate;
    const double v1 = cmt[k].summary.estimates[1].estimate;
    CHECK(b1 == Approx(1 / v1).epsilon(1e-5));
    // The IV reading of tf2 and its delta-method SEs equal the direct 2cmt_iv fit and its SEs
    // (a smooth one-to-one reparameterisation with the same residual variance).
    REQUIRE(tf[k].derived.size() == 3);
    const pk::TransferFunctionReading& iv = tf[k].derived[1];
    REQUIRE(iv.reading == "iv");
    REQUIRE(iv.ok);
    for (size_t p = 0; p < 4; ++p) {
      const pk::ParameterEstimate& direct = cmt[k].summary.estimates[p];
      INFO(direct.name);
      CHECK(iv.parameters[p].name == direct.name);
      CHECK(iv.parameters[p].value == Approx(direct.estimate).epsilon(1e-5));
      CHECK(iv.parameters[p].se == Approx(direct.se).epsilon(1e-3));
    }
  }
  // Exponentials -> transfer function coefficients for a known case.
  std::vector<double> coeffs;
  pk::ExponentialsToTransferFunction({{2.0, 1.0}, {0.5, 0.1}}, &coeffs);
  // A(s) = (s+0.5)(s+0.1) = s² + 0.6 s + 0.05; B(s) = 2(s+0.1) + (s+0.5) = 3 s + 0.7.
  REQUIRE(coeffs.size() == 4);
  CHECK(coeffs[0] == Approx(0.6));
  CHECK(coeffs[1] == Approx(0.05));
  CHECK(coeffs[2] == Approx(3.0));
  CHECK(coeffs[3] == Approx(0.7));
}

TEST_CASE("each catalogue model declares the structure its starting values assume, in its own names", "[initial]") {
  using Kind = pk::InitialStructure::Kind;
  for (const std::string& name : pk::CatalogueModelNames()) {
    INFO(name);
    const auto model = pk::MakeModel(name);
    const pk::InitialStructure& s = model->initial_structure();
    if (s.kind == Kind::kNone) {
      // Only the models the exponential method cannot describe: transit absorption and an effect compartment.
      CHECK((name == "1cmt_oral_transit" || name == "1cmt_iv_emax"));
      continue;
    }
    const int expected = s.kind == Kind::kTransferFunction ? 2 * s.order : 2 * s.order + (s.depot ? 1 : 0);
    CHECK(static_cast<int>(s.names.size()) == expected);
    for (size_t k = 0; k < s.names.size(); ++k) {
      // The saturable models' clearance slot is the linear block's CL, which becomes VMAX and KM.
      const bool clearance_slot = !s.vmax.empty() && k == (s.depot ? 1u : 0u);
      CHECK((model->ParameterIndex(s.names[k]) >= 0) != clearance_slot);
    }
    if (!s.vmax.empty()) {
      CHECK(model->ParameterIndex(s.vmax) >= 0);
      CHECK(model->ParameterIndex(s.km) >= 0);
    }
    CHECK(s.depot == (model->default_dose_compartment() != model->central_compartment()));
  }
}

TEST_CASE("a model without a declared structure, or with one the method cannot convert, says so", "[initial]") {
  // A four-compartment mammillary model, built here and absent from the catalogue.
  const auto build = [](bool declare) {
    pk::LinearModelBuilder b("4cmt_iv", "four compartments");
    const int cl = b.Parameter("CL", 3), v1 = b.Parameter("V1", 10);
    const int central = b.Compartment("CENTRAL", v1);
    b.ClearanceFlow(central, pk::LinearModelBuilder::kOutside, cl);
    std::vector<std::string> names = {"CL", "V1"};
    for (int k = 2; k <= 4; ++k) {
      const int q = b.Parameter("Q" + std::to_string(k), 2.0 * k), v = b.Parameter("V" + std::to_string(k), 10.0 * k);
      const int p = b.Compartment("P" + std::to_string(k), v);
      b.ClearanceFlow(central, p, q);
      b.ClearanceFlow(p, central, q);
      names.push_back("Q" + std::to_string(k));
      names.push_back("V" + std::to_string(k));
    }
    b.SetCentral(central);
    b.SetDefaultDose(central);
    if (declare) b.SetInitialStructure({pk::InitialStructure::Kind::kMammillary, 4, false, names, "", ""});
    return b.Build();
  };
  const pk::ParameterValues truth = {{"CL", 3}, {"V1", 10}, {"Q2", 20}, {"V2", 20}, {"Q3", 4}, {"V3", 30},
                                     {"Q4", 0.5}, {"V4", 80}};
  // Samples of the model's own curve, so that four exponentials fit it exactly.
  std::ostringstream grid, csv;
  grid << "ID,TIME,AMT,RATE,EVID,DV\n1,0,100,0,1,.\n";
  csv.precision(17);
  csv << "ID,TIME,AMT,RATE,EVID,DV\n1,0,100,0,1,.\n";
  const std::vector<double> times = {0.05, 0.1, 0.2, 0.3, 0.6, 1.0, 2.0, 4.0, 8.0, 12.0, 24.0, 48.0, 96.0};
  for (double t : times) grid << "1," << t << ",0,0,2,.\n";
  const auto sim = pk::SimulateSubject(*build(false), pk::ParseDataset(grid.str(), "grid"), 0, truth);
  REQUIRE(sim.ok);
  for (size_t k = 0; k < times.size(); ++k) csv << "1," << times[k] << ",0,0,0," << sim.rows[k].cp << "\n";
  const pk::Dataset data = pk::ParseDataset(csv.str(), "four.csv");
  const pk::InitialEstimate none = pk::EstimateInitialValues(*build(false), data, 0);
  CHECK_FALSE(none.ok);
  CHECK(none.message == "model 4cmt_iv declares no structure for starting values from the data");
  const pk::InitialEstimate four = pk::EstimateInitialValues(*build(true), data, 0);
  CHECK_FALSE(four.ok);
  CHECK_THAT(four.message, Catch::Contains("1, 2 or 3 exponentials"));
}
