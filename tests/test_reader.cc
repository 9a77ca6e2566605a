// The dataset reader: NM-TRAN defaults and every error path, each naming file, line and column.
#include <cmath>
#include <cctype>
#include <clocale>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>

#include <unistd.h>

#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/estimates.h"
#include "pk/output.h"
#include "pk/simulate.h"
#include "test_util.h"

namespace {

// Parses `csv` expecting an InputError at (line, column) whose message contains `text`.
void ExpectError(const std::string& csv, int line, int column, const std::string& text) {
  INFO(csv);
  try {
    pk::ParseDataset(csv, "bad.csv");
    FAIL("no error raised");
  } catch (const pk::InputError& e) {
    CHECK(e.file() == "bad.csv");
    CHECK(e.line() == line);
    CHECK(e.column() == column);
    CHECK_THAT(e.what(), Catch::Contains(text));
    CHECK_THAT(e.what(), Catch::StartsWith(line > 0 ? "bad.csv:" + std::to_string(line) + ":" : "bad.csv: "));
  }
}

void ExpectSimulationError(const std::string& model, const std::string& csv, const pk::ParameterValues& values,
                           int line, int column, const std::string& text) {
  INFO(csv);
  const pk::Dataset data = pk::ParseDataset(csv, "bad.csv");
  try {
    pk::Simulate(*pk::MakeModel(model), data, values);
    FAIL("no error raised");
  } catch (const pk::InputError& e) {
    CHECK(e.line() == line);
    CHECK(e.column() == column);
    CHECK_THAT(e.what(), Catch::Contains(text));
  }
}

}  // namespace

TEST_CASE("optional columns take NM-TRAN defaults", "[reader]") {
  const pk::Dataset d = pk::ParseDataset("time,amt,dv,wt\n0,100,.,70\n1,0,5.5,70\n2,0,.,71\n", "x.csv");
  REQUIRE(d.subjects.size() == 1);
  const auto& r = d.subjects[0].records;
  REQUIRE(r.size() == 3);
  CHECK(r[0].evid == pk::Evid::kDose);
  CHECK(r[0].mdv == 1);
  CHECK(r[1].evid == pk::Evid::kObservation);
  CHECK(r[1].IsSample());
  CHECK(r[1].dv == 5.5);
  CHECK(!r[2].IsSample());  // DV missing: not a sample
  CHECK(r[2].mdv == 1);
  CHECK(d.extra_columns == std::vector<std::string>{"WT"});
  CHECK(r[2].extra[0] == 71);
  CHECK(r[0].cmt == 0);
  CHECK(d.ColumnNumber("dv") == 3);
}

TEST_CASE("subjects split on ID changes, comments, blank lines, quotes and CRLF are handled", "[reader]") {
  const pk::Dataset d = pk::ParseDataset(
      "# a comment\r\n\"ID\",TIME,AMT,EVID,MDV\r\n1,0,10,1,1\r\n\r\n1,1,0,0,0\r\n2,0,10,1,1\r\n1,0,5,1,1\r\n", "x.csv");
  REQUIRE(d.subjects.size() == 3);
  CHECK(d.subjects[0].records.size() == 2);
  CHECK(d.subjects[0].records[1].line == 5);
  CHECK(d.subjects[2].id == 1);
}

