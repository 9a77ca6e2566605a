#!/usr/bin/env bash
# Command-line tests of pkpop: a population fit on bundled data, its output set, thread
# independence, fixed parameters, and error exits.
set -uo pipefail
pkpop=$1; root=$2; work=$3; pksim=$4
rm -rf "$work"; mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }

# Phenobarbital, FOCEI, proportional error: the whole output set.
"$pkpop" --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --eta CL,V --error proportional -o "$work/pheno" \
  >"$work/pheno.txt" 2>"$work/pheno.err" || fail "phenobarbital FOCEI exited non-zero: $(cat "$work/pheno.err")"
for f in population_estimates.csv sdtab.csv subjects.csv iterations.csv covariance.csv report.txt pkpop.ext pkpop.phi MANIFEST; do
  [ -s "$work/pheno/$f" ] || fail "missing $f"
done
grep -q "pkpop.ext" "$work/pheno/MANIFEST" || fail "pkpop.ext is not in the MANIFEST"
[ "$(tail -n +3 "$work/pheno/pkpop.phi" | wc -l)" -eq 59 ] || fail "pkpop.phi: expected 59 subjects"
# The .ext's final row: CL, V, σ as THETA1-3, SIGMA(1,1) = 1, Ω's lower triangle, and the OFV.
awk 'NR == 2 { ok = ($2 == "THETA1" && $5 == "SIGMA(1,1)" && $6 == "OMEGA(1,1)" && $9 == "OBJ") }
     $1 == "-1000000000" { final = ($5 == "1.00000E+00" && $7 == "0.00000E+00" && $9 ~ /^730\.8947/) }
     END { exit !(ok && final) }' "$work/pheno/pkpop.ext" || fail "pkpop.ext: $(sed -n '2p;/-1000000000/p' "$work/pheno/pkpop.ext")"
grep -q "^FOCEI: OFV 730.8947" "$work/pheno.txt" || fail "the table's OFV: $(head -1 "$work/pheno.txt")"
grep -q "evaluation [0-9]*  OFV" "$work/pheno.err" || fail "no progress line on stderr"
[ "$(tail -n +2 "$work/pheno/sdtab.csv" | wc -l)" -eq 155 ] || fail "sdtab: expected 155 samples"
[ "$(tail -n +2 "$work/pheno/subjects.csv" | wc -l)" -eq 59 ] || fail "subjects: expected 59"
head -1 "$work/pheno/sdtab.csv" | grep -qx "ID,TIME,DVID,DV,PRED,IPRED,RES,WRES,CWRES,IWRES" || fail "sdtab header"
# CWRES of a good model: mean near 0 and SD near 1.
awk -F, 'NR>1 { s += $9; ss += $9*$9; n++ } END { m = s/n; sd = sqrt(ss/n - m*m);
  if (m < -0.3 || m > 0.3 || sd < 0.7 || sd > 1.3) { print m, sd; exit 1 } }' "$work/pheno/sdtab.csv" ||
  fail "CWRES are not about N(0, 1)"
awk -F, '$1 ~ /^OMEGA|^CL$|^V$|^SIGMA/ && $3 == "" { bad = 1 } END { exit bad }' "$work/pheno/population_estimates.csv" ||
  fail "an estimate without SE"

# Two threads give the same numbers, byte for byte.
"$pkpop" --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --eta CL,V --error proportional -j 2 -q \
  -o "$work/pheno2" || fail "two threads exited non-zero"
cmp -s "$work/pheno/population_estimates.csv" "$work/pheno2/population_estimates.csv" || fail "threads changed the estimates"
cmp -s "$work/pheno/sdtab.csv" "$work/pheno2/sdtab.csv" || fail "threads changed sdtab"

# FO (METHOD=ZERO) at Wang 2007's values: NONMEM's OFV 39.213; η̂ post hoc; the .ext names the method.
"$pkpop" --model 1cmt_iv --data "$root/datasets/wang2007.csv" --eta CL --method fo --error proportional \
  --theta CL=0.5 --theta V=1 --fix V --omega CL=0.04 --sigma SIGMA_PROP=0.31622776601683794 \
  --max-evaluations 0 -q -o "$work/wang_fo" 2>"$work/err.txt" || fail "FO at Wang's values: $(cat "$work/err.txt")"
grep -q "^FO: OFV 39.213" "$work/wang_fo/report.txt" || fail "FO's OFV: $(head -1 "$work/wang_fo/report.txt")"
grep -q "η̂: post hoc" "$work/wang_fo/report.txt" || fail "FO's report does not say its η̂ are post hoc"
head -1 "$work/wang_fo/pkpop.ext" | grep -q "First Order:" || fail "FO's .ext title: $(head -1 "$work/wang_fo/pkpop.ext")"
awk -F, 'NR > 1 && $6 != $5 { moved = 1 } END { exit !moved }' "$work/wang_fo/sdtab.csv" ||
  fail "FO's IPRED are its PRED: no post hoc η̂"

