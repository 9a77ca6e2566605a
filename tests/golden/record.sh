#!/usr/bin/env bash
# Records pkfit's and pksim's outputs over every catalogue model on every bundled dataset, plus
# the error models, optimisers, gradient routes and propagators on a few, into OUT. Two such
# records (before and after a change that must keep every number) are compared by compare.sh:
#
#   tests/golden/record.sh build/apps /tmp/before      # at the old commit
#   tests/golden/record.sh build/apps /tmp/after       # at the new one
#   tests/golden/compare.sh /tmp/before /tmp/after     # 1e-12 relative, timings left out
#
# pkfit's exit code and stderr are recorded too. Takes about a minute on 2 cores.
set -uo pipefail
bin=$1; out=$2
root=$(cd "$(dirname "$0")/../.." && pwd)
pkfit=$bin/pkfit; pksim=$bin/pksim
rm -rf "$out"; mkdir -p "$out"
data=$root/datasets

fit() {  # fit NAME ARGS...
  local name=$1; shift
  timeout 120 "$pkfit" "$@" -o "$out/$name" -q -j 2 >"$out/$name.stdout" 2>"$out/$name.stderr"
  echo "exit $?" >>"$out/$name.stderr"
}
sim() {  # sim NAME ARGS...
  local name=$1; shift
  timeout 120 "$pksim" "$@" >"$out/$name.sim.csv" 2>"$out/$name.sim.stderr"
  echo "exit $?" >>"$out/$name.sim.stderr"
}

models=$("$pkfit" --model no_such_model --data "$data/theophylline.csv" 2>&1 | sed -n 's/.*the catalogue has //p' | tr -d ',')
for model in $models; do
  for file in "$data"/*.csv; do
    name=$(basename "$file" .csv)
    case $name in *_truth) continue ;; esac
    fit "grid.$model.$name" --model "$model" --data "$file"
    sim "grid.$model.$name" --model "$model" --data "$file" --times 0:1:24
  done
done

theo=$data/theophylline.csv
for error in additive proportional combined exponential; do
  fit "error.$error" --model 1cmt_oral --data "$theo" --error "$error"
  fit "error.$error.bfgs" --model 1cmt_oral --data "$theo" --error "$error" --optimizer bfgs
done
fit "blq.m3" --model 1cmt_oral --data "$data/theophylline_blq.csv" --error additive
fit "blq.m3.exp" --model 1cmt_oral --data "$data/theophylline_blq.csv" --error exponential --optimizer bfgs
for route in forward adjoint fd; do
  fit "route.$route" --model 2cmt_iv --data "$data/indomethacin.csv" --gradient "$route" --optimizer bfgs
  fit "route.ode.$route" --model 1cmt_oral --data "$theo" --propagator ode --gradient "$route" --optimizer bfgs
  fit "route.mm.$route" --model 1cmt_iv_mm --data "$data/mm_synthetic.csv" --gradient "$route" --optimizer bfgs \
    --error proportional
done
fit "opt.newton" --model 2cmt_iv --data "$data/indomethacin.csv" --optimizer newton
fit "opt.slsqp" --model 1cmt_oral --data "$theo" --optimizer nlopt:LD_SLSQP
fit "opt.bobyqa" --model 1cmt_oral --data "$theo" --optimizer nlopt:LN_BOBYQA
fit "opt.starts" --model 2cmt_iv --data "$data/indomethacin.csv" --starts 4
fit "opt.linear" --model 1cmt_oral --data "$theo" --linear-scale --lower KA=0.1 --upper KA=10
fit "weights.dv2" --model 1cmt_oral --data "$theo" --weighting dv2
fit "weights.column" --model 1cmt_iv_emax --data "$data/emax_synthetic.csv" --weighting column:W
fit "prior" --model 1cmt_oral --data "$theo" --error additive --prior KA=1.5,0.5
fit "tf2" --model tf2 --data "$data/indomethacin.csv" --gradient companion
fit "fixed" --model 1cmt_oral --data "$theo" --fix KA=1.5 --init CL=2
fit "population.full" --model 1cmt_oral --data "$theo" --omega full
fit "catalogue_init" --model 2cmt_oral --data "$theo" --catalogue-init
fit "filter" --model 1cmt_oral --data "$theo" --ignore 'ID.GT.6'
"$pkfit" --model 1cmt_oral --data "$theo" --evaluate --init KA=1.2 --gradient adjoint \
  >"$out/evaluate.csv" 2>"$out/evaluate.stderr"
"$pkfit" --model 1cmt_iv_mm --data "$data/mm_synthetic.csv" --evaluate --gradient forward --error combined \
  >"$out/evaluate.mm.csv" 2>"$out/evaluate.mm.stderr"

sim "regimen.oral" --model 2cmt_oral --dose 500 --ii 12 --doses 14 --times 0:0.5:168
sim "regimen.summary" --model 2cmt_oral --dose 500 --ii 12 --doses 5 --times 0:0.5:72 --summary
sim "regimen.infusion" --model 1cmt_iv --dose 1000 --duration 2 --times 0:0.1:24 --param CL=4
sim "regimen.ss" --model 1cmt_oral_mm --dose 100 --ii 12 --ss 1 --times 0:0.5:24
sim "estimates" --model 1cmt_oral --estimates "$out/grid.1cmt_oral.theophylline/estimates.csv" --dose 320 \
  --ii 12 --doses 10 --times 0:1:120
echo "recorded in $out"
