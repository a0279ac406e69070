#!/usr/bin/env bash
# Soak test (not part of `make test`): 30 minutes of simulated flight through diekf_bag_runner, reporting the
# peak resident memory and its growth. A SOAK_SEQUENCE_S second sequence is simulated once and played
# back to back (--repeat) so that the estimator sees SOAK_TOTAL_S seconds of continuous data; the runner prints
# VmRSS after every pass. Pass: growth of VmRSS from the end of the 2nd pass to the end of the last < 5 MB.
# Usage: scripts/soak.sh [OUTPUT_DIR]   (run by `make soak`; DIEKF_WS or DIEKF_BIN_DIR locate the binaries)
set -euo pipefail
out="${1:-$(mktemp -d)}"
bin="${DIEKF_BIN_DIR:-${DIEKF_WS:-.}/devel/lib/diekf}"
seq_s="${SOAK_SEQUENCE_S:-60}"
total_s="${SOAK_TOTAL_S:-1800}"
preset="${SOAK_PRESET:-flight4}"
limit_kb="${SOAK_MAX_GROWTH_KB:-5120}"
repeat=$(( (total_s + seq_s - 1) / seq_s ))
mkdir -p "$out"
if [ ! -f "$out/sequence/sequence.bag" ]; then
  "$bin/diekf_simulate" --preset "$preset" --duration "$seq_s" --output "$out/sequence" 2> "$out/simulate.log"
fi
/usr/bin/time -v "$bin/diekf_bag_runner" --bag "$out/sequence/sequence.bag" --camchain "$out/sequence/camchain.yaml" \
  --imu "$out/sequence/imu.yaml" --output "$out/run" --repeat "$repeat" --quiet 2> "$out/runner.log" > "$out/summary.txt"
grep "pass .* done" "$out/runner.log" | tee "$out/memory.txt"
peak_kb=$(awk '/Maximum resident set size/ {print $NF}' "$out/runner.log")
rss=( $(sed -n 's/.*VmRSS \([0-9]*\) kB.*/\1/p' "$out/memory.txt") )
n=${#rss[@]}
if [ "$n" -lt 3 ]; then echo "soak: too few passes ($n)"; exit 1; fi
growth_kb=$(( rss[n-1] - rss[1] ))
resets=$(awk -F, 'NR > 1 && $NF == "reset"' "$out/run/estimates.csv" | wc -l)
frames=$(( $(wc -l < "$out/run/estimates.csv") - 1 ))
nonfinite=$(awk -F, 'NR > 1 { for (i = 1; i < NF; ++i) if ($i ~ /nan|inf/) { n++; break } } END { print n + 0 }' "$out/run/estimates.csv")
echo "soak: $((n * seq_s)) s of data ($n passes of $seq_s s, $preset), $frames estimates, $resets reset frames, $nonfinite non-finite rows"
echo "soak: peak RSS $((peak_kb / 1024)) MB; VmRSS after pass 2 ${rss[1]} kB, after pass $n ${rss[n-1]} kB: growth ${growth_kb} kB (limit ${limit_kb} kB)"
[ "$nonfinite" -eq 0 ] && [ "$growth_kb" -lt "$limit_kb" ]