# FOCE on theophylline with a fixed θ and a fixed Ω block.
"$pkpop" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --eta KA,CL,V --method foce --error additive \
  --theta KA=1.5 --fix KA,'OMEGA(V)' --omega V=0.02 -q -o "$work/theo" || fail "theophylline FOCE exited non-zero"
grep -q "^KA,1.5,,,1,0$" "$work/theo/population_estimates.csv" || fail "KA was not held at 1.5"
grep -q "^OMEGA(V),0.02,,,1,0$" "$work/theo/population_estimates.csv" || fail "OMEGA(V) was not held at 0.02"
# NPDE from 5 simulations of 11 samples a subject: no subject's covariance has a factor, so no NPDE: exit 1
# with the PD written.
"$pkpop" --model 1cmt_oral --data "$root/datasets/theophylline.csv" --eta KA,CL,V --method foce --error additive \
  --init-from "$work/theo" --max-evaluations 0 --npde 5 -q -o "$work/theo_npde" 2>"$work/err.txt"
[ $? -eq 1 ] && grep -q "the NPDE failed: no sample has an NPDE" "$work/err.txt" && [ -s "$work/theo_npde/npde.csv" ] ||
  fail "NPDE without a factor: $(cat "$work/err.txt")"

# A model file's own η and covariates (NONMEM's phenobarbital example, models/pheno_pop.pkm): the
# η keep the file's names and Ω starts from its $OMEGA. Its linear right-hand side runs on Φ/Γ with
# derived coefficients, so the whole fit is quick: it reaches NONMEM 7's OFV, 586.27605628.
"$pkpop" --model "$root/models/pheno_pop.pkm" --data "$root/datasets/phenobarbital.csv" \
  --no-covariance -q -o "$work/pheno_file" 2>"$work/pheno_file.err" ||
  fail "the phenobarbital file fit exited non-zero: $(cat "$work/pheno_file.err")"
awk -F, '$1 == "OFV" { d = $2 - 586.27605628; if (d < 0) d = -d; found = 1; if (d > 1e-4) exit 1 }
         END { if (!found) exit 1 }' "$work/pheno_file/population_estimates.csv" ||
  fail "the file's OFV is not NONMEM's: $(grep OFV "$work/pheno_file/population_estimates.csv")"
head -1 "$work/pheno_file/iterations.csv" |
  grep -qx "EVALUATION,OFV,GRADIENT_NORM,TVCL,TVV,APGV,OMEGA(ETA_CL),OMEGA(ETA_V),SIGMA_PROP" ||
  fail "the file's θ and η names: $(head -1 "$work/pheno_file/iterations.csv")"
awk -F, 'NR == 2 { if ($7 != 0.05 && $7 !~ /^0.0500000000/) exit 1 }' "$work/pheno_file/iterations.csv" ||
  fail "Ω did not start from \$OMEGA"
head -1 "$work/pheno_file/subjects.csv" | grep -qx "ID,OK,OFV,ETA_CL,ETA_V,TVCL,TVV,APGV,FAPG,CL,V,MESSAGE" ||
  fail "subjects.csv lacks the file's \$PK definitions: $(head -1 "$work/pheno_file/subjects.csv")"
head -1 "$work/pheno_file/subjects.csv" | grep -q "^ID,OK,OFV,ETA_CL,ETA_V," || fail "subjects.csv η columns"
head -1 "$work/pheno_file/patab.csv" | grep -qx "ID,TIME,ETA_CL,ETA_V,FAPG,CL,V" ||
  fail "patab.csv: $(head -1 "$work/pheno_file/patab.csv")"
[ "$(($(wc -l <"$work/pheno_file/patab.csv")))" -eq "$(($(wc -l <"$work/pheno_file/sdtab.csv")))" ] ||
  fail "patab.csv and sdtab.csv should have a row per sample each"
# $OMEGA blocks: "ETA_CL + ETA_V ~ c(ω²_CL, ω_V,CL, ω²_V)" is NONMEM's BLOCK(2), estimated with its
# covariance from the file's values; with FIX the whole block stays there.
sed 's/^ETA_CL ~ 0.05$/ETA_CL + ETA_V ~ c(0.05, 0.01, 0.05)/; /^ETA_V  ~ 0.05$/d' \
  "$root/models/pheno_pop.pkm" >"$work/pheno_block.pkm"
grep -q "c(0.05, 0.01, 0.05)" "$work/pheno_block.pkm" || fail "the block file was not written"
"$pkpop" --model "$work/pheno_block.pkm" --data "$root/datasets/phenobarbital.csv" --no-covariance -q \
  -o "$work/pheno_block" || fail "the Ω block fit exited non-zero"
