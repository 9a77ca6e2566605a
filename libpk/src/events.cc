#include "events.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "internal_text.h"
#include "pk/error.h"
#include "pk/output.h"

namespace pk {
namespace internal {
namespace {

// More implied (ADDL) doses before a subject's last record than any regimen
// needs (hourly for eleven years); a larger count is a data error, not a regimen.
constexpr double kMaxImpliedDoses = 1e5;

std::string CompartmentList(const Model& model) {
  std::vector<std::string> items;
  for (int c = 0; c < model.num_compartments(); ++c) {
    items.push_back(std::to_string(c + 1) + "=" + model.compartment_names()[c]);
  }
  return Join(items, ", ");
}

}  // namespace

void RebindParameters(const ParameterLayout& layout, const Eigen::VectorXd& base, PreparedSubject* s) {
  const std::vector<Record>& records = s->records();
  s->sets.clear();
  s->from_data.clear();
  s->set_of_record.assign(records.size(), 0);
  // One scratch vector for every record: a subject's records mostly repeat the set before them.
  Eigen::VectorXd v(base.size());
  std::vector<char> data_flags(static_cast<size_t>(layout.size()));
  for (size_t r = 0; r < records.size(); ++r) {
    // The same columns as the record before (bitwise, as an added output record copies them): its set.
    const std::vector<double>& extra = records[r].extra;
    if (r > 0 && extra.size() == records[r - 1].extra.size() &&
        (extra.empty() || std::memcmp(extra.data(), records[r - 1].extra.data(), extra.size() * sizeof(double)) == 0)) {
      s->set_of_record[r] = s->set_of_record[r - 1];
      continue;
    }
    v = base;
    std::fill(data_flags.begin(), data_flags.end(), 0);
    for (int i = 0; i < layout.size(); ++i) {
      const int col = s->column_of_parameter[i];
      if (col >= 0 && !std::isnan(records[r].extra[col])) {
        v(i) = records[r].extra[col];
        data_flags[i] = 1;
      }
    }
    layout.ComputeModifiers(&v);  // F1 = … in a model file's $PK: from this record's parameters
    // Unused modifiers (R, D of compartments nobody infuses into) are NaN: NaN matches NaN here.
    if (s->sets.empty() || !SameValues(s->sets.back(), v) || s->from_data.back() != data_flags) {
      s->sets.push_back(v);
      s->from_data.push_back(data_flags);
    }
    s->set_of_record[r] = static_cast<int>(s->sets.size()) - 1;
  }
}

namespace {

// A covariate must have a value on every record: from its column, else the model's reference value.
void CheckCovariates(const Model& model, const ParameterLayout& layout, const PreparedSubject& s, size_t r) {
  const Record& rec = s.records()[r];
  const Eigen::VectorXd& p = s.sets[s.set_of_record[r]];
  for (int i = 0; i < model.num_parameters(); ++i) {
    if (!model.is_covariate(i) || !std::isnan(p(i))) continue;
    const int col = s.column_of_parameter[i];
    if (col < 0) {
      throw InputError(s.data->source, s.data->header_line, 0,
                       "model " + model.name() + " reads the covariate " + layout.name(i) +
                           ", but the dataset has no column " + layout.name(i) + " (the header has " +
                           Join(s.data->columns, ",") + "); add the column, give a reference value in $COVARIATE ("
                           + layout.name(i) + " = …), or, in pksim, --param " + layout.name(i) + "=VALUE");
    }
    throw ParameterValueError(s.data->source, rec.line, s.data->ColumnNumber(layout.name(i)),
                              "the covariate " + layout.name(i) + " has no value on this record, and model " +
                                  model.name() + " gives it no reference value");
  }
}

// A clearance, volume or rate constant of zero or below gives rising concentrations or a "converged"
// fit of nonsense: every parameter the model does not declare signed must be positive on record r.
// Values from data columns are always checked; given ones when `given`.
void CheckPositive(const Model& model, const ParameterLayout& layout, const PreparedSubject& s, size_t r, bool given) {
  const Record& rec = s.records()[r];
  const Eigen::VectorXd& p = s.sets[s.set_of_record[r]];
  for (int i = 0; i < model.num_parameters(); ++i) {
    if (!model.must_be_positive(i) || !(p(i) <= 0)) continue;  // NaN: not given, reported where it is used
    const int col = s.column_of_parameter[i];
    const bool from_data = col >= 0 && !std::isnan(rec.extra[col]);
    if (!from_data && !given) continue;
    const Dataset& data = *s.data;
    const std::string why = layout.name(i) + " of " + model.name() + " must be positive, not " + FormatNumber(p(i));
    // A subject's own data fail that subject; a value given for every subject is the request's error.
    if (from_data) throw ParameterValueError(data.source, rec.line, data.ColumnNumber(layout.name(i)), why);
    throw InputError(why + " (as given)");
  }
}

}  // namespace

void CheckColumns(const Model& model, const Dataset& data, bool fitting) {
  const ParameterLayout layout(model);
  for (const std::string& column : data.extra_columns) {
    try {
      layout.CheckNotComputed(column, "the data column " + column);
    } catch (const InputError& e) {
      throw InputError(data.source, data.header_line, data.ColumnNumber(column), e.message());
    }
    if (!model.IsFormerName(column)) continue;
    throw InputError(data.source, data.header_line, data.ColumnNumber(column),
                     "column " + column + ": " + model.UnknownParameter(column, model.parameter_names()) +
                         "; rename the column");
  }
  if (fitting && data.ColumnNumber("DV") == 0) {
    throw InputError(data.source, data.header_line, 0,
                     "missing column DV: a fit needs the observations (the header has " + Join(data.columns, ",") +
                         ")");
  }
}

int OutputOfRecord(const Model& model, const Dataset& data, const Record& record, int dvid_column) {
  if (dvid_column < 0) return 1;
  const double v = record.extra[dvid_column];
  if (std::isnan(v)) return 1;
  if (v != std::floor(v) || v < 1 || v > model.num_outputs()) {
    std::string names;
    for (int k = 0; k < model.num_outputs(); ++k) {
      names += (k ? ", " : "") + std::to_string(k + 1) + "=" + model.output_names()[k];
    }
    throw InputError(data.source, record.line, data.ColumnNumber("DVID"),
                     "DVID " + std::to_string(v) + " is not an output of model " + model.name() + " (" + names + ")");
  }
  return static_cast<int>(v);
}

PreparedSubject PrepareSubject(const Model& model, const ParameterLayout& layout, const Dataset& data,
                               int subject, const Eigen::VectorXd& base, bool check_modifiers, bool check_given) {
  PreparedSubject s;
  s.data = &data;
  s.subject = subject;
  s.column_of_parameter.resize(layout.size());
  for (int i = 0; i < layout.size(); ++i) {
    s.column_of_parameter[i] = layout.is_computed(i) ? -1 : data.ExtraColumn(layout.name(i));
  }
  RebindParameters(layout, base, &s);

  const std::vector<Record>& records = s.records();
  const int n = model.num_compartments();
  // A linear model's named outputs are output rows n + 1, n + 2, … (a nonlinear model's samples
  // are keyed by their DVID elsewhere).
  const int dvid_col = model.is_linear() && model.num_outputs() > 0 ? data.ExtraColumn("DVID") : -1;
  s.cmt.resize(records.size());
  s.last_time = -INFINITY;
  for (const Record& rec : records) s.last_time = std::max(s.last_time, rec.time);
  for (size_t r = 0; r < records.size(); ++r) {
    const Record& rec = records[r];
    if (rec.cmt > n) {
      throw InputError(data.source, rec.line, data.ColumnNumber("CMT"),
                       "CMT " + std::to_string(rec.cmt) + " is out of range for model " + model.name() + " (" +
                           CompartmentList(model) + ")");
    }
    // Each implied dose up to the last record is an event of its own (later ones are dropped).
    if (rec.IsDose() && rec.addl > 0 &&
        std::min(static_cast<double>(rec.addl), std::floor((s.last_time - rec.time) / rec.ii)) > kMaxImpliedDoses) {
      throw InputError(data.source, rec.line, data.ColumnNumber("ADDL"),
                       "ADDL=" + std::to_string(rec.addl) + " with II=" + FormatNumber(rec.ii) +
                           " implies more than " + std::to_string(static_cast<long>(kMaxImpliedDoses)) +
                           " doses before the subject's last record");
    }
    const int c = rec.cmt > 0 ? rec.cmt - 1 : (rec.IsDose() ? model.default_dose_compartment() - 1
                                                            : model.central_compartment() - 1);
    s.cmt[r] = c;
    if (dvid_col >= 0 && !rec.IsDose() && !std::isnan(rec.extra[dvid_col])) {
      s.cmt[r] = n + OutputOfRecord(model, data, rec, dvid_col) - 1;
    }
    // A record under the same set as the one before it (same values, same sources) passes the same checks.
    if (r == 0 || s.set_of_record[r] != s.set_of_record[r - 1]) {
      CheckCovariates(model, layout, s, r);
      if (check_modifiers) CheckPositive(model, layout, s, r, check_given);
    }
    if (!rec.IsDose() || !check_modifiers) continue;
    const Eigen::VectorXd& p = s.sets[s.set_of_record[r]];
    // A modifier the dose needs must be a finite value in range; name where it came from.
    auto check = [&](int index, bool positive, const char* what) {
      const double v = p(index);
      const bool ok = std::isfinite(v) && (positive ? v > 0 : v >= 0);
      if (ok) return;
      const int col = s.column_of_parameter[index];
      const bool from_data = col >= 0 && !std::isnan(rec.extra[col]);
      const std::string name = layout.name(index);
      throw InputError(data.source, rec.line,
                       from_data ? data.ColumnNumber(name) : data.ColumnNumber("RATE"),
                       std::string(what) + " needs " + name + (positive ? " > 0" : " >= 0") +
                           (std::isnan(v) ? ", but no value is given (use --param " + name +
                                                "=... or a data column " + name + ")"
                                          : ", but it is " + std::to_string(v)));
    };
    check(layout.F(c), false, "a dose");
    check(layout.Alag(c), false, "a dose");
    if (rec.rate == -1) check(layout.Rate(c), true, "a dose with RATE=-1");
    if (rec.rate == -2) check(layout.Duration(c), true, "a dose with RATE=-2");
  }
  return s;
}

}  // namespace internal
}  // namespace pk
