#!/usr/bin/env bash
# Command-line tests of pkfit: outputs on bundled data, --evaluate, failures and error exits.
set -uo pipefail
pkfit=$1; root=$2; work=$3; pksim=${4:-}
rm -rf "$work"; mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }

"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" -o "$work/theo" --jobs 2 >"$work/theo.txt" ||
  fail "theophylline fit exited non-zero"
for f in estimates.csv summary.csv predictions.csv fit_details.csv report.html fit_ID1.svg fit_ID12.svg; do
  [ -s "$work/theo/$f" ] || fail "missing output $f"
done
head -1 "$work/theo/estimates.csv" | grep -qx "ID,PARAMETER,ESTIMATE,SE,RSE_PCT,UNIT" || fail "estimates header"
head -1 "$work/theo/summary.csv" |
  grep -qx "ID,NOBS,OBJECTIVE,OFV,RSS,AIC,BIC,ITERATIONS,CONVERGED,GRADIENT,OPTIMIZER,SECONDS,PROPAGATOR,NCENS" ||
  fail "summary header"
# NONMEM's names for individual quantities, then the dataset's other columns as $TABLE carries covariates.
head -1 "$work/theo/predictions.csv" | grep -qx "ID,TIME,DV,IPRED,IRES,IWRES,CENS,WT,DOSE" || fail "predictions header"
awk -F, 'NR == FNR { if (FNR > 1) wt[$1] = $11; next } FNR > 1 && $8 != wt[$1] { bad = 1 } END { exit bad }' \
  "$root/datasets/theophylline.csv" "$work/theo/predictions.csv" || fail "predictions: WT is not the subject's"
# Least squares shows the RSS (twice the minimised V), with AIC and BIC.
awk -F, 'NR > 1 { d = $5 - 2 * $3; if (d < 0) d = -d; if (d > 1e-9 * $5 || $4 != "") bad = 1 } END { exit bad }' \
  "$work/theo/summary.csv" || fail "summary: RSS should be 2 x OBJECTIVE and OFV empty for least squares"
grep -q "^ID .* RSS .* AIC .* BIC .*KA (RSE%)" "$work/theo.txt" || fail "console table: RSS, AIC, BIC columns"
[ "$(tail -n +2 "$work/theo/estimates.csv" | wc -l)" -eq 36 ] || fail "expected 12 x 3 estimates"
[ "$(tail -n +2 "$work/theo/predictions.csv" | wc -l)" -eq 132 ] || fail "expected 132 predictions"
[ "$(awk -F, 'NR>1 && $9==1' "$work/theo/summary.csv" | wc -l)" -eq 12 ] || fail "all 12 fits should converge"
# summary.json: the run for R and Python, each subject with its estimates; RSS as in summary.csv.
grep -q '"num_subjects": 12' "$work/theo/summary.json" || fail "summary.json: num_subjects"
[ "$(grep -c '"status": "converged"' "$work/theo/summary.json")" -eq 12 ] || fail "summary.json: 12 converged subjects"
[ "$(grep -c '"name": "CL"' "$work/theo/summary.json")" -eq 13 ] || fail "summary.json: a CL per subject and in the population"
grep -q "\"libpk_version\": \"$("$pkfit" --version | sed 's/.* //')\"" "$work/theo/summary.json" || fail "summary.json: version"
# A units row in Latin-1 (not UTF-8): the report and summary.json are still written, the bytes replaced.
{ head -1 "$root/datasets/theophylline.csv"; printf '#,h,\xb5g,,,,\xb5g/mL,,,,kg,\n'; tail -n +2 "$root/datasets/theophylline.csv"; } \
  >"$work/latin1.csv"
"$pkfit" --model 1cmt_oral --data "$work/latin1.csv" --subject 1 -o "$work/latin1" -q --population none ||
  fail "a Latin-1 units row should not stop pkfit"
[ -s "$work/latin1/MANIFEST" ] && grep -q '"concentration": "' "$work/latin1/summary.json" ||
  fail "Latin-1 units: summary.json and MANIFEST should be written"
rss1=$(awk -F, '$1 == 1 { print $5 }' "$work/theo/summary.csv")
grep -q "\"rss\": ${rss1%%e*}" "$work/theo/summary.json" || fail "summary.json: ID 1's RSS $rss1"
# RES = DV - PRED on every row.
awk -F, 'NR>1 { d = $3 - $4 - $5; if (d < 0) d = -d; if (d > 1e-9) bad = 1 } END { exit bad }' \
  "$work/theo/predictions.csv" || fail "RES is not DV - PRED"