TEST_CASE("reader errors name file, line and column", "[reader]") {
  ExpectError("ID,TIME,AMT\n1,0,abc\n", 2, 3, "'abc' is not a number");
  ExpectError("ID,AMT\n1,0\n", 1, 0, "missing required column TIME");
  ExpectError("ID,TIME,AMT\n1,0,-5\n", 2, 3, "AMT must not be negative");
  ExpectError("ID,TIME,AMT,EVID\n1,5,0,0\n1,3,0,0\n", 3, 2, "TIME decreases within ID 1 (3 after 5)");
  ExpectError("ID;TIME;AMT\n1;0;100\n", 1, 0, "this header seems to use ';'");
  ExpectError("ID|TIME|AMT\n1|0|100\n", 1, 0, "this header seems to use '|'");
  ExpectError("ID,TIME,AMT,II,ADDL\n1,0,10,0,3\n", 2, 4, "ADDL>0 needs II>0");
  ExpectError("ID,TIME,AMT\n1,0\n", 2, 3, "expected 3 fields");
  ExpectError("ID,TIME,AMT\n1,0,1,2\n", 2, 4, "expected 3 fields");
  ExpectError("ID,TIME,time\n1,0,1\n", 1, 3, "duplicate column TIME (also column 2)");
  // The first column, left to right, whose name an earlier one has: A at 6, not B at 7 (B sorts first).
  ExpectError("ID,TIME,B,A,DV,a,b\n1,0,1,2,3,4,5\n", 1, 6, "duplicate column A (also column 4)");
  ExpectError("ID,TIME,X,x,X\n1,0,1,2,3\n", 1, 4, "duplicate column X (also column 3)");
  ExpectError("ID,TIME,,ID\n1,0,1,2\n", 1, 3, "empty column name");  // the empty name comes first
  ExpectError("ID,TIME,EVID\n1,0,7\n", 2, 3, "EVID must be 0, 1, 2, 3 or 4");
  ExpectError("ID,TIME,AMT,SS,II\n1,0,10,3,12\n", 2, 4, "SS must be 0, 1 or 2");
  ExpectError("ID,TIME,AMT,RATE\n1,0,10,-3\n", 2, 4, "RATE must be positive, 0, -1");
  ExpectError("ID,TIME,AMT,SS\n1,0,10,1\n", 2, 0, "a steady-state dose needs II>0");
  ExpectError("ID,TIME,AMT,SS,II\n1,0,10,1,.\n", 2, 5, "a steady-state dose needs II>0");
  ExpectError("ID,TIME,MDV\n1,0,2\n", 2, 3, "MDV must be 0 or 1");
  ExpectError("ID,TIME,AMT,ADDL,II\n1,0,10,1.5,12\n", 2, 4, "ADDL must be a whole number");
  ExpectError("ID,TIME,AMT,EVID\n1,0,10,0\n", 2, 3, "AMT must be 0 on a record that is not a dose");
  ExpectError("ID,TIME,AMT,EVID\n1,0,0,1\n", 2, 3, "AMT must be positive on a dose record");
  ExpectError("ID,TIME,CMT\n1,0,-1\n", 2, 3, "negative CMT");
  ExpectError("ID,TIME,II\n1,0,-1\n", 2, 3, "II must not be negative");
  ExpectError("ID,TIME,AMT,RATE,SS,II,ADDL\n1,0,0,5,1,0,2\n", 2, 7, "ADDL must be 0 on a steady-state constant infusion");
  ExpectError("", 0, 0, "no header line");
  ExpectError("ID,TIME\n", 1, 0, "no data records");
  ExpectError("ID,,TIME\n1,2,3\n", 1, 2, "empty column name");
  ExpectError("ID,TIME\n1,1e999\n", 2, 2, "is not a number");
  ExpectError("ID,TIME\n1,.\n", 2, 2, "TIME is missing");
}

namespace {
std::vector<double> Times(const pk::Subject& s) {
  std::vector<double> t;
  for (const pk::Record& r : s.records) t.push_back(r.time);
  return t;
}
}  // namespace

TEST_CASE("dates and clock times become hours since each subject's first record, as NM-TRAN translates them",
          "[reader][dates]") {
  {  // NM-TRAN's own example (help for the DATE data item): 9:15 to 14:40 is 5.42 h, to 8:30 the next day 23.25 h.
    const pk::Dataset d = pk::ParseDataset(
        "ID,DATE,TIME,AMT,DV\n1,10-1-86,9:15,100,.\n1,10-1-86,14:40,0,5\n1,10-2-86,8:30,0,2\n"
        "2,10-12,8,100,.\n2,10-14,10,0,1\n",
        "d.csv");
    CHECK(d.relative_times);
    REQUIRE(d.subjects.size() == 2);
    CHECK(Times(d.subjects[0]) == std::vector<double>{0, 14 + 40.0 / 60 - (9 + 15.0 / 60), 23.25});
    CHECK(Times(d.subjects[1]) == std::vector<double>{0, 50});
    CHECK(d.ExtraColumn("DATE") < 0);  // read with TIME, not kept as a number
    CHECK(d.ColumnNumber("DATE") == 2);
  }
  {  // Clock times without dates (the TIME help's example); decimal hours beside them, seconds, negative times.
    const pk::Dataset d =
        pk::ParseDataset("ID,TIME,DV\n1,8:00,1\n1,14:45,1\n1,14.75,1\n1,15:00:36,1\n2,-1:30,1\n2,0:15,1\n", "c.csv");
    CHECK(d.relative_times);
    CHECK(Times(d.subjects[0]) == std::vector<double>{0, 6.75, 6.75, 7.01});
    CHECK(Times(d.subjects[1]) == std::vector<double>{0, 1.75});
  }
  {  // The four labels read the same dates in their own orders; years of two and four digits.
    const char* files[] = {"ID,DATE,TIME\n1,12/31/99,23:00\n1,1/1/2000,1:00\n1,3/1/00,1:00\n",
                           "ID,DAT1,TIME\n1,31.12.1999,23:00\n1,1.1.00,1:00\n1,1.3.2000,1:00\n",
                           "ID,DAT2,TIME\n1,99-12-31,23:00\n1,2000-01-01,1:00\n1,00-03-01,1:00\n",
                           "ID,DAT3,TIME\n1,1999/31/12,23:00\n1,0/1/1,1:00\n1,2000/1/3,1:00\n"};
    // 1999-12-31 23:00 -> 2000-01-01 01:00 is 2 h; to 2000-03-01 (a leap year: 31 + 29 days later) 1442 h.
    for (const char* f : files) {
      INFO(f);
      CHECK(Times(pk::ParseDataset(f, "d.csv").subjects[0]) == std::vector<double>{0, 2, 2 + 24 * 60});
    }
  }
  {  // Years up to 50 are 20xx, above 50 19xx (NM-TRAN's LAST20 = 50); 2021 is not a leap year.
    const double two_digit = pk::ParseDataset("ID,DATE,TIME\n1,1/1/51,0\n1,1/1/50,0\n", "d.csv").subjects[0].records[1].time;
    CHECK(two_digit == 24.0 * (365 * 99 + 25));  // 1951 to 2050: 99 years, 25 leap days (1952, 1956, ..., 2048)
    CHECK(pk::ParseDataset("ID,DATE,TIME\n1,1/1/1951,0\n1,1/1/2050,0\n", "d.csv").subjects[0].records[1].time == two_digit);
    CHECK(Times(pk::ParseDataset("ID,DATE,TIME\n1,2/28/2021,0\n1,3/1/2021,0\n", "d.csv").subjects[0])[1] == 24);
    CHECK(Times(pk::ParseDataset("ID,DATE,TIME\n1,2/28/2024,0\n1,3/1/2024,0\n", "d.csv").subjects[0])[1] == 48);
  }
  {  // One component is a day number (0 or negative too); a first record that is a sample is still time 0.
    const pk::Dataset d = pk::ParseDataset("ID,DATE,TIME,AMT,DV\n1,-1,20:00,0,0.1\n1,0,8,100,.\n1,1,8,0,3\n", "d.csv");
    CHECK(Times(d.subjects[0]) == std::vector<double>{0, 12, 36});
  }
  {  // Plain numeric times without dates are left as they are.
    const pk::Dataset d = pk::ParseDataset("ID,TIME,DV\n1,2,1\n1,3.5,1\n", "n.csv");
    CHECK_FALSE(d.relative_times);
    CHECK(Times(d.subjects[0]) == std::vector<double>{2, 3.5});
  }
}

