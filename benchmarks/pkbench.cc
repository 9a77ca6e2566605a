// pkbench: costs measured in one run and reported as ratios (docs/performance.md).
//
//   1. 2cmt_oral, one oral dose, 12 samples: the loss alone, loss + gradient by
//      the forward (a) and adjoint (b) Φ/Γ routes, against a closed-form loss
//      (the biexponential-with-absorption formula, hand-coded here).
//   2. The gradient/loss cost ratio against the number of parameters m on a
//      mammillary model with K peripheral compartments (m = 2K + 2).
//   3. Fitting the 12 theophylline subjects (1cmt_oral, LM), per subject and in total.
//   4. The ODE routes on a scalable nonlinear model, a chain of n compartments
//      with saturable transfer (m = 2n): a plain forward solve against the
//      loss + gradient by (a) CVODES forward sensitivities and (b) the CVODES
//      adjoint, with the adjoint's stored bytes; then the adjoint's time and
//      storage against the checkpoint interval; the same through Dormand–Prince (rk),
//      and a chain with first-order losses too, whose f runs on 8 lanes.
//   5. Fits of catalogue ODE models on bundled data (LM with forward
//      sensitivities through CVODES), per subject and in total.
//   6. Simulation throughput: 10^5 subjects x 100 samples of 2cmt_oral (10^4 with --quick),
//      rows per second with and without CSV formatting and writing, and peak memory.
//   7. Model files against their catalogue twins: fitting time from the same start.
//   8. Population estimation (FOCEI): phenobarbital and 120 simulated subjects; the implicit-function
//      outer gradient against central differences, its cost over one OFV, and two threads.
//  10. Population simulation at the FOCEI estimates: one simulated replicate of the data against one
//      OFV evaluation, and a VPC of 200 replicates on one thread and two.
//
// Timing: the cases compared in a table are timed in interleaved rounds and
// their ratios are medians over the rounds (see Interleaved()).
//
//   pkbench [--only N] [--min-time SECONDS] [--quick] [--datasets DIR]
//   pkbench --count closed|loss|forward|adjoint|population CALLS
//
// --count repeats one call of section 1, untimed, for instruction counts:
//   valgrind --tool=callgrind pkbench --count adjoint 1000
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include "pk/catalogue.h"
#include "pk/model_file.h"
#include "pk/dataset.h"
#include "pk/output.h"
#include "pk/simulate.h"
#include "pk/simulation_csv.h"
#include "pk/fit_subjects.h"
#include "pk/linear_model.h"
#include "pk/objective.h"
#include "pk/ode_model.h"
#include "pk/population.h"
#include "pk/population_simulation.h"
#include "pk/npde.h"
#include "pk/vpc.h"
#include "pk/residual_error.h"
#include "population/engine.h"

namespace {

double g_min_time = 0.05;

// An evaluation whose figures a table reports: a failed one would report nothing true, so it stops.
const pk::Objective::Evaluation& Checked(const pk::Objective::Evaluation& e, const char* what) {
  if (!e.ok) {
    std::fprintf(stderr, "pkbench: %s failed: %s\n", what, e.message.c_str());
    std::exit(1);
  }
  return e;
}

// Seconds per call of each function. The functions are timed in interleaved
// rounds (each round runs every function for about --min-time seconds), so a
// change of machine load affects all of them alike; per round, each time is
// divided by the first function's, and the median over 7 rounds of those
// ratios is reported together with the median time of the first.
struct Timing {
  double base_seconds;
  std::vector<double> ratios;  // per function, relative to the first
};

Timing Interleaved(const std::vector<std::function<void()>>& fs) {
  using Clock = std::chrono::steady_clock;
  std::vector<long> reps(fs.size(), 1);
  auto batch = [&](size_t i) {
    for (;;) {
      const auto t0 = Clock::now();
      for (long r = 0; r < reps[i]; ++r) fs[i]();
      const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
      if (dt >= g_min_time) return dt / reps[i];
      reps[i] = std::max(reps[i] * 2, static_cast<long>(reps[i] * g_min_time / std::max(dt, 1e-9)));
    }
  };
  std::vector<double> base;
  std::vector<std::vector<double>> ratios(fs.size());
  for (int round = 0; round < 7; ++round) {
    const double t0 = batch(0);
    base.push_back(t0);
    ratios[0].push_back(1.0);
    for (size_t i = 1; i < fs.size(); ++i) ratios[i].push_back(batch(i) / t0);
  }
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  Timing t{median(base), {}};
  for (const auto& r : ratios) t.ratios.push_back(median(r));
  return t;
}

double SecondsPerCall(const std::function<void()>& f) { return Interleaved({f}).base_seconds; }

volatile double g_sink = 0;

const double kTimes[12] = {0.25, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 12, 16, 24};

std::shared_ptr<pk::Dataset> OneDose(const std::string& cmt_dose, double amt) {
  std::ostringstream csv;
  csv.precision(17);
  csv << "ID,TIME,AMT,EVID,CMT,DV\n1,0," << amt << ",1," << cmt_dose << ",.\n";
  for (int k = 0; k < 12; ++k) csv << "1," << kTimes[k] << ",0,0,0," << 5 * std::exp(-0.1 * kTimes[k]) + 0.3 << "\n";
  return std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "bench"));
}

// The closed-form 2cmt oral concentration and the least-squares loss over the same samples.
double ClosedFormLoss(const double* p, const double* y) {
  const double ka = p[0], cl = p[1], v1 = p[2], q = p[3], v2 = p[4], dose = 100;
  const double k10 = cl / v1, k12 = q / v1, k21 = q / v2;
  const double s = k10 + k12 + k21, disc = std::sqrt(s * s - 4 * k10 * k21);
  const double a = (s + disc) / 2, b = (s - disc) / 2;
  const double ca = ka * dose / v1 * (k21 - a) / ((ka - a) * (b - a));
  const double cb = ka * dose / v1 * (k21 - b) / ((ka - b) * (a - b));
  const double cka = -(ca + cb);
  double v = 0;
  for (int k = 0; k < 12; ++k) {
    const double t = kTimes[k];
    const double c = ca * std::exp(-a * t) + cb * std::exp(-b * t) + cka * std::exp(-ka * t);
    v += 0.5 * (y[k] - c) * (y[k] - c);
  }
  return v;
}

std::shared_ptr<const pk::LinearModel> Mammillary(int k_peripherals) {
  pk::LinearModelBuilder b("mammillary", "central + K peripherals");
  const int cl = b.Parameter("CL", 3), v1 = b.Parameter("V1", 10);
  const int central = b.Compartment("CENTRAL", v1);
  b.ClearanceFlow(central, pk::LinearModelBuilder::kOutside, cl);
  for (int k = 0; k < k_peripherals; ++k) {
    const int q = b.Parameter("Q" + std::to_string(k + 2), 1.0 + 0.37 * k);
    const int v = b.Parameter("VP" + std::to_string(k + 2), 5.0 + 3.1 * k);
    const int p = b.Compartment("P" + std::to_string(k + 2), v);
    b.ClearanceFlow(central, p, q);
    b.ClearanceFlow(p, central, q);
  }
  b.SetCentral(central);
  b.SetDefaultDose(central);
  return b.Build();
}

}  // namespace