grep -q "converged" "$work/theo.txt" || fail "no estimates table on stdout"
# pksim --estimates simulates each subject at its fitted parameters: at the samples it predicts what pkfit did.
if [ -n "$pksim" ]; then
  "$pksim" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --estimates "$work/theo/estimates.csv" \
    --out "$work/theo_sim.csv" || fail "pksim --estimates exited non-zero"
  awk -F, 'NR > 1 && $3 == 0 { print $1 "," $2 "," $4 }' "$work/theo_sim.csv" >"$work/theo_sim_cp.csv"
  awk -F, 'NR > 1 { print $1 "," $2 "," $4 }' "$work/theo/predictions.csv" >"$work/theo_pred.csv"
  [ "$(wc -l <"$work/theo_sim_cp.csv")" -eq 132 ] || fail "pksim --estimates: expected 132 sample rows"
  paste -d, "$work/theo_sim_cp.csv" "$work/theo_pred.csv" | awk -F, '{
    if ($1 != $4 || $2 != $5) bad = 1; d = $3 - $6; if (d < 0) d = -d; if (d > 1e-10 * (1 + ($6 < 0 ? -$6 : $6))) bad = 1
  } END { exit bad }' || fail "pksim at the estimates does not reproduce pkfit's predictions"
fi
# The output set: MANIFEST lists every file of the run; a set without it (a run killed half-way) or with a
# changed file is refused by pksim --estimates and pkfit --init-from.
[ "$(tail -n +3 "$work/theo/MANIFEST" | cut -d, -f1 | sort | tr '\n' ' ')" = "$(cd "$work/theo" && ls | grep -v MANIFEST | sort | tr '\n' ' ')" ] ||
  fail "MANIFEST should list every file of the run"
if [ -n "$pksim" ]; then
  cp -r "$work/theo" "$work/theo_killed" && rm "$work/theo_killed/MANIFEST"
  "$pksim" --model 1cmt_oral --estimates "$work/theo_killed/estimates.csv" --dose 320 --times 1 >/dev/null 2>"$work/killed.err"
  [ $? -eq 2 ] && grep -q "has no MANIFEST" "$work/killed.err" || fail "pksim should refuse a set without MANIFEST (exit 2)"
  "$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --init-from "$work/theo_killed/estimates.csv" \
    -o "$work/theo_init" -q 2>"$work/killed2.err"
  [ $? -eq 2 ] && grep -q "did not finish" "$work/killed2.err" || fail "pkfit --init-from should refuse a set without MANIFEST"
  cp -r "$work/theo" "$work/theo_edited" && sed -i 's/^1,KA,/1,KA,9/' "$work/theo_edited/estimates.csv"
  "$pksim" --model 1cmt_oral --estimates "$work/theo_edited/estimates.csv" --dose 320 --times 1 >/dev/null 2>"$work/edited.err"
  [ $? -eq 2 ] && grep -q "differs from the file pkfit wrote" "$work/edited.err" || fail "pksim should refuse an edited set"
fi

# Two-stage population estimates over the subjects: one row per structural parameter, in the report and on stdout.
head -1 "$work/theo/population.csv" | grep -qx "PARAMETER,N,MEAN,SD,CV_PCT,GEOMEAN,GEOCV_PCT,MEDIAN,MIN,MAX,GTS_N,TYPICAL,TYPICAL_SE,TYPICAL_RSE_PCT,OMEGA2,OMEGA2_SE,OMEGA2_RSE_PCT,BSV_CV_PCT,UNIT" ||
  fail "population header"
[ "$(awk -F, 'NR > 1 && $2 == 12 && $11 == 12' "$work/theo/population.csv" | cut -d, -f1 | tr '\n' ' ')" = "KA CL V " ] ||
  fail "population.csv should summarise KA, CL and V over 12 subjects"
# The STS mean is the mean of the estimates in estimates.csv.
mean_cl=$(awk -F, '$2 == "CL" { s += $3; n++ } END { printf "%.10g", s / n }' "$work/theo/estimates.csv")
awk -F, -v m="$mean_cl" '$1 == "CL" { d = $3 - m; if (d < 0) d = -d; exit !(d < 1e-8 * m) }' "$work/theo/population.csv" ||
  fail "population.csv: the STS mean of CL is not the mean of the estimates"
[ "$(tail -n +2 "$work/theo/population_omega.csv" | wc -l)" -eq 3 ] || fail "a diagonal Omega has 3 entries"
grep -q "<h2>Population (two-stage)</h2>" "$work/theo/report.html" || fail "report lacks the population section"
grep -q "^population: two-stage" "$work/theo.txt" || fail "no population table on stdout"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --omega full --population lognormal \
  -o "$work/theo_full" -q || fail "--omega full failed"
[ "$(tail -n +2 "$work/theo_full/population_omega.csv" | wc -l)" -eq 6 ] || fail "a full Omega has 6 entries"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --population none --subject 1 --subject 2 \
  -o "$work/theo_nopop" -q || fail "--population none failed"
[ ! -e "$work/theo_nopop/population.csv" ] || fail "--population none wrote population.csv"
# Every row has all 19 fields, also when no fit converged and neither STS nor GTS could run.
awk -F, '{ if (NF != 19) bad = 1 } END { exit bad }' "$work/theo/population.csv" || fail "population.csv row widths"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --subject 1 --subject 2 --max-iterations 1 \
  -o "$work/theo_unconverged" -q 2>/dev/null
