#!/usr/bin/env bash
# pkpop's report as a person sees it: rendered by headless Chromium, screenshotted, and its DOM read
# back. Fails on a blank or broken page: a template that did not render, missing plots, an empty
# screenshot. The screenshot stays in the work directory (report.png) to look at.
set -uo pipefail
pkpop=$1; root=$2; work=$3; chromium=$4
rm -rf "$work"; mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
. "$(dirname "$0")/browser.sh"

# Phenobarbital: 59 subjects, covariates WT and APGAR.
"$pkpop" --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --eta CL,V --error proportional -q -o "$work/pheno" ||
  fail "pkpop on phenobarbital"
browse --dump-dom "file://$work/pheno/report.html" >"$work/dom.html"
grep -q "pkpop report: 1cmt_iv on phenobarbital.csv" "$work/dom.html" || fail "the rendered page has no title"
grep -q "{{" "$work/dom.html" && fail "a mustache tag was left unrendered"
# 5 goodness-of-fit plots, 2 η × 2 covariates, 59 subjects' panels.
[ "$(grep -o "<svg" "$work/dom.html" | wc -l)" -eq $((5 + 4 + 59)) ] ||
  fail "the page should show 5 goodness-of-fit plots, 4 η-covariate plots and 59 panels: $(grep -o "<svg" "$work/dom.html" | wc -l)"
grep -q "ETA_CL against WT" "$work/dom.html" || fail "no plot of η(CL) against WT"
grep -q "CWRES against TIME" "$work/dom.html" || fail "no CWRES against TIME"
grep -q "730.8947" "$work/dom.html" || fail "the OFV card"
# σ and, as NONMEM's $SIGMA, σ² with SE(σ²) = 2σ·SE(σ): 0.1282² = 0.01642.
grep -q "SIGMA_PROP²</td><td>0.0164" "$work/dom.html" || fail "no σ² row (NONMEM's \$SIGMA) in the estimates table"
for f in gof_dv_pred.svg gof_cwres_time.svg eta_CL_WT.svg; do
  grep -q "^$f," "$work/pheno/MANIFEST" || fail "$f is not in the output set's MANIFEST"
done

check_screenshot "$work/pheno/report.html"

# Two outputs (1cmt_iv_emax on emax_synthetic: CP and EFFECT, 4 subjects): the goodness-of-fit plots
# and the subject panels per output.
"$pkpop" --model 1cmt_iv_emax --data "$root/datasets/emax_synthetic.csv" --eta CL,EMAX --error proportional -q \
  -o "$work/emax" || fail "pkpop on emax_synthetic"
browse --dump-dom "file://$work/emax/report.html" >"$work/emax_dom.html"
[ "$(grep -o "<svg" "$work/emax_dom.html" | wc -l)" -eq $((2 * 5 + 2 * 4)) ] ||
  fail "two outputs: 10 goodness-of-fit plots and 8 panels, not $(grep -o "<svg" "$work/emax_dom.html" | wc -l)"
grep -q "ID 3 · EFFECT" "$work/emax_dom.html" || fail "no EFFECT panel for ID 3"

if [ $failures -eq 0 ]; then echo "cli_pop_report: all checks passed ($report_bytes-byte screenshot)"; else exit 1; fi