// A chain of n compartments: x_i flows to x_{i+1} at VMAX_i x_i/(KM_i + x_i),
// and the last one is eliminated the same way. θ = (VMAX_1..n, KM_1..n). When leaky, each compartment
// also loses K_i x_i, θ = (VMAX, KM, K): 7 colours, so f runs on 8 lanes (FixedDual<8>, copied in
// groups: pk/fixed_dual.h).
struct SaturableChain {
  int n;
  bool leaky = false;
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    T inflow(0.0);
    for (int i = 0; i < n; ++i) {
      const T out = p[i] * x[i] / (p[n + i] + x[i]);
      dxdt[i] = inflow - out;
      if (leaky) dxdt[i] -= p[2 * n + i] * x[i];
      inflow = out;
    }
  }
  template <typename T>
  T Output(int, const T* x, const T*) const { return x[n - 1]; }
};

// A chain's compartments X1…Xn and its parameters VMAX_i, KM_i, observed in Xn.
pk::OdeModelSpec ChainSpec(const std::string& name, int n, double vmax_scale) {
  pk::OdeModelSpec spec;
  spec.name = name + std::to_string(n);
  for (int i = 1; i <= n; ++i) spec.compartments.push_back("X" + std::to_string(i));
  for (int i = 1; i <= n; ++i) spec.parameters.push_back({"VMAX" + std::to_string(i), vmax_scale * (40.0 + i)});
  for (int i = 1; i <= n; ++i) spec.parameters.push_back({"KM" + std::to_string(i), 5.0 + 0.1 * i});
  spec.central = n;
  return spec;
}

std::shared_ptr<const pk::OdeModel> Chain(int n, double vmax_scale = 1.0) {
  return pk::MakeOdeModel(ChainSpec("chain", n, vmax_scale), SaturableChain{n});
}

std::shared_ptr<const pk::OdeModel> Leaky(int n) {
  pk::OdeModelSpec spec = ChainSpec("leaky", n, 1.0);
  for (int i = 1; i <= n; ++i) spec.parameters.push_back({"K" + std::to_string(i), 0.01 * i});
  return pk::MakeOdeModel(spec, SaturableChain{n, true});
}

namespace {

// f() with models evaluated on the x86-64 baseline's lanes, not the AVX2 clone (pk/fixed_dual.h).
template <typename F>
auto BaselineLanes(F f) {
  bool& avx2 = pk::internal::LanesOnAvx2();
  const bool saved = avx2;
  avx2 = false;
  auto result = f();
  avx2 = saved;
  return result;
}

// CVODES throughout (auto takes Dormand–Prince for nonlinear models).
pk::ObjectiveOptions CvodesOptions() {
  pk::ObjectiveOptions o;
  o.propagator = pk::Propagator::kOde;
  return o;
}

// Stiff segments: rk hands them to RODAS4 (its own Rosenbrock method), against CVODES's BDF on the
// whole problem; each route's time and the forward steps. (a) 2cmt_iv with Q = 1e6 (exchange 10⁵
// times faster than elimination), two doses, four samples; (b) 1cmt_iv_mm with KM = 0.002, which
// stiffens as the drug clears.
void StiffSegments() {
  using Need = pk::Objective::Need;
  using Route = pk::GradientRoute;
  const std::pair<const char*, const char*> cases[] = {
      {"2cmt_iv", "ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,1,0,0,3\n1,6,0,0,2\n1,12,80,1,.\n1,24,0,0,1\n"},
      {"1cmt_iv_mm", "ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,0.5,0,0,4\n1,2,0,0,3\n1,48,0,0,0.01\n1,72,0,0,0.001\n"}};
  std::printf("== stiff segments, rtol 1e-8: rk (RODAS4 there) against CVODES ==\n");
  std::printf("%-12s %14s %16s %16s %16s %10s %10s\n", "model", "rk solve (ms)", "CVODES / rk solve",
              "CVODES / rk (a)", "CVODES / rk (b)", "rk steps", "BDF steps");
  for (const auto& c : cases) {
    const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(c.second, "stiff.csv"));
    pk::ObjectiveOptions rk_options;
    rk_options.propagator = pk::Propagator::kRungeKutta;
    const pk::Objective rk(pk::MakeModel(c.first), data, 0, rk_options);
    const pk::Objective ode(pk::MakeModel(c.first), data, 0, CvodesOptions());
    Eigen::VectorXd v = rk.DefaultValues();
    if (std::string(c.first) == "2cmt_iv") v(rk.ParameterIndex("Q")) = 1e6;
    if (std::string(c.first) == "1cmt_iv_mm") v(rk.ParameterIndex("KM")) = 0.002;
    std::vector<int> free;
    for (int i = 0; i < rk.model().num_parameters(); ++i) free.push_back(i);
    const auto a = rk.Evaluate(v, free, Need::kValue), b = ode.Evaluate(v, free, Need::kValue);
    const Timing t = Interleaved({[&] { g_sink = rk.Evaluate(v, free, Need::kValue).value; },
                                  [&] { g_sink = ode.Evaluate(v, free, Need::kValue).value; },
                                  [&] { g_sink = rk.Evaluate(v, free, Need::kGradient, Route::kForward).value; },
                                  [&] { g_sink = ode.Evaluate(v, free, Need::kGradient, Route::kForward).value; },
                                  [&] { g_sink = rk.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; },
                                  [&] { g_sink = ode.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; }});
    std::printf("%-12s %14.3f %16.2f %16.2f %16.2f %10ld %10ld\n", c.first, t.base_seconds * 1e3, t.ratios[1],
                t.ratios[3] / t.ratios[2], t.ratios[5] / t.ratios[4], a.ode_statistics.steps, b.ode_statistics.steps);
    std::fflush(stdout);
  }
  std::printf("\n");
}


// The peak resident memory since the last ResetPeakMemory(), in MB (Linux: VmHWM).
double PeakMemoryMb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::atof(line.c_str() + 6) / 1024.0;
  }
  return NAN;
}
void ResetPeakMemory() { std::ofstream("/proc/self/clear_refs") << "5"; }

