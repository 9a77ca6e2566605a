#!/usr/bin/env bash
# pksim as a whole process against R's vectorised closed form, in one run (issue 28): 1000 subjects ×
# 200 output times of 2cmt_oral, 500 mg every 12 h (five doses by ADDL), each subject's KA, CL, V2, Q, V3
# in data columns. Times are medians of 5 (pksim: wall time of the process, CSV written whole; R: the
# computation alone, in-process). Run from the repository root after a Release build:
#   benchmarks/pksim_vs_r.sh [build]
set -euo pipefail
build=${1:-build}
pksim=$build/apps/pksim
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
awk 'BEGIN { print "ID,TIME,AMT,ADDL,II,KA,CL,V2,Q,V3";
             for (id = 1; id <= 1000; ++id)
               printf "%d,0,500,4,12,%.4g,%.4g,%.4g,%.4g,%.4g\n", id, 1.2 * exp(0.2 * sin(3 * id)),
                      3 * exp(0.3 * sin(id)), 20 * exp(0.2 * cos(id)), 4 * exp(0.1 * cos(2 * id)), 40 }' \
  > "$work/doses.csv"
run_pksim() {  # median wall time of 5 runs, in ms: jobs, output file, pksim's further options
  local jobs=$1 out=$2 t=()
  shift 2
  for r in 1 2 3 4 5; do
    local t0=$(date +%s%N)
    "$pksim" --model 2cmt_oral --data "$work/doses.csv" --times 0.48:0.48:96 -j "$jobs" --out "$out" "$@"
    t+=($(( ($(date +%s%N) - t0) / 1000 )))
  done
  printf '%s\n' "${t[@]}" | sort -n | sed -n 3p | awk '{ printf "%.1f", $1 / 1000 }'
}
one=$(run_pksim 1 "$work/sim.csv")
two=$(run_pksim 2 "$work/sim.csv")
echo "pksim, 1000 subjects x 200 times, whole process, CSV fsynced to $(df --output=fstype "$work" | tail -1):" \
     "${one} ms (-j 1), ${two} ms (-j 2); $(wc -c < "$work/sim.csv") bytes"
# What R computes, the concentration: --columns ID,TIME,CP (the three amounts are most of the text).
echo "pksim --columns ID,TIME,CP, the same process: $(run_pksim 1 "$work/cp.csv" --columns ID,TIME,CP) ms (-j 1)," \
     "$(run_pksim 2 "$work/cp.csv" --columns ID,TIME,CP) ms (-j 2); $(wc -c < "$work/cp.csv") bytes"
if [ -w /dev/shm ]; then  # the same without the disk: memory-backed, where fsync and rename cost nothing
  shm=/dev/shm/pksim_vs_r_$$.csv
  echo "pksim, the same written to /dev/shm (tmpfs): $(run_pksim 1 "$shm") ms (-j 1), $(run_pksim 2 "$shm") ms (-j 2)"
  rm -f "$shm"
fi
Rscript tests/reference/time_closed_form.R "$work/doses.csv" 0.48 0.48 96 "$work/sim.csv"
