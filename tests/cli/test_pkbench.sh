#!/bin/bash
# A smoke test of pkbench (benchmarks/pkbench.cc): its quick sections run to the end and print their
# tables. Figures are not checked here (they are measured, not asserted: docs/performance.md).
pkbench=$1; root=$2; work=$3
mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
for section in 1 3 7; do
  "$pkbench" --quick --only "$section" --datasets "$root/datasets" >"$work/section$section.txt" 2>&1 ||
    fail "pkbench --only $section exited non-zero: $(tail -3 "$work/section$section.txt")"
  grep -q "^== " "$work/section$section.txt" || fail "pkbench --only $section printed no table"
  grep -qiE "nan|unexpected" "$work/section$section.txt" && fail "pkbench --only $section: $(grep -iE 'nan|unexpected' "$work/section$section.txt" | head -2)"
done
# Section 7 compares every model file with its catalogue twin: four rows of ratios.
[ "$(grep -cE '^(1cmt|2cmt)' "$work/section7.txt")" -eq 4 ] || fail "section 7 should have four rows"
[ $failures -eq 0 ] && echo "pkbench smoke: all checks passed"
exit $failures