[ "$(awk -F, 'NR > 1 && NF == 19 && $2 == 0 && $3 == "" && $11 == 0 && $12 == ""' "$work/theo_unconverged/population.csv" |
  cut -d, -f1 | tr '\n' ' ')" = "KA CL V " ] || fail "population.csv without converged fits: N = 0 rows"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --omega block -o "$work/bad_omega" 2>"$work/bad_omega.err"
[ $? -eq 2 ] || fail "--omega block should exit 2"
grep -q "omega: expected diagonal or full, got 'block'" "$work/bad_omega.err" || fail "--omega error message"
# The output directory is made with its parents.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --subject 1 -o "$work/nested/a/b" -q ||
  fail "pkfit into a new nested directory"
[ -s "$work/nested/a/b/report.html" ] || fail "no report in the nested output directory"
# --init-from: each subject restarts from its earlier estimates and stops sooner, at the same objective.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --init-from "$work/theo/estimates.csv" \
  -o "$work/theo_again" -q || fail "--init-from refit failed"
paste -d, "$work/theo/summary.csv" "$work/theo_again/summary.csv" | awk -F, 'NR > 1 {
  d = $3 - $17; if (d < 0) d = -d; if (d > 1e-9 * $3 || $22 >= $8) bad = 1 } END { exit bad }' ||
  fail "--init-from: refits should take fewer iterations to the same objective"
grep -q "the values given for this subject" "$work/theo_again/fit_details.csv" || fail "--init-from: source not recorded"
printf 'ID,PARAMETER,ESTIMATE\n1,KA,x\n' >"$work/bad_init.csv"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --init-from "$work/bad_init.csv" -o "$work/bi" \
  2>"$work/bad_init.err"
[ $? -eq 2 ] || fail "--init-from with a bad table should exit 2"
grep -q "bad_init.csv:2:3: ESTIMATE: 'x' is not a number" "$work/bad_init.err" || fail "--init-from error location"
# Exponents and half-lives of every fitted compartment model, with SEs (KA and k for 1cmt_oral).
grep -q "^exponents and half-lives" "$work/theo.txt" || fail "no half-lives on stdout"
[ "$(grep -cE "^[0-9]*,exponents,THALF(_ABS|1)," "$work/theo/derived.csv")" -eq 24 ] ||
  fail "derived.csv should hold two half-lives per subject"
# Goodness of fit over all subjects: one point per prediction row in each plot, and the plots in the report.
for f in gof_dv_ipred.svg gof_iwres_time.svg gof_iwres_ipred.svg; do
  [ "$(grep -c "<circle" "$work/theo/$f")" -eq 132 ] || fail "$f should hold the 132 samples"
  grep -q 'stroke="#d62728"' "$work/theo/$f" || fail "$f should have a LOWESS smoother"
  grep -q 'stroke-dasharray' "$work/theo/$f" || fail "$f should have its identity or zero line"
done
# Log-log: the samples with DV > 0 (IPRED > 0 at every sample after the dose).
[ "$(grep -c "<circle" "$work/theo/gof_dv_ipred_log.svg")" -eq "$(awk -F, 'NR>1 && $3>0 && $4>0' "$work/theo/predictions.csv" | wc -l)" ] ||
  fail "gof_dv_ipred_log.svg should hold the positive samples"
grep -q "<h2>Goodness of fit</h2>" "$work/theo/report.html" || fail "report lacks the goodness-of-fit section"
[ "$(grep -c "<svg" "$work/theo/report.html")" -eq 16 ] || fail "theophylline report should hold 4 + 12 plots"
[ "$(grep -c "<figure id=\"id" "$work/theo/report.html")" -eq 12 ] || fail "theophylline report: a panel per subject"

# Censored samples (CENS=1, below 2 mg/L): maximum likelihood counts each by its probability (M3);
# they have no residuals and are drawn hollow. Least squares refuses them, naming line and column.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline_blq.csv" --error additive -o "$work/blq" --jobs 2 \
  >"$work/blq.txt" || fail "BLQ fit exited non-zero"
[ "$(awk -F, 'NR>1 && $7==1' "$work/blq/predictions.csv" | wc -l)" -eq 27 ] || fail "BLQ: expected 27 censored rows"
awk -F, 'NR>1 && $7==1 && ($5 != "" || $6 != "") { bad = 1 } END { exit bad }' "$work/blq/predictions.csv" ||
  fail "BLQ: censored rows should have no RES or WRES"
[ "$(awk -F, 'NR>1 { s += $14 } END { print s }' "$work/blq/summary.csv")" -eq 27 ] || fail "BLQ: NCENS should sum to 27"
[ "$(awk -F, 'NR>1 && $9==1' "$work/blq/summary.csv" | wc -l)" -eq 12 ] || fail "BLQ: all 12 fits should converge"
# Maximum likelihood shows NONMEM's OFV: -2LL without N log(2 pi) of the uncensored samples.
awk -F, 'NR == FNR { if (FNR > 1) m2ll[$1] = $7; next } FNR > 1 { n = $2 - $14; d = m2ll[$1] - n * log(2 * 3.141592653589793) - $4
  if (d < 0) d = -d; if (d > 1e-6) bad = 1 } END { exit bad }' "$work/blq/fit_details.csv" "$work/blq/summary.csv" ||
  fail "BLQ: OFV should be -2LL - N log(2 pi) over the uncensored samples"
