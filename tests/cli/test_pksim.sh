#!/usr/bin/env bash
# Command-line tests of pksim: bundled data, regimens from flags, outputs, and error exits.
set -uo pipefail
pksim=$1; root=$2; work=$3
rm -rf "$work"; mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }

# The catalogue.
n=$("$pksim" --list-models | wc -l)
[ "$n" -eq 15 ] || fail "--list-models printed $n models, expected 15 (6 compartmental, tf1..tf4, transit, 4 nonlinear)"

# The ODE propagator: a linear model agrees with the exact one; a nonlinear model has its outputs as columns.
"$pksim" --model 2cmt_oral --dose 100 --ii 12 --doses 3 --times 0:2:36 --out "$work/exact.csv" || fail "exact run"
"$pksim" --model 2cmt_oral --dose 100 --ii 12 --doses 3 --times 0:2:36 --propagator ode --rtol 1e-10 --atol 1e-12 \
  --out "$work/ode.csv" || fail "ode run"
paste -d, "$work/exact.csv" "$work/ode.csv" | awk -F, 'NR>1 { d = $4 - $11; if (d < 0) d = -d; if (d > 1e-8 * ($4 + 1e-6)) bad = 1 }
  END { exit bad }' || fail "ode and exact CP differ"
"$pksim" --model 1cmt_iv_emax --dose 100 --times 0:1:12 --out "$work/emax.csv" || fail "emax run"
head -1 "$work/emax.csv" | grep -qx "ID,TIME,EVID,CP,EFFECT,A1,A2" || fail "emax header"
"$pksim" --model 1cmt_oral_transit:NTR=5 --dose 100 --times 0:1:12 --out "$work/transit.csv" || fail "transit NTR=5"
head -1 "$work/transit.csv" | grep -q ",A7$" || fail "NTR=5 should give 7 compartments"
"$pksim" --model 1cmt_oral_transit:NTR=0 --dose 100 --times 0:1:2 >/dev/null 2>&1
[ $? -eq 2 ] || fail "NTR=0 should be an input error"

# A regimen from flags: 1cmt_iv bolus, CP(t) = 100/30 exp(-0.1 t).
"$pksim" --model 1cmt_iv --dose 100 --param CL=3 --param V=30 --times 0:1:10 --out "$work/bolus.csv" ||
  fail "regimen run exited non-zero"
head -1 "$work/bolus.csv" | grep -qx "ID,TIME,EVID,CP,A1" || fail "bad header: $(head -1 "$work/bolus.csv")"
[ "$(tail -n +2 "$work/bolus.csv" | wc -l)" -eq 11 ] || fail "expected 11 rows"
awk -F, 'NR>1 { e = 100/30*exp(-0.1*$2); d = $4 - e; if (d < 0) d = -d; if (d > 1e-12*e) { print "row " NR ": " $4 " vs " e; bad = 1 } }
         END { exit bad }' "$work/bolus.csv" || fail "bolus concentrations differ from the closed form"

# An infusion given by duration, and a repeated oral regimen with a summary.
"$pksim" --model 1cmt_iv --dose 100 --duration 2 --times 0:0.5:12 >"$work/inf.csv" || fail "infusion run failed"
[ "$(tail -n +2 "$work/inf.csv" | wc -l)" -eq 25 ] || fail "infusion: expected 25 rows"
# --units label the plot's axes.
"$pksim" --model 1cmt_oral --dose 100 --times 0:1:24 --param KA=1 --param CL=2 --param V=20 --units time=h,conc=mg/L \
  --plot "$work/units.svg" --summary >"$work/units.txt" || fail "--units run"
grep -q "^ID 1: Cmax [0-9.]* mg/L at t=[0-9.]* h, .* AUC [0-9.]* mg/L·h$" "$work/units.txt" || fail "--units: the summary's units"
grep -q ">time (h)<" "$work/units.svg" && grep -q ">concentration (mg/L)" "$work/units.svg" || fail "--units: axis labels"
# Parameters neither --param nor the data give take the catalogue's defaults, and pksim says so.
"$pksim" --model 1cmt_oral --dose 100 --times 1 --param CL=2 2>"$work/defaults.err" >/dev/null
grep -q "note: the catalogue's defaults for what --param and the data do not give: KA=1.5, V=30" "$work/defaults.err" ||
  fail "no note on the catalogue's defaults"
"$pksim" --model 2cmt_oral --dose 500 --ii 12 --doses 14 --times 0:0.5:168 --summary --summary-csv "$work/sum.csv" \
  --plot "$work/plot.svg" --log >"$work/summary.txt" || fail "summary run failed"
