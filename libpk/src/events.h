// The PREDPP event engine (not installed).
//
// EventEngine walks one subject's records in file order and turns them into a
// sequence of calls on a propagator ("visitor"):
//
//   Advance(h, u, set)            x(t+h) from x(t) under constant input rates u
//   Bolus(cmt, amount, set)       x[cmt] += amount (a jump of the state)
//   Reset()                       x = 0
//   SteadyState(cycle, set, add)  x = (or +=) the periodic steady state at the record time
//   SteadyInfusion(u, set, add)   x = (or +=) the steady state of constant rates u
//   DoseEntered(time, set)        a dose is about to enter (for exposure metrics)
//   RecordDone(record, set)       the record has been processed
//
// The input rates u are the running infusions plus the constant zero-order inputs K0_<n> of the
// set in force (pk/parameters.h), which a steady state with SS=1 includes.
//
// `set` indexes the parameter vector in force: the values on record i govern
// the interval ending at record i (PREDPP's "next observation carried
// backward"), including implied events inside that interval.
//
// The engine is a template on the scalar type T so that times, amounts and
// rates may carry derivatives with respect to θ (ALAG, F, R, D): an event time
// that moves with θ moves the interval lengths passed to Advance, which is how
// the lag term (f⁻ − f⁺)∂τ/∂θ arises in the gradient routes. Decisions
// (which event comes first) use the values only.
#ifndef PK_SRC_EVENTS_H_
#define PK_SRC_EVENTS_H_

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "autodiff.h"
#include "numerical_failure.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/model.h"
#include "pk/output.h"
#include "pk/parameters.h"

namespace pk {
namespace internal {

template <typename T>
using Vec = Eigen::Matrix<T, Eigen::Dynamic, 1>;

inline double Value(double x) { return x; }
inline bool IsExactlyZero(double x) { return x == 0.0; }

/// A stretch of time with constant input rates.
template <typename T>
struct Segment {
  T duration;
  Vec<T> rate;
};

/// The periodic dosing cycle of a steady-state dose. Starting at a dose time
/// (just before its bolus), one period is: add `bolus` to compartment `cmt`,
/// then run through `period`. The steady state is the fixed point of that map;
/// the state at the record time is reached from the fixed point by adding the
/// bolus and running through `to_record`.
template <typename T>
struct SteadyStateCycle {
  int cmt = 0;
  T bolus = T(0.0);
  std::vector<Segment<T>> period;
  std::vector<Segment<T>> to_record;
};

/// One subject's records bound to a model: resolved compartments and the
/// per-record parameter vectors (in ParameterLayout order).
struct PreparedSubject {
  const Dataset* data = nullptr;
  int subject = 0;
  /// 0-based compartment of each record; for a record with a DVID on a linear model with named
  /// outputs, n + DVID − 1, so that cmt + 1 indexes that output's row (LinearModel::OutputRow).
  std::vector<int> cmt;
  std::vector<int> set_of_record;  ///< which parameter set governs the interval ending at each record
  std::vector<Eigen::VectorXd> sets;
  /// Per set, which layout entries come from a data column (those carry no derivative).
  std::vector<std::vector<char>> from_data;
  /// For each layout entry, the dataset column supplying it (index into Record::extra), or -1.
  std::vector<int> column_of_parameter;
  /// The latest record time. Implied (ADDL) doses after it cannot change a prediction and are not generated.
  double last_time = 0;

  const std::vector<Record>& records() const { return data->subjects[subject].records; }
};

/// The output a record measures: its DVID (column index `dvid_column` into Record::extra, or -1),
/// default 1. Throws pk::InputError naming the line and column for a DVID that is not one of the
/// model's outputs (Model::output_names).
int OutputOfRecord(const Model& model, const Dataset& data, const Record& record, int dvid_column);

/// The output (1-based) an observation measures from its key: a nonlinear model's key is its output;
/// a linear model's is its compartment (1-based; output 1) or n + k for named output k.
inline int OutputOfKey(const Model& model, int key) {
  if (!model.is_linear()) return key;
  return key > model.num_compartments() ? key - model.num_compartments() : 1;
}

/// Binds a subject to a model. `base` is the full layout vector used where no
/// data column supplies a value. Throws pk::InputError (file, line, column)
/// for CMT out of range and for modifiers a dose needs but nobody supplies.
PreparedSubject PrepareSubject(const Model& model, const ParameterLayout& layout, const Dataset& data,
                               int subject, const Eigen::VectorXd& base, bool check_modifiers = true,
                               bool check_given = true);

/// Refuses, once for the whole dataset, a column named as one of the model's former parameter names
/// (Model::IsFormerName: its values would silently be ignored), and, when `fitting`, a dataset
/// without DV. Throws pk::InputError naming the file, the header line and the column.
void CheckColumns(const Model& model, const Dataset& data, bool fitting);

/// A parameter value the model cannot take (zero or below where it must be positive), on one
/// subject: that subject fails with this message, and the others go on.
class ParameterValueError : public InputError {
 public:
  using InputError::InputError;
};

/// Equal parameter vectors, where NaN (an unused modifier) matches NaN.
inline bool SameValues(const Eigen::Ref<const Eigen::VectorXd>& a, const Eigen::Ref<const Eigen::VectorXd>& b) {
  if (a.size() != b.size()) return false;
  // Bitwise equal (the usual case: the same values again) is equal; otherwise compare as numbers.
  if (a.size() == 0 || std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<size_t>(a.size())) == 0) {
    return true;
  }
  return std::equal(a.data(), a.data() + a.size(), b.data(),
                    [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); });
}