// Section 6: `subjects` subjects x 100 output times of 2cmt_oral, five doses by ADDL, parameters from
// data columns, on one thread with the exact propagator: (a) simulation alone, (b) simulation, CSV
// formatting and writing to a file committed whole, as pksim does. Rows per second, µs per row, and
// the peak memory of (b), which must not grow with the number of subjects.
void SimulationThroughput(int subjects) {
  std::string text = "ID,TIME,AMT,ADDL,II,CL,V2\n";
  for (int id = 1; id <= subjects; ++id) {
    text += std::to_string(id) + ",0,500,4,12," + std::to_string(3 * std::exp(0.3 * std::sin(id))) + "," +
            std::to_string(20 * std::exp(0.2 * std::cos(id))) + "\n";
  }
  const pk::Dataset data = pk::ParseDataset(text, "bench.csv");
  text.clear();
  text.shrink_to_fit();
  const auto model = pk::MakeModel("2cmt_oral");
  pk::SimulationOptions options;
  options.jobs = 1;
  for (int k = 1; k <= 100; ++k) options.output_times.push_back(0.96 * k);
  const pk::ParameterValues values = {{"KA", 1.2}, {"Q", 4}, {"V3", 40}};
  const double rows = 100.0 * subjects;
  using Clock = std::chrono::steady_clock;

  long checksum = 0;
  pk::SimulationSink alone;
  alone.consume = [&](pk::SubjectSimulation&& s, std::string&&) { checksum += static_cast<long>(s.rows.size()); };
  auto t0 = Clock::now();
  pk::SimulateEach(*model, data, values, options, alone);
  const double simulate = std::chrono::duration<double>(Clock::now() - t0).count();

  const std::string path = "/tmp/pkbench_simulation_" + std::to_string(::getpid()) + ".csv";
  ResetPeakMemory();
  const double before = PeakMemoryMb();
  t0 = Clock::now();
  size_t bytes = 0;
  double commit = 0;
  {
    pk::AtomicFile file(path);
    file.Write(pk::SimulationCsvHeader(*model));
    pk::SimulationSink csv;
    csv.render = [](const pk::SubjectSimulation& s) {
      std::string rows_text;
      pk::AppendSimulationCsv(s, &rows_text);
      return rows_text;
    };
    csv.consume = [&](pk::SubjectSimulation&&, std::string&& t) {
      bytes += t.size();
      file.Write(t);
    };
    pk::SimulateEach(*model, data, values, options, csv);
    const auto c0 = Clock::now();
    file.Commit();
    commit = std::chrono::duration<double>(Clock::now() - c0).count();
  }
  const double written = std::chrono::duration<double>(Clock::now() - t0).count();
  const double peak = PeakMemoryMb();
  std::remove(path.c_str());
  std::printf("\n== simulation: %d subjects x 100 samples of 2cmt_oral, five doses (ADDL), exact Φ/Γ, one thread ==\n",
              subjects);
  std::printf("%-44s %10s %12s %10s\n", "", "time (s)", "rows/s", "µs/row");
  std::printf("%-44s %10.2f %12.3g %10.3f\n", "(a) simulation", simulate, rows / simulate, 1e6 * simulate / rows);
  std::printf("%-44s %10.2f %12.3g %10.3f\n", "(b) simulation + CSV + write (fsynced file)", written, rows / written,
              1e6 * written / rows);
  std::printf("(b) of which fsync and rename at the end: %.2f s\n", commit);
  std::printf("(b) wrote %.0f MB; peak resident memory during (b): %.1f MB (%.1f MB before it, the dataset included)\n",
              bytes / 1e6, peak, before);
  if (checksum != static_cast<long>(rows)) std::printf("unexpected row count %ld\n", checksum);
}

// Section 8: population estimation. (a) phenobarbital (59 neonates, 155 samples), 1cmt_iv, η on CL
// and V, proportional error; (b) 120 simulated subjects x 19 samples of a one-compartment IV bolus
// (CL 2, V 20, ω² 0.09 each, proportional σ 0.1; the closed form and the noise are drawn here with a
// fixed seed). Both FOCEI from the same start: the fit's time without the covariance step, by the
// implicit-function gradient and by central differences of the OFV; the cost of one outer gradient
// over one OFV evaluation (modes warm-started, as in the fit); and the implicit fit on 2 threads.
pk::Dataset SimulatedBolus(int subjects) {
  std::mt19937_64 rng(20261125);
  std::normal_distribution<double> normal;
  const double times[19] = {0.1, 0.25, 0.5, 0.75, 1, 1.5, 2, 3, 4, 5, 6, 8, 10, 12, 14, 16, 18, 21, 24};
  std::string text = "ID,TIME,AMT,EVID,MDV,DV\n";
  char line[160];
  for (int id = 1; id <= subjects; ++id) {
    const double cl = 2 * std::exp(0.3 * normal(rng)), v = 20 * std::exp(0.3 * normal(rng));
    text += std::to_string(id) + ",0,100,1,1,0\n";
    for (double t : times) {
      const double c = 100 / v * std::exp(-cl / v * t) * (1 + 0.1 * normal(rng));
      std::snprintf(line, sizeof line, "%d,%g,0,0,0,%.6g\n", id, t, c);
      text += line;
    }
  }
  return pk::ParseDataset(text, "bolus120.csv");
}

pk::PopulationProblem BolusProblem(std::shared_ptr<const pk::Dataset> data) {
  pk::ObjectiveOptions o;
  o.error_model = pk::MakeResidualError("proportional");
  return pk::PopulationProblem(pk::MakeModel("1cmt_iv"), std::move(data), {"CL", "V"}, o);
}

// A nonlinear model on the ODE propagator (pkpop's rtol 1e-9): 1cmt_iv_emax on emax_synthetic (both
// outputs), η on CL and EMAX, proportional error.
pk::PopulationProblem EmaxProblem(const std::string& data_dir) {
  pk::ObjectiveOptions ode;
  ode.error_model = pk::MakeResidualError("proportional");
  ode.ode.relative_tolerance = 1e-9;
  ode.ode.absolute_tolerance = 1e-11;
  return pk::PopulationProblem(pk::MakeModel("1cmt_iv_emax"),
                               std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/emax_synthetic.csv")),
                               {"CL", "EMAX"}, ode);
}

// models/theo_lag_pop.pkm on theophylline: η on CL, and on a lag and a bioavailability computed in
// $PK, which move the doses (the second and third orders from the event engine on jets), on Φ/Γ.
pk::PopulationProblem TheoLagProblem(const std::string& data_dir) {
  pk::ObjectiveOptions o;
  o.error_model = pk::MakeResidualError("combined");
  return pk::PopulationProblem(pk::LoadModelFile(data_dir + "/../models/theo_lag_pop.pkm", pk::RandomEffects::kParameters),
                               std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/theophylline.csv")),
                               {"ETA_CL", "ETA_LAG", "ETA_F"}, o);
}

// A nonlinear model whose doses move with η on the ODE propagator (pkpop's rtol 1e-9): 1cmt_oral_mm
// as a file with η on VMAX and F1 = exp(ETA_F), on theophylline, combined error (ode/moving_events.h).
pk::PopulationProblem MmBioavailabilityProblem(const std::string& data_dir) {
  const char* text =
      "$PROBLEM mm_f  one compartment, oral, Michaelis-Menten; η on VMAX and on a bioavailability\n"
      "$PARAM\nKA = 1.5\nTVVMAX = 20\nKM = 2\nV = 30\n$OMEGA\nETA_VMAX ~ 0.1\nETA_F ~ 0.05\n"
      "$CMT\nDEPOT dose\nCENTRAL central\n$PK\nVMAX = TVVMAX * exp(ETA_VMAX)\nF1 = exp(ETA_F)\n"
      "$ODE\nC = CENTRAL / V\nd/dt(DEPOT) = -KA * DEPOT\nd/dt(CENTRAL) = KA * DEPOT - VMAX * C / (KM + C)\n"
      "$OUTPUT\nCP = C\n";
  pk::ObjectiveOptions ode;
  ode.error_model = pk::MakeResidualError("combined");
  ode.ode.relative_tolerance = 1e-9;
  ode.ode.absolute_tolerance = 1e-11;
  return pk::PopulationProblem(pk::ParseModel(text, "mm_f.pkm", pk::RandomEffects::kParameters),
                               std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/theophylline.csv")),
                               {"ETA_VMAX", "ETA_F"}, ode);
}