# A covariance's name holds a comma, so CSV quotes it: every row has as many fields as the header.
# (the header's one quoted comma is a field boundary to awk's split: one more than each row).
awk -F, 'NR == 1 { n = NF } NR > 1 && NF != n - 1 { exit 1 }' "$work/pheno_block/iterations.csv" ||
  fail "iterations.csv: a header and rows of unequal width"
head -1 "$work/pheno_block/iterations.csv" | grep -qF ',OMEGA(ETA_CL),"OMEGA(ETA_V,ETA_CL)",OMEGA(ETA_V),' ||
  fail "the covariance's column: $(head -1 "$work/pheno_block/iterations.csv")"
awk -F, 'NR == 2 { if ($8 != 0.01) exit 1 }' "$work/pheno_block/iterations.csv" ||
  fail "the block's covariance did not start from \$OMEGA: $(head -2 "$work/pheno_block/iterations.csv")"
grep -q '^"OMEGA(ETA_V,ETA_CL)",[0-9.e-]*,,,0,0$' "$work/pheno_block/population_estimates.csv" ||
  fail "the block's covariance is not estimated"
# A block run reads back (Ω's lower triangle by rows: the covariance before the second variance).
"$pksim" --model "$work/pheno_block.pkm" --population "$work/pheno_block" --dose 30 --times 1,2 --param WT=1.2 \
  --param APGAR=7 --subjects 3 --out "$work/pheno_block_sim.csv" 2>"$work/err.txt" ||
  fail "pksim --population of a run with an Ω block: $(cat "$work/err.txt")"
sed 's/c(0.05, 0.01, 0.05)/c(0.03, 0.005, 0.03) FIX/' "$work/pheno_block.pkm" >"$work/pheno_fix.pkm"
"$pkpop" --model "$work/pheno_fix.pkm" --data "$root/datasets/phenobarbital.csv" --no-covariance -q \
  -o "$work/pheno_fix" || fail "the fixed Ω block fit exited non-zero"
for row in "OMEGA(ETA_CL),0.03" '"OMEGA(ETA_V,ETA_CL)",0.005' "OMEGA(ETA_V),0.03"; do
  grep -qF "$row,,,1,0" "$work/pheno_fix/population_estimates.csv" || fail "$row is not held by FIX"
done
"$pkpop" --model "$root/models/pheno_pop.pkm" --data "$root/datasets/phenobarbital.csv" --eta ETA_KA \
  -o "$work/bad_eta" 2>"$work/bad_eta.err"
[ $? -eq 2 ] && grep -q "'ETA_KA' is not an estimable parameter or a random effect" "$work/bad_eta.err" ||
  fail "an unknown η: $(cat "$work/bad_eta.err")"

# Censored samples (CENS=1, DV the limit: Beal's M3) under Laplace: sdtab gains CENS, and a censored
# row has no residuals.
"$pkpop" --model 1cmt_oral --data "$root/datasets/theophylline_blq.csv" --error additive --method laplace \
  --no-covariance -q -o "$work/blq" || fail "the M3 Laplace fit exited non-zero"
head -1 "$work/blq/sdtab.csv" | grep -qx "ID,TIME,DVID,DV,PRED,IPRED,RES,WRES,CWRES,IWRES,CENS" ||
  fail "sdtab.csv without CENS: $(head -1 "$work/blq/sdtab.csv")"
[ "$(awk -F, '$11 == 1 && $7 == "" && $9 == "" && $10 == ""' "$work/blq/sdtab.csv" | wc -l)" -eq 27 ] ||
  fail "the 27 censored rows should have CENS=1 and empty RES, CWRES and IWRES"

# A VPC and simulated replicates at the estimates (the phenobarbital file; Φ/Γ, so quick): vpc.csv,
# vpc.svg, simtab.csv in the output set; a seed gives the same numbers, and another seed others.
vpc_run() {  # output directory, then further options
  local out=$1; shift
  "$pkpop" --model "$root/models/pheno_pop.pkm" --data "$root/datasets/phenobarbital.csv" --no-covariance -q \
    -o "$out" "$@" 2>"$out.err" || fail "the VPC run $* exited non-zero: $(cat "$out.err")"
}
vpc_run "$work/vpc" --vpc 50 --simulate 3 --seed 11
for f in vpc.csv vpc.svg simtab.csv; do
  grep -q "^$f," "$work/vpc/MANIFEST" || fail "$f is not in the MANIFEST"
done
head -1 "$work/vpc/vpc.csv" | grep -qx "DVID,BIN,TIME,TIME_LOWER,TIME_UPPER,N,PERCENTILE,OBSERVED,SIM_LOWER,SIM_MEDIAN,SIM_UPPER,CORRECTION" ||
  fail "vpc.csv header: $(head -1 "$work/vpc/vpc.csv")"