TEST_CASE("bad dates and clock times name the line and column", "[reader][dates]") {
  ExpectError("ID,TIME,DV\n1,8:00,1\n1,8:75,1\n", 3, 2, "column TIME: '8:75' is not a clock time (hh:mm)");
  ExpectError("ID,TIME,DV\n1,8:00,1\n1,8h30,1\n", 3, 2, "'8h30' is not a clock time");
  ExpectError("ID,DATE,TIME\n1,13/1/2020,8\n", 2, 2, "column DATE: '13/1/2020': month 13 is not 1 to 12 (month/day/year)");
  ExpectError("ID,DAT1,TIME\n1,30/2/2020,8\n", 2, 2, "day 30 is not in month 2 (day/month/year)");
  ExpectError("ID,DATE,TIME\n1,2/29,8\n", 2, 2, "February 29 needs a year");
  ExpectError("ID,DATE,TIME\n1,1/2/3/4,8\n", 2, 2, "not a date (month/day/year)");
  ExpectError("ID,DATE,TIME\n1,1.5,8\n", 2, 2, "a single date component is a whole day number");
  ExpectError("ID,DATE,TIME\n1,.,8\n", 2, 2, "DATE is missing");
  ExpectError("ID,date,TIME,DAT2\n", 1, 4, "a second date column DAT2 (also DATE, column 2)");
  ExpectError("ID,TIME,DV\n1,23:00,1\n1,01:00,1\n", 3, 2,
              "TIME decreases within ID 1 (-22 after 0) on a record that is not a reset (EVID 3 or 4); clock times "
              "cannot pass midnight without a date column");
}

TEST_CASE("model-dependent errors are raised when a dataset meets a model", "[reader]") {
  ExpectSimulationError("1cmt_iv", "ID,TIME,AMT,CMT\n1,0,100,2\n", {}, 2, 4, "CMT 2 is out of range for model 1cmt_iv");
  ExpectSimulationError("1cmt_iv", "ID,TIME,AMT,RATE\n1,0,100,-1\n", {}, 2, 4, "needs R1 > 0, but no value is given");
  ExpectSimulationError("1cmt_iv", "ID,TIME,AMT,RATE\n1,0,100,-2\n", {}, 2, 4, "needs D1 > 0");
  ExpectSimulationError("1cmt_iv", "ID,TIME,AMT,F1\n1,0,100,-0.5\n", {}, 2, 4, "needs F1 >= 0, but it is -0.5");
  try {
    pk::Simulate(*pk::MakeModel("1cmt_iv"), pk::ParseDataset("TIME,AMT\n0,1\n", "x.csv"), {{"KA", 1}});
    FAIL("no error raised");
  } catch (const pk::InputError& e) {
    CHECK_THAT(e.what(), Catch::Contains("unknown parameter 'KA'"));
  }
  CHECK_THROWS_WITH(pk::MakeModel("4cmt"), Catch::Contains("unknown model '4cmt'"));
}

