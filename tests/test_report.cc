// The report library (pk::report): the LOWESS smoother against R's lowess(), the axes of the SVG
// plots; and the units of parameters (pk/units.h) and a dataset's units row.
#include <algorithm>
#include <cmath>
#include <regex>
#include <set>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

#include "pk/dataset.h"
#include "pk/plot.h"
#include "pk/units.h"

namespace {

void CheckEqualsR(const pk::PlotSeries& s, const std::vector<double>& r, const std::vector<size_t>& at = {}) {
  for (size_t k = 0; k < r.size(); ++k) {
    const size_t i = at.empty() ? k : at[k];
    INFO("point " << i + 1);
    REQUIRE(i < s.y.size());
    CHECK(s.y[i] == Approx(r[k]).epsilon(1e-12).margin(1e-13));
  }
}

// The numbers in an SVG attribute, e.g. every cx="...".
std::vector<double> Attribute(const std::string& svg, const std::string& name) {
  std::vector<double> out;
  const std::regex re(" " + name + "=\"([-0-9.e+]+)\"");
  for (auto it = std::sregex_iterator(svg.begin(), svg.end(), re); it != std::sregex_iterator(); ++it) {
    out.push_back(std::stod((*it)[1]));
  }
  return out;
}

}  // namespace

TEST_CASE("LOWESS equals R's lowess() (tests/reference/make_lowess_reference.R)", "[report]") {
  SECTION("a line with an outlier: the robustness passes down-weight it") {
    const std::vector<double> x{1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 15};
    const std::vector<double> y{2.1, 3.9, 6.2, 7.8, 10.1, 12.2, 13.8, 16.1, 18.3, 19.7, 30, 29};
    CheckEqualsR(pk::Lowess(x, y), {2.0333889343766725, 4.0300849169945057, 6.0288699583143854, 8.0321234669363761,
                                    10.026656630465915, 12.034817209088699, 14.064606803987914, 16.046977838686818,
                                    18.005034585205053, 19.964980007312022, 23.631397542046436, 29.11417542085897});
  }
  SECTION("a noisy sine, f = 0.3") {
    const std::vector<double> noise{0.3, -0.2, 0.5, -0.4, 0.1, 0.0, -0.3, 0.2, -0.1, 0.4, -0.5, 0.3, 0.1, -0.2,
                                    0.0, 0.2, -0.3, 0.1, 0.4, -0.1, 0.2, -0.4, 0.3, 0.0, -0.2, 0.1, 0.5, -0.3,
                                    0.2, -0.1, 0.0, 0.3, -0.2, 0.1, -0.4, 0.2, 0.0, -0.1, 0.3, -0.3, 0.1};
    std::vector<double> x, y;
    for (int i = 0; i <= 40; ++i) {
      x.push_back(i / 4.0);
      y.push_back(std::sin(i / 4.0) + noise[static_cast<size_t>(i)]);
    }
    CheckEqualsR(pk::Lowess(x, y, 0.3),
                 {0.28105898475101787,  0.38879102088593248,  0.49252602855972544,  0.59336689821944277,
                  0.6914704356084137,   0.78940383380313217,  0.82628118048466881,  0.81244165982378014,
                  0.75829259708162788,  0.65259674598734385,  0.508443759003954,    0.33210631807086383,
                  0.12379261816080271,  -0.086902850947344804, -0.27893687750020935, -0.44663144025465523,
                  -0.59347604965320611, -0.7080276537300888,  -0.76930240371223313, -0.78219447619673599,
                  -0.75187162759083814, -0.6722997192707888,  -0.55101432002074235, -0.3915063576046679,
                  -0.19578687676856982, 0.010779869390798922, 0.22017002912023792,  0.42195578096991487,
                  0.59932976705230767,  0.7318250868581806,   0.80240108913265451,  0.82917156774259904,
                  0.819052423787897,    0.75979876030749738,  0.65857466427541145,  0.50874628603880978,
                  0.31644946549105923,  0.12537066842898104,  -0.067497454956233438, -0.26368077031204229,
                  -0.46456705103174611});
  }
  SECTION("tied x share their fit") {
    const std::vector<double> x{0, 0, 1, 1, 1, 2, 3, 3, 4, 5, 5, 6};
    const std::vector<double> y{1, 1.2, 2.1, 1.9, 2.3, 2.8, 4.1, 3.7, 4.4, 5.2, 4.9, 6.3};
    CheckEqualsR(pk::Lowess(x, y, 0.5), {1.1, 1.1, 2.1, 2.1, 2.1, 2.8, 3.6718326182043697, 3.6718326182043697,
                                         4.4216032596117802, 5.2278905795918265, 5.2278905795918265,
                                         6.2309534900374706});
  }
  SECTION("200 points: fits δ = range/100 apart, interpolated between") {
    std::vector<double> x, y;
    for (int i = 0; i < 200; ++i) {
      x.push_back(i * i / (199.0 * 199.0));
      y.push_back(std::cos(3 * x.back()) + 0.1 * std::sin(37 * x.back()));
    }
    CheckEqualsR(pk::Lowess(x, y),
                 {1.0737782491031884, 1.0737442247105777, 0.99106113898932302, 0.69111532579158064,
                  -0.095259174833779492, -1.1488908162574429, -1.1730460490634009},
                 {0, 1, 49, 100, 149, 198, 199});
  }
  SECTION("n = 10: the neighbourhood of f·n = 6.67 points is truncated to 6") {
    std::vector<double> x;
    for (int i = 1; i <= 10; ++i) x.push_back(i);
    CheckEqualsR(pk::Lowess(x, {2, 4.1, 5.8, 8.3, 9.9, 12.4, 13.7, 16.2, 18.1, 19.6}),
                 {2.0016349430639848, 4.0157894301034132, 6.0360182453750095, 8.0568938472115281, 10.097785791034271,
                  12.063443206752371, 14.074296790403828, 16.016195929029784, 17.898287492413054,
                  19.774418598133728});
  }
  SECTION("ties at the window's edge with a half-width of 0 all count") {
    CheckEqualsR(pk::Lowess({1, 1, 1, 1, 1, 1, 1, 2, 3}, {1, 2, 3, 4, 5, 6, 7, 8, 9}),
                 {4, 4, 4, 4, 4, 4, 4, 8, 9.0000000000000036});
  }
  SECTION("x far from 0: the spread of x is taken about its mean") {
    std::vector<double> x, y;
    for (int i = 0; i < 30; ++i) {
      x.push_back(1e7 + i / 10.0);
      y.push_back(std::sin(i / 3.0));
    }
    // Uncentred sums were 7% off here. The x themselves are known to an ulp of 1e7 (1.9e-9), 2e-8 of
    // their spacing of 0.1, so R's order of summation and ours agree to that, not to 1e-12.
    const pk::PlotSeries s = pk::Lowess(x, y);
    const std::vector<double> r{0.8940058732393017, 0.055958141175387818, 0.018416266990092255, 0.68829534905674117};
    const size_t at[] = {0, 9, 19, 29};
    for (size_t k = 0; k < 4; ++k) CHECK(s.y[at[k]] == Approx(r[k]).epsilon(0).margin(2e-8));  // y is of order 1
  }
  SECTION("a straight line is its own smooth; too few points give none") {
    const pk::PlotSeries s = pk::Lowess({3, 1, 2, 5, 4}, {7, 3, 5, 11, 9});  // unsorted: y = 2x + 1
    REQUIRE(s.x == std::vector<double>{1, 2, 3, 4, 5});
    for (size_t i = 0; i < s.x.size(); ++i) CHECK(s.y[i] == Approx(2 * s.x[i] + 1).epsilon(1e-12));
    CHECK(pk::Lowess({1, 2}, {1, 2}).y.empty());
    CHECK(pk::Lowess({1, 2}, {1, 2}).x.empty());
  }
}