/// Replaces the base values of a prepared subject (the data columns still override).
void RebindParameters(const ParameterLayout& layout, const Eigen::VectorXd& base, PreparedSubject* s);

template <typename T, typename Visitor>
class EventEngine {
 public:
  EventEngine(const PreparedSubject& subject, const ParameterLayout& layout, const std::vector<Vec<T>>& sets,
              Visitor* visitor)
      : s_(subject), layout_(layout), sets_(sets), v_(visitor), n_(layout.num_compartments()) {
    for (const Vec<T>& p : sets_) {
      for (int c = 0; c < n_; ++c) constant_input_ = constant_input_ || !IsExactlyZero(p(layout_.ConstantInput(c)));
    }
  }

  void Run() {
    const std::vector<Record>& records = s_.records();
    if (records.empty()) return;
    t_ = T(records[0].time);
    InitialState(s_.set_of_record[0]);
    for (int r = 0; r < static_cast<int>(records.size()); ++r) {
      const Record& rec = records[r];
      const int set = s_.set_of_record[r];
      if (rec.time < Value(t_)) {
        // Time may only go back on a reset record (checked by the reader).
        Reset();
        t_ = T(rec.time);
      } else {
        ProcessImpliedUpTo(rec.time, set);
        AdvanceTo(T(rec.time), set);
      }
      ProcessRecord(r, set);
      v_->RecordDone(r, set);
    }
  }

 private:
  struct DoseSpec {
    int cmt = 0;
    T amount = T(0.0);
    bool infusion = false;
    T rate = T(0.0);
    T duration = T(0.0);
  };
  struct Pending {
    T time;
    long seq;
    DoseSpec dose;
  };
  struct Infusion {
    int cmt;
    T rate;
    T end;
  };

  void AdvanceTo(const T& t, int set) {
    const T h = t - t_;
    if (!IsExactlyZero(h)) {
      // The rates in a member: a step is a few hundred instructions, an allocation a good part of that.
      rates_.setZero(n_);
      for (const Infusion& inf : active_) rates_(inf.cmt) += inf.rate;
      AddConstantInput(set, &rates_);
      v_->Advance(h, rates_, set);
    }
    t_ = t;
  }

  // Initial amounts (X0_<n>) as jumps of the state: at the first record and after a reset record
  // (EVID 3 or 4), where NONMEM's PREDPP sets A_0FLG and applies A_0 again. A steady-state dose
  // (SS=1) starts from zero: NONMEM ignores A_0 there.
  void InitialState(int set) {
    const Vec<T>& p = sets_[set];
    for (int c = 0; c < n_; ++c) {
      const T& x0 = p(layout_.InitialState(c));
      if (!IsExactlyZero(x0)) v_->Bolus(c, x0, set);
    }
  }

  // The zero-order inputs K0_<n> of parameter set `set` (endogenous production), always on.
  void AddConstantInput(int set, Vec<T>* u) const {
    if (!constant_input_) return;
    const Vec<T>& p = sets_[set];
    for (int c = 0; c < n_; ++c) {
      const T& k0 = p(layout_.ConstantInput(c));
      if (!IsExactlyZero(k0)) (*u)(c) += k0;
    }
  }

  void Reset() {
    v_->Reset();
    active_.clear();
    pending_.clear();
  }