TEST_CASE("ADDL doses after the last record are dropped, absurd counts are errors, not exhaustion", "[reader]") {
  // A billion implied doses every 24 h: only those up to the last record (48 h) exist.
  const pk::ParameterValues values = {{"KA", 1.2}, {"CL", 3}, {"V", 30}};
  const auto model = pk::MakeModel("1cmt_oral");
  const auto huge = pk::Simulate(*model, pk::ParseDataset("ID,TIME,AMT,II,ADDL,DV\n1,0,100,24,1000000000,.\n1,49,0,0,0,1\n", "x.csv"), values);
  const auto two = pk::Simulate(*model, pk::ParseDataset("ID,TIME,AMT,II,ADDL,DV\n1,0,100,24,2,.\n1,49,0,0,0,1\n", "x.csv"), values);
  REQUIRE(huge.at(0).ok);
  REQUIRE(two.at(0).ok);
  CHECK(huge[0].rows.back().cp == two[0].rows.back().cp);
  CHECK(huge[0].rows.back().cp > 0);
  // A billion doses inside the observed span is not a regimen.
  ExpectSimulationError("1cmt_oral", "ID,TIME,AMT,II,ADDL,DV\n1,0,100,1e-9,1000000000,.\n1,1,0,0,0,1\n", values, 2, 5,
                        "implies more than 100000 doses before the subject's last record");
  // A steady-state lag spanning 1e6 intervals is reported for the subject, not allocated.
  const auto lagged = pk::Simulate(
      *model, pk::ParseDataset("ID,TIME,AMT,II,SS,ALAG1,DV\n1,0,100,1e-6,1,1,.\n1,1,0,0,0,1,1\n", "x.csv"), values);
  REQUIRE(lagged.size() == 1);
  CHECK(!lagged[0].ok);
  CHECK_THAT(lagged[0].message, Catch::Contains("spans more than 100000 dosing intervals"));
}

TEST_CASE("a file that cannot be opened is an input error naming it", "[reader]") {
  CHECK_THROWS_WITH(pk::ReadDataset("/nonexistent/data.csv"), Catch::Contains("/nonexistent/data.csv: cannot open"));
}

// Parses an estimates table for 1cmt_oral expecting an InputError at (line, column) whose message contains `text`.
void ExpectEstimatesError(const std::string& csv, int line, int column, const std::string& text) {
  INFO(csv);
  try {
    pk::ParseEstimates(csv, "est.csv", *pk::MakeModel("1cmt_oral"));
    FAIL("no error raised");
  } catch (const pk::InputError& e) {
    CHECK(e.file() == "est.csv");
    CHECK(e.line() == line);
    CHECK(e.column() == column);
    CHECK_THAT(e.what(), Catch::Contains(text));
  }
}

TEST_CASE("estimates tables: subjects in order, canonical names, other columns ignored", "[reader][estimates]") {
  const auto model = pk::MakeModel("1cmt_oral");
  // pkfit's columns, a quoted field with a comma in an ignored column, a comment, lower-case names and CRLF.
  const std::string csv =
      "ID,PARAMETER,ESTIMATE,SE,RSE_PCT\r\n"
      "# fitted by pkfit\r\n"
      "2,ka,1.5,0.1,6.7\r\n"
      "2,CL,3,\"0,2\",\r\n"
      "\r\n"
      "1,V,30,,\r\n"
      "2,sigma_add,0.4,,\r\n"
      "1,Sigma_Log,0.2,,\r\n";
  const auto table = pk::ParseEstimates(csv, "est.csv", *model);
  REQUIRE(table.size() == 2);
  CHECK(table[0].first == 2);
  CHECK(table[0].second == pk::ParameterValues{{"KA", 1.5}, {"CL", 3}, {"SIGMA_ADD", 0.4}});
  CHECK(table[1].first == 1);
  CHECK(table[1].second == pk::ParameterValues{{"V", 30}, {"SIGMA_LOG", 0.2}});
  // Columns in another order, found by name.
  const auto swapped = pk::ParseEstimates("ESTIMATE,\"ID\",PARAMETER\n0.8,7,F1\n", "est.csv", *model);
  REQUIRE(swapped.size() == 1);
  CHECK(swapped[0].first == 7);
  CHECK(swapped[0].second == pk::ParameterValues{{"F1", 0.8}});
}