TEST_CASE("plots: a decimated line keeps its order, its peak and trough, and at most the points asked", "[report][plot]") {
  pk::PlotSeries line{"ID 1", {}, {}};
  for (int i = 0; i < 100000; ++i) {
    const double t = 0.001 * i;
    line.x.push_back(t);
    line.y.push_back(std::exp(-0.3 * t) - std::exp(-2 * t) + (i == 4321 ? 5.0 : 0.0) - (i == 77777 ? 3.0 : 0.0));
  }
  const pk::PlotSeries d = pk::DecimateLine(line, 4000);
  REQUIRE(d.x.size() == d.y.size());
  CHECK(d.x.size() <= 4000);
  CHECK(d.x.size() >= 2000);
  CHECK(std::is_sorted(d.x.begin(), d.x.end()));
  CHECK(*std::max_element(d.y.begin(), d.y.end()) == *std::max_element(line.y.begin(), line.y.end()));
  CHECK(*std::min_element(d.y.begin(), d.y.end()) == *std::min_element(line.y.begin(), line.y.end()));
  CHECK(std::find(d.x.begin(), d.x.end(), line.x[4321]) != d.x.end());  // the spike, at its time
  CHECK(d.label == "ID 1");
  CHECK(pk::DecimateLine(d, 4000).x == d.x);  // short enough: as it is
  CHECK_THROWS_AS(pk::DecimateLine(line, 3), std::invalid_argument);
}