# Up to 10 bins (Jenks, those of fewer than 5 samples merged) × 3 percentiles; the bins hold all 155
# samples, 5 or more each; each interval holds its median.
awk -F, 'NR > 1 && $7 == 50 { n += $6; bins++; if ($6 < 5) bad = 1 } NR > 1 && !($9 <= $10 && $10 <= $11) { bad = 1 }
         END { exit bad || n != 155 || bins < 5 || bins > 10 || NR - 1 != 3 * bins }' "$work/vpc/vpc.csv" ||
  fail "vpc.csv: bins or intervals are wrong"
grep -q "<polygon" "$work/vpc/vpc.svg" || fail "vpc.svg has no bands"
grep -q "Visual predictive check" "$work/vpc/report.html" || fail "report.html has no VPC section"
head -1 "$work/vpc/simtab.csv" | grep -qx "REP,ID,TIME,DVID,DV,IPRED,PRED,ETA_CL,ETA_V" ||
  fail "simtab.csv header: $(head -1 "$work/vpc/simtab.csv")"
[ "$(tail -n +2 "$work/vpc/simtab.csv" | wc -l)" -eq 465 ] || fail "simtab.csv: expected 3 × 155 rows"
vpc_run "$work/vpc_again" --vpc 50 --simulate 3 --seed 11 -j 2
cmp -s "$work/vpc/vpc.csv" "$work/vpc_again/vpc.csv" || fail "the same seed (and two threads) changed vpc.csv"
cmp -s "$work/vpc/simtab.csv" "$work/vpc_again/simtab.csv" || fail "the same seed changed simtab.csv"
vpc_run "$work/vpc_other" --vpc 50 --seed 12 --pcvpc --vpc-bins 0,24,48,96,400
cmp -s "$work/vpc/vpc.csv" "$work/vpc_other/vpc.csv" && fail "another seed gave the same vpc.csv"
[ "$(tail -n +2 "$work/vpc_other/vpc.csv" | wc -l)" -eq 12 ] || fail "vpc.csv with 4 given bins: expected 12 rows"
grep -q "Prediction-corrected VPC" "$work/vpc_other/vpc.svg" || fail "the pcVPC's title"
awk -F, 'NR > 1 && $NF != "pc" { bad = 1 } END { exit bad }' "$work/vpc_other/vpc.csv" || fail "the pcVPC's vpc.csv does not say pc"
# pvcVPC (--pvcvpc implies the prediction correction): the same bins, other values, its own title.
vpc_run "$work/vpc_pvc" --vpc 50 --seed 12 --pvcvpc --vpc-bins 0,24,48,96,400
[ "$(tail -n +2 "$work/vpc_pvc/vpc.csv" | wc -l)" -eq 12 ] || fail "pvcVPC vpc.csv with 4 given bins: expected 12 rows"
cmp -s "$work/vpc_other/vpc.csv" "$work/vpc_pvc/vpc.csv" && fail "the variability correction changed nothing"
grep -q "Prediction- and variability-corrected VPC" "$work/vpc_pvc/vpc.svg" || fail "the pvcVPC's title"
grep -q "Prediction- and variability-corrected VPC: 50 replicates" "$work/vpc_pvc/report.html" ||
  fail "report.html does not name the pvcVPC"
# Stratified by Apgar score: a panel per score, the column first in vpc.csv.
vpc_run "$work/vpc_apgar" --vpc 20 --vpc-stratify apgar --vpc-bins 2
head -1 "$work/vpc_apgar/vpc.csv" | grep -q "^APGAR,DVID,BIN," || fail "the stratified vpc.csv's header"
[ "$(awk -F, 'NR > 1 && $8 == 50 { n += $7 } END { print n }' "$work/vpc_apgar/vpc.csv")" -eq 155 ] ||
  fail "the strata's bins should hold all 155 samples"
[ "$(grep -c "APGAR = " "$work/vpc_apgar/vpc.svg")" -eq "$(awk -F, 'NR > 1 { print $1 }' "$work/vpc_apgar/vpc.csv" | sort -u | wc -l)" ] ||
  fail "vpc.svg: a panel per Apgar score"

# --init-from that run with --max-evaluations 0 (NONMEM's MAXEVAL=0): no estimation, the run's estimates
# kept to every digit, and a VPC of the run without fitting again.
vpc_run "$work/vpc_of_run" --init-from "$work/vpc" --max-evaluations 0 --vpc 20 --seed 11
cmp -s <(grep -v '^OFV' "$work/vpc/population_estimates.csv") <(grep -v '^OFV' "$work/vpc_of_run/population_estimates.csv") ||
  fail "--init-from with --max-evaluations 0 moved the estimates"
