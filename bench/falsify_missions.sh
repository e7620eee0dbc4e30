#!/usr/bin/env bash
# The shipped missions under swarm falsify (docs/falsify.md, "The shipped missions"): each mission's [falsify] space
# (the conditions it is meant to fly in) searched with a budget of 40 flights for a flight that breaks one of its
# [[invariants]]. One line per mission: its exit code (0: nothing broke, 3: something did) and its summary's first
# lines. The campaigns stay in $OUT (default falsify-missions/): run again, each resumes where it stopped.
#
#   bench/falsify_missions.sh                       # every shipped mission
#   bench/falsify_missions.sh missions/pole_swap.toml missions/square_four.toml
#   BUDGET=10 bench/falsify_missions.sh             # a smaller budget
set -uo pipefail
cd "$(dirname "$0")/.."
swarm=${SWARM:-.venv/bin/swarm}
budget=${BUDGET:-40}
out=${OUT:-falsify-missions}
if [ "$#" -eq 0 ]; then set -- missions/*.toml; fi
mkdir -p "$out"
for mission in "$@"; do
    name=$(basename "$mission" .toml)
    started=$(date +%s)
    "$swarm" falsify "$mission" --budget "$budget" --seed 1 --out "$out/$name" > "$out/$name.log" 2>&1
    code=$?
    took=$(( $(date +%s) - started ))
    echo "$name: exit $code in ${took} s: $(head -2 "$out/$name/summary.txt" 2>/dev/null | tr '\n' ' ')"
done