TEST_CASE("plots: log ticks at 1-2-5, every marker inside the frame, a bounded log range", "[report][plot]") {
  pk::PlotSeries curve{"fitted", {0, 1, 2, 3, 4}, {0, 1e-300, 0.3, 40, 7}};
  pk::PlotSeries points{"observed", {0.5, 1, 2, 3, 4}, {0.2, 0.25, 0.3, 40, 7}, true};
  pk::PlotOptions o;
  o.log_y = true;
  const std::string svg = pk::RenderSvg({curve, points}, o);
  // The frame, then the markers' centres within it.
  const std::vector<double> fx = Attribute(svg, "x"), fy = Attribute(svg, "y");
  const std::regex frame("<rect x=\"([-0-9.e+]+)\" y=\"([-0-9.e+]+)\" width=\"([-0-9.e+]+)\" height=\"([-0-9.e+]+)\" fill=\"none\"");
  std::smatch m;
  REQUIRE(std::regex_search(svg, m, frame));
  const double left = std::stod(m[1]), top = std::stod(m[2]), right = left + std::stod(m[3]), bottom = top + std::stod(m[4]);
  const std::vector<double> cx = Attribute(svg, "cx"), cy = Attribute(svg, "cy");
  REQUIRE(cx.size() == 5);
  for (size_t i = 0; i < cx.size(); ++i) {
    CHECK(cx[i] - 3.5 >= left);
    CHECK(cx[i] + 3.5 <= right);
    CHECK(cy[i] - 3.5 >= top);
    CHECK(cy[i] + 3.5 <= bottom);
  }
  // 0.2 to 40 spans about two decades: labels at 0.2, 0.5, 1, 2, 5, 10, 20 (and not 1e-300's decades).
  for (const char* label : {">0.2<", ">0.5<", ">1<", ">2<", ">5<", ">10<", ">20<"}) {
    INFO(label);
    CHECK(svg.find(label) != std::string::npos);
  }
  CHECK(svg.find("e-30") == std::string::npos);
}

TEST_CASE("the palette has 20 distinct colours", "[report][plot]") {
  std::set<std::string> colours;
  for (int k = 0; k < 20; ++k) colours.insert(pk::PaletteColour(k));
  CHECK(colours.size() == 20);
  CHECK(std::string(pk::PaletteColour(20)) == pk::PaletteColour(0));
}

TEST_CASE("units: the parameters' units follow from time, amount and concentration", "[units]") {
  pk::Units u = pk::ParseUnits("time=h,amt=mg,conc=mg/L");
  CHECK(pk::VolumeUnit(u) == "L");
  CHECK(pk::ParameterUnit("CL", u) == "L/h");
  CHECK(pk::ParameterUnit("Q3", u) == "L/h");
  CHECK(pk::ParameterUnit("V2", u) == "L");
  CHECK(pk::ParameterUnit("KA", u) == "1/h");
  CHECK(pk::ParameterUnit("K20", u) == "1/h");
  CHECK(pk::ParameterUnit("LAMBDA_ABS", u) == "1/h");
  CHECK(pk::ParameterUnit("THALF1", u) == "h");
  CHECK(pk::ParameterUnit("ALAG1", u) == "h");
  CHECK(pk::ParameterUnit("VMAX", u) == "mg/h");
  CHECK(pk::ParameterUnit("KM", u) == "mg/L");
  CHECK(pk::ParameterUnit("SIGMA_ADD", u) == "mg/L");
  CHECK(pk::ParameterUnit("F1", u) == "1");
  CHECK(pk::ParameterUnit("AUC", u) == "mg/L·h");
  CHECK(pk::ParameterUnit("CMAX", u) == "mg/L");
  CHECK(pk::ParameterUnit("TMAX", u) == "h");
  CHECK(pk::ParameterUnit("A1", u).empty());  // a tf coefficient: no unit is claimed
  CHECK(pk::ParameterUnit("EMAX", u).empty());
  CHECK(pk::WithUnit("CL", "L/h") == "CL (L/h)");
  CHECK(pk::WithUnit("F1", "1") == "F1");
  // Mass units that differ: the volume unit says so rather than converting.
  u.concentration = "ng/mL";
  CHECK(pk::VolumeUnit(u) == "mg/(ng/mL)");
  CHECK(pk::ParameterUnit("V", pk::Units{"h", "", "", {}}).empty());
  CHECK_THROWS_WITH(pk::ParseUnits("volume=L"), Catch::Contains("unknown key 'volume'"));
  CHECK_THROWS_WITH(pk::ParseUnits("h"), Catch::Contains("expected KEY=UNIT"));
}

TEST_CASE("a units row: '#' and a unit per column right after the header", "[units][reader]") {
  const pk::Dataset d = pk::ParseDataset("ID,TIME,AMT,DV,WT\n#,h,mg,mg/L,kg\n1,0,100,.,70\n1,1,0,3,70\n", "u.csv");
  const pk::Units u = pk::DatasetUnits(d);
  CHECK(u.time == "h");
  CHECK(u.amount == "mg");
  CHECK(u.concentration == "mg/L");
  CHECK(d.column_units.at("WT") == "kg");
  CHECK(d.subjects.at(0).records.size() == 2);  // the row is not a record
  // --units takes precedence; the row fills in the rest.
  const pk::Units merged = pk::MergeUnits(pk::ParseUnits("conc=ug/mL"), u);
  CHECK(merged.concentration == "ug/mL");
  CHECK(merged.time == "h");
  // A commented-out record is a comment, not units.
  const pk::Dataset c = pk::ParseDataset("ID,TIME,AMT,DV\n#1,0,100,.\n1,0,100,.\n1,1,0,3\n", "c.csv");
  CHECK(c.column_units.empty());
}