grep -q "MAXEVAL=0" "$work/vpc_of_run/report.txt" || fail "report.txt should say that nothing was estimated"
[ -s "$work/vpc_of_run/vpc.csv" ] || fail "no VPC of the run"
# A bootstrap of 3 replicates: bootstrap.csv in the set, a section of report.html and of report.txt, the
# same on one thread and on two.
vpc_run "$work/boot" --bootstrap 3 --seed 3 -j 2
grep -q "^bootstrap.csv," "$work/boot/MANIFEST" || fail "bootstrap.csv is not in the MANIFEST"
[ "$(tail -n +2 "$work/boot/bootstrap.csv" | wc -l)" -eq 3 ] || fail "bootstrap.csv: expected 3 replicates"
head -1 "$work/boot/bootstrap.csv" | grep -q "^REPLICATE,CONVERGED,BOUNDARY,USED,OFV,TVCL,TVV,APGV," ||
  fail "bootstrap.csv header"
grep -q "<h2>Bootstrap</h2>" "$work/boot/report.html" || fail "report.html has no bootstrap section"
grep -q "^Bootstrap: 3 replicates (seed 3)" "$work/boot/report.txt" || fail "report.txt has no bootstrap table"
vpc_run "$work/boot_serial" --bootstrap 3 --seed 3 -j 1
cmp -s "$work/boot/bootstrap.csv" "$work/boot_serial/bootstrap.csv" || fail "threads changed bootstrap.csv"
# Stratified on Apgar (PsN's -stratify_on): said in the report, other draws than unstratified; an unknown
# column, or strata without a bootstrap, are option errors before any fitting.
vpc_run "$work/boot_strata" --bootstrap 3 --seed 3 --bootstrap-stratify APGAR
grep -q "^Bootstrap: 3 replicates (seed 3), stratified on APGAR (10 strata)" "$work/boot_strata/report.txt" ||
  fail "report.txt does not name the strata: $(grep '^Bootstrap' "$work/boot_strata/report.txt")"
cmp -s "$work/boot/bootstrap.csv" "$work/boot_strata/bootstrap.csv" && fail "strata did not change the draws"
grep -q "^warning: 5 of the 10 strata of APGAR hold fewer than 5 subjects" "$work/boot_strata/report.txt" ||
  fail "no warning of the small strata (APGAR 1, 2, 3, 4 and 10 hold fewer than 5 of the 59 neonates)"
"$pkpop" --model "$root/models/pheno_pop.pkm" --data "$root/datasets/phenobarbital.csv" --bootstrap 5 \
  --bootstrap-stratify ARM -q -o "$work/bad" >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "stratify by 'ARM'" "$work/err.txt" || fail "--bootstrap-stratify ARM: $(cat "$work/err.txt")"
"$pkpop" --model "$root/models/pheno_pop.pkm" --data "$root/datasets/phenobarbital.csv" --bootstrap-stratify APGAR \
  -q -o "$work/bad" >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "needs --bootstrap N" "$work/err.txt" || fail "--bootstrap-stratify alone: $(cat "$work/err.txt")"
"$pkpop" --model "$root/models/pheno_pop.pkm" --data "$root/datasets/phenobarbital.csv" --bootstrap 5 \
  --max-evaluations 0 -q -o "$work/bad" >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "bootstrap needs estimation" "$work/err.txt" || fail "--bootstrap at MAXEVAL=0: $(cat "$work/err.txt")"

# A bootstrap stopped midway loses nothing of the fit: its output set is written whole before the analyses,
# and a later run reads it (--init-from checks the manifest).
"$pkpop" --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --eta CL,V --error proportional --no-covariance \
  --bootstrap 100000 -q -o "$work/stopped" >/dev/null 2>&1 &
stopped=$!
for _ in $(seq 1200); do [ -s "$work/stopped/MANIFEST" ] && break; sleep 0.05; done
kill "$stopped" 2>/dev/null; wait "$stopped" 2>/dev/null
[ -s "$work/stopped/MANIFEST" ] || fail "no complete output set before the bootstrap"
grep -q "^bootstrap.csv," "$work/stopped/MANIFEST" && fail "the stopped bootstrap's set lists bootstrap.csv"
"$pkpop" --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --eta CL,V --error proportional --no-covariance \
  --init-from "$work/stopped" --max-evaluations 0 -q -o "$work/stopped_again" 2>"$work/err.txt" ||
  fail "the set written before a stopped bootstrap cannot be read: $(cat "$work/err.txt")"
grep -q "^FOCEI: OFV 730.8947" "$work/stopped_again/report.txt" || fail "the stopped run's estimates: $(head -1 "$work/stopped_again/report.txt")"
# Nor does pkpop stopped while it writes the set with the analyses: until its MANIFEST, the fit's own
# vouches for the files the second set holds byte for byte, which are all the fit's (the same run,
# finished, lists them with the same size and CRC-32 as the first set, written before the analyses).
"$pkpop" --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --eta CL,V --error proportional --no-covariance \
  --simulate 1 -q -o "$work/finished" >/dev/null 2>&1 || fail "the run with --simulate 1 failed"