  // Implied events (infusion ends, ADDL, lagged and steady-state train doses)
  // at or before `until` enter before the record at `until`. Ties: infusion
  // ends first, then doses in the order they were scheduled.
  void ProcessImpliedUpTo(double until, int set) {
    for (;;) {
      int end_index = -1;
      double end_time = std::numeric_limits<double>::infinity();
      for (int i = 0; i < static_cast<int>(active_.size()); ++i) {
        if (Value(active_[i].end) < end_time) {
          end_time = Value(active_[i].end);
          end_index = i;
        }
      }
      const double dose_time =
          pending_.empty() ? std::numeric_limits<double>::infinity() : Value(pending_.front().time);
      if (std::min(end_time, dose_time) > until) return;
      if (end_index >= 0 && end_time <= dose_time) {
        AdvanceTo(active_[end_index].end, set);
        active_.erase(active_.begin() + end_index);
      } else {
        const Pending p = pending_.front();
        pending_.erase(pending_.begin());
        AdvanceTo(p.time, set);
        Give(p.dose, set);
      }
    }
  }

  void Schedule(const T& time, const DoseSpec& dose) {
    Pending p{time, seq_++, dose};
    auto it = std::upper_bound(pending_.begin(), pending_.end(), p, [](const Pending& a, const Pending& b) {
      return Value(a.time) < Value(b.time) || (Value(a.time) == Value(b.time) && a.seq < b.seq);
    });
    pending_.insert(it, p);
  }

  // A dose enters the system now.
  void Give(const DoseSpec& dose, int set) {
    if (Value(dose.amount) <= 0) return;  // F = 0: nothing enters
    v_->DoseEntered(t_, set);
    if (dose.infusion) {
      active_.push_back({dose.cmt, dose.rate, t_ + dose.duration});
    } else {
      v_->Bolus(dose.cmt, dose.amount, set);
    }
  }

  void ProcessRecord(int r, int set) {
    const Record& rec = s_.records()[r];
    switch (rec.evid) {
      case Evid::kReset:
        Reset();
        InitialState(set);
        break;
      case Evid::kResetDose:
        Reset();
        InitialState(set);
        Dose(r, set);
        break;
      case Evid::kDose:
        Dose(r, set);
        break;
      default:
        break;
    }
  }

  void Dose(int r, int set) {
    const Record& rec = s_.records()[r];
    const Vec<T>& p = sets_[set];
    const int c = s_.cmt[r];
    if (rec.ss > 0 && rec.amt == 0 && rec.ii == 0) {
      // Steady state of a constant infusion, which then stops at the record's time, as NONMEM 7.5
      // computes it (docs/events.md; mrgsolve/nmtests dosing scenario 1001, ID 29). ALAG and F do
      // not apply.
      const T rate = rec.rate == -1 ? p(layout_.Rate(c)) : T(rec.rate);
      if (rec.ss == 1) Reset();
      Vec<T> u = Vec<T>::Zero(n_);
      u(c) = rate;
      if (rec.ss == 1) AddConstantInput(set, &u);  // SS=2 adds to a state that holds it already
      v_->SteadyInfusion(u, set, rec.ss == 2);
      return;
    }
    DoseSpec dose;
    dose.cmt = c;
    CheckModifiers(p, c, rec);
    dose.amount = p(layout_.F(c)) * rec.amt;
    if (rec.rate != 0) {
      dose.infusion = true;
      if (rec.rate > 0) {
        // F scales the duration, not the rate.
        dose.rate = T(rec.rate);
        dose.duration = dose.amount / dose.rate;
      } else if (rec.rate == -1) {
        dose.rate = p(layout_.Rate(c));
        dose.duration = dose.amount / dose.rate;
      } else {
        // RATE=-2: modelled duration; F scales the rate.
        dose.duration = p(layout_.Duration(c));
        dose.rate = dose.amount / dose.duration;
      }
    }
    const T lag = p(layout_.Alag(c));
    const T ii = T(rec.ii);
    if (rec.ss > 0) {
      if (rec.ss == 1) Reset();
      SteadyStateDose(dose, ii, lag, set, rec.ss == 2);
    }
    const T start = t_ + lag;
    if (Value(lag) == 0) {
      // A zero lag that carries a derivative still moves the dose time.
      AdvanceTo(start, set);
      Give(dose, set);
    } else {
      Schedule(start, dose);
    }
    // Implied doses after the last record cannot affect anything (ADDL may be large).
    for (int k = 1; k <= rec.addl && Value(start) + k * Value(ii) <= s_.last_time; ++k) {
      Schedule(start + double(k) * ii, dose);
    }
  }