grep -q "Cmax" "$work/summary.txt" || fail "summary lacks Cmax"
[ "$(grep -c '^1,[0-9]' "$work/sum.csv")" -eq 14 ] || fail "summary CSV should have 14 dosing intervals"
grep -q "^<svg" "$work/plot.svg" || fail "plot is not SVG"
# A model with two outputs: a panel for each, stacked, each with its own frame and a line per subject; E's
# panel starts at the baseline E0 = 10 at t = 0 (the first point of its line is at the top of its range).
"$pksim" --model "$root/models/effect_linear.pkm" --dose 100 --times 0:1:24 --plot "$work/panels.svg" >/dev/null 2>&1 ||
  fail "two-output plot run"
[ "$(grep -c '<svg' "$work/panels.svg")" -eq 3 ] || fail "two-output plot: expected an outer svg and two panels"
[ "$(grep -c '<polyline' "$work/panels.svg")" -eq 2 ] || fail "two-output plot: expected one line per panel"
grep -q '<svg y="400"' "$work/panels.svg" || fail "two-output plot: the second panel is not below the first"
grep -q ">E<" "$work/panels.svg" && grep -q ">CP<" "$work/panels.svg" || fail "two-output plot: the outputs' names"
# Many subjects: the plot draws the first 100 and says so, on stderr and in its title.
awk 'BEGIN { print "ID,TIME,AMT"; for (id = 1; id <= 150; ++id) printf "%d,0,100\n", id }' > "$work/many.csv"
"$pksim" --model 1cmt_iv --data "$work/many.csv" --times 0:1:24 --out "$work/many_out.csv" --plot "$work/many.svg" \
  2>"$work/many.err" || fail "150-subject plot run"
[ "$(grep -c '<polyline' "$work/many.svg")" -eq 100 ] || fail "150 subjects: expected 100 lines"
grep -q "the first 100 of 150 subjects" "$work/many.svg" || fail "150 subjects: the plot's title"
grep -q "note: --plot draws the first 100 of 150 subjects simulated" "$work/many.err" || fail "150 subjects: the note"
[ "$(tail -n +2 "$work/many_out.csv" | wc -l)" -eq 3750 ] || fail "150 subjects: every row is still written"

# Bundled data: theophylline has 132 observation records.
"$pksim" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --out "$work/theo.csv" || fail "theophylline run failed"
[ "$(tail -n +2 "$work/theo.csv" | wc -l)" -eq 132 ] || fail "theophylline: expected 132 rows"
head -1 "$work/theo.csv" | grep -qx "ID,TIME,EVID,CP,A1,A2" || fail "theophylline header"
for f in quinidine phenobarbital remifentanil; do
  model=1cmt_iv; [ $f = quinidine ] && model=1cmt_oral
  "$pksim" --model $model --data "$root/datasets/$f.csv" --out "$work/$f.csv" || fail "$f run failed"
done

# Bad input: a malformed number exits 2 naming file, line and column, and writes no output.
printf 'ID,TIME,AMT\n1,0,100\n1,x1,0\n' >"$work/bad.csv"
msg=$("$pksim" --model 1cmt_iv --data "$work/bad.csv" --out "$work/never.csv" 2>&1); rc=$?
[ $rc -eq 2 ] || fail "malformed data exited $rc, expected 2"
echo "$msg" | grep -q "bad.csv:3:2: column TIME: 'x1' is not a number" || fail "message was: $msg"
[ ! -e "$work/never.csv" ] || fail "an output file was written despite the error"
"$pksim" --model nosuch --dose 1 --times 0 >/dev/null 2>&1; [ $? -eq 2 ] || fail "unknown model should exit 2"
"$pksim" --model 1cmt_iv --dose 1 --times 0 --param CL=abc >/dev/null 2>&1; [ $? -eq 2 ] || fail "bad --param should exit 2"
"$pksim" --model 1cmt_iv --bogus >/dev/null 2>&1; [ $? -eq 2 ] || fail "unknown option should exit 2"

# One failing subject does not stop the others; the exit code says some failed.
printf 'ID,TIME,AMT,EVID,V\n1,0,100,1,0\n1,1,0,0,0\n2,0,100,1,10\n2,1,0,0,10\n' >"$work/partial.csv"
"$pksim" --model 1cmt_iv --data "$work/partial.csv" --out "$work/partial_out.csv" 2>"$work/partial.err"; rc=$?
[ $rc -eq 1 ] || fail "a failed subject should exit 1, got $rc"
grep -q "ID 1: simulation failed" "$work/partial.err" || fail "failed subject not reported"
grep -q "^2,1," "$work/partial_out.csv" || fail "the other subject's rows are missing"