for f in population_estimates.csv sdtab.csv patab.csv subjects.csv iterations.csv covariance.csv pkpop.ext pkpop.phi; do
  first=$(grep "^$f," "$work/stopped/MANIFEST"); second=$(grep "^$f," "$work/finished/MANIFEST")
  [ -n "$first" ] && [ "$first" = "$second" ] || fail "$f: the fit's set lists '$first', the set with the analyses '$second'"
done
grep -q "^simtab.csv," "$work/finished/MANIFEST" || fail "simtab.csv is not in the finished run's MANIFEST"

# Inter-occasion variability: models/iov_pop.pkm's IOV2 and IOV3 ~ SAME as IOV1, tabled with IOV1's value
# and flagged SAME (at the initial estimates: the table, not the fit, is under test here).
vpc_run_iov() { "$pkpop" --model "$root/models/iov_pop.pkm" --data "$root/datasets/iov_synthetic.csv" --error additive \
  --max-evaluations 0 --no-covariance -q -o "$work/iov" 2>"$work/iov.err" || fail "the IOV run: $(cat "$work/iov.err")"; }
vpc_run_iov
grep -q "OMEGA(IOV3) .* SAME" "$work/iov/report.txt" || fail "report.txt does not flag OMEGA(IOV3) SAME"
[ "$(awk -F, '$1 ~ /^OMEGA\(IOV[123]\)$/ { print $2 }' "$work/iov/population_estimates.csv" | sort -u | wc -l)" -eq 1 ] ||
  fail "the SAME variances differ from IOV1's in population_estimates.csv"

# --block CL and V into one block keeps the occasions' SAME ties, which it leaves as they were; --block
# IOV1,IOV2 regroups them and drops the ties it breaks (IOV3's source is no longer a block of one), with a note.
"$pkpop" --model "$root/models/iov_pop.pkm" --data "$root/datasets/iov_synthetic.csv" --error additive \
  --block ETA_CL,ETA_V --max-evaluations 0 --no-covariance -q -o "$work/iov_block" 2>"$work/err.txt" ||
  fail "--block with SAME ties: $(cat "$work/err.txt")"
grep -q "OMEGA(IOV3) .* SAME" "$work/iov_block/report.txt" && grep -q "OMEGA(IOV2) .* SAME" "$work/iov_block/report.txt" &&
  grep -q "OMEGA(ETA_V,ETA_CL)" "$work/iov_block/report.txt" || fail "--block ETA_CL,ETA_V: $(cat "$work/iov_block/report.txt")"
grep -q "SAME" "$work/err.txt" && fail "--block ETA_CL,ETA_V noted a dropped tie: $(cat "$work/err.txt")"
"$pkpop" --model "$root/models/iov_pop.pkm" --data "$root/datasets/iov_synthetic.csv" --error additive \
  --block IOV1,IOV2 --max-evaluations 0 --no-covariance -q -o "$work/iov_block2" 2>"$work/err.txt" ||
  fail "--block IOV1,IOV2: $(cat "$work/err.txt")"
grep -q "the model file's SAME ties of IOV2, IOV3 are dropped" "$work/err.txt" ||
  fail "--block IOV1,IOV2: no note of the dropped ties: $(cat "$work/err.txt")"
grep -q "SAME" "$work/iov_block2/report.txt" && fail "--block IOV1,IOV2 kept a tie"
# FIX stays with a block --block leaves as it was: IOV1 ~ 0.03 FIX beside --block ETA_CL,ETA_V.
sed 's/^IOV1   ~ 0.03$/IOV1   ~ 0.03 FIX/' "$root/models/iov_pop.pkm" > "$work/iov_fix.pkm"
grep -q "IOV1   ~ 0.03 FIX" "$work/iov_fix.pkm" || fail "the FIX variant of iov_pop.pkm was not made"
"$pkpop" --model "$work/iov_fix.pkm" --data "$root/datasets/iov_synthetic.csv" --error additive \
  --block ETA_CL,ETA_V --max-evaluations 0 --no-covariance -q -o "$work/iov_fix" 2>"$work/err.txt" ||
  fail "--block with a FIX block: $(cat "$work/err.txt")"
grep -q "^OMEGA(IOV1),0.03,,,1,0$" "$work/iov_fix/population_estimates.csv" ||
  fail "--block ETA_CL,ETA_V freed IOV1's FIX: $(grep IOV1 "$work/iov_fix/population_estimates.csv")"

"$pkpop" --model "$root/models/iov_pop.pkm" --data "$root/datasets/iov_synthetic.csv" --fix 'OMEGA(IOV2)' -q \
  -o "$work/bad" >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "SAME as the block before it, and follows it: fix that one" "$work/err.txt" ||
  fail "--fix on a SAME block: $(cat "$work/err.txt")"

