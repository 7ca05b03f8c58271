#!/usr/bin/env bash
# Cold command-line runs (a new process each): `tuner analyze` of the README's roll loop against `tuner tune` of it
# and of px4_rate. First the tunes' first runs (they fill the caches: the NLPs' stored graphs), then ROUNDS rounds of
# second runs. Prints each run's wall and CPU seconds (user + sys, the process and its children) and exit code, and
# the load average before and after; asserts nothing.
#   bash bench/cold_cli.sh [--skip-px4] [ROUNDS]
# --skip-px4: the roll loop alone (px4_rate's tunes left out: 5-10 s each; the default runs them).
# The caches: $TUNER_CACHE_DIR if set (as it is: a first run there may find them filled), else a new empty folder
# (removed at the end). Another tree's code: PYTHONPATH=/other/tree bash bench/cold_cli.sh (this tree's venv).
# TUNER_NLP_COMPILE: as set, else load (the compiled NLP entries the cache holds, and no background compile that
# would run beside the timed runs; the product's default, auto, compiles new shapes in the background)
set -u
cd "$(dirname "$0")/.."
export TUNER_NLP_COMPILE=${TUNER_NLP_COMPILE:-load}
T=.venv/bin/tuner
PX4=1
if [ "${1:-}" = "--skip-px4" ]; then PX4=0; shift; fi
ROUNDS=${1:-3}
A=(analyze --plant "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)" --dt 0.04 --controller "3.868*(z^2-1.305*z+0.5668)/(z*(z-1))")
R=(tune --plant "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)" --dt 0.04 --structure pid_z)
P=(tune --plant "200/((s+2)*(0.03*s+1))" --dt 0.0025 --structure px4_rate)
if [ -z "${TUNER_CACHE_DIR:-}" ]; then
  TUNER_CACHE_DIR=$(mktemp -d); export TUNER_CACHE_DIR; trap 'rm -rf "$TUNER_CACHE_DIR"' EXIT
fi
echo "caches: $TUNER_CACHE_DIR; $(uptime)"
run() {
  local TIMEFORMAT='%R %U %S' out rc w u s
  out=$( { time "$T" "$@" > /dev/null 2>&1; } 2>&1 ); rc=$?
  read -r w u s <<< "$out"
  printf '%6.2f s wall, %5.2f s CPU, exit %s' "$w" "$(echo "$u + $s" | bc)" "$rc"
}
echo "first tune roll: $(run "${R[@]}")"
[ "$PX4" = 1 ] && echo "first tune px4_rate: $(run "${P[@]}")"
for _ in $(seq "$ROUNDS"); do
  echo "analyze roll: $(run "${A[@]}")"
  echo "tune roll: $(run "${R[@]}")"
  [ "$PX4" = 1 ] && echo "tune px4_rate: $(run "${P[@]}")"
done
uptime