TEST_CASE("estimates table errors name file, line and column (the field's number)", "[reader][estimates]") {
  ExpectEstimatesError("", 0, 0, "no header line");
  ExpectEstimatesError("ID,PARAMETER\n1,CL\n", 1, 0, "needs the columns ID, PARAMETER and ESTIMATE");
  ExpectEstimatesError("ID,PARAMETER,ESTIMATE,id\n", 1, 4, "duplicate column ID (also column 1)");
  ExpectEstimatesError("ID,PARAMETER,ESTIMATE\n", 1, 0, "has no rows");
  ExpectEstimatesError("ID,PARAMETER,ESTIMATE\n1,CL\n", 2, 0, "expected 3 fields as in the header, found 2");
  ExpectEstimatesError("ID,PARAMETER,ESTIMATE\nx,CL,1\n", 2, 1, "ID: 'x' is not a number");
  ExpectEstimatesError("ID,PARAMETER,ESTIMATE\n1,KA,1\n1,CLX,2\n", 3, 2, "'CLX' is not a parameter of model 1cmt_oral");
  ExpectEstimatesError("ID,PARAMETER,ESTIMATE\n1,CL,inf\n", 2, 3, "ESTIMATE: 'inf' is not a number");
  ExpectEstimatesError("ID,SE,PARAMETER,ESTIMATE\n1,,CL,2\n1,,cl,3\n", 3, 3, "cl is given twice for ID 1 (also line 2)");
  ExpectEstimatesError("ID,PARAMETER,ESTIMATE\n1,SIGMA_PROP,2\n1,sigma_prop,3\n", 3, 2, "sigma_prop is given twice for ID 1");
  ExpectEstimatesError("ID,PARAMETER,ESTIMATE\n1,SIGMA_EXP,2\n", 2, 2, "'SIGMA_EXP' is not a parameter of model 1cmt_oral");
  // The same parameter for two subjects is not a repeat.
  CHECK(pk::ParseEstimates("ID,PARAMETER,ESTIMATE\n1,CL,2\n2,CL,3\n", "est.csv", *pk::MakeModel("1cmt_oral")).size() == 2);
}

TEST_CASE("an estimates file that cannot be opened is an input error naming it", "[reader][estimates]") {
  try {
    pk::ReadEstimates("/nonexistent/estimates.csv", *pk::MakeModel("1cmt_oral"));
    FAIL("no error raised");
  } catch (const pk::InputError& e) {
    CHECK(e.file() == "/nonexistent/estimates.csv");
    CHECK_THAT(e.what(), Catch::Contains("cannot open the file"));
  }
}

TEST_CASE("numerical failure of one subject is reported, not thrown", "[simulate]") {
  // V = 0 makes CL/V infinite: the propagator reports it for that subject only.
  const pk::Dataset d = pk::ParseDataset("ID,TIME,AMT,EVID,V\n1,0,100,1,0\n1,1,0,0,0\n2,0,100,1,10\n2,1,0,0,10\n", "x.csv");
  const auto sims = pk::Simulate(*pk::MakeModel("1cmt_iv"), d, {});
  REQUIRE(sims.size() == 2);
  CHECK(!sims[0].ok);
  CHECK(!sims[0].message.empty());
  CHECK(sims[1].ok);
}