grep -q "censored samples (CENS, Beal's M3) per ID: 1: 1, 2: 3" "$work/blq.txt" || fail "BLQ: no censoring note"
[ "$(grep -c '<circle[^>]*fill="white"' "$work/blq/fit_ID2.svg")" -eq 3 ] || fail "BLQ: ID 2 should show 3 hollow samples"
[ "$(grep -c '<circle[^>]*fill="white"' "$work/blq/gof_dv_ipred.svg")" -eq 27 ] || fail "BLQ: dv_ipred should show 27 hollow"
[ "$(grep -c '<circle' "$work/blq/gof_iwres_time.svg")" -eq 105 ] || fail "BLQ: residual plots hold the 105 values only"
# The exponential error (log DV against log PRED): SIGMA_LOG estimated, WRES on log scale for the values.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline_blq.csv" --error exponential -o "$work/blq_exp" -q ||
  fail "BLQ fit with the exponential error failed"
[ "$(grep -c ",SIGMA_LOG," "$work/blq_exp/estimates.csv")" -eq 12 ] || fail "exponential: 12 SIGMA_LOG estimates"
awk -F, 'NR > 1 && $7 == 0 { if ($6 == "") bad = 1 } END { exit bad }' "$work/blq_exp/predictions.csv" ||
  fail "exponential: every value should have a WRES"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --error exponential -o "$work/theo_exp" -q \
  2>"$work/theo_exp.err"
[ $? -eq 2 ] || fail "exponential error on DV = 0 should exit 2"
grep -q "theophylline.csv:15:7: the exponential error model compares log DV with log PRED, so DV must be > 0, not 0" \
  "$work/theo_exp.err" || fail "exponential error on DV = 0: message"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline_blq.csv" -o "$work/blq_ls" -q 2>"$work/blq_ls.err"
[ $? -eq 2 ] || fail "BLQ with least squares should exit 2"
grep -q "theophylline_blq.csv:3:13: a censored sample (CENS=1) needs maximum likelihood" "$work/blq_ls.err" ||
  fail "BLQ with least squares: error location"
[ ! -e "$work/blq_ls" ] || fail "BLQ with least squares: no output directory expected"
# --ignore/--accept (NM-TRAN's IGNORE=/ACCEPT=): the records kept are the ones fitted.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --ignore '(ID.GT.3,TIME.GT.20)' -o "$work/ignored" -q ||
  fail "--ignore fit failed"
[ "$(tail -n +2 "$work/ignored/summary.csv" | cut -d, -f1-2 | tr '\n' ' ')" = "1,10 2,10 3,10 " ] ||
  fail "--ignore '(ID.GT.3,TIME.GT.20)' should leave IDs 1-3 with 10 samples each"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --ignore 'ID.EQ.1' --accept 'ID.EQ.2' -o "$work/both" \
  -q 2>"$work/both.err"
[ $? -eq 2 ] || fail "--ignore with --accept conditions should exit 2"
grep -q "cannot be combined" "$work/both.err" || fail "--ignore with --accept: message"
# --init auto prints the starting values computed from the data, and the report names their source.
"$pkfit" --model 2cmt_iv --data "$root/datasets/indomethacin.csv" --init auto -o "$work/auto" -q >"$work/auto.txt" ||
  fail "--init auto fit failed"
head -1 "$work/auto.txt" | grep -qx "ID,PARAMETER,INITIAL,SOURCE" || fail "--init auto did not print the starting values"
[ "$(grep -c '^[0-9],' "$work/auto.txt")" -eq 24 ] || fail "--init auto: expected 6 x 4 starting values"
grep -q "data (terminal log-linear regression" "$work/auto/fit_details.csv" || fail "fit_details lacks the starting-value source"
"$pkfit" --model 2cmt_iv --data "$root/datasets/indomethacin.csv" --catalogue-init --init auto -o "$work/cat" -q \
  >"$work/cat.txt" || true
grep -q "catalogue defaults" "$work/cat.txt" || fail "--catalogue-init did not start from the defaults"

# Oral data alone do not determine CL, V and F1 separately: pkfit says so under its table, in fit_details.csv,
# on stderr and in its exit code (1: a fit that is not identifiable is not an answer).
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --subject 1 --init F1=0.8 --optimizer bfgs \
  -o "$work/f1" >"$work/f1.txt" 2>"$work/f1.err"; rc=$?
[ $rc -eq 1 ] || fail "an unidentifiable fit should exit 1, got $rc"
grep -q "^pkfit: ID 1: not identifiable: the information matrix is singular" "$work/f1.err" ||
  fail "stderr does not say the fit is not identifiable: $(cat "$work/f1.err")"
grep -q "^1,not identifiable," "$work/f1/fit_details.csv" || fail "fit_details STATUS is not 'not identifiable'"
grep -q "^ID 1: no standard errors: the information matrix is singular: CL, V and F1 are not determined separately" \
  "$work/f1.txt" || fail "pkfit does not say what the data leave undetermined"