# NPDE of that run: every sample, in the set and the report; the same on one thread and on two.
vpc_run "$work/npde" --init-from "$work/vpc" --max-evaluations 0 --npde 200 --seed 5 -j 2
grep -q "^npde.svg," "$work/npde/MANIFEST" && grep -q "^npde.csv," "$work/npde/MANIFEST" || fail "npde files not in the MANIFEST"
head -1 "$work/npde/npde.csv" | grep -qx "ID,TIME,DVID,DV,CENS,EPRED,PD,NPD,PDE,NPDE" ||
  fail "npde.csv header: $(head -1 "$work/npde/npde.csv")"
awk -F, 'NR > 1 && $10 != "" && $9 > 0 && $9 < 1 { n++ } END { exit n != 155 }' "$work/npde/npde.csv" ||
  fail "npde.csv: expected an NPDE for each of the 155 samples"
grep -q "Normalised prediction distribution errors" "$work/npde/report.html" || fail "report.html has no NPDE section"
vpc_run "$work/npde_serial" --init-from "$work/vpc" --max-evaluations 0 --npde 200 --seed 5 -j 1
cmp -s "$work/npde/npde.csv" "$work/npde_serial/npde.csv" || fail "threads changed npde.csv"
"$pkpop" --model "$root/models/pheno_pop.pkm" --data "$root/datasets/phenobarbital.csv" --npde 1 -q -o "$work/bad" \
  >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "npde: expected 0 (none) or 2 to 100000" "$work/err.txt" || fail "--npde 1: $(cat "$work/err.txt")"
"$pkpop" --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --init-from "$work/vpc" -q -o "$work/bad" \
  >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "'TVCL' is not a parameter of model 1cmt_iv" "$work/err.txt" ||
  fail "--init-from a run of another model: $(cat "$work/err.txt")"

# pksim --population simulates with that run's θ, Ω and σ: on the fitted data and seed, the η of
# simtab.csv exactly and its DV to rounding; a regimen for 20 subjects, each its own η.
"$pksim" --model "$root/models/pheno_pop.pkm" --data "$root/datasets/phenobarbital.csv" --population "$work/vpc" \
  --seed 11 --replicates 3 --out "$work/pksim_pop.csv" 2>"$work/pksim_pop.err" ||
  fail "pksim --population exited non-zero: $(cat "$work/pksim_pop.err")"
head -1 "$work/pksim_pop.csv" | grep -qx "REP,ID,TIME,EVID,CP,DV,A1,ETA_CL,ETA_V" ||
  fail "pksim --population header: $(head -1 "$work/pksim_pop.csv")"
cmp -s <(awk -F, 'NR > 1 { print $1, $2, $3, $8, $9 }' "$work/vpc/simtab.csv") \
       <(awk -F, 'NR > 1 { print $1, $2, $3, $8, $9 }' "$work/pksim_pop.csv") ||
  fail "pksim --population drew other η than pkpop --simulate"
paste -d, <(tail -n +2 "$work/vpc/simtab.csv") <(tail -n +2 "$work/pksim_pop.csv") |
  awk -F, '{ d = ($5 - $15) / $5; if (d < 0) d = -d; if (d > 1e-12) bad = 1 } END { exit bad }' ||
  fail "pksim --population's DV differ from simtab.csv's"
"$pksim" --model "$root/models/pheno_pop.pkm" --population "$work/vpc" --dose 30 --ii 12 --doses 4 --times 0:6:48 \
  --param WT=1.2 --param APGAR=7 --subjects 20 --seed 5 --out "$work/pksim_regimen.csv" 2>"$work/pksim_regimen.err" ||
  fail "pksim --population with a regimen exited non-zero: $(cat "$work/pksim_regimen.err")"
[ "$(awk -F, 'NR > 1 { print $1 }' "$work/pksim_regimen.csv" | sort -u | wc -l)" -eq 20 ] ||
  fail "the regimen for 20 subjects"
[ "$(awk -F, 'NR > 1 { print $7 }' "$work/pksim_regimen.csv" | sort -u | wc -l)" -eq 20 ] ||
  fail "the 20 subjects should each have an η of their own"
# With the estimates' uncertainty: each replicate's θ, Ω and σ drawn from the covariance step's normal, or
# taken from a bootstrap's used replicates; a run without a covariance step has none to draw from.
regimen=(--dose 30 --ii 12 --doses 4 --times 0:6:48 --subjects 5 --replicates 4 --seed 5)
"$pksim" --model 1cmt_iv --population "$work/pheno" "${regimen[@]}" --out "$work/plain.csv" 2>/dev/null ||
  fail "pksim --population of the phenobarbital run"
"$pksim" --model 1cmt_iv --population "$work/pheno" "${regimen[@]}" --uncertainty covariance \
  --out "$work/uncertain.csv" 2>"$work/err.txt" || fail "pksim --uncertainty covariance: $(cat "$work/err.txt")"
