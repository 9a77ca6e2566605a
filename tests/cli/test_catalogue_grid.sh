#!/usr/bin/env bash
# Every catalogue model on every bundled dataset, with pkfit's defaults: each run ends within its time limit with
# exit 0 (converged), 1 (some subject failed or did not converge) or 2 (the data do not fit the model, said with
# file:line:column). A crash or a hang fails. (3cmt_iv on theophylline hung until c941975.)
set -uo pipefail
pkfit=$1; root=$2; work=$3
rm -rf "$work"; mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }

# The catalogue, as pkfit lists it for an unknown model.
models=$("$pkfit" --model no_such_model --data "$root/datasets/theophylline.csv" 2>&1 | sed -n 's/.*which has //p' |
         tr -d ',')
[ -n "$models" ] || { echo "FAIL: pkfit did not list the catalogue"; exit 1; }
runs=0
for model in $models; do
  for data in "$root"/datasets/*.csv; do
    name=$(basename "$data" .csv)
    case $name in *_truth) continue ;; esac  # a table of true values, not a dataset
    out="$work/$model.$name"
    timeout 60 "$pkfit" --model "$model" --data "$data" -o "$out" -q -j 2 >"$out.stdout" 2>"$out.stderr"
    rc=$?
    runs=$((runs + 1))
    case $rc in
      0|1) [ -s "$out/summary.csv" ] || fail "$model on $name: exit $rc without summary.csv" ;;
      2) grep -q "^pkfit: error: .*$name.csv:[0-9]*:[0-9]*: " "$out.stderr" ||
           fail "$model on $name: exit 2 without file:line:column: $(head -c 200 "$out.stderr")" ;;
      124) fail "$model on $name: no result within 60 s" ;;
      *) fail "$model on $name: exit $rc: $(tail -c 300 "$out.stderr")" ;;
    esac
  done
done
[ "$runs" -ge 100 ] || fail "only $runs runs"
echo "$runs runs, $failures failures"
[ "$failures" -eq 0 ]
