// NM-TRAN's IGNORE= and ACCEPT= on the lines of a dataset (not installed).
#ifndef PK_SRC_IO_RECORD_FILTER_H_
#define PK_SRC_IO_RECORD_FILTER_H_

#include <string>
#include <vector>

#include "pk/dataset.h"

namespace pk {
namespace internal {

class RecordFilter {
 public:
  /// Compiles `filter` against the header's upper-cased column names. Throws
  /// pk::InputError (naming `source`) for a condition it cannot read, a label
  /// that is no column, or both an IGNORE and an ACCEPT list.
  RecordFilter(const DatasetFilter& filter, const std::vector<std::string>& columns, const std::string& source);

  /// Whether a data line is dropped by IGNORE=c before it is split.
  bool DropsLine(const std::string& line) const;
  /// Whether the record with these fields is dropped by the condition lists.
  bool DropsRecord(const std::vector<std::string>& fields) const;

 private:
  enum class Op { kEq, kNe, kGt, kGe, kLt, kLe };
  struct Condition {
    size_t column;
    Op op;
    std::string text;  // the value as written
    double number;     // NaN unless the value is a number
  };
  static bool Holds(const Condition& c, const std::vector<std::string>& fields);

  char ignore_character_ = 0;
  bool accept_ = false;  // the conditions are ACCEPT's, not IGNORE's
  std::vector<Condition> conditions_;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_IO_RECORD_FILTER_H_