head -1 "$work/f1/fit_details.csv" | grep -q ",COVARIANCE$" || fail "fit_details lacks the COVARIANCE column"
grep -q "CL, V and F1 are not determined separately" "$work/f1/fit_details.csv" || fail "fit_details lacks the covariance message"

# --evaluate: objective and gradient; the adjoint and forward routes print the same gradient.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --evaluate --subject 1 --init KA=1.2 \
  --gradient adjoint >"$work/eval_adj.csv" || fail "--evaluate (adjoint) failed"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --evaluate --subject 1 --init KA=1.2 \
  --gradient forward >"$work/eval_fwd.csv" || fail "--evaluate (forward) failed"
head -1 "$work/eval_adj.csv" | grep -qx "ID,PARAMETER,VALUE,OBJECTIVE,GRADIENT" || fail "evaluate header"
[ "$(tail -n +2 "$work/eval_adj.csv" | wc -l)" -eq 3 ] || fail "evaluate: expected 3 rows"
grep -q "^1,KA,1.2," "$work/eval_adj.csv" || fail "evaluate did not use --init KA=1.2"
paste -d, "$work/eval_adj.csv" "$work/eval_fwd.csv" | awk -F, 'NR>1 { d = $5 - $10; if (d < 0) d = -d;
  s = $10 < 0 ? -$10 : $10; if (d > 1e-9 * (s + 1e-12)) bad = 1 } END { exit bad }' ||
  fail "adjoint and forward gradients differ"

# A transfer-function model by the companion route reaches the 2cmt_iv optimum.
"$pkfit" --model tf2 --data "$root/datasets/indomethacin.csv" --gradient companion -o "$work/tf2" -q ||
  fail "tf2 fit by the companion route failed"
grep -q ",companion,lm," "$work/tf2/summary.csv" || fail "summary does not report the companion route"
grep -q "^1,iv,CL," "$work/tf2/derived.csv" || fail "derived.csv lacks the IV reading"
grep -q "^1,exponents,THALF2," "$work/tf2/derived.csv" || fail "derived.csv lacks the half-lives"
"$pkfit" --model tf2 --data "$root/datasets/indomethacin.csv" --subject 1 -o "$work/tf2b" | grep -q "as an IV compartment model" ||
  fail "pkfit does not print the compartmental reading of a tf model"
paste -d, <(cut -d, -f3 "$work/tf2/summary.csv") <(cut -d, -f3 "$work/auto/summary.csv") | awk -F, 'NR>1 {
  d = $1 - $2; if (d < 0) d = -d; if (d > 1e-7 * $2) bad = 1 } END { exit bad }' ||
  fail "tf2 and 2cmt_iv objectives differ on indomethacin"

# Maximum likelihood with an estimated lag, by Newton.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --subject 1 --error combined \
  --init ALAG1=0.1 --optimizer newton -o "$work/ml" -q || fail "ML fit failed"
grep -q "^1,SIGMA_PROP," "$work/ml/estimates.csv" || fail "ML estimates lack SIGMA_PROP"
grep -q "^1,ALAG1," "$work/ml/estimates.csv" || fail "--init ALAG1 was not estimated"

# ID 2's likelihood has no maximum (DV 0 predicted 0 at TIME 0 with a combined error): exit 1, the cause named,
# "unbounded" in the tables, CONVERGED 0.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --subject 2 --error combined \
  -o "$work/ml2" 2>"$work/ml2.err" >"$work/ml2.out"; rc=$?
[ $rc -eq 1 ] || fail "an unbounded likelihood should exit 1, got $rc"
grep -q "ID 2: the likelihood has no maximum: the sample at TIME 0" "$work/ml2.err" || fail "ml2: $(cat "$work/ml2.err")"
grep -q "unbounded" "$work/ml2.out" || fail "the estimates table does not say unbounded"
grep -q "^2,11,[^,]*,[^,]*,[^,]*,[^,]*,[^,]*,[0-9]*,0," "$work/ml2/summary.csv" || fail "summary.csv does not say CONVERGED 0"

# Observations outside the central compartment are fitted as such (NONMEM's CMT), with a note saying so.
"$pkfit" --model 1cmt_oral_transit --data "$root/datasets/theophylline.csv" --subject 1 -o "$work/transit" -q \
  2>"$work/transit.err"
grep -q "note: 11 observations with CMT 2 measure TR2, not CENTRAL (CMT 5)" "$work/transit.err" ||
  fail "no note on observations outside the central compartment: $(cat "$work/transit.err")"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --subject 1 -o "$work/oral1" -q 2>"$work/oral1.err"
[ ! -s "$work/oral1.err" ] || fail "a note where CMT is the central compartment: $(cat "$work/oral1.err")"
# A nonlinear model's observations measure their DVID's output: no note for CMT=2 with DVID=2.
awk -F, 'BEGIN { OFS = "," } NR == 1 { print $0, "CMT"; next } { print $0, ($6 == 2 ? 2 : 1) }' \
  "$root/datasets/emax_synthetic.csv" >"$work/emax_cmt.csv"