// The estimation tables' header: a row per PopulationCase.
void EstimationTable(const char* title) {
  std::printf("\n== %s ==\n", title);
  std::printf("%-14s %9s %9s %11s %9s %9s %11s %10s %9s\n", "data", "OFV", "evals", "fit (ms)", "fd evals",
              "fd/impl", "|ΔOFV| fd", "grad/OFV", "2 thr/1");
}

// The start of the 1cmt_iv bolus problems (θ 0.005, 1.0 on phenobarbital; ω² 0.1; σ 0.2).
pk::PopulationParameters BolusStart() {
  pk::PopulationParameters start;
  start.theta = Eigen::Vector2d(0.005, 1.0);
  start.omega = 0.1 * Eigen::MatrixXd::Identity(2, 2);
  start.sigma = Eigen::VectorXd::Constant(1, 0.2);
  return start;
}

void PopulationCase(const char* name, const pk::PopulationProblem& problem, const pk::PopulationParameters& start,
                    pk::PopulationMethod method = pk::PopulationMethod::kFocei) {
  pk::PopulationOptions options;
  options.covariance = false;
  options.method = method;
  pk::PopulationOptions fd = options, two = options;
  fd.gradient = pk::PopulationGradient::kFiniteDifference;
  two.threads = 2;
  pk::PopulationSummary a, b, c;
  const Timing t = Interleaved({[&] { a = pk::FitPopulation(problem, start, options); },
                                [&] { b = pk::FitPopulation(problem, start, fd); },
                                [&] { c = pk::FitPopulation(problem, start, two); }});
  // One outer gradient against one OFV evaluation at the estimate, from the estimate's modes.
  const pk::internal::Packing packing(problem, {}, a.parameters);
  const pk::internal::PopulationEngine engine(problem, method, 1);
  const Eigen::VectorXd x = packing.Pack(a.parameters);
  std::vector<Eigen::VectorXd> etas;
  for (const auto& s : a.subjects) etas.push_back(s.eta);
  pk::internal::PopulationEngine::Result r = engine.Evaluate(a.parameters, etas, true);
  Eigen::VectorXd g;
  std::string why;
  const Timing u = Interleaved({[&] { g_sink = engine.Evaluate(a.parameters, etas, false).ofv; },
                                [&] { engine.Gradient(packing, x, r.modes, &g, nullptr, &why); }});
  std::printf("%-14s %9.1f %9d %11.1f %9d %9.2f %11.3f %10.2f %9.2f\n", name, a.ofv, a.evaluations,
              t.base_seconds * 1e3, b.evaluations, t.ratios[1], std::abs(a.ofv - b.ofv), u.ratios[1],
              t.ratios[2]);
  std::fflush(stdout);
}

// One Laplace OFV evaluation (every subject's mode, warm-started from the modes found before, and
// its H) with the exact ½∇²l against Richardson differences of the exact ∇l, as the difference
// gradient calls it 2m times an outer step.
void LaplaceHessianCase(const char* name, const pk::PopulationProblem& problem, const pk::PopulationParameters& p) {
  pk::internal::PopulationEngine exact(problem, pk::PopulationMethod::kLaplace, 1), differences = exact;
  differences.set_exact_hessian(false);
  const std::vector<Eigen::VectorXd> zero(static_cast<size_t>(problem.num_subjects()),
                                          Eigen::VectorXd::Zero(static_cast<Eigen::Index>(problem.eta_names().size())));
  const pk::internal::PopulationEngine::Result start = exact.Evaluate(p, zero, true);
  std::vector<Eigen::VectorXd> etas;
  for (const auto& m : start.modes) etas.push_back(m.eta);
  double a = 0, b = 0;
  const Timing t = Interleaved({[&] { a = exact.Evaluate(p, etas, false).ofv; },
                                [&] { b = differences.Evaluate(p, etas, false).ofv; }});
  std::printf("%-22s %11.3f %14.2f %12.2e\n", name, t.base_seconds * 1e3, t.ratios[1], std::abs(a - b));
  std::fflush(stdout);
}

void LaplaceHessian(const std::string& data_dir) {
  std::printf("\n== Laplace: one OFV evaluation with the exact ½∇²l against differences of the exact ∇l ==\n");
  std::printf("%-22s %11s %14s %12s\n", "problem", "exact (ms)", "differences/ex", "|ΔOFV|");
  const auto pheno = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/phenobarbital.csv"));
  pk::PopulationParameters start;
  start.theta = Eigen::Vector2d(0.0047, 0.99);
  start.omega = Eigen::Vector2d(0.03, 0.03).asDiagonal();
  start.sigma = Eigen::VectorXd::Constant(1, 0.12);
  LaplaceHessianCase("phenobarbital (Φ/Γ)", BolusProblem(pheno), start);
  pk::ObjectiveOptions o;
  o.error_model = pk::MakeResidualError("combined");
  const auto theo = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/theophylline.csv"));
  const pk::PopulationProblem oral(pk::MakeModel("1cmt_oral"), theo, {"KA", "CL", "V"}, o);
  pk::PopulationParameters p = oral.DefaultParameters();
  p.theta = Eigen::Vector3d(1.5, 2.8, 32);
  p.sigma = Eigen::Vector2d(0.3, 0.1);
  LaplaceHessianCase("theophylline 3 η (Φ/Γ)", oral, p);
  const pk::PopulationProblem emax = EmaxProblem(data_dir);
  LaplaceHessianCase("emax (ODE)", emax, emax.DefaultParameters());
}

void PopulationEstimation(const std::string& data_dir) {
  EstimationTable("population estimation: FOCEI, 1cmt_iv, η on CL and V, proportional error, one thread");
  pk::PopulationParameters start = BolusStart();
  const auto pheno = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/phenobarbital.csv"));
  PopulationCase("phenobarbital", BolusProblem(pheno), start);
  // NONMEM's own phenobarbital model from its model file: CL and V per kg, V larger at Apgar < 5.
  // Its coefficients are expressions (derived coefficients), still on Φ/Γ.
  pk::ObjectiveOptions o;
  o.error_model = pk::MakeResidualError("proportional");
  const auto file = pk::LoadModelFile(data_dir + "/../models/pheno_pop.pkm", pk::RandomEffects::kParameters);
  pk::PopulationParameters file_start = start;
  file_start.theta = Eigen::Vector3d(0.005, 1.0, 0.1);
  PopulationCase("pheno_pop.pkm", pk::PopulationProblem(file, pheno, {"ETA_CL", "ETA_V"}, o), file_start);
  start.theta << 3, 15;
  PopulationCase("bolus 120x19", BolusProblem(std::make_shared<pk::Dataset>(SimulatedBolus(120))), start);
  const pk::PopulationProblem lag = TheoLagProblem(data_dir);
  PopulationCase("theo lag, F", lag, lag.DefaultParameters());
  // EmaxProblem on Dormand–Prince from the catalogue's defaults. The implicit gradient's second order
  // is integrated with the ODEs (ode/second_order.h).
  const pk::PopulationProblem emax = EmaxProblem(data_dir);
  PopulationCase("emax (ODE)", emax, emax.DefaultParameters());
  const pk::PopulationProblem mm_f = MmBioavailabilityProblem(data_dir);
  pk::PopulationParameters mm_start = mm_f.DefaultParameters();
  mm_start.sigma = Eigen::Vector2d(0.3, 0.1);
  PopulationCase("MM, F1 (ODE)", mm_f, mm_start);
}

