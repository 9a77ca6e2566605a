#!/usr/bin/env bash
# Installs what is missing, builds, and runs the main job on bundled data:
# fits the 12 theophylline subjects with a one-compartment oral model, prints
# the estimates and writes a report; simulates dosing regimens; and estimates a
# population model (FOCEI) from the sparse phenobarbital data of 59 neonates.
set -euo pipefail
cd "$(dirname "$0")/.."
echo "== installing what is missing (Debian packages) =="
scripts/install-deps.sh
echo "== configuring =="
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
# The build's own progress lines ([ 42%] ...) and any warning stay visible: about 9 minutes on 2 cores
# the first time, seconds after.
echo "== building pkfit, pksim and pkpop =="
cmake --build build -j "$(nproc 2>/dev/null || echo 2)" --target pkfit pksim pkpop
mkdir -p out

echo "== pkfit: theophylline (12 subjects, single oral dose), 1cmt_oral, least squares =="
build/apps/pkfit --model 1cmt_oral --data datasets/theophylline.csv --units time=h,amt=mg,conc=mg/L \
  --output-dir out/theophylline
echo "open out/theophylline/report.html for the fits, goodness-of-fit plots, standard errors, correlations and the"
echo "two-stage population summary (out/theophylline/population.csv)"
echo

echo "== pkfit: theophylline below an imposed limit of 2 mg/L (27 of 132 samples censored), Beal's M3 =="
build/apps/pkfit --model 1cmt_oral --data datasets/theophylline_blq.csv --error additive --output-dir out/theophylline_blq
echo "(censored samples are drawn hollow at their limit in out/theophylline_blq/report.html)"
echo

echo "== pksim: each fitted theophylline subject on 320 mg every 12 h for 5 days (--estimates) =="
build/apps/pksim --model 1cmt_oral --estimates out/theophylline/estimates.csv --dose 320 --ii 12 --doses 10 \
  --times 0:0.5:120 --out out/theophylline_regimen.csv --summary-csv out/theophylline_regimen_summary.csv
grep ",ALL," out/theophylline_regimen_summary.csv | awk -F, '{ printf "  ID %-3s Cmax %6.2f at t = %5.1f h\n", $1, $5, $6 }'
echo

echo "== pkfit: Michaelis-Menten elimination (synthetic, 6 subjects), 1cmt_iv_mm through CVODES =="
build/apps/pkfit --model 1cmt_iv_mm --data datasets/mm_synthetic.csv --output-dir out/mm
echo "(the truth per subject is in datasets/mm_synthetic_truth.csv)"
echo

echo "== pksim: 2cmt_oral, 1000 mg loading dose then 500 mg every 12 h for a week =="
cat > out/regimen.csv <<'CSV'
ID,TIME,AMT,II,ADDL,EVID,CMT
1,0,1000,0,0,1,1
1,12,500,12,12,1,1
CSV
build/apps/pksim --model 2cmt_oral --data out/regimen.csv --param KA=1.2 --param CL=4 --param V2=25 \
  --param Q=6 --param V3=60 --times 0:0.25:168 --out out/regimen_sim.csv --summary \
  --summary-csv out/regimen_summary.csv --plot out/regimen.svg | head -8
echo "   ... (full table in out/regimen_summary.csv; plot in out/regimen.svg)"
echo

echo "== pkpop: phenobarbital (59 neonates, 155 samples), 1cmt_iv, FOCEI, η on CL and V, proportional error =="
build/apps/pkpop --model 1cmt_iv --data datasets/phenobarbital.csv --eta CL,V --error proportional \
  -o out/phenobarbital_pop --vpc 200 --pcvpc --npde 1000
echo "open out/phenobarbital_pop/report.html for the estimates with SE and shrinkage, goodness-of-fit plots"
echo "(DV against PRED and IPRED, CWRES, IWRES), a visual predictive check of 200 simulated replicates"
echo "(prediction-corrected: each neonate's dose follows its weight), NPDE from 1000 simulations,"
echo "η against weight and Apgar score, and each neonate's fit"