# Per-subject parameters from an estimates table: each ID gets its own, --param overrides them, an ID without
# estimates fails alone, and a bad table names file, line and column.
printf 'ID,PARAMETER,ESTIMATE,SE\n1,KA,1.5,\n1,CL,2.5,0.1\n1,V,30,\n2,KA,0.8,\n2,CL,4,\n2,V,45,\n' >"$work/est.csv"
"$pksim" --model 1cmt_oral --estimates "$work/est.csv" --dose 320 --ii 12 --doses 3 --times 0:4:36 \
  --out "$work/est_sim.csv" || fail "--estimates with a regimen"
"$pksim" --model 1cmt_oral --param KA=0.8 --param CL=4 --param V=45 --dose 320 --ii 12 --doses 3 --times 0:4:36 \
  --out "$work/id2.csv" || fail "--param run"
diff <(awk -F, 'NR > 1 && $1 == 2 { $1 = ""; print }' "$work/est_sim.csv") \
  <(awk -F, 'NR > 1 { $1 = ""; print }' "$work/id2.csv") >/dev/null || fail "--estimates: ID 2 differs from --param"
[ "$(awk -F, 'NR > 1 && $1 == 1' "$work/est_sim.csv" | wc -l)" -eq 10 ] || fail "--estimates: ID 1 missing"
"$pksim" --model 1cmt_oral --estimates "$work/est.csv" --param CL=4 --dose 320 --times 0:4:8 --out "$work/over.csv" ||
  fail "--estimates with --param"
"$pksim" --model 1cmt_oral --param KA=1.5 --param CL=4 --param V=30 --dose 320 --times 0:4:8 --out "$work/over1.csv"
diff <(awk -F, 'NR > 1 && $1 == 1 { $1 = ""; print }' "$work/over.csv") \
  <(awk -F, 'NR > 1 { $1 = ""; print }' "$work/over1.csv") >/dev/null || fail "--param does not override --estimates"
printf 'ID,TIME,AMT,EVID,CMT\n1,0,100,1,1\n1,2,0,2,0\n3,0,100,1,1\n3,2,0,2,0\n' >"$work/two.csv"
"$pksim" --model 1cmt_oral --estimates "$work/est.csv" --data "$work/two.csv" >"$work/two_sim.csv" 2>"$work/two.err"
[ $? -eq 1 ] || fail "an ID without estimates should exit 1"
grep -q "ID 3: simulation failed: no estimates for this ID" "$work/two.err" || fail "missing-ID message"
[ "$(awk -F, 'NR > 1 && $1 == 1' "$work/two_sim.csv" | wc -l)" -eq 1 ] || fail "ID 1 should still be simulated"
printf 'ID,PARAMETER,ESTIMATE\n1,KA,1\n1,CLX,2\n' >"$work/bad.csv"
"$pksim" --model 1cmt_oral --estimates "$work/bad.csv" --dose 1 --times 0:1:2 2>"$work/bad.err"
[ $? -eq 2 ] || fail "a bad estimates table should exit 2"
grep -q "bad.csv:3:2: 'CLX' is not a parameter of model 1cmt_oral" "$work/bad.err" || fail "bad estimates message"

# Dates and clock times: NM-TRAN's example data set, simulated at its relative times (0, 5.42, 23.25; 0, 50 h).
printf 'ID,DATE,TIME,AMT,DV\n1,10-1-86,9:15,100,.\n1,10-1-86,14:40,0,5\n1,10-2-86,8:30,0,2\n2,10-12,8,100,.\n2,10-14,10,0,1\n' \
  >"$work/dated.csv"
"$pksim" --model 1cmt_iv --param CL=1 --param V=10 --data "$work/dated.csv" --out "$work/dated_sim.csv" || fail "dated run"
[ "$(awk -F, 'NR > 1 { printf "%s:%.4f ", $1, $2 }' "$work/dated_sim.csv")" = "1:5.4167 1:23.2500 2:50.0000 " ] ||
  fail "dated times: $(awk -F, 'NR > 1 { printf "%s:%s ", $1, $2 }' "$work/dated_sim.csv")"
# --ignore C drops NONMEM comment rows (a C column); a condition on a column the file lacks exits 2.
printf 'C,ID,TIME,AMT,DV\n.,1,0,100,.\nC,1,1,0,bad\n.,1,2,0,5\n' >"$work/commented.csv"
"$pksim" --model 1cmt_iv --param CL=1 --param V=10 --data "$work/commented.csv" --ignore C --out "$work/commented_sim.csv" ||
  fail "--ignore C run"
