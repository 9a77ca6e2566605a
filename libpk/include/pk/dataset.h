// libpk: NONMEM-style event datasets.
//
// A dataset is a CSV file whose header names the columns. The PREDPP data
// items are recognised case-insensitively:
//
//   ID, TIME, AMT, RATE, II, ADDL, SS, EVID, CMT, MDV, DV
//
// Only TIME is required. Missing optional columns take NM-TRAN's defaults:
// AMT, RATE, II, ADDL, SS = 0; EVID = 1 when AMT > 0, else 0 when MDV = 0 or
// absent, else 2; MDV = 1 on non-observation records and on observations whose
// DV is missing; CMT = 0 (the model's default dose or observation compartment);
// ID = 1. A field holding "." is missing. Every other column is kept by name
// (upper-cased) so that covariates, time-varying model parameters (CL, V, ...)
// and dose modifiers (F1, ALAG1, R1, D1, ...) can be read from it.
//
// Dates and clock times follow NM-TRAN's day-time translation. With a date
// column (DATE: month/day/year, DAT1: day/month/year, DAT2: year/month/day,
// DAT3: year/day/month; any non-digit separates the components), or when any
// TIME is a clock time (hh:mm or hh:mm:ss; decimal hours are accepted beside
// them), TIME becomes hours since the subject's first record, which is at 0.
// A date with one component is a day number; with two, the day and month in
// the label's order; one- or two-digit years are 2000–2050 (≤ 50) or
// 1951–1999. The date column is not kept as a number.
//
// Records are grouped into subjects in file order: a new subject starts
// whenever ID changes, as in NONMEM. Lines starting with '#' and blank lines
// are ignored; a DatasetFilter drops more, as NM-TRAN's $DATA IGNORE= and
// ACCEPT= do. Every violation throws pk::InputError naming file, line and
// column.
#ifndef PK_DATASET_H_
#define PK_DATASET_H_

#include <map>
#include <string>
#include <utility>
#include <vector>

namespace pk {

/// PREDPP event types.
enum class Evid { kObservation = 0, kDose = 1, kOther = 2, kReset = 3, kResetDose = 4 };

/// One data record (one line of the file).
struct Record {
  double id = 1;
  double time = 0;
  double amt = 0;
  double rate = 0;   ///< > 0 rate; -1 rate modelled (R<n>); -2 duration modelled (D<n>)
  double ii = 0;     ///< interdose interval
  int addl = 0;      ///< additional doses
  int ss = 0;        ///< 0, 1 (reset to steady state) or 2 (add steady state)
  Evid evid = Evid::kObservation;
  int cmt = 0;       ///< 1-based compartment; 0 = the model's default
  int mdv = 0;
  double dv = 0;
  bool dv_missing = true;
  int line = 0;      ///< line number in the source file (1-based)
  std::vector<double> extra;  ///< other columns, NaN where missing

  bool IsDose() const { return evid == Evid::kDose || evid == Evid::kResetDose; }
  /// A measured sample that enters a loss: an observation record with MDV=0 and a DV.
  bool IsSample() const { return evid == Evid::kObservation && mdv == 0 && !dv_missing; }
};

struct Subject {
  double id = 1;
  /// 1, or 2, 3, ... when the ID comes back after other IDs: NONMEM counts each run of records as
  /// a subject of its own, and so does libpk; outputs name such a subject by ID and occurrence.
  int occurrence = 1;
  std::vector<Record> records;
};

struct Dataset {
  std::string source;                      ///< file name, for error messages
  /// IDs that came back after other IDs, with the line where each came back (Subject::occurrence).
  std::vector<std::pair<double, int>> repeated_ids;
  int header_line = 0;                     ///< line of the header in the source (1-based)
  std::vector<std::string> columns;        ///< upper-cased header, in file order
  /// Units by column (upper-cased name) from a units row: '#' and a field per column right after
  /// the header (pk/units.h). Empty without one.
  std::map<std::string, std::string> column_units;
  std::vector<std::string> extra_columns;  ///< upper-cased names of the non-PREDPP columns
  std::vector<Subject> subjects;
  /// TIME was translated to hours since each subject's first record (a date
  /// column or clock times; see above).
  bool relative_times = false;

  /// Index into Record::extra of a non-PREDPP column, or -1 (case-insensitive).
  int ExtraColumn(const std::string& name) const;
  /// 1-based position of any column in the file, or 0 when absent (case-insensitive).
  int ColumnNumber(const std::string& name) const;
  int NumRecords() const;
};

/// The records to read, as NM-TRAN's $DATA options. Dropped lines are not
/// read at all (a bad value on them is no error), and the others keep their
/// line numbers in messages. The header is the first line that is not blank or
/// a '#' comment, whatever the options say.
struct DatasetFilter {
  /// IGNORE=c: data lines whose first character is `c` are dropped, besides
  /// '#' comments and blank lines (so 'C' drops the rows of a NONMEM comment
  /// column C). '@' drops every line whose first non-blank character is a
  /// letter or '@' (NM-TRAN's IGNORE=@, e.g. repeated headers). 0: none.
  char ignore_character = 0;
  /// IGNORE=(list): a record is dropped when any condition holds. ACCEPT=(list):
  /// a record is kept only when one holds. At most one of the two lists. A
  /// condition is LABEL OP VALUE, LABEL a column of the header, OP one of
  /// NM-TRAN's .EQ. .NE. .GT. .GE. .LT. .LE. .EQN. .NEN. or ==, /=, !=, >, >=,
  /// <, <=, e.g. "DVID.EQ.2" or "TIME > 24"; one string may hold several,
  /// separated by commas, optionally in parentheses: "(DVID.EQ.2,BLQ.EQ.1)".
  /// When the field and VALUE are numbers they compare as numbers (so 2 equals
  /// 2.0), a missing field ('.' or empty) counting as 0 as in NM-TRAN;
  /// otherwise .EQ./.NE. compare the text and the ordering operators do not hold.
  std::vector<std::string> ignore;
  std::vector<std::string> accept;

  bool empty() const { return ignore_character == 0 && ignore.empty() && accept.empty(); }
};

/// Reads a dataset file. Throws pk::InputError on any malformed input,
/// including a filter that names no column of the header.
Dataset ReadDataset(const std::string& path, const DatasetFilter& filter = {});

/// Parses dataset text; `source` names it in error messages.
Dataset ParseDataset(const std::string& text, const std::string& source, const DatasetFilter& filter = {});

/// What is wrong with one record's items as NONMEM defines them, and the column it concerns.
struct RecordProblem {
  std::string column;   ///< AMT, RATE, II, ADDL, SS or CMT
  std::string message;  ///< empty: nothing is wrong
};
/// The first problem with `r`: negative AMT, II or ADDL; a RATE other than > 0, 0, -1 or -2; SS
/// outside 0–2; a negative CMT; dose items on a record that is not a dose; a dose that needs an
/// amount or an interval it lacks. The reader and RegimenToDataset apply it to every record.
RecordProblem CheckRecord(const Record& r);

}  // namespace pk

#endif  // PK_DATASET_H_
