#!/usr/bin/env bash
# pkfit's report as a person sees it: rendered by headless Chromium, screenshotted, and its DOM read
# back. Fails on a blank or broken page: a template that did not render, missing plots, an empty
# screenshot. The screenshot stays in the work directory (report.png) to look at.
set -uo pipefail
pkfit=$1; root=$2; work=$3; chromium=$4
rm -rf "$work"; mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
. "$(dirname "$0")/browser.sh"

"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --units time=h,amt=mg,conc=mg/L -o "$work/theo" -q ||
  fail "pkfit on theophylline"
browse --dump-dom "file://$work/theo/report.html" >"$work/dom.html"
grep -q "pkfit report: 1cmt_oral on theophylline.csv" "$work/dom.html" || fail "the rendered page has no title"
grep -q "{{" "$work/dom.html" && fail "a mustache tag was left unrendered"
[ "$(grep -o "<svg" "$work/dom.html" | wc -l)" -eq 16 ] || fail "the page should show 4 goodness-of-fit plots and 12 panels"
[ "$(grep -o "<figure id=\"id" "$work/dom.html" | wc -l)" -eq 12 ] || fail "a panel per subject"
grep -q "CL (L/h) (RSE%)" "$work/dom.html" || fail "the estimates table should carry units"
[ "$(grep -c ',CL,.*,L/h$' "$work/theo/estimates.csv")" -eq 12 ] || fail "estimates.csv: CL's unit per subject"
grep -q '^CL,.*,L/h$' "$work/theo/population.csv" || fail "population.csv: CL's unit"
grep -q ',exponents,THALF1,.*,h$' "$work/theo/derived.csv" || fail "derived.csv: a half-life's unit"
grep -q "libpk $("$pkfit" --version | sed 's/.* //')" "$work/dom.html" || fail "the header should name libpk's version"

check_screenshot "$work/theo/report.html"

if [ $failures -eq 0 ]; then echo "cli_report: all checks passed ($report_bytes-byte screenshot)"; else exit 1; fi