  // A modifier out of its range at run time (PrepareSubject checks the starting values; a modifier
  // computed in $PK may leave its range during a fit, as NONMEM stops on a negative ALAG): the
  // evaluation fails rather than running time backwards.
  void CheckModifiers(const Vec<T>& p, int c, const Record& rec) const {
    const auto check = [&](int index, bool positive) {
      const double v = Value(p(index));
      if (positive ? v > 0 : v >= 0) return;
      throw NumericalFailure(layout_.name(index) + " is " + FormatNumber(v) + " for the dose at TIME " +
                             FormatNumber(rec.time) + ": it must be " + (positive ? "positive" : "0 or more"));
    };
    check(layout_.F(c), false);
    check(layout_.Alag(c), false);
    if (rec.rate == -1) check(layout_.Rate(c), true);
    if (rec.rate == -2) check(layout_.Duration(c), true);
  }

  // The record's dose is the last of an infinite train at start times
  // s_j = t + lag - j·II (j ≥ 1). As NONMEM does, the steady state is computed
  // without the lag and then advanced to the right point of the cycle: the most
  // recent train dose before t is j = k = floor(lag/II) + 1, a phase
  // ψ = k·II − lag ∈ (0, II] before t. Train infusions still running at t run
  // to their natural end; train doses at or after t (lag ≥ II) are scheduled.
  void SteadyStateDose(const DoseSpec& dose, const T& ii, const T& lag, int set, bool add) {
    // Each train dose that overlaps the record (by its lag or its infusion) is a
    // separate event; bound their number rather than exhaust memory.
    constexpr double kMaxOverlap = 1e5;
    if (!(Value(lag) / Value(ii) < kMaxOverlap) || !(Value(dose.duration) / Value(ii) < kMaxOverlap)) {
      throw NumericalFailure("steady state with II = " + FormatNumber(Value(ii)) +
                             ": the lag or the infusion spans more than " +
                             std::to_string(static_cast<long>(kMaxOverlap)) + " dosing intervals");
    }
    const int k = static_cast<int>(std::floor(Value(lag) / Value(ii))) + 1;
    const T psi = double(k) * ii - lag;
    SteadyStateCycle<T> cycle;
    cycle.cmt = dose.cmt;
    if (!dose.infusion) {
      cycle.bolus = dose.amount;
      cycle.period.push_back({ii, Vec<T>::Zero(n_)});
      cycle.to_record.push_back({psi, Vec<T>::Zero(n_)});
    } else {
      // Over one period, q+1 train infusions run for ρ and q for II−ρ, with D = q·II + ρ.
      cycle.bolus = T(0.0);
      const int q = static_cast<int>(std::floor(Value(dose.duration) / Value(ii)));
      const T rho = dose.duration - double(q) * ii;
      Vec<T> high = Vec<T>::Zero(n_), low = Vec<T>::Zero(n_);
      high(dose.cmt) = double(q + 1) * dose.rate;
      low(dose.cmt) = double(q) * dose.rate;
      if (Value(rho) > 0) cycle.period.push_back({rho, high});
      if (Value(rho) < Value(ii)) cycle.period.push_back({ii - rho, low});
      if (Value(psi) <= Value(rho)) {
        cycle.to_record.push_back({psi, high});
      } else {
        if (Value(rho) > 0) cycle.to_record.push_back({rho, high});
        cycle.to_record.push_back({psi - rho, low});
      }
    }
    if (!add) {  // the train on top of the constant inputs (SS=2 adds to a state that holds them)
      for (Segment<T>& segment : cycle.period) AddConstantInput(set, &segment.rate);
      for (Segment<T>& segment : cycle.to_record) AddConstantInput(set, &segment.rate);
    }
    v_->SteadyState(cycle, set, add);
    if (dose.infusion) {
      // Train infusion started at t − ψ − m·II is still running if D > ψ + m·II.
      for (int m = 0; Value(dose.duration) > Value(psi) + m * Value(ii); ++m) {
        active_.push_back({dose.cmt, dose.rate, t_ - psi - double(m) * ii + dose.duration});
      }
    }
    for (int j = 1; j < k; ++j) Schedule(t_ + lag - double(j) * ii, dose);
  }

  const PreparedSubject& s_;
  const ParameterLayout& layout_;
  const std::vector<Vec<T>>& sets_;
  Visitor* v_;
  const int n_;
  Vec<T> rates_;  // AdvanceTo's input rates
  bool constant_input_ = false;  // some set has a K0_<n> other than 0
  T t_;
  std::vector<Infusion> active_;
  std::vector<Pending> pending_;
  long seq_ = 0;
};

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_EVENTS_H_