// FO fits (no mode searches: the linearisation at η = 0) by its exact gradient against differences of
// the OFV, on the problems of the FOCEI table above, for the cost of each method.
void FirstOrderEstimation(const std::string& data_dir) {
  EstimationTable("population estimation: FO, exact gradient against differences of the OFV, one thread");
  pk::PopulationParameters start = BolusStart();
  const auto pheno = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/phenobarbital.csv"));
  PopulationCase("phenobarbital", BolusProblem(pheno), start, pk::PopulationMethod::kFo);
  start.theta << 3, 15;
  PopulationCase("bolus 120x19", BolusProblem(std::make_shared<pk::Dataset>(SimulatedBolus(120))), start,
                 pk::PopulationMethod::kFo);
  const pk::PopulationProblem emax = EmaxProblem(data_dir);
  PopulationCase("emax (ODE)", emax, emax.DefaultParameters(), pk::PopulationMethod::kFo);
}

// Laplace fits by the implicit gradient (third-order sensitivities) against differences of the OFV:
// phenobarbital and theophylline with its 27 samples below 2 mg/L (M3, three η) on Φ/Γ, and
// EmaxProblem on the ODE propagator.
void LaplaceEstimation(const std::string& data_dir) {
  EstimationTable("population estimation: Laplace, implicit gradient against differences of the OFV, one thread");
  pk::PopulationParameters start = BolusStart();
  const auto pheno = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/phenobarbital.csv"));
  PopulationCase("phenobarbital", BolusProblem(pheno), start, pk::PopulationMethod::kLaplace);
  pk::ObjectiveOptions o;
  o.error_model = pk::MakeResidualError("additive");
  const auto blq = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/theophylline_blq.csv"));
  const pk::PopulationProblem theo(pk::MakeModel("1cmt_oral"), blq, {"KA", "CL", "V"}, o);
  PopulationCase("theo M3 3η", theo, theo.DefaultParameters(), pk::PopulationMethod::kLaplace);
  const pk::PopulationProblem lag = TheoLagProblem(data_dir);
  PopulationCase("theo lag, F", lag, lag.DefaultParameters(), pk::PopulationMethod::kLaplace);
  const pk::PopulationProblem emax = EmaxProblem(data_dir);
  PopulationCase("emax (ODE)", emax, emax.DefaultParameters(), pk::PopulationMethod::kLaplace);
}
// Simulation at population estimates and the VPC (population.md): one replicate of the data's design
// (η and ε drawn, the predictions at η) against one OFV evaluation from the modes, and a VPC of 200
// replicates, on one thread and on two.
void PopulationSimulationCase(const char* name, const pk::PopulationProblem& problem) {
  pk::PopulationOptions options;
  options.covariance = false;
  const pk::PopulationSummary fit = pk::FitPopulation(problem, problem.DefaultParameters(), options);
  const pk::internal::PopulationEngine engine(problem, pk::PopulationMethod::kFocei, 1);
  std::vector<Eigen::VectorXd> etas;
  for (const auto& s : fit.subjects) etas.push_back(s.eta);
  pk::PopulationSimulationOptions one;
  pk::VpcOptions vpc, vpc2;
  vpc2.threads = 2;
  pk::NpdeOptions npde, npde2;  // 1000 simulations of each subject
  npde2.threads = 2;
  const Timing t = Interleaved({[&] { g_sink = engine.Evaluate(fit.parameters, etas, false).ofv; },
                                [&] {
                                  pk::SimulatePopulation(problem, fit.parameters, one, [](const pk::SimulatedReplicate& r) {
                                    g_sink = r.subjects[0].dv(0);
                                  });
                                },
                                [&] { g_sink = pk::ComputeVpc(problem, fit.parameters, vpc).outside; },
                                [&] { g_sink = pk::ComputeVpc(problem, fit.parameters, vpc2).outside; },
                                [&] { g_sink = pk::ComputeNpde(problem, fit.parameters, npde).npde.mean; },
                                [&] { g_sink = pk::ComputeNpde(problem, fit.parameters, npde2).npde.mean; }});
  std::printf("%-14s %9d %11.3f %13.2f %13.1f %9.2f %14.1f %9.2f\n", name, problem.num_subjects(), t.base_seconds * 1e3,
              t.ratios[1], t.base_seconds * t.ratios[2] * 1e3, t.ratios[3] / t.ratios[2],
              t.base_seconds * t.ratios[4] * 1e3, t.ratios[5] / t.ratios[4]);
  std::fflush(stdout);
}

void PopulationSimulation(const std::string& data_dir) {
  std::printf("\n== population simulation, VPC and NPDE at the FOCEI estimates ==\n");
  std::printf("%-14s %9s %11s %13s %13s %9s %14s %9s\n", "data", "subjects", "OFV (ms)", "replicate/OFV",
              "VPC 200 (ms)", "2 thr/1", "NPDE 1000 (ms)", "2 thr/1");
  const auto pheno = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/phenobarbital.csv"));
  PopulationSimulationCase("phenobarbital", BolusProblem(pheno));
  PopulationSimulationCase("bolus 120x19", BolusProblem(std::make_shared<pk::Dataset>(SimulatedBolus(120))));
  PopulationSimulationCase("emax (ODE)", EmaxProblem(data_dir));
}

}  // namespace