"$pkfit" --model 1cmt_iv_emax --data "$work/emax_cmt.csv" --subject 1 --weighting column:W --evaluate \
  >/dev/null 2>"$work/emax.err" || fail "emax with CMT and DVID: $(cat "$work/emax.err")"
[ ! -s "$work/emax.err" ] || fail "a note for a nonlinear model's observations: $(cat "$work/emax.err")"

# A subject with too few samples fails; the others finish; exit code 1.
printf 'ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,1,0,0,3\n1,2,0,0,2.2\n1,4,0,0,1.2\n1,8,0,0,0.4\n2,0,100,1,.\n2,1,0,0,3\n' \
  >"$work/partial.csv"
"$pkfit" --model 1cmt_iv --data "$work/partial.csv" -o "$work/partial" -q 2>"$work/partial.err"; rc=$?
[ $rc -eq 1 ] || fail "a failed subject should exit 1, got $rc"
grep -q "ID 2" "$work/partial.err" || fail "the failed subject is not named"
grep -q "^1,CL," "$work/partial/estimates.csv" || fail "the good subject's estimates are missing"

# Bad input exits 2 with file:line:column.
printf 'ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,1,0,0,abc\n' >"$work/bad.csv"
msg=$("$pkfit" --model 1cmt_iv --data "$work/bad.csv" -o "$work/never" 2>&1); rc=$?
[ $rc -eq 2 ] || fail "bad data exited $rc"
echo "$msg" | grep -q "bad.csv:3:5: column DV: 'abc' is not a number" || fail "message was: $msg"
[ ! -e "$work/never" ] || fail "output written despite bad input"
"$pkfit" --model 1cmt_iv --data "$root/datasets/indomethacin.csv" --init KX=1 >/dev/null 2>&1
[ $? -eq 2 ] || fail "unknown parameter should exit 2"
"$pkfit" --model 1cmt_iv --data "$root/datasets/indomethacin.csv" --optimizer lm --gradient adjoint -o "$work/x" \
  >/dev/null 2>&1; [ $? -eq 2 ] || fail "lm with the adjoint route should exit 2"
"$pkfit" --model 1cmt_iv_mm --data "$root/datasets/mm_synthetic.csv" --propagator exact >/dev/null 2>"$work/exact.err"
[ $? -eq 2 ] || fail "the exact propagator with a nonlinear model should exit 2"
grep -q "nonlinear" "$work/exact.err" || fail "no clear message for --propagator exact on a nonlinear model"

# A nonlinear model: auto takes the one-step integrator (rk), reported as such, and all subjects
# converge; so they do through CVODES (ode).
"$pkfit" --model 1cmt_iv_mm --data "$root/datasets/mm_synthetic.csv" -o "$work/mm" >"$work/mm.txt" ||
  fail "1cmt_iv_mm fit exited non-zero"
[ "$(awk -F, 'NR>1 && $9==1 && $13=="rk"' "$work/mm/summary.csv" | wc -l)" -eq 6 ] ||
  fail "all 6 MM fits should converge with the rk propagator (auto)"
grep -q "propagator rk, gradient forward" "$work/mm.txt" || fail "pkfit does not report the rk propagator and route"
"$pkfit" --model 1cmt_iv_mm --data "$root/datasets/mm_synthetic.csv" --propagator ode -o "$work/mm_ode" -q ||
  fail "1cmt_iv_mm fit through CVODES exited non-zero"
[ "$(awk -F, 'NR>1 && $9==1 && $13=="ode"' "$work/mm_ode/summary.csv" | wc -l)" -eq 6 ] ||
  fail "all 6 MM fits should converge with the ode propagator"
# BFGS on the adjoint: the summary names that route, and the forward one that the SEs needed.
"$pkfit" --model 1cmt_iv_mm --data "$root/datasets/mm_synthetic.csv" --subject 1 --optimizer bfgs --gradient adjoint \
  -o "$work/mm_bfgs" -q || fail "1cmt_iv_mm with bfgs and the adjoint failed"
grep -q "^1,.*,adjoint (SE: forward),bfgs,.*,rk,0$" "$work/mm_bfgs/summary.csv" ||
  fail "summary does not report the adjoint route and the SE route"
# A linear model through CVODES reaches the exact propagator's objective.
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --subject 1 --propagator ode --rtol 1e-10 \
  --atol 1e-12 -o "$work/theo_ode" -q || fail "1cmt_oral with --propagator ode failed"
paste -d, <(cut -d, -f3 "$work/theo/summary.csv" | sed -n 2p) <(cut -d, -f3 "$work/theo_ode/summary.csv" | sed -n 2p) |
  awk -F, '{ d = ($1 - $2) / $1; if (d < 0) d = -d; exit !(d < 1e-7) }' ||
  fail "ode and exact objectives differ for theophylline ID 1"
