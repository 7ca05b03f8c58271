#!/usr/bin/env bash
# Stop 49: what the compiled-code default (TUNER_NLP_COMPILE unset: auto) costs and gives a cold `tuner tune` of the
# README's roll loop: its first run in a fresh cache against TUNER_NLP_COMPILE=load, alternating (3 rounds), the
# second run right after, the wait until its shapes are compiled, then 3 pairs of cold `tuner analyze` / `tuner tune`
# (second runs, the compiled code loaded). Prints walls; asserts nothing. Run it alone (e.g. under flock).
#   bash bench/cold_cli_compile.sh
cd "$(dirname "$0")/.."
export OPENBLAS_NUM_THREADS=1; unset TUNER_NLP_COMPILE TUNER_CACHE_DIR
T=.venv/bin/tuner
A=(analyze --plant "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)" --dt 0.04 --controller "3.868*(z^2-1.305*z+0.5668)/(z*(z-1))")
R=(tune --plant "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)" --dt 0.04 --structure pid_z)
w() { local TIMEFORMAT='%R'; { time "$@" > /dev/null 2>/tmp/fr.err; } 2>&1; }
echo "== $(git rev-parse --short HEAD), $(date -u +%T) UTC, $(uptime)"
for i in 1 2 3; do
  for m in load unset; do
    d=$(mktemp -d); chmod 700 $d
    if [ $m = load ]; then first=$(TUNER_CACHE_DIR=$d TUNER_NLP_COMPILE=load w $T "${R[@]}"); second=$(TUNER_CACHE_DIR=$d TUNER_NLP_COMPILE=load w $T "${R[@]}")
    else first=$(TUNER_CACHE_DIR=$d w $T "${R[@]}"); note=$(grep -c "asked for the compiled" /tmp/fr.err)
      second=$(TUNER_CACHE_DIR=$d w $T "${R[@]}"); fi
    echo "round $i $m: first run ${first} s, second run right after ${second} s$( [ $m = unset ] && echo ", note printed: $note")"
    if [ $m = unset ]; then
      t0=$(date +%s.%N); TUNER_CACHE_DIR=$d .venv/bin/python -m tuner.optimize.nlp.codecache --wait | tail -1; t1=$(date +%s.%N)
      echo "  compiled after $(echo "$t1 - $t0" | bc) s more"
      for k in 1 2 3; do a=$(TUNER_CACHE_DIR=$d w $T "${A[@]}"); t=$(TUNER_CACHE_DIR=$d w $T "${R[@]}"); echo "  analyze ${a} s, tune ${t} s, ratio $(echo "scale=3; $t / $a" | bc)"; done
    fi
    rm -rf $d
  done
done
uptime
