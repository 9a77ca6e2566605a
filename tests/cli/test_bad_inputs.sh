#!/usr/bin/env bash
# The catalogue of bad inputs (issue 28): each input a user can get wrong, the exit code it must give
# (docs/cli.md: 1 some subject failed, 2 input or option error, 3 output failure) and a fragment of
# the message that must name what is wrong. One line per case below; add a case with its line.
set -uo pipefail
pkfit=$1; pksim=$2; root=$3; work=$4
rm -rf "$work"; mkdir -p "$work"; cd "$work" || exit 1
theo=$root/datasets/theophylline.csv
failures=0

printf 'ID,TIME,AMT,DV\n1,0,100,.\n1,1,0,2.\0 84\n' >nul.csv
printf 'ID,TIME,AMT,DV\r1,0,100,.\r1,1,0,3\r' >cr_only.csv
printf 'ID,TIME,AMT,DV\n1,0,100,.\n1,0x1p-2,0,3\n' >hex.csv
printf 'ID,TIME,AMT,DV\n1,0,100,.\n1,inf,0,3\n' >inf.csv
printf 'ID,TIME,AMT,DV\n2.5,0,100,.\n2.5,1,0,3\n' >fractional_id.csv
printf 'ID,TIME,AMT,DV\n1e300,0,100,.\n1e300,1,0,3\n' >huge_id.csv
printf 'ID,TIME,AMT,DV\n1,0,100,.\n1,1e300,0,3\n' >huge_time.csv
printf 'ID,TIME,AMT,DV,CL\n1,0,100,.,-3\n1,1,0,3,-3\n1,2,0,2,-3\n' >negative_cl_column.csv
printf 'ID,TIME,AMT,DV\n1,0,100,.\n1,1,0,5\n1,2,0,5\n1,4,0,5\n1,8,0,5\n' >constant_dv.csv
printf 'ID,TIME,AMT,RATE,DV\n1,0,100,-1,.\n1,1,0,0,3\n1,2,0,0,2\n' >rate_without_r1.csv
printf 'ID,TIME,AMT,DV\n1,0,100,.\n1,1,0,\001\002junk\n' >binary_junk.csv
printf 'ID;TIME;AMT;DV\n1;0;100;.\n' >semicolons.csv
printf 'ID,TIME,AMT,DV\n1,0,100,.\n1,2,0,3\n1,1,0,4\n' >time_decreases.csv
printf 'ID,TIME,AMT,DV\n1,0,100,.\n1,1,0,3,7\n' >extra_field.csv
printf 'ID,TIME,AMT,DV\n1,0,-100,.\n1,1,0,3\n' >negative_amt.csv
printf 'ID,TIME,AMT,DV\n' >no_records.csv
printf 'ID,PARAMETER,ESTIMATE\n1,KA,1\n1,CL,2\n1,V,30\n1,KA,2\n' >estimates_twice.csv
printf 'ID,PARAMETER,ESTIMATE\n1,KA,1\n1,CLEARANCE,2\n' >estimates_unknown.csv
printf 'ID,TIME,AMT,DV,V1\n1,0,100,.,20\n1,1,0,3,20\n' >former_name_column.csv
printf 'ID,TIME,AMT\n1,0,100\n1,1,0\n' >no_dv.csv
printf '$PROBLEM typo\n$PARAM\nCL = 3\nV = 30\n$CMT\nCENTRAL\n$ODE\nd/dt(CENTRAL) = -CL / VV * CENTRAL\n$OUTPUT\nCP = CENTRAL / V\n' >typo.pkm
printf '$PROBLEM wt\n$PARAM\nCL = 3\nV = 30\n$COVARIATE\nWT\n$CMT\nCENTRAL\n$ODE\nd/dt(CENTRAL) = -CL * WT / 70 / V * CENTRAL\n$OUTPUT\nCP = CENTRAL / V\n' >wt.pkm
mkdir -p killed && printf 'ID,PARAMETER,ESTIMATE\n1,KA,1\n' >killed/estimates.csv && printf 'ID\n1\n' >killed/fit_details.csv