int main(int argc, char** argv) {
  std::string data_dir = "datasets";
  int only = 0;  // --only N: section N alone
  std::string count_case;  // --count CASE CALLS
  long count_calls = 0;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--count") && i + 2 < argc) {
      count_case = argv[++i];
      count_calls = std::atol(argv[++i]);
    }
    if (!std::strcmp(argv[i], "--min-time") && i + 1 < argc) g_min_time = std::atof(argv[++i]);
    if (!std::strcmp(argv[i], "--datasets") && i + 1 < argc) data_dir = argv[++i];
    if (!std::strcmp(argv[i], "--quick")) g_min_time = 0.01;
    if (!std::strcmp(argv[i], "--only") && i + 1 < argc) only = std::atoi(argv[++i]);
  }
  using Need = pk::Objective::Need;
  using Route = pk::GradientRoute;

  if (count_case == "population") {
    // Phenobarbital's FOCEI fit of section 8, repeated untimed: perf record pkbench --count population 50
    const auto pheno = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/phenobarbital.csv"));
    const pk::PopulationProblem problem = BolusProblem(pheno);
    pk::PopulationParameters start;
    start.theta = Eigen::Vector2d(0.005, 1.0);
    start.omega = 0.1 * Eigen::MatrixXd::Identity(2, 2);
    start.sigma = Eigen::VectorXd::Constant(1, 0.2);
    pk::PopulationOptions options;
    options.covariance = false;
    for (long k = 0; k < count_calls; ++k) g_sink = pk::FitPopulation(problem, start, options).ofv;
    return 0;
  }
  // ---- 1. 2cmt_oral, 12 samples.
  if (only == 0 || only == 1 || !count_case.empty()) {
    const pk::Objective obj(pk::MakeModel("2cmt_oral"), OneDose("1", 100), 0, pk::ObjectiveOptions());
    Eigen::VectorXd v = obj.DefaultValues();
    const std::vector<int> free{0, 1, 2, 3, 4};
    const double p[5] = {v(0), v(1), v(2), v(3), v(4)};
    const Eigen::VectorXd y = obj.observations();
    if (!count_case.empty()) {
      const std::map<std::string, std::function<void()>> cases = {
          {"closed", [&] { g_sink = ClosedFormLoss(p, y.data()); }},
          {"loss", [&] { g_sink = obj.Evaluate(v, free, Need::kValue).value; }},
          {"forward", [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kForward).value; }},
          {"adjoint", [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; }}};
      const auto it = cases.find(count_case);
      if (it == cases.end() || count_calls <= 0) {
        std::fprintf(stderr, "pkbench: --count takes closed, loss, forward or adjoint and a number of calls\n");
        return 2;
      }
      for (long c = 0; c < count_calls; ++c) it->second();
      std::printf("%ld calls of %s\n", count_calls, count_case.c_str());
      return 0;
    }
    // Check that the closed form is the same loss.
    const double exact = obj.Evaluate(v, free, Need::kValue).value, closed = ClosedFormLoss(p, y.data());
    const Timing t = Interleaved({[&] { g_sink = ClosedFormLoss(p, y.data()); },
                                  [&] { g_sink = obj.Evaluate(v, free, Need::kValue).value; },
                                  [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kForward).value; },
                                  [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; }});
    const double closed_us = t.base_seconds * 1e6;
    std::printf("== 2cmt_oral, one dose, 12 samples, 5 parameters ==\n");
    std::printf("closed-form loss agrees with the Φ/Γ loss to %.1e relative\n", std::fabs(exact - closed) / exact);
    std::printf("%-34s %10s %12s %14s\n", "", "time (µs)", "/ loss", "/ closed form");
    const char* names[] = {"closed-form loss (baseline)", "loss (Φ/Γ)", "loss + gradient (a) forward",
                           "loss + gradient (b) adjoint"};
    for (int i = 0; i < 4; ++i) {
      std::printf("%-34s %10.2f %12.2f %14.1f\n", names[i], closed_us * t.ratios[i], t.ratios[i] / t.ratios[1],
                  t.ratios[i]);
    }
    std::printf("\n");
  }

  // ---- 2. Gradient/loss ratio against m.
  if (only == 0 || only == 2) {
    std::printf("== mammillary model, K peripherals, IV bolus, 12 samples: cost / loss ==\n");
    std::printf("%4s %4s %4s %12s %12s %12s\n", "K", "n", "m", "loss (µs)", "(a) forward", "(b) adjoint");
    for (int k : {1, 2, 4, 8, 16, 30}) {
      const pk::Objective obj(Mammillary(k), OneDose("1", 100), 0, pk::ObjectiveOptions());
      const Eigen::VectorXd v = obj.DefaultValues();
      std::vector<int> free;
      for (int i = 0; i < 2 * k + 2; ++i) free.push_back(i);
      const Timing t = Interleaved({[&] { g_sink = obj.Evaluate(v, free, Need::kValue).value; },
                                    [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kForward).value; },
                                    [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; }});
      std::printf("%4d %4d %4d %12.1f %12.2f %12.2f\n", k, k + 1, 2 * k + 2, t.base_seconds * 1e6, t.ratios[1],
                  t.ratios[2]);
      std::fflush(stdout);
    }
    std::printf("\n");
  }

  // ---- 4. ODE routes on the saturable chain.
  if (only == 0 || only == 4) {
    // VMAX_i ≈ 40: the drug has left the chain by about 6 h for small n, so most
    // samples see almost none of it. VMAX_i ≈ 4: it is present at every sample.
    for (const double vmax_scale : {1.0, 0.1}) {
      std::printf("== saturable chain of n compartments (m = 2n), VMAX_i = %g(40 + i), bolus into X1, 12 samples of "
                  "Xn to 24 h; CVODES rtol 1e-8 ==\n",
                  vmax_scale);
      std::printf("%4s %4s %14s %14s %14s %16s %12s\n", "n", "m", "solve (ms)", "(a) / solve", "(b) / solve",
                  "(b) stored bytes", "bwd/fwd steps");
      for (int n : {1, 2, 4, 8, 16, 24, 32}) {
        const pk::Objective obj(Chain(n, vmax_scale), OneDose("1", 100), 0, CvodesOptions());
        const Eigen::VectorXd v = obj.DefaultValues();
        std::vector<int> free;
        for (int i = 0; i < 2 * n; ++i) free.push_back(i);
        // Statistics of the second evaluation: the first may also size this thread's adjoint memories.
        obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint);
        const auto adj = obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint);
        const Timing t = Interleaved({[&] { g_sink = obj.Evaluate(v, free, Need::kValue).value; },
                                      [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kForward).value; },
                                      [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; }});
        std::printf("%4d %4d %14.3f %14.2f %14.2f %16ld %12.2f\n", n, 2 * n, t.base_seconds * 1e3, t.ratios[1],
                    t.ratios[2], adj.ode_statistics.peak_adjoint_bytes,
                    double(adj.ode_statistics.backward_steps) / double(adj.ode_statistics.steps));
        std::fflush(stdout);
      }
      std::printf("\n");
    }
    // The same chains through Dormand–Prince (rk): its loss against CVODES's, and its routes' cost.
    for (const double vmax_scale : {1.0, 0.1}) {
      std::printf("== the same chain, VMAX_i = %g(40 + i), through Dormand-Prince (rk), rtol 1e-8 ==\n", vmax_scale);
      // (b) takes its stage products from compressed Jacobians; "(b) tape" records f on the tape instead
      // (OdeOptions::compressed_jacobians = false). |(b)−(a)|: the adjoint's gradient against forward
      // sensitivities, relative to the largest entry of (a).
      // "(b) base/solve": the same adjoint with f on lanes and the sweeps in the x86-64 baseline's two
      // lanes an instruction, where "(b)" takes the AVX2 clone when the CPU has AVX2 (pk/fixed_dual.h).
      std::printf("%4s %4s %14s %16s %14s %14s %14s %14s %16s %14s %12s\n", "n", "m", "rk solve (ms)",
                  "ode solve / rk", "(a) / solve", "(b) / solve", "(b) base/solve", "(b) tape/solve",
                  "(b) stored bytes", "(b)/solve steps", "|(b)-(a)|");
      for (int n : {1, 2, 4, 8, 16, 24, 32}) {
        pk::ObjectiveOptions rk_options;
        rk_options.propagator = pk::Propagator::kRungeKutta;
        pk::ObjectiveOptions tape_options = rk_options;
        tape_options.ode.compressed_jacobians = false;
        const pk::Objective rk(Chain(n, vmax_scale), OneDose("1", 100), 0, rk_options);
        const pk::Objective rk_tape(Chain(n, vmax_scale), OneDose("1", 100), 0, tape_options);
        const pk::Objective ode(Chain(n, vmax_scale), OneDose("1", 100), 0, CvodesOptions());
        const Eigen::VectorXd v = rk.DefaultValues();
        std::vector<int> free;
        for (int i = 0; i < 2 * n; ++i) free.push_back(i);
        const auto adj = Checked(rk.Evaluate(v, free, Need::kGradient, Route::kAdjoint), "the rk adjoint");
        const auto fwd = Checked(rk.Evaluate(v, free, Need::kGradient, Route::kForward), "rk forward sensitivities");
        const auto plain = Checked(rk.Evaluate(v, free, Need::kValue), "the rk loss");
        Checked(rk_tape.Evaluate(v, free, Need::kGradient, Route::kAdjoint), "the recorded rk adjoint");
        const Timing t = Interleaved({[&] { g_sink = rk.Evaluate(v, free, Need::kValue).value; },
                                      [&] { g_sink = ode.Evaluate(v, free, Need::kValue).value; },
                                      [&] { g_sink = rk.Evaluate(v, free, Need::kGradient, Route::kForward).value; },
                                      [&] { g_sink = rk.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; },
                                      [&] { g_sink = BaselineLanes([&] { return rk.Evaluate(v, free, Need::kGradient,
                                                                                            Route::kAdjoint); }).value; },
                                      [&] { g_sink = rk_tape.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; }});
        std::printf("%4d %4d %14.3f %16.2f %14.2f %14.2f %14.2f %14.2f %16ld %14.2f %12.1e\n", n, 2 * n,
                    t.base_seconds * 1e3, t.ratios[1], t.ratios[2], t.ratios[3], t.ratios[4], t.ratios[5],
                    adj.ode_statistics.peak_adjoint_bytes,
                    double(adj.ode_statistics.steps) / double(plain.ode_statistics.steps),
                    (adj.gradient - fwd.gradient).cwiseAbs().maxCoeff() / fwd.gradient.cwiseAbs().maxCoeff());
        std::fflush(stdout);
      }
      std::printf("\n");
    }
    // A model on 8 lanes: the rk adjoint's cost where f runs on FixedDual<8>.
    std::printf("== the first chain with a first-order loss too (m = 3n, 7 colours: f on 8 lanes), rk, rtol 1e-8 ==\n");
    std::printf("%4s %4s %14s %14s %16s\n", "n", "m", "rk solve (ms)", "(b) / solve", "(b) stored bytes");
    for (int n : {8, 16, 32}) {
      pk::ObjectiveOptions rk_options;
      rk_options.propagator = pk::Propagator::kRungeKutta;
      const pk::Objective rk(Leaky(n), OneDose("1", 100), 0, rk_options);
      const Eigen::VectorXd v = rk.DefaultValues();
      std::vector<int> free;
      for (int i = 0; i < 3 * n; ++i) free.push_back(i);
      const auto adj = Checked(rk.Evaluate(v, free, Need::kGradient, Route::kAdjoint), "the rk adjoint");
      const Timing t = Interleaved({[&] { g_sink = rk.Evaluate(v, free, Need::kValue).value; },
                                    [&] { g_sink = rk.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; }});
      std::printf("%4d %4d %14.3f %14.2f %16ld\n", n, 3 * n, t.base_seconds * 1e3, t.ratios[1],
                  adj.ode_statistics.peak_adjoint_bytes);
      std::fflush(stdout);
    }
    std::printf("\n");
    // The same choice on catalogue models and bundled data (first four
    // subjects, all model parameters free): what pk::kOdeAdjointThreshold rests on.
    std::printf("== catalogue ODE models on bundled data: gradient by (a) forward sensitivities over (b) the adjoint ==\n");
    std::printf("%-18s %-24s %4s %18s\n", "model", "data", "m", "(a) / (b)");
    const std::pair<const char*, const char*> cases[] = {{"1cmt_iv_mm", "mm_synthetic.csv"},
                                                         {"1cmt_oral_mm", "theophylline.csv"},
                                                         {"1cmt_oral_transit", "theophylline.csv"},
                                                         {"2cmt_iv_mm", "mm_synthetic.csv"},
                                                         {"1cmt_iv_emax", "emax_synthetic.csv"}};
    for (const auto& c : cases) {
      pk::Dataset read = pk::ReadDataset(data_dir + "/" + c.second);
      // Observations in the central compartment: theophylline's CMT=2 is TR2 of the transit model.
      for (pk::Subject& subject : read.subjects) {
        for (pk::Record& r : subject.records) {
          if (!r.IsDose()) r.cmt = 0;
        }
      }
      const auto data = std::make_shared<pk::Dataset>(std::move(read));
      pk::ObjectiveOptions oo;
      oo.propagator = pk::Propagator::kOde;
      std::vector<double> ratios;
      int m = 0;
      for (int s = 0; s < std::min<int>(4, static_cast<int>(data->subjects.size())); ++s) {
        const pk::Objective obj(pk::MakeModel(c.first), data, s, oo);
        const Eigen::VectorXd v = obj.DefaultValues();
        std::vector<int> free;
        for (int i = 0; i < obj.model().num_parameters(); ++i) free.push_back(i);
        m = static_cast<int>(free.size());
        const Timing t =
            Interleaved({[&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; },
                         [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kForward).value; }});
        ratios.push_back(t.ratios[1]);
      }
      std::sort(ratios.begin(), ratios.end());
      std::printf("%-18s %-24s %4d %11.2f-%.2f\n", c.first, c.second, m, ratios.front(), ratios.back());
      std::fflush(stdout);
    }
    std::printf("\n");
    StiffSegments();
    for (const int nc : {16, 32}) {
      std::printf("== the first chain, n = %d (m = %d): the adjoint's time and storage against how much it keeps ==\n",
                  nc, 2 * nc);
      std::printf("%-28s %12s %14s %16s %10s\n", "trajectory kept", "steps/check", "(b) / solve", "stored bytes",
                  "fwd steps");
      for (bool all : {true, false}) {
        for (int steps : {2, 10, 100, 1000, 10000}) {
          pk::ObjectiveOptions oo = CvodesOptions();
          oo.ode.checkpoint_steps = steps;
          oo.ode.adjoint_store_all_segments = all;
          const pk::Objective obj(Chain(nc), OneDose("1", 100), 0, oo);
          const Eigen::VectorXd v = obj.DefaultValues();
          std::vector<int> free;
          for (int i = 0; i < 2 * nc; ++i) free.push_back(i);
          obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint);  // as above
          const auto adj = obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint);
          const Timing t = Interleaved({[&] { g_sink = obj.Evaluate(v, free, Need::kValue).value; },
                                        [&] { g_sink = obj.Evaluate(v, free, Need::kGradient, Route::kAdjoint).value; }});
          std::printf("%-28s %12d %14.2f %16ld %10ld\n", all ? "all segments (1 fwd pass)" : "one segment (2 fwd passes)",
                      steps, t.ratios[1], adj.ode_statistics.peak_adjoint_bytes, adj.ode_statistics.steps);
        }
      }
      std::printf("\n");
    }
  }

  // ---- 3. Theophylline fits.
  if (only == 0 || only == 3) {
    pk::FitSubjectsRequest req;
    req.model = pk::MakeModel("1cmt_oral");
    req.data = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/theophylline.csv"));
    for (const std::string& p : req.model->parameter_names()) req.parameters.push_back({p, NAN});
    req.jobs = 1;
    req.curve_points = 2;
    // The fitting time of every call (the sum of FitSummary::seconds), reported as the median.
    std::vector<double> fit_seconds;
    const double t_all = SecondsPerCall([&] {
      const auto fits = pk::FitSubjects(req);
      double sum = 0;
      for (const auto& f : fits) sum += f.summary.seconds;
      fit_seconds.push_back(sum);
    });
    std::sort(fit_seconds.begin(), fit_seconds.end());
    const double fit_median = fit_seconds[fit_seconds.size() / 2];
    std::printf("== theophylline, 12 subjects, 1cmt_oral, Levenberg-Marquardt, one thread ==\n");
    std::printf("fitting time, sum over subjects (median of %zu runs): %.2f ms (%.3f ms per subject); "
                "with setup and plots: %.2f ms\n",
                fit_seconds.size(), fit_median * 1e3, fit_median * 1e3 / 12, t_all * 1e3);
  }

  // ---- 5. ODE fits: Levenberg-Marquardt with forward sensitivities, through CVODES and through Dormand–Prince.
  if (only == 0 || only == 5) {
    std::printf("\n== nonlinear models fitted by Levenberg-Marquardt (forward sensitivities), rtol 1e-8, one thread: "
                "CVODES (ode) and Dormand-Prince (rk) ==\n");
    std::printf("%-14s %-22s %9s %12s %12s %9s %14s %12s\n", "model", "data", "subjects", "ode fit (ms)",
                "rk fit (ms)", "ode / rk", "evals/fit ode", "max |dOBJ|");
    const std::pair<const char*, const char*> fits[] = {{"1cmt_oral_mm", "theophylline.csv"},
                                                        {"1cmt_iv_emax", "emax_synthetic.csv"},
                                                        {"1cmt_iv_mm", "mm_synthetic.csv"}};
    for (const auto& c : fits) {
      pk::FitSubjectsRequest req;
      req.model = pk::MakeModel(c.first);
      req.data = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/" + c.second));
      for (const std::string& p : req.model->parameter_names()) req.parameters.push_back({p, NAN});
      req.jobs = 1;
      req.curve_points = 2;
      double median[2] = {0, 0}, evaluations = 0, worst = 0;
      std::vector<double> objectives[2];
      size_t subjects = 0;
      for (int k = 0; k < 2; ++k) {
        req.objective.propagator = k == 0 ? pk::Propagator::kOde : pk::Propagator::kRungeKutta;
        std::vector<double> fit_seconds;
        SecondsPerCall([&] {
          const auto results = pk::FitSubjects(req);
          double sum = 0;
          if (k == 0) evaluations = 0;
          objectives[k].clear();
          for (const auto& f : results) {
            sum += f.summary.seconds;
            if (k == 0) evaluations += f.summary.evaluations;
            objectives[k].push_back(f.summary.objective);
          }
          subjects = results.size();
          fit_seconds.push_back(sum);
        });
        std::sort(fit_seconds.begin(), fit_seconds.end());
        median[k] = fit_seconds[fit_seconds.size() / 2];
      }
      for (size_t i = 0; i < objectives[0].size(); ++i) {
        worst = std::max(worst, std::fabs(objectives[0][i] - objectives[1][i]));
      }
      std::printf("%-14s %-22s %9zu %12.2f %12.2f %9.1f %14.1f %12.1e\n", c.first, c.second, subjects,
                  median[0] * 1e3, median[1] * 1e3, median[0] / median[1], evaluations / double(subjects), worst);
      std::fflush(stdout);
    }
  }

  // ---- 7. Model files against the catalogue: the same model, fitted from the same start.
  if (only == 0 || only == 7) {
    std::printf("\n== model files (models/*.pkm) against the catalogue: fitting time, all subjects, one thread ==\n");
    std::printf("%-14s %-22s %-10s %14s %14s %8s\n", "model", "data", "propagator", "catalogue (ms)", "file (ms)",
                "ratio");
    const std::pair<const char*, const char*> cases[] = {{"1cmt_oral_mm", "theophylline.csv"},
                                                         {"1cmt_iv_emax", "emax_synthetic.csv"},
                                                         {"1cmt_oral", "theophylline.csv"},
                                                         {"2cmt_iv", "remifentanil.csv"}};
    const std::string models_dir = data_dir + "/../models/";
    for (const auto& c : cases) {
      const auto data = std::make_shared<pk::Dataset>(pk::ReadDataset(data_dir + "/" + c.second));
      auto request = [&](std::shared_ptr<const pk::Model> model) {
        pk::FitSubjectsRequest req;
        req.data = data;
        req.jobs = 1;
        req.curve_points = 2;
        req.initial_from_data = false;  // both start from the catalogue's values
        const auto catalogue = pk::MakeModel(c.first);
        for (int i = 0; i < catalogue->num_parameters(); ++i) {
          req.parameters.push_back({catalogue->parameter_names()[i], catalogue->default_parameters()(i)});
        }
        req.model = std::move(model);
        return req;
      };
      const pk::FitSubjectsRequest a = request(pk::MakeModel(c.first));
      const pk::FitSubjectsRequest b = request(pk::LoadModelFile(models_dir + c.first + ".pkm"));
      const Timing t = Interleaved({[&] { g_sink = double(pk::FitSubjects(a).size()); },
                                    [&] { g_sink = double(pk::FitSubjects(b).size()); }});
      std::printf("%-14s %-22s %-10s %14.1f %14.1f %8.2f\n", c.first, c.second,
                  pk::ToString(pk::ResolvePropagator(*b.model, pk::Propagator::kAuto)), t.base_seconds * 1e3, t.base_seconds * t.ratios[1] * 1e3,
                  t.ratios[1]);
      std::fflush(stdout);
    }
  }
  if (only == 0 || only == 8) PopulationEstimation(data_dir);
  if (only == 0 || only == 8) LaplaceHessian(data_dir);
  if (only == 0 || only == 8) LaplaceEstimation(data_dir);
  if (only == 0 || only == 8) FirstOrderEstimation(data_dir);
  // ---- 6. Simulation throughput and memory.
  if (only == 0 || only == 6) SimulationThroughput(g_min_time < 0.05 ? 10000 : 100000);
  if (only == 0 || only == 10) PopulationSimulation(data_dir);
  return 0;
}