[ "$(awk -F, 'NR > 1 { printf "%s ", $2 }' "$work/commented_sim.csv")" = "2 " ] || fail "--ignore C: rows kept"
"$pksim" --model 1cmt_iv --data "$work/commented.csv" --ignore 'XX.EQ.1' 2>"$work/filter.err" >/dev/null
[ $? -eq 2 ] || fail "--ignore on a missing column should exit 2"
grep -q "IGNORE=(XX.EQ.1): no column XX in the header" "$work/filter.err" || fail "--ignore: message"
# An output into a directory that does not exist: a non-zero exit that says why, and no file.
"$pksim" --model 1cmt_iv --dose 100 --times 0:1:4 --out "$work/no/such/dir/sim.csv" 2>"$work/nodir.err" >/dev/null &&
  fail "--out into a missing directory should fail"
grep -q "sim.csv: cannot write (could not create .*: No such file or directory)" "$work/nodir.err" ||
  fail "--out into a missing directory: message"
[ ! -e "$work/no" ] || fail "--out into a missing directory: nothing should be created"

# An impossible parameter given for every subject is an option error.
"$pksim" --model 1cmt_iv --dose 100 --times 0:1:2 --param CL=-1 >/dev/null 2>"$work/negcl.err"; rc=$?
[ $rc -eq 2 ] || fail "--param CL=-1 should exit 2, got $rc"
grep -q "CL of 1cmt_iv must be positive, not -1" "$work/negcl.err" || fail "--param CL=-1: message"

# A model file's covariate from --param when the regimen has no such column (the ODE propagator at its
# default tolerance against the exact one: 7 digits); the shipped IDR model's
# response (DVID 2) next to CP.
printf '$PROBLEM wt\n$PARAM\nCL = 3\nV = 30\n$COVARIATE\nWT\n$CMT\nCENTRAL\n$ODE\nd/dt(CENTRAL) = -CL * WT / 70 / V * CENTRAL\n$OUTPUT\nCP = CENTRAL / V\n' >"$work/wt.pkm"
"$pksim" --model "$work/wt.pkm" --dose 100 --times 1 --param WT=140 >"$work/wt.csv" 2>/dev/null || fail "covariate by --param"
"$pksim" --model 1cmt_iv --dose 100 --times 1 --param CL=6 --param V=30 >"$work/cl6.csv" 2>/dev/null
[ "$(cut -d, -f4 "$work/wt.csv" | tail -1 | cut -c1-8)" = "$(cut -d, -f4 "$work/cl6.csv" | tail -1 | cut -c1-8)" ] ||
  fail "WT=140 doubles CL=3: the model file should match 1cmt_iv with CL=6"
"$pksim" --model "$root/models/idr3.pkm" --dose 100 --times 0,6 >"$work/idr3.csv" 2>/dev/null || fail "idr3.pkm"
head -1 "$work/idr3.csv" | grep -q "^ID,TIME,EVID,CP,E," || fail "idr3.pkm: CP and E columns"
# A linear model file with two outputs runs on the exact propagator and writes both; CVODES at
# rtol 1e-12 gives the same metabolite concentrations to 8 digits.
for p in exact ode; do
  "$pksim" --model "$root/models/parent_metabolite.pkm" --dose 100 --ii 12 --addl 2 --times 0:6:36 --propagator $p \
    --rtol 1e-12 --columns ID,TIME,CP,CPM >"$work/pm_$p.csv" 2>/dev/null || fail "parent_metabolite.pkm on $p"
done
head -1 "$work/pm_exact.csv" | grep -qx "ID,TIME,CP,CPM" || fail "parent_metabolite.pkm: CP and CPM columns"
awk -F, 'NR == FNR { cpm[FNR] = $4; next } FNR > 2 { d = $4 - cpm[FNR]; if (d < 0) d = -d; if (d > 1e-8 * $4) bad = 1 }
         END { exit bad }' "$work/pm_exact.csv" "$work/pm_ode.csv" || fail "parent_metabolite.pkm: CPM exact against CVODES"
[ "$(wc -l <"$work/pm_exact.csv")" -eq 8 ] || fail "parent_metabolite.pkm: 7 output times"
# A STEP equal to the range, which rounding makes a little longer (0.3 − 0.1 < 0.2): two times.
"$pksim" --model 1cmt_iv --dose 100 --times 0.1:0.2:0.3 --columns TIME >"$work/two_times.csv" 2>/dev/null ||
  fail "--times 0.1:0.2:0.3 refused"
[ "$(tr '\n' ' ' <"$work/two_times.csv")" = "TIME 0.1 0.3 " ] || fail "--times 0.1:0.2:0.3: $(cat "$work/two_times.csv")"

if [ $failures -eq 0 ]; then echo "cli_pksim: all checks passed"; else exit 1; fi