# exit | program | message fragment | arguments (one string, split on spaces)
cases=$(cat <<CASES
2|pkfit|a NUL byte|--model 1cmt_oral --data nul.csv
2|pkfit|carriage return (CR) that does not end a line|--model 1cmt_oral --data cr_only.csv
2|pkfit|write numbers in decimal|--model 1cmt_oral --data hex.csv
2|pkfit|'inf' is not a number|--model 1cmt_oral --data inf.csv
2|pkfit|ID must be a whole number|--model 1cmt_oral --data fractional_id.csv
2|pkfit|ID must be a whole number (of at most 15 digits)|--model 1cmt_oral --data huge_id.csv
2|pkfit|is beyond ±1e+10|--model 1cmt_oral --data huge_time.csv
2|pkfit|\\x01\\x02junk' is not a number|--model 1cmt_oral --data binary_junk.csv
2|pkfit|this header seems to use ';'|--model 1cmt_oral --data semicolons.csv
2|pkfit|TIME decreases within ID 1|--model 1cmt_oral --data time_decreases.csv
2|pkfit|expected 4 fields as in the header, found 5|--model 1cmt_oral --data extra_field.csv
2|pkfit|AMT must not be negative|--model 1cmt_oral --data negative_amt.csv
2|pkfit|the file has no data records|--model 1cmt_oral --data no_records.csv
2|pkfit|is a directory, not a data file|--model 1cmt_oral --data $work
2|pkfit|cannot open the file|--model 1cmt_oral --data no_such_file.csv
2|pkfit|unbalanced parentheses|--model 1cmt_oral --data $theo --ignore (ID.GT.1
2|pkfit|KA: the lower bound 2 is not below the upper bound 1|--model 1cmt_oral --data $theo --lower KA=2 --upper KA=1
2|pkfit|KA of 1cmt_oral must be positive, not 0|--model 1cmt_oral --data $theo --init KA=0
2|pkfit|V of 1cmt_oral must be positive, not 0|--model 1cmt_oral --data $theo --fix V=0
2|pkfit|starts must be from 1 to 1000|--model 1cmt_oral --data $theo --starts 100000
2|pkfit|a dose with RATE=-1 needs R1 > 0|--model 1cmt_oral --data rate_without_r1.csv
2|pkfit|has no MANIFEST|--model 1cmt_oral --data $theo --init-from killed/estimates.csv
2|pkfit|a model of the catalogue, which has|--model no_such_model --data $theo
1|pkfit|CL of 1cmt_iv must be positive, not -3|--model 1cmt_iv --data negative_cl_column.csv
1|pkfit|not identifiable|--model 1cmt_iv --data constant_dv.csv
1|pkfit|CL and V do not affect the predictions|--model 1cmt_oral --data $root/datasets/indomethacin.csv
2|pkfit|former_name_column.csv:1:5: column V1: 'V1' is no longer a parameter of 2cmt_oral|--model 2cmt_oral --data former_name_column.csv
2|pkfit|'Q2' is no longer a parameter of 3cmt_oral|--model 3cmt_oral --data $theo --init Q2=3
2|pkfit|no_dv.csv:1: missing column DV|--model 1cmt_oral --data no_dv.csv
2|pkfit|unknown model '1cmt_orla' (did you mean 1cmt_oral?)|--model 1cmt_orla --data $theo
2|pkfit|unrecognised option '--dta' (did you mean --data?)|--model 1cmt_oral --dta $theo
2|pkfit|unknown parameter 'CLL' (did you mean CL?)|--model 1cmt_oral --data $theo --fix CLL=3
2|pkfit|give --axis or --log, not both|--model 1cmt_oral --data $theo --axis both --log
2|pkfit|--units: unknown key 'volume' (time, amt or conc)|--model 1cmt_oral --data $theo --units volume=L
3|pkfit|cannot create the output directory|--model 1cmt_oral --data $theo -o /proc/no/such/dir
2|pksim|a dose with RATE=-1 needs R1 > 0|--model 1cmt_oral --data rate_without_r1.csv --param KA=1 --param CL=1 --param V=10
2|pksim|CL of 1cmt_oral must be positive, not -1|--model 1cmt_oral --dose 100 --times 1 --param CL=-1
2|pksim|KA is given twice for ID 1|--model 1cmt_oral --estimates estimates_twice.csv --dose 100 --times 1
2|pksim|'CLEARANCE' is not a parameter of model 1cmt_oral|--model 1cmt_oral --estimates estimates_unknown.csv --dose 100 --times 1
2|pksim|has no MANIFEST|--model 1cmt_oral --estimates killed/estimates.csv --dose 100 --times 1
2|pksim|give --rate or --duration, not both|--model 1cmt_iv --dose 100 --rate 10 --duration 2 --times 1
2|pksim|is FROM:STEP:TO, and STEP 72 is longer than the range 0 to 0.5 (did you mean 0:0.5:72?)|--model 1cmt_iv --dose 100 --times 0:72:0.5
2|pksim|a NUL byte|--model 1cmt_oral --data nul.csv --times 1
1|pksim|CL of 1cmt_iv must be positive, not -3|--model 1cmt_iv --data negative_cl_column.csv --param V=10
2|pksim|'V1' is no longer a parameter of 2cmt_oral: its volumes have NONMEM's ADVAN4 TRANS4 names|--model 2cmt_oral --dose 100 --times 1 --param V1=25
2|pkfit|typo.pkm:8:23: d/dt(CENTRAL) reads VV, which is not defined (did you mean V?)|--model typo.pkm --data $theo
2|pksim|typo.pkm:8:23:|--model typo.pkm --dose 100 --times 1
2|pkfit|no.pkm: cannot read the model file|--model no.pkm --data $theo
2|pkfit|reads the covariate WT, but the dataset has no column WT|--model wt.pkm --data $root/datasets/cefamandole.csv
2|pksim|reads the covariate WT, but the dataset has no column WT|--model wt.pkm --dose 100 --times 1
3|pksim|cannot write|--model 1cmt_oral --dose 100 --times 1 --out /proc/no/such/dir/sim.csv
CASES
)

n=0
while IFS='|' read -r code program fragment args; do
  [ -z "$code" ] && continue
  n=$((n + 1))
  bin=$pkfit; [ "$program" = pksim ] && bin=$pksim
  extra=(); [ "$program" = pkfit ] && extra=(-q)
  [ "$program" = pkfit ] && [[ " $args " != *" -o "* ]] && extra+=(-o "$work/out$n")
  read -r -a argv <<<"$args"
  "$bin" "${extra[@]}" "${argv[@]}" >"$n.out" 2>"$n.err"
  got=$?
  if [ "$got" -ne "$code" ]; then
    echo "FAIL: $program $args: exit $got, expected $code"; sed 's/^/  /' "$n.err" | head -3; failures=$((failures + 1))
  elif ! grep -qF -- "$fragment" "$n.err"; then
    echo "FAIL: $program $args: stderr lacks '$fragment'"; sed 's/^/  /' "$n.err" | head -3; failures=$((failures + 1))
  fi
done <<<"$cases"
# Messages about data name the file, line and column.
grep -q "nul.csv:3:4:" 1.err || { echo "FAIL: the NUL byte's place (nul.csv:3:4)"; failures=$((failures + 1)); }
# Nothing a failed run wrote is left behind as a temporary.
if find "$work" -name '*.tmp.*' | grep -q .; then echo "FAIL: temporaries left behind"; failures=$((failures + 1)); fi
echo "$n cases, $failures failures"
[ "$failures" -eq 0 ]