# --evaluate through the adjoint and forward ODE routes prints the same gradient.
for r in forward adjoint; do
  "$pkfit" --model 1cmt_iv_mm --data "$root/datasets/mm_synthetic.csv" --subject 2 --evaluate --gradient $r \
    --rtol 1e-10 --atol 1e-12 >"$work/mm_eval_$r.csv" || fail "--evaluate --gradient $r (ode) failed"
done
paste -d, "$work/mm_eval_forward.csv" "$work/mm_eval_adjoint.csv" | awk -F, 'NR>1 {
  d = $5 - $10; if (d < 0) d = -d; s = $5 < 0 ? -$5 : $5; if (d > 1e-6 * (s + 1e-3)) bad = 1 } END { exit bad }' ||
  fail "ODE forward and adjoint gradients differ"
# Two outputs (DVID): one plot per output, weighted by a column.
"$pkfit" --model 1cmt_iv_emax --data "$root/datasets/emax_synthetic.csv" --weighting column:W -o "$work/emax" -q ||
  fail "1cmt_iv_emax fit failed"
for f in fit_ID1.svg fit_ID1_EFFECT.svg report.html; do [ -s "$work/emax/$f" ] || fail "emax: missing $f"; done
[ "$(grep -c "<figure id=\"id" "$work/emax/report.html")" -eq "$(tail -n +2 "$work/emax/summary.csv" | wc -l)" ] ||
  fail "emax report: one anchored panel per subject"
[ "$(grep -c "<svg" "$work/emax/report.html")" -eq $((2 * $(tail -n +2 "$work/emax/summary.csv" | wc -l) + 8)) ] ||
  fail "emax report should hold 2 plots per subject and 4 goodness-of-fit plots per output"
for f in gof_dv_ipred.svg gof_dv_ipred_2.svg gof_iwres_time_2.svg; do [ -s "$work/emax/$f" ] || fail "emax: missing $f"; done
grep -q "DV against IPRED (EFFECT, DVID 2)" "$work/emax/gof_dv_ipred_2.svg" || fail "emax: DVID 2 plot title"

# Settings that cannot make a fit are option errors, before any fitting (exit 2, one line).
theo="$root/datasets/theophylline.csv"
expect2() {  # expect2 MESSAGE-FRAGMENT ARGS...
  local want=$1; shift
  "$pkfit" --model 1cmt_oral --data "$theo" -o "$work/conflict" -q "$@" 2>"$work/conflict.err"; local rc=$?
  [ $rc -eq 2 ] || fail "$* should exit 2, got $rc"
  grep -q -- "$want" "$work/conflict.err" || fail "$*: expected '$want', got: $(cat "$work/conflict.err")"
  [ "$(wc -l <"$work/conflict.err")" -eq 1 ] || fail "$*: more than one line on stderr"
}
expect2 "KA: the lower bound 2 is not below the upper bound 1" --lower KA=2 --upper KA=1
expect2 "KA of 1cmt_oral must be positive, not 0" --init KA=0
expect2 "the initial value of KA (1) must lie strictly within its bounds (2, inf)" --lower KA=2 --init KA=1
expect2 "V of 1cmt_oral must be positive, not 0" --fix V=0
expect2 "CL of 1cmt_oral must be positive, not -1" --param CL=-1
# A data column the model takes as a parameter: a subject whose value is impossible fails with its place.
printf 'ID,TIME,AMT,DV,EVID,CMT,CL\n1,0,100,.,1,1,-3\n1,1,0,5,0,2,-3\n1,4,0,3,0,2,-3\n2,0,100,.,1,1,3\n2,1,0,5,0,2,3\n2,2,0,4,0,2,3\n2,4,0,3,0,2,3\n2,8,0,1,0,2,3\n' >"$work/negcl.csv"
"$pkfit" --model 1cmt_oral --data "$work/negcl.csv" -o "$work/negcl" -q 2>"$work/negcl.err"; rc=$?
[ $rc -eq 1 ] || fail "a subject with CL=-3 in the data should fail alone (exit 1), got $rc"
grep -q "ID 1: .*negcl.csv:2:7: CL of 1cmt_oral must be positive, not -3" "$work/negcl.err" ||
  fail "CL=-3 in the data: message: $(cat "$work/negcl.err")"