namespace {

// The records kept under `filter`: their lines.
std::vector<int> KeptLines(const std::string& csv, const pk::DatasetFilter& filter) {
  std::vector<int> lines;
  for (const pk::Subject& s : pk::ParseDataset(csv, "f.csv", filter).subjects) {
    for (const pk::Record& r : s.records) lines.push_back(r.line);
  }
  return lines;
}

std::string FilterError(const std::string& csv, const pk::DatasetFilter& filter) {
  try {
    pk::ParseDataset(csv, "f.csv", filter);
  } catch (const pk::InputError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST_CASE("IGNORE= and ACCEPT= drop records as NM-TRAN's $DATA options do", "[reader][filter]") {
  // A comment column C (NONMEM's convention), a repeated header, a DVID and a bad value on a dropped line.
  const std::string csv =
      "C,ID,TIME,AMT,DV,DVID\n"  // 1
      ".,1,0,100,.,.\n"           // 2
      ".,1,1,0,5.5,1\n"           // 3
      "C,1,2,0,oops,1\n"          // 4: commented out, with a value that is no number
      ".,1,2,0,4.0,2\n"           // 5
      ".,2,0,100,.,.\n"           // 6
      "@ repeated header\n"       // 7
      ".,2,1.0,0,6.1,1\n"         // 8
      ".,2,24,0,0.9,1\n";         // 9
  pk::DatasetFilter f;
  f.ignore_character = 'C';
  CHECK(FilterError(csv, f).find("f.csv:7:") == 0);  // '@' lines are read without IGNORE=@
  f.ignore_character = 0;
  CHECK(FilterError(csv, f).find("f.csv:4:5: column DV: 'oops' is not a number") == 0);  // without a filter
  // IGNORE=@ drops line 7 and, 'C' being a letter, the commented line 4 too, as NM-TRAN does.
  f.ignore_character = '@';
  CHECK(KeptLines(csv, f) == std::vector<int>{2, 3, 5, 6, 8, 9});
  std::string no_at = csv;
  no_at.erase(no_at.find("@ repeated header\n"), 18);
  f.ignore_character = 'C';
  CHECK(KeptLines(no_at, f) == std::vector<int>{2, 3, 5, 6, 7, 8});
  std::string no_c = csv;
  no_c.erase(no_c.find("C,1,2,0,oops,1\n"), 15);
  f.ignore_character = '@';
  CHECK(KeptLines(no_c, f) == std::vector<int>{2, 3, 4, 5, 7, 8});
  // Conditions: IGNORE drops a record meeting any; numbers compare as numbers, a missing field as 0.
  f.ignore_character = 'C';
  f.ignore = {"DVID.EQ.2"};
  CHECK(KeptLines(no_at, f) == std::vector<int>{2, 3, 6, 7, 8});  // line 5 is the DVID 2 sample
  f.ignore = {"(DVID==2, TIME>=24)"};
  CHECK(KeptLines(no_at, f) == std::vector<int>{2, 3, 6, 7});
  f.ignore = {"TIME.EQ.1"};  // 1.0 equals 1
  CHECK(KeptLines(no_at, f) == std::vector<int>{2, 5, 6, 8});
  f.ignore = {"DVID.EQ.0"};  // '.' counts as 0: the dose records go
  CHECK(KeptLines(no_at, f) == std::vector<int>{3, 5, 7, 8});
  f.ignore = {"DVID.NEN.1"};
  CHECK(KeptLines(no_at, f) == std::vector<int>{3, 7, 8});
  // ACCEPT keeps only records meeting one; several options add up.
  f.ignore.clear();
  f.accept = {"ID.EQ.2", "AMT.GT.0"};
  CHECK(KeptLines(no_at, f) == std::vector<int>{2, 6, 7, 8});
  f.accept = {"ID /= 1"};
  CHECK(KeptLines(no_at, f) == std::vector<int>{6, 7, 8});
  // Text compares as text when either side is not a number; an ordering does not hold for text.
  const std::string text = "ID,TIME,DV,FLAG\n1,0,1,0\n1,1,2,BLQ\n1,2,3,1\n";
  pk::DatasetFilter t;
  t.ignore = {"FLAG.EQ.BLQ"};
  CHECK(KeptLines(text, t) == std::vector<int>{2, 4});
  t.ignore = {"FLAG.EQ.'BLQ'"};
  CHECK(KeptLines(text, t) == std::vector<int>{2, 4});
  t.ignore = {"FLAG.GT.0"};
  CHECK(FilterError(text, t) == "f.csv:3:4: column FLAG: 'BLQ' is not a number");
}

TEST_CASE("IGNORE= and ACCEPT= errors name what is wrong", "[reader][filter]") {
  const std::string csv = "ID,TIME,DV\n1,0,1\n1,1,2\n";
  pk::DatasetFilter f;
  f.ignore = {"XX.EQ.1"};
  CHECK(FilterError(csv, f) == "f.csv: IGNORE=(XX.EQ.1): no column XX in the header (it has: ID,TIME,DV)");
  f.ignore = {"TIME~1"};
  CHECK_THAT(FilterError(csv, f), Catch::StartsWith("f.csv: IGNORE=(TIME~1): expected LABEL OP VALUE"));
  f.ignore = {"TIME.GT.abc"};
  CHECK(FilterError(csv, f) == "f.csv: IGNORE=(TIME.GT.abc): 'abc' is not a number to order by");
  f.ignore = {"TIME.GT."};
  CHECK(FilterError(csv, f) == "f.csv: IGNORE=(TIME.GT.): no value to compare with");
  f.ignore = {"(TIME.GT.1,)"};
  CHECK(FilterError(csv, f) == "f.csv: IGNORE=(): an empty condition");
  f.accept = {"ID.EQ.1"};
  CHECK_THAT(FilterError(csv, f), Catch::Contains("cannot be combined"));
  f.ignore.clear();
  f.accept = {"ID.EQ.7"};
  CHECK(FilterError(csv, f) == "f.csv:1: the file has no data records");
}

TEST_CASE("text and files are split into the same lines (BOM, CRLF, blank lines, no final newline)", "[reader]") {
  const std::string texts[] = {
      "ID,TIME,DV\n1,0,1\n1,1,2\n",
      "\xEF\xBB\xBFID,TIME,DV\r\n1,0,1\r\n\r\n1,1,2",
      "# comment\n\nID,TIME,DV\n1,0,1\n\n\n1,1,2\r\n\n",
  };
  const std::string path = std::string(PK_BINARY_DIR) + "/split_lines.csv";
  for (const std::string& text : texts) {
    INFO(text);
    {
      std::ofstream out(path, std::ios::binary);
      out << text;
    }
    const pk::Dataset from_text = pk::ParseDataset(text, path), from_file = pk::ReadDataset(path);
    REQUIRE(from_text.columns == from_file.columns);
    REQUIRE(from_text.columns == std::vector<std::string>{"ID", "TIME", "DV"});
    REQUIRE(from_text.NumRecords() == 2);
    REQUIRE(from_file.NumRecords() == 2);
    for (int k = 0; k < 2; ++k) {
      const pk::Record &a = from_text.subjects[0].records[k], &b = from_file.subjects[0].records[k];
      CHECK(a.line == b.line);
      CHECK(a.time == b.time);
      CHECK(a.dv == b.dv);
    }
  }
  std::remove(path.c_str());
}

TEST_CASE("bytes a text line cannot hold are refused with their place", "[reader][trust]") {
  const auto error_of = [](const std::string& text) {
    try {
      pk::ParseDataset(text, "bad.csv");
    } catch (const pk::InputError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  // A NUL inside DV would end the line early and read "2.\0 84" as 2.
  CHECK_THAT(error_of(std::string("ID,TIME,DV\n1,0,2.\0 84\n", 23)), Catch::StartsWith("bad.csv:2:3: a NUL byte"));
  // CR-only line ends would make the whole file one header line.
  CHECK_THAT(error_of("ID,TIME,DV\r1,0,1\r1,1,2\r"), Catch::StartsWith("bad.csv:1:3: a carriage return (CR)"));
  CHECK(error_of("ID,TIME,DV\r\n1,0,1\r\n") == "no error");  // CRLF is fine
  CHECK_THAT(error_of("ID,TIME,DV\n1,0,0x1p-2\n"), Catch::Contains("is not a number (write numbers in decimal)"));
  CHECK_THAT(error_of("ID,TIME,DV\n1,0,inf\n"), Catch::Contains("'inf' is not a number"));
  CHECK_THAT(error_of("ID,TIME,DV\n1,0,\x01\xff\n"), Catch::Contains("'\\x01\\xFF' is not a number"));
  CHECK_THAT(error_of("ID,TIME,DV\n2.5,0,1\n"), Catch::StartsWith("bad.csv:2:1: ID must be a whole number"));
  CHECK_THAT(error_of("ID,TIME,DV\n1e300,0,1\n"), Catch::StartsWith("bad.csv:2:1: ID must be a whole number"));
  CHECK_THAT(error_of("ID,TIME,DV\n1,1e300,1\n"), Catch::StartsWith("bad.csv:2:2: TIME 1e+300 is beyond"));
  try {
    pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets");
    FAIL("a directory was read");
  } catch (const pk::InputError& e) {
    CHECK_THAT(e.what(), Catch::EndsWith("datasets: is a directory, not a data file"));
  }
  pk::DatasetFilter unbalanced;
  unbalanced.ignore = {"(ID.GT.1"};
  CHECK_THROWS_WITH(pk::ParseDataset("ID,TIME,DV\n1,0,1\n", "f.csv", unbalanced), Catch::Contains("unbalanced parentheses"));
}

TEST_CASE("numbers are read and written the same under a comma-decimal locale", "[reader][locale]") {
  // tests/cli/test_locale.sh runs this with PK_TEST_COMMA_LOCALE set to a locale it generated, whose
  // decimal point is a comma; without it the checks run in the C locale.
  const char* comma = std::getenv("PK_TEST_COMMA_LOCALE");
  if (comma != nullptr) {
    REQUIRE(std::setlocale(LC_ALL, comma) != nullptr);
    REQUIRE(std::string(std::localeconv()->decimal_point) == ",");
  }
  double v = 0;
  CHECK(pk::ParseNumber("0.25", &v));
  CHECK(v == 0.25);
  CHECK(pk::ParseNumber(" +1.5e-3 ", &v));
  CHECK(v == 1.5e-3);
  CHECK_FALSE(pk::ParseNumber("0,25", &v));
  CHECK_FALSE(pk::ParseNumber("0x1p-2", &v));
  CHECK_FALSE(pk::ParseNumber("nan", &v));
  CHECK_FALSE(pk::ParseNumber("+-1", &v));
  CHECK(pk::FormatNumber(0.25) == "0.25");
  CHECK(pk::FormatNumber(0.1 + 0.2) == "0.30000000000000004");
  CHECK(pk::FormatNumber(1e-300) == "1e-300");
  const pk::Dataset d = pk::ParseDataset("ID,TIME,AMT,DV\n1,0,320.5,.\n1,0.25,0,2.84\n", "d.csv");
  CHECK(d.subjects[0].records[0].amt == 320.5);
  CHECK(d.subjects[0].records[1].dv == 2.84);
  if (comma != nullptr) std::setlocale(LC_ALL, "C");
}

TEST_CASE("column names are matched in ASCII upper case under a locale whose toupper maps i to a dotted I",
          "[reader][locale]") {
  // tests/cli/test_locale.sh runs this with PK_TEST_DOTTED_I_LOCALE set to tr_TR.ISO-8859-9, where the C
  // toupper('i') is 0xDD; a name upper-cased through it ("ID" from "id") would match no column.
  const char* turkish = std::getenv("PK_TEST_DOTTED_I_LOCALE");
  const pk_test::LocaleGuard locale(turkish);
  if (turkish != nullptr) {
    REQUIRE(locale.set());
    REQUIRE(std::toupper('i') != 'I');
  }
  const pk::Dataset d = pk::ParseDataset("id,time,amt,dv,mdv,cmt,dvid,clint\n1,0,100,.,1,1,1,2\n1,1,0,4.5,0,1,1,2\n",
                                         "lower.csv");
  REQUIRE(d.subjects.size() == 1);
  CHECK(d.subjects[0].records[0].amt == 100);
  CHECK(d.subjects[0].records[1].dv == 4.5);
  CHECK(d.ExtraColumn("dvid") == d.ExtraColumn("DVID"));
  CHECK(d.ExtraColumn("dvid") >= 0);
  CHECK(d.ExtraColumn("ClInt") >= 0);
  CHECK(d.ExtraColumn("CLIN") == -1);
  const auto model = pk::MakeModel("1cmt_iv");
  pk::SimulationOptions options;
  options.jobs = 1;
  const auto sims = pk::Simulate(*model, d, {{"cl", 2}, {"v", 10}}, options);
  REQUIRE(sims.size() == 1);
  REQUIRE(sims[0].ok);
  CHECK(sims[0].rows.back().cp == Approx(10 * std::exp(-0.2)).epsilon(1e-12));
}

TEST_CASE("an ID that comes back after other IDs is another subject, numbered as an occurrence", "[reader][trust]") {
  const pk::Dataset d =
      pk::ParseDataset("ID,TIME,AMT,DV\n1,0,100,.\n1,1,0,5\n2,0,100,.\n1,0,100,.\n1,2,0,4\n", "rep.csv");
  REQUIRE(d.subjects.size() == 3);
  CHECK(d.subjects[0].occurrence == 1);
  CHECK(d.subjects[1].occurrence == 1);
  CHECK(d.subjects[2].occurrence == 2);
  REQUIRE(d.repeated_ids.size() == 1);
  CHECK(d.repeated_ids[0] == std::make_pair(1.0, 5));
}

TEST_CASE("temporaries of a killed writer are removed, others kept", "[output][trust]") {
  const std::string dir = std::string(PK_BINARY_DIR) + "/stale_tmp";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  // pid 999999999 cannot be running (Linux pids stay below 2^22); ours is.
  for (const std::string& name : std::vector<std::string>{"estimates.csv.tmp.999999999",
                                                          "estimates.csv.tmp." + std::to_string(::getpid()),
                                                          "notes.tmp.txt", "estimates.csv"}) {
    std::ofstream(dir + "/" + name) << "x";
  }
  pk::RemoveStaleTemporaries(dir);
  CHECK_FALSE(std::filesystem::exists(dir + "/estimates.csv.tmp.999999999"));
  CHECK(std::filesystem::exists(dir + "/estimates.csv.tmp." + std::to_string(::getpid())));
  CHECK(std::filesystem::exists(dir + "/notes.tmp.txt"));
  CHECK(std::filesystem::exists(dir + "/estimates.csv"));
  std::filesystem::remove_all(dir);
}

TEST_CASE("a file separated by blanks (spaces or tabs), as NONMEM accepts, reads as its CSV twin", "[reader]") {
  const pk::Dataset csv = pk::ParseDataset("ID,TIME,AMT,DV,WT\n1,0,100,.,70\n1,1.5,0,3.2,70\n2,0,50,.,60\n2,2,0,1e-1,60\n",
                                           "a.csv");
  const pk::Dataset blanks =
      pk::ParseDataset("ID  TIME\tAMT DV WT\n# . h mg mg/L kg\n1 0 100 . 70\n 1\t1.5  0 3.2 70 \n2 0 50 . 60\n2 2 0 1e-1 60\n",
                       "a.txt");
  CHECK(blanks.columns == csv.columns);
  CHECK(blanks.column_units.at("AMT") == "mg");
  REQUIRE(blanks.subjects.size() == csv.subjects.size());
  for (size_t s = 0; s < csv.subjects.size(); ++s) {
    REQUIRE(blanks.subjects[s].records.size() == csv.subjects[s].records.size());
    for (size_t r = 0; r < csv.subjects[s].records.size(); ++r) {
      const pk::Record& a = csv.subjects[s].records[r];
      const pk::Record& b = blanks.subjects[s].records[r];
      CHECK(a.time == b.time);
      CHECK(a.amt == b.amt);
      CHECK(a.dv_missing == b.dv_missing);
      if (!a.dv_missing) CHECK(a.dv == b.dv);
      CHECK(a.extra == b.extra);
    }
  }
  // A record with a field too many names its line, as in a CSV file.
  CHECK_THROWS_WITH(pk::ParseDataset("ID TIME AMT\n1 0 100 7\n", "b.txt"),
                    Catch::Contains("b.txt:2:4: expected 3 fields as in the header, found 4"));
}
