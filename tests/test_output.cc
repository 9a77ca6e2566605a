// Output: numbers as text, files written whole or not at all, output sets, streamed simulation.
#include <catch2/catch.hpp>

#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <sys/stat.h>
#include <unistd.h>

#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/plot.h"
#include "pk/regimen.h"
#include "pk/simulate.h"
#include "pk/simulation_csv.h"

namespace {

// FormatNumber's definition, computed the slow way: %.Pg (to_chars) with the least P >= 6 that
// reads back, up to 17.
std::string ReferenceFormat(double value) {
  char buf[64];
  for (int precision = 6; precision <= 17; ++precision) {
    const auto end = std::to_chars(buf, buf + sizeof buf, value, std::chars_format::general, precision).ptr;
    double back = 0;
    const auto parsed = std::from_chars(buf, end, back);
    if ((parsed.ec == std::errc() && back == value) || precision == 17) return std::string(buf, end);
  }
  return "";
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string TempDir(const std::string& name) {
  const std::string dir = std::string(PK_BINARY_DIR) + "/output_test_" + name + "_" + std::to_string(::getpid());
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

}  // namespace

TEST_CASE("FormatNumber is %.Pg with the least P >= 6 that reads back, for every kind of double", "[output]") {
  std::vector<double> values = {0.0, -0.0, 1.0, -1.0, 0.1, 0.48, 4.800000000000001, 1e-5, 1e-4, 9.99999e-5,
                                123456, 1234567, 999999.5, 1e15, 1e16, 1e17, 1e21, 1e300, 5e-324, 2.2250738585072014e-308,
                                1.7976931348623157e308, 100000, 12345678901234567.0, 0.000123456789, 3.14159265358979};
  std::mt19937_64 rng(42);
  for (int i = 0; i < 200000; ++i) {  // random bit patterns: every exponent and mantissa
    const std::uint64_t bits = rng();
    double v;
    std::memcpy(&v, &bits, sizeof v);
    if (std::isfinite(v)) values.push_back(v);
  }
  // Every power of two and its neighbours: a lopsided rounding interval, where the shortest digits
  // and the correctly rounded ones of as many digits part (2^-24, 2^-44, 2^89, …).
  for (int e = -1074; e <= 1023; ++e) {
    const double v = std::ldexp(1.0, e);
    for (double w : {v, std::nextafter(v, 0.0), std::nextafter(v, INFINITY), -v}) {
      if (std::isfinite(w)) values.push_back(w);
    }
  }
  std::uniform_int_distribution<int> digits(1, 17), exponent(-12, 22);
  for (int i = 0; i < 200000; ++i) {  // short decimals, as data hold them, around %g's switch points
    const double mantissa = std::floor(std::ldexp(static_cast<double>(rng() >> 11), -53) * std::pow(10.0, digits(rng)));
    values.push_back(mantissa * std::pow(10.0, exponent(rng) - 10));
  }
  int differ = 0;
  for (double v : values) {
    const std::string fast = pk::FormatNumber(v), slow = ReferenceFormat(v);
    if (fast != slow && ++differ <= 5) FAIL_CHECK(fast << " != " << slow);
    double back = 0;
    if (!pk::ParseNumber(fast, &back) || back != v) FAIL_CHECK(fast << " does not read back");
  }
  CHECK(differ == 0);
  std::string appended = "x";
  pk::AppendNumber(&appended, 0.25);
  CHECK(appended == "x0.25");
  CHECK(pk::FormatNumber(std::numeric_limits<double>::infinity()) == "inf");
}

TEST_CASE("an AtomicFile replaces its path whole, or leaves the old file when not committed", "[output]") {
  const std::string dir = TempDir("atomic");
  const std::string path = dir + "/out.csv";
  pk::WriteFileAtomically(path, "old\n");
  {
    pk::AtomicFile file(path);
    file.Write("new, ");
    CHECK(ReadAll(path) == "old\n");  // nothing under the name until Commit
    // destroyed without Commit: an error half-way
  }
  CHECK(ReadAll(path) == "old\n");
  CHECK(std::distance(std::filesystem::directory_iterator(dir), std::filesystem::directory_iterator()) == 1);
  {
    pk::AtomicFile file(path);
    file.Write("new, ");
    file.Write(std::string("in pieces\n"));
    file.Commit();
  }
  CHECK(ReadAll(path) == "new, in pieces\n");
  CHECK_THROWS_WITH(pk::AtomicFile(dir + "/no/such/dir/x.csv"), Catch::Contains("cannot write"));
  std::filesystem::remove_all(dir);
}

TEST_CASE("an AtomicFile writes a device in place instead of renaming a file over it", "[output]") {
  pk::WriteFileAtomically("/dev/null", "discarded\n");
  struct stat st;
  REQUIRE(::stat("/dev/null", &st) == 0);
  CHECK(S_ISCHR(st.st_mode));
}

TEST_CASE("an output set is complete with its manifest, and readers refuse it otherwise", "[output]") {
  const std::string dir = TempDir("set");
  pk::WriteFileAtomically(dir + "/estimates.csv", "ID,PARAMETER,ESTIMATE\n1,CL,2\n");
  pk::WriteFileAtomically(dir + "/fit_details.csv", "ID\n1\n");
  pk::WriteFileAtomically(dir + "/subject_7.svg", "<svg/>\n");
  // The first run killed here: no manifest, and fit_details.csv marks the directory as a pkfit set.
  CHECK_THROWS_WITH(pk::CheckOutputSet(dir + "/estimates.csv", "pkfit", "fit_details.csv"),
                    Catch::Contains("has no MANIFEST") && Catch::Contains("did not finish"));
  pk::CompleteOutputSet(dir, {"estimates.csv", "fit_details.csv", "subject_7.svg"}, "pkfit");
  CHECK_NOTHROW(pk::CheckOutputSet(dir + "/estimates.csv", "pkfit", "fit_details.csv"));
  // The next run writes over the last one's files; a file of the user's own stays.
  pk::WriteFileAtomically(dir + "/notes.txt", "mine\n");
  pk::WriteFileAtomically(dir + "/estimates.csv", "ID,PARAMETER,ESTIMATE\n1,CL,3\n");
  pk::WriteFileAtomically(dir + "/fit_details.csv", "ID\n1\n");
  pk::WriteFileAtomically(dir + "/summary.csv", "ID\n1\n");
  // Killed here: what it rewrote differently, or wrote new, is refused; what it has not touched, or
  // rewrote byte for byte, is the last complete set's and stays readable.
  CHECK_THROWS_WITH(pk::CheckOutputSet(dir + "/estimates.csv", "pkfit", "fit_details.csv"),
                    Catch::Contains("differs from the file pkfit wrote"));
  CHECK_THROWS_WITH(pk::CheckOutputSet(dir + "/summary.csv", "pkfit", "fit_details.csv"),
                    Catch::Contains("is not one of the files"));
  CHECK_NOTHROW(pk::CheckOutputSet(dir + "/fit_details.csv", "pkfit", "fit_details.csv"));
  CHECK_NOTHROW(pk::CheckOutputSet(dir + "/subject_7.svg", "pkfit", "fit_details.csv"));
  // Complete: the new set is readable, and the last run's file it did not write again is gone.
  pk::CompleteOutputSet(dir, {"estimates.csv", "fit_details.csv", "summary.csv"}, "pkfit");
  CHECK_NOTHROW(pk::CheckOutputSet(dir + "/estimates.csv", "pkfit", "fit_details.csv"));
  CHECK_NOTHROW(pk::CheckOutputSet(dir + "/summary.csv", "pkfit", "fit_details.csv"));
  CHECK_FALSE(std::filesystem::exists(dir + "/subject_7.svg"));
  CHECK(std::filesystem::exists(dir + "/notes.txt"));
  // A file changed after the run, or one the run did not write.
  pk::WriteFileAtomically(dir + "/estimates.csv", "ID,PARAMETER,ESTIMATE\n1,CL,4\n");
  CHECK_THROWS_WITH(pk::CheckOutputSet(dir + "/estimates.csv", "pkfit", "fit_details.csv"),
                    Catch::Contains("differs from the file pkfit wrote"));
  pk::WriteFileAtomically(dir + "/derived.csv", "x\n");
  CHECK_THROWS_WITH(pk::CheckOutputSet(dir + "/derived.csv", "pkfit", "fit_details.csv"),
                    Catch::Contains("is not one of the files"));
  // A table of the user's own, in a directory without pkfit's files, is accepted.
  const std::string own = TempDir("own");
  pk::WriteFileAtomically(own + "/mine.csv", "ID,PARAMETER,ESTIMATE\n1,CL,2\n");
  CHECK_NOTHROW(pk::CheckOutputSet(own + "/mine.csv", "pkfit", "fit_details.csv"));
  std::filesystem::remove_all(dir);
  std::filesystem::remove_all(own);
}

TEST_CASE("SimulateEach hands subjects over in order, the same with any number of threads", "[output][simulate]") {
  std::string text = "ID,TIME,AMT,CL\n";
  for (int id = 1; id <= 40; ++id) text += std::to_string(id) + ",0,100," + std::to_string(1 + 0.1 * id) + "\n";
  const pk::Dataset data = pk::ParseDataset(text, "many.csv");
  const auto model = pk::MakeModel("1cmt_iv");
  pk::SimulationOptions options;
  options.output_times = {0.5, 1, 2, 4, 8};
  const auto serial = pk::Simulate(*model, data, {{"V", 10}}, options);
  // The grid as an option equals the grid added to the dataset.
  const auto added = pk::Simulate(*model, pk::AddOutputTimes(data, options.output_times), {{"V", 10}});
  REQUIRE(serial.size() == 40);
  for (size_t i = 0; i < serial.size(); ++i) {
    REQUIRE(serial[i].rows.size() == added[i].rows.size());
    for (size_t k = 0; k < serial[i].rows.size(); ++k) CHECK(serial[i].rows[k].cp == added[i].rows[k].cp);
  }
  for (int jobs : {2, 3, 0}) {
    options.jobs = jobs;
    std::vector<double> ids;
    std::vector<std::string> texts;
    pk::SimulationSink sink;
    sink.render = [](const pk::SubjectSimulation& s) { return pk::FormatNumber(s.rows.back().cp); };
    sink.consume = [&](pk::SubjectSimulation&& s, std::string&& t) {
      ids.push_back(s.id);
      texts.push_back(t);
    };
    pk::SimulateEach(*model, data, {{"V", 10}}, options, sink);
    REQUIRE(ids.size() == 40);
    for (size_t i = 0; i < ids.size(); ++i) {
      CHECK(ids[i] == serial[i].id);
      CHECK(texts[i] == pk::FormatNumber(serial[i].rows.back().cp));
    }
  }
}

TEST_CASE("an input error of one subject is thrown after the subjects before it were handed over", "[output][simulate]") {
  std::string text = "ID,TIME,AMT,CMT\n";
  for (int id = 1; id <= 12; ++id) text += std::to_string(id) + ",0,100," + (id == 9 ? "7" : "1") + "\n";
  const pk::Dataset data = pk::ParseDataset(text, "bad.csv");
  const auto model = pk::MakeModel("1cmt_iv");
  for (int jobs : {1, 2}) {
    pk::SimulationOptions options;
    options.jobs = jobs;
    options.output_times = {1};
    std::vector<double> ids;
    pk::SimulationSink sink;
    sink.consume = [&](pk::SubjectSimulation&& s, std::string&&) { ids.push_back(s.id); };
    CHECK_THROWS_AS(pk::SimulateEach(*model, data, {{"CL", 1}, {"V", 10}}, options, sink), pk::InputError);
    CHECK(ids == std::vector<double>{1, 2, 3, 4, 5, 6, 7, 8});
  }
}

TEST_CASE("a regimen simulated under every ID of an estimates table takes each ID's values", "[output][simulate]") {
  pk::Regimen regimen;
  pk::Dose dose;
  dose.amount = 100;
  regimen.doses.push_back(dose);
  regimen.times = {1, 2};
  const pk::Dataset one = pk::RegimenToDataset(regimen);
  const std::vector<pk::SubjectEstimates> table = {{7, {{"CL", 1}, {"V", 10}}}, {3, {{"CL", 2}, {"V", 10}}}};
  std::vector<pk::SubjectSimulation> out;
  pk::SimulationSink sink;
  sink.consume = [&](pk::SubjectSimulation&& s, std::string&&) { out.push_back(std::move(s)); };
  pk::SimulationOptions options;
  options.jobs = 2;
  pk::SimulateEachWithEstimates(*pk::MakeModel("1cmt_iv"), one, table, {}, pk::EstimatesMatch::kEveryId, options,
                                "t.csv", sink);
  REQUIRE(out.size() == 2);
  CHECK(out[0].id == 7);
  CHECK(out[1].id == 3);
  CHECK(out[0].rows[0].cp == Approx(10 * std::exp(-0.1)).epsilon(1e-14));
  CHECK(out[1].rows[0].cp == Approx(10 * std::exp(-0.2)).epsilon(1e-14));
}

TEST_CASE("a plot of values equal to the last digits has an axis (it looped until memory ran out)", "[output][plot]") {
  for (double level : {5.0, 0.0, 1e-300, -2e12}) {
    pk::PlotSeries s;
    s.label = "flat";
    s.x = {1, 2, 4, 8};
    s.y = {level, std::nextafter(level, 1e308), level, std::nextafter(level, -1e308)};
    const std::string svg = pk::RenderSvg({s}, pk::PlotOptions());
    CHECK(svg.find("<svg") != std::string::npos);
    CHECK(svg.size() < 100000);
  }
}

TEST_CASE("the simulation CSV's TIME is each row's own, whatever the subjects before it wrote", "[output]") {
  // Rows' TIME texts are kept between subjects (a shared grid); subjects whose grids differ, partly or
  // in length, and −0 against 0, must still write their own times.
  const auto model = pk::MakeModel("1cmt_iv");
  const char* grids[] = {"0,0.5,1,2", "0,0.5,1.5,2,3", "-0,0.5", "0,0.5,1,2"};
  for (const char* grid : grids) {
    std::string csv = "ID,TIME,AMT,EVID\n";
    std::stringstream times(grid);
    for (std::string t; std::getline(times, t, ',');) csv += "1," + t + ",0,2\n";
    const auto data = pk::ParseDataset(csv, "grid.csv");
    const pk::SubjectSimulation sim = pk::SimulateSubject(*model, data, 0, {});
    REQUIRE(sim.ok);
    std::string all, chosen;
    pk::AppendSimulationCsv(sim, &all);
    pk::SimulationColumns(*model, "TIME").Append(sim, &chosen);
    std::string want_all, want_chosen;
    for (const pk::SimulatedRecord& r : sim.rows) {
      want_chosen += pk::FormatNumber(r.time) + "\n";
      want_all += "1," + pk::FormatNumber(r.time) + ",2," + pk::FormatNumber(r.cp) + ",0\n";
    }
    INFO(grid);
    CHECK(chosen == want_chosen);
    CHECK(all == want_all);
  }
}

TEST_CASE("pksim's --columns: the chosen columns of the full CSV, in the chosen order", "[output]") {
  const auto data = pk::ParseDataset("ID,TIME,AMT,DV\n7,0,100,.\n7,0.5,0,1\n7,2,0,1\n7,7.25,0,1\n", "cols.csv");
  const auto model = pk::MakeModel("2cmt_oral");
  const pk::SubjectSimulation sim = pk::SimulateSubject(*model, data, 0, {});
  REQUIRE(sim.ok);
  std::string all, chosen;
  pk::AppendSimulationCsv(sim, &all);
  const pk::SimulationColumns columns(*model, "a3, time,ID,cp");
  CHECK(columns.Header() == "A3,TIME,ID,CP\n");
  columns.Append(sim, &chosen);
  // The same fields, picked from the full rows (ID,TIME,EVID,CP,A1,A2,A3).
  std::istringstream a(all), c(chosen);
  std::string line, got;
  int rows = 0;
  while (std::getline(a, line)) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
    REQUIRE(f.size() == 7);
    REQUIRE(std::getline(c, got));
    CHECK(got == f[6] + "," + f[1] + "," + f[0] + "," + f[3]);
    ++rows;
  }
  CHECK(rows == 3);
  CHECK_THROWS_WITH(pk::SimulationColumns(*model, "ID,CC"), Catch::Contains("no column CC (did you mean CP?)"));
  CHECK_THROWS_WITH(pk::SimulationColumns(*model, "ID,TIME,id"), Catch::Contains("ID is named twice"));
  CHECK_THROWS_WITH(pk::SimulationColumns(*model, "ID,"), Catch::Contains("an empty name"));
}

TEST_CASE("a band and a line of one point are drawn with a width (a VPC of one bin)", "[output]") {
  pk::PlotSeries band{"sim. 50th", {4.0}, {1.0}}, line{"obs. 50th", {4.0}, {2.0}};
  band.upper = {3.0};
  band.colour = "#1f77b4";
  line.colour = "#111111";
  pk::PlotSeries points{"observed", {1.0, 8.0}, {0.5, 3.5}, true};
  const std::string svg = pk::RenderSvg({band, points, line}, pk::PlotOptions());
  // The band: a box 24 px wide from 1 to 3, where a polygon through one x had no area.
  const size_t box = svg.find("<rect fill=\"#1f77b4\" fill-opacity=\"0.3\"");
  REQUIRE(box != std::string::npos);
  CHECK(svg.find("width=\"24\"", box) < svg.find("/>", box));
  CHECK(svg.find("<polygon") == std::string::npos);
  // The line: a level through its point, two coordinates 24 px apart at one height.
  const size_t at = svg.find("<polyline fill=\"none\" stroke=\"#111111\"");
  REQUIRE(at != std::string::npos);
  const size_t open = svg.find("points=\"", at) + 8, close = svg.find('"', open);
  std::istringstream coordinates(svg.substr(open, close - open));
  double x0, y0, x1, y1;
  char comma;
  REQUIRE(static_cast<bool>(coordinates >> x0 >> comma >> y0 >> x1 >> comma >> y1));
  CHECK(x1 - x0 == Approx(24));
  CHECK(y0 == y1);
  // Two points or more are drawn as before: a polygon for the band.
  band.x = {4.0, 6.0}, band.y = {1.0, 1.5}, band.upper = {3.0, 3.5};
  CHECK(pk::RenderSvg({band}, pk::PlotOptions()).find("<polygon") != std::string::npos);
}