expect2 "starts must be from 1 to 1000" --starts 100000
# A dose that needs a modifier nobody gives is the same input error in pkfit as in pksim (exit 2).
printf 'ID,TIME,AMT,RATE,EVID,CMT,DV\n1,0,100,-1,1,1,.\n1,1,0,0,0,1,5\n1,2,0,0,0,1,4\n' >"$work/r1.csv"
"$pkfit" --model 1cmt_iv --data "$work/r1.csv" -o "$work/r1" -q 2>"$work/r1.err"; rc=$?
[ $rc -eq 2 ] || fail "RATE=-1 without R1 should exit 2 in pkfit, got $rc"
grep -q "r1.csv:2:4: a dose with RATE=-1 needs R1 > 0" "$work/r1.err" || fail "RATE=-1 without R1: message"
# An ID that comes back is another subject: a note, and its plot is not overwritten.
printf 'ID,TIME,AMT,DV,EVID,CMT\n1,0,100,.,1,1\n1,1,0,5,0,2\n1,4,0,3,0,2\n1,8,0,1.5,0,2\n2,0,100,.,1,1\n2,1,0,4,0,2\n2,4,0,3,0,2\n2,8,0,1.8,0,2\n1,0,100,.,1,1\n1,1,0,6,0,2\n1,4,0,3.5,0,2\n1,8,0,1.2,0,2\n' >"$work/rep.csv"
"$pkfit" --model 1cmt_oral --data "$work/rep.csv" -o "$work/rep" -q --population none 2>"$work/rep.err"
grep -q "note: ID 1 comes back at .*rep.csv:10 after other IDs" "$work/rep.err" || fail "no note for a repeated ID"
for f in fit_ID1.svg fit_ID1_occ2.svg fit_ID2.svg; do [ -s "$work/rep/$f" ] || fail "repeated ID: missing $f"; done
grep -q 'id="id1_occ2" class=""><figcaption>ID 1 (occurrence 2)' "$work/rep/report.html" || fail "repeated ID: report panel"

# A model file in place of a catalogue name (docs/model_language.md): its twin of 1cmt_oral gives the
# catalogue's estimates to the optimiser's precision (it starts from its own values, the catalogue
# from the data), with the units it declares; its own error model and σ start.
"$pkfit" --model "$root/models/1cmt_oral.pkm" --data "$root/datasets/theophylline.csv" -o "$work/file" -q --jobs 1 \
  >/dev/null 2>&1 || fail "model file fit exited non-zero"
paste -d, "$work/theo/estimates.csv" "$work/file/estimates.csv" |
  awk -F, 'NR > 1 { d = ($3 - $9) / $3; if (d < 0) d = -d; if ($2 != $8 || d > 1e-6) bad = 1 } END { exit bad }' ||
  fail "the model file twin of 1cmt_oral should give the catalogue's estimates"
grep -q '^1,KA,.*,1/h$' "$work/file/estimates.csv" || fail "the model file's unit of KA (1/h)"
grep -q '^1,exponents,LAMBDA_ABS,' "$work/file/derived.csv" || fail "the model file's depot: its exponent is LAMBDA_ABS"
[ -s "$work/file/report.html" ] || fail "model file: no report"
printf '$PROBLEM mm  saturable\n$PARAM\nVMAX = 20 mg/h\nKM = 2 mg/L\nV = 30 L\n$CMT\nCENTRAL\n$ODE\nC = CENTRAL / V\nd/dt(CENTRAL) = -VMAX * C / (KM + C)\n$OUTPUT\nCP = C\n$ERROR\nCP ~ proportional(0.05)\n' >"$work/mm.pkm"
"$pkfit" --model "$work/mm.pkm" --data "$root/datasets/mm_synthetic.csv" -o "$work/mm" -q >"$work/mm.txt" 2>&1 ||
  fail "model file with \$ERROR: exit non-zero"
grep -q "proportional" "$work/mm/summary.json" || fail "the model file's \$ERROR should choose the proportional error"
grep -q ',SIGMA_PROP,' "$work/mm/estimates.csv" || fail "the model file's error model: SIGMA_PROP estimated"
# A line per output in $ERROR: each output its own error model and σ, named after it.
{ cat "$root/models/1cmt_iv_emax.pkm"; printf '$ERROR\nCP ~ proportional(0.1)\nE ~ additive(2)\n'; } >"$work/emax_err.pkm"
"$pkfit" --model "$work/emax_err.pkm" --data "$root/datasets/emax_synthetic.csv" --subject 1 -o "$work/emax_err" -q \
  >/dev/null 2>&1 || fail "per-output \$ERROR: exit non-zero"
grep -q ',SIGMA_PROP_CP,' "$work/emax_err/estimates.csv" && grep -q ',SIGMA_ADD_E,' "$work/emax_err/estimates.csv" ||
  fail "per-output \$ERROR: SIGMA_PROP_CP and SIGMA_ADD_E estimated"
grep -q "proportional (SIGMA_PROP_CP); additive (SIGMA_ADD_E)" "$work/emax_err/report.html" ||
  fail "per-output \$ERROR: the report names both error models"
# A second run into the same directory removes the first run's files it does not write again (the
# plots of subjects 2-12 here), and leaves a file of the user's own.
cp -r "$work/theo" "$work/rerun"
echo mine > "$work/rerun/notes.txt"
"$pkfit" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --accept "ID.EQ.1" -q -o "$work/rerun" >/dev/null ||
  fail "rerun: exited non-zero"
[ -e "$work/rerun/fit_ID1.svg" ] || fail "rerun: fit_ID1.svg missing"
[ -e "$work/rerun/fit_ID2.svg" ] && fail "rerun: the first run's fit_ID2.svg stayed"
[ -e "$work/rerun/notes.txt" ] || fail "rerun: a file of the user's own was removed"
if [ $failures -eq 0 ]; then echo "cli_pkfit: all checks passed"; else exit 1; fi