grep -q "drawn from N(estimates, .*covariance.csv)" "$work/err.txt" || fail "no note of the draws: $(cat "$work/err.txt")"
[ "$(wc -l < "$work/uncertain.csv")" -eq "$(wc -l < "$work/plain.csv")" ] || fail "--uncertainty changed the rows"
cmp -s "$work/plain.csv" "$work/uncertain.csv" && fail "--uncertainty covariance changed nothing"
"$pksim" --model "$root/models/pheno_pop.pkm" --population "$work/boot" "${regimen[@]}" --param WT=1.2 --param APGAR=7 \
  --uncertainty "$work/boot" --out "$work/uncertain_boot.csv" 2>"$work/err.txt" ||
  fail "pksim --uncertainty from a bootstrap: $(cat "$work/err.txt")"
grep -q "from one of the 3 used replicates of .*bootstrap.csv" "$work/err.txt" ||
  fail "no note of the bootstrap's sets: $(cat "$work/err.txt")"
"$pksim" --model "$root/models/pheno_pop.pkm" --population "$work/vpc" "${regimen[@]}" --param WT=1.2 --param APGAR=7 \
  --uncertainty covariance >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "no estimate has a variance" "$work/err.txt" ||
  fail "--uncertainty covariance without a covariance step: $(cat "$work/err.txt")"
"$pksim" --model 1cmt_iv --population "$work/pheno" "${regimen[@]}" --uncertainty "$work/pheno" >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "the run has no bootstrap.csv" "$work/err.txt" || fail "--uncertainty DIR without a bootstrap: $(cat "$work/err.txt")"
"$pksim" --model 1cmt_iv --dose 1 --times 1 --uncertainty covariance >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "need --population" "$work/err.txt" || fail "--uncertainty without --population: $(cat "$work/err.txt")"
"$pksim" --model 1cmt_iv --dose 1 --times 1 --seed 3 >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "need --population" "$work/err.txt" || fail "--seed without --population: $(cat "$work/err.txt")"
"$pksim" --model 1cmt_iv --dose 1 --times 1 --population "$work/vpc" >"$work/err.txt" 2>&1
[ $? -eq 2 ] && grep -q "population_estimates.csv:2:1: 'TVCL' is not a parameter of model 1cmt_iv" "$work/err.txt" ||
  fail "a population of another model: $(cat "$work/err.txt")"

# Input errors exit with 2 and say what is wrong.
expect_error() {  # expected message, then arguments
  local msg=$1; shift
  "$pkpop" "$@" -q -o "$work/bad" >"$work/err.txt" 2>&1
  local rc=$?
  [ $rc -eq 2 ] || fail "'$*' exited $rc, expected 2"
  grep -qF -- "$msg" "$work/err.txt" || fail "'$*': expected '$msg', got: $(cat "$work/err.txt")"
}
pheno=("--model" "1cmt_iv" "--data" "$root/datasets/phenobarbital.csv")
expect_error "'Q' is not an estimable parameter" "${pheno[@]}" --eta CL,Q
expect_error "expected fo, foce, focei or laplace" "${pheno[@]}" --method foi
expect_error "needs a residual-error model" "${pheno[@]}" --error least-squares
expect_error "--block CL,V: the η must be consecutive" --model 1cmt_oral --data "$root/datasets/theophylline.csv" \
  --eta CL,KA,V --block CL,V
expect_error "--omega: unknown name 'KA'" "${pheno[@]}" --omega KA=0.1
expect_error "--model and --data are required" --model 1cmt_iv
expect_error "27 censored samples (CENS): their likelihood (Beal's M3) needs --method laplace" \
  --model 1cmt_oral --data "$root/datasets/theophylline_blq.csv" --error additive
expect_error "--omega CL:V: the two η are not in one Ω block" "${pheno[@]}" --omega CL:V=0.01
expect_error "initial Ω block of CL is not positive definite" "${pheno[@]}" --block CL,V --omega CL:V=1
expect_error "--vpc: expected 0 to 100000 replicates" "${pheno[@]}" --vpc -1
expect_error "need --vpc N" "${pheno[@]}" --pcvpc
expect_error "need --vpc N" "${pheno[@]}" --pvcvpc
expect_error "--vpc: the bin edges must increase" "${pheno[@]}" --vpc 10 --vpc-bins 0,5,5
expect_error "--vpc: the percentiles must increase" "${pheno[@]}" --vpc 10 --vpc-percentiles 95,5
expect_error "--seed: expected a whole number" "${pheno[@]}" --simulate 2 --seed -3
expect_error "--seed needs --vpc N, --npde N, --simulate N or --bootstrap N" "${pheno[@]}" --seed 3
expect_error "VPC: WT has 21 values; stratify by a categorical column" "${pheno[@]}" --vpc 5 --vpc-stratify WT
expect_error "stratify by 'AGE': " "${pheno[@]}" --vpc 5 --vpc-stratify AGE

[ $failures -eq 0 ] && echo "pkpop CLI: all checks passed"
exit $failures
