#!/usr/bin/env bash
# Cold command-line runs (a new process each; caches as they are after a first run): `tuner analyze` of the README's
# roll loop against `tuner tune` of it and of px4_rate. Prints each run's wall seconds and exit code; asserts nothing.
#   bash bench/cold_cli.sh [ROUNDS]
set -u
cd "$(dirname "$0")/.."
T=.venv/bin/tuner
ROUNDS=${1:-3}
A=(analyze --plant "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)" --dt 0.04 --controller "3.868*(z^2-1.305*z+0.5668)/(z*(z-1))")
R=(tune --plant "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)" --dt 0.04 --structure pid_z)
P=(tune --plant "200/((s+2)*(0.03*s+1))" --dt 0.0025 --structure px4_rate)
run() { local s; s=$(date +%s.%N); "$T" "$@" > /dev/null 2>&1; local rc=$?; echo "$(echo "$(date +%s.%N) - $s" | bc) s, exit $rc"; }
"$T" "${R[@]}" > /dev/null 2>&1; "$T" "${P[@]}" > /dev/null 2>&1  # a first run: caches filled
for _ in $(seq "$ROUNDS"); do
  echo "analyze roll: $(run "${A[@]}")"
  echo "tune roll: $(run "${R[@]}")"
  echo "tune px4_rate: $(run "${P[@]}")"
done
uptime
