#!/usr/bin/env bash
# `make cross-check`: the ROS-free core on ARM (docs/performance.md, "ARM"; docs/ros.md, "Building for the Odroid").
#
#  1. Host tools with apt-get: crossbuild-essential-<arch>, qemu-user, cmake, googletest (refused if apt would remove
#     any installed package).
#  2. Per architecture (CROSS_ARCHES, default "arm64 armhf") a private sysroot of Debian packages (OpenCV core,
#     imgproc, video, calib3d, yaml-cpp, Google Benchmark, Eigen and their dependencies), fetched with apt-get in a
#     private apt state (-o Dir::State..., APT::Architecture) and unpacked with dpkg-deb -x into the build folder.
#     The host's package database is not touched: no dpkg --add-architecture, no foreign packages installed
#     (installing OpenCV's arm64 -dev packages through multiarch removes the native libopencv-dev). An
#     architecture whose packages cannot be fetched (e.g. a mirror mid-sync) is skipped with the reason; the others
#     go on.
#  3. cross/CMakeLists.txt (core, core unit tests, no-allocation test, benchmark, diekf_replay) built natively (the
#     x86-64 reference) and for each architecture with cross/toolchain-<triplet>.cmake.
#  4. The core's unit tests under qemu-<arch> (ctest; CMAKE_CROSSCOMPILING_EMULATOR), natively as well.
#  5. The SIMD instruction set each build's photometric sweep uses (diekf_replay's start-up line).
#  6. One simulated flight (diekf_simulate, native ROS build) exported with diekf_bag_runner --export-sequence, replayed
#     by the x86-64 build and by each ARM build under qemu at 90, 180 and 376 px working width; states compared
#     (cross/compare_states.py) against stated tolerances.
#  7. Instructions per frame of each build (a qemu plugin, cross/qemu_insn_count.c): diekf_replay --preload over
#     COUNT_FROM and COUNT_TO images minus the same reading without processing, divided by the frame difference;
#     as the flight runs, and with every image forced to 3 Gauss-Newton passes (the most expensive frame).
#
# Usage (from the Makefile): DIEKF_WS=<catkin ws> CROSS_DIR=<build folder> bash cross/cross_check.sh RESULTS_DIR
# Writes RESULTS_DIR/summary.txt, instructions.csv, comparisons.json; exit status 1 when a test, a comparison or
# a whole architecture failed.
set -uo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
export LC_ALL=C
unset PYTHONPATH PYTHONHOME VIRTUAL_ENV

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
OUT=${1:?usage: cross_check.sh RESULTS_DIR}
: "${DIEKF_WS:?DIEKF_WS: the catkin workspace of the native build}"
: "${CROSS_DIR:?CROSS_DIR: build folder of the cross builds}"
ARCHES=${CROSS_ARCHES:-arm64 armhf}
JOBS=${JOBS:-2}
SUDO=${SUDO-}
WIDTHS=${CROSS_WIDTHS:-90 180 376}
FLIGHT_PRESET=${CROSS_FLIGHT_PRESET:-flight4}
FLIGHT_SECONDS=${CROSS_FLIGHT_SECONDS:-10}
FLIGHT_SEED=${CROSS_FLIGHT_SEED:-1}
COUNT_FROM=${CROSS_COUNT_FROM:-90}   # images: after ~3 s of convergence
COUNT_TO=${CROSS_COUNT_TO:-240}
# x86-64 vs ARM: floating-point differences only (the SIMD code's fused multiply-add on ARM, libm, NEON's
# reciprocal and square-root estimates on ARMv7); far below the estimator's own errors (cm, cm/s, tenths of a
# degree). Judged from 3 s after the first update (cross/compare_states.py); docs/performance.md, "ARM".
TOL_D_M=${CROSS_TOL_D_M:-0.001}
TOL_V_MPS=${CROSS_TOL_V_MPS:-0.001}
TOL_ANGLE_DEG=${CROSS_TOL_ANGLE_DEG:-0.01}
SYSROOT_PACKAGES="libopencv-core-dev libopencv-imgproc-dev libopencv-video-dev libopencv-calib3d-dev \
libyaml-cpp-dev libbenchmark-dev libeigen3-dev"
NICE="nice -n 10"

START=$SECONDS
mkdir -p "$OUT" "$CROSS_DIR"
SUMMARY=$OUT/summary.txt
: > "$SUMMARY"
FAILED=0
log() { echo "[cross-check] $*"; }
note() { echo "$*" | tee -a "$SUMMARY"; }
fail() { FAILED=1; note "FAILED: $*"; }

triplet_of() { case $1 in arm64) echo aarch64-linux-gnu ;; armhf) echo arm-linux-gnueabihf ;; *) return 1 ;; esac; }
qemu_of() { case $1 in arm64) echo qemu-aarch64 ;; armhf) echo qemu-arm ;; *) return 1 ;; esac; }

for a in $ARCHES; do
  triplet_of "$a" >/dev/null || { echo "cross_check.sh: unknown architecture '$a' (arm64, armhf)" >&2; exit 2; }
done

# ------------------------------------------------------------------------------------------------------------
# 1. Host tools.
# ------------------------------------------------------------------------------------------------------------
host_packages="qemu-user cmake googletest gcc"
for a in $ARCHES; do host_packages="$host_packages crossbuild-essential-$a"; done
missing=""
for p in $host_packages; do
  dpkg-query -W -f='${Status}\n' "$p" 2>/dev/null | grep -q '^install ok installed' || missing="$missing $p"
done
if [ -n "$missing" ]; then
  log "installing:$missing"
  $SUDO apt-get update -qq || log "apt-get update reported errors (continuing with the indexes it has)"
  # Never let a tool install remove something another build needs.
  if $SUDO apt-get install -s --no-install-recommends $missing 2>/dev/null | grep -q '^Remv'; then
    echo "cross_check.sh: installing$missing would remove installed packages; refusing:" >&2
    $SUDO apt-get install -s --no-install-recommends $missing | grep '^Remv' >&2
    exit 1
  fi
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends -o DPkg::Lock::Timeout=900 \
    $missing || log "apt-get install failed; architectures without a cross compiler are skipped"
fi
BUILT_ARCHES=""
for a in $ARCHES; do
  t=$(triplet_of "$a")
  if ! command -v "$t-g++" >/dev/null || ! command -v "$(qemu_of "$a")" >/dev/null; then
    fail "$a: no $t-g++ or $(qemu_of "$a") (crossbuild-essential-$a, qemu-user): skipped"
  else
    BUILT_ARCHES="$BUILT_ARCHES $a"
  fi
done

# ------------------------------------------------------------------------------------------------------------
# 2. Sysroots: Debian packages of the architecture in a private apt state, unpacked with dpkg-deb -x.
# ------------------------------------------------------------------------------------------------------------
make_sysroot() {
  local arch=$1 base=$CROSS_DIR/$1
  local root=$base/sysroot stamp=$base/sysroot/.diekf-sysroot want="$1: $SYSROOT_PACKAGES"
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    return 0
  fi
  log "$arch: fetching the sysroot packages (private apt state in $base/apt)"
  mkdir -p "$base/apt/lists/partial" "$base/apt/cache" "$base/apt/archives/partial"
  : > "$base/apt/status"  # an empty package database: the whole dependency closure is fetched
  local opts=(-o "APT::Architecture=$arch" -o "APT::Architectures::=$arch" -o "Dir::State::Lists=$base/apt/lists"
    -o "Dir::State::status=$base/apt/status" -o "Dir::Cache=$base/apt/cache"
    -o "Dir::Cache::archives=$base/apt/archives" -o Debug::NoLocking=1 -o "APT::Sandbox::User=$(id -un)"
    -o Acquire::Retries=3)
  if ! apt-get "${opts[@]}" update > "$base/apt-update.log" 2>&1; then
    # Typically one index mid-sync on the mirror ("File has unexpected size"); the others may still do.
    note "$arch: apt-get update of the $arch indexes failed: $(grep -E '^(E|Err):' "$base/apt-update.log" | head -2 | tr '\n' ' ')"
    note "$arch: trying with the indexes that did download"
  fi
  if ! apt-get "${opts[@]}" install -y -qq --download-only --no-install-recommends $SYSROOT_PACKAGES \
      > "$base/apt-download.log" 2>&1; then
    note "$arch: the sysroot packages cannot be fetched: $(grep -E '^E:' "$base/apt-download.log" | head -3 | tr '\n' ' ')"
    return 1
  fi
  log "$arch: unpacking $(ls "$base/apt/archives"/*.deb | wc -l) packages into $root"
  rm -rf "$root"
  mkdir -p "$root"
  local deb
  for deb in "$base/apt/archives"/*.deb; do
    dpkg-deb -x "$deb" "$root" || { note "$arch: cannot unpack $deb"; return 1; }
  done
  # Absolute symlinks (e.g. usr/lib/<triplet>/libm.so -> /lib/<triplet>/libm.so.6) would point into the host.
  local link target
  while IFS= read -r -d '' link; do
    target=$(readlink "$link")
    ln -sfr "$root$target" "$link"
  done < <(find "$root" -type l -lname '/*' -print0)
  echo "$want" > "$stamp"
}

ARM_OK=""
for a in $BUILT_ARCHES; do
  if make_sysroot "$a"; then
    ARM_OK="$ARM_OK $a"
  else
    fail "$a: no sysroot: skipped (the other architectures go on)"
  fi
done

# ------------------------------------------------------------------------------------------------------------
# 3. Builds: native reference and each architecture.
# ------------------------------------------------------------------------------------------------------------
build_tree() {  # name, cmake arguments...
  local name=$1 dir=$CROSS_DIR/build-$1
  shift
  log "$name: configure and build ($dir)"
  if ! cmake -S "$REPO/cross" -B "$dir" -DCMAKE_BUILD_TYPE=Release "$@" > "$CROSS_DIR/$name-configure.log" 2>&1; then
    tail -20 "$CROSS_DIR/$name-configure.log"
    return 1
  fi
  if ! $NICE cmake --build "$dir" -j"$JOBS" > "$CROSS_DIR/$name-build.log" 2>&1; then
    grep -E "error|Error" "$CROSS_DIR/$name-build.log" | head -20
    return 1
  fi
}

BUILDS=""
if build_tree x86_64; then BUILDS="x86_64"; else fail "x86_64: ROS-free build failed ($CROSS_DIR/x86_64-build.log)"; fi
for a in $ARM_OK; do
  t=$(triplet_of "$a")
  if build_tree "$a" -DCMAKE_TOOLCHAIN_FILE="$REPO/cross/toolchain-$t.cmake" -DDIEKF_SYSROOT="$CROSS_DIR/$a/sysroot"; then
    BUILDS="$BUILDS $a"
  else
    fail "$a: cross build failed ($CROSS_DIR/$a-build.log)"
  fi
done

# The emulator command of a build (empty for the native one), as the toolchain file made it.
emulator_of() { cat "$CROSS_DIR/build-$1/emulator.txt"; }

# ------------------------------------------------------------------------------------------------------------
# 4. Unit tests (under qemu for ARM: ctest prefixes the emulator).
# ------------------------------------------------------------------------------------------------------------
note "== unit tests of the core (ctest; ARM under qemu-user)"
for b in $BUILDS; do
  dir=$CROSS_DIR/build-$b
  rm -rf "$dir/test_results"
  t0=$SECONDS
  (cd "$dir" && $NICE ctest --output-on-failure) > "$CROSS_DIR/$b-ctest.log" 2>&1
  rc=$?
  counts=$(python3 - "$dir/test_results" <<'EOF'
import glob, sys, xml.etree.ElementTree as ET
tests = failures = 0
for f in sorted(glob.glob(sys.argv[1] + "/*.xml")):
    r = ET.parse(f).getroot()
    tests += int(r.get("tests", 0)) - int(r.get("disabled", 0))
    failures += int(r.get("failures", 0)) + int(r.get("errors", 0))
print("%d %d" % (tests, failures))
EOF
)
  read -r n_tests n_fail <<< "$counts"
  note "$b: $n_tests tests, $n_fail failed, ctest exit $rc ($((SECONDS - t0)) s; $CROSS_DIR/$b-ctest.log)"
  if [ "$rc" != 0 ] || [ "$n_fail" != 0 ] || [ "$n_tests" = 0 ]; then fail "$b: unit tests"; fi
  # The benchmark runs too (a smoke test: times under emulation mean nothing).
  if [ -x "$dir/diekf_benchmark" ]; then
    # shellcheck disable=SC2046
    if $(emulator_of "$b") "$dir/diekf_benchmark" --benchmark_filter='BM_PredictStep|BM_PhotometricUpdateOnePass/90' \
        --benchmark_min_time=0.01 > "$CROSS_DIR/$b-benchmark.log" 2>&1; then
      note "$b: diekf_benchmark runs ($CROSS_DIR/$b-benchmark.log)"
    else
      fail "$b: diekf_benchmark failed ($CROSS_DIR/$b-benchmark.log)"
    fi
  else
    fail "$b: no diekf_benchmark (Google Benchmark missing from the sysroot?)"
  fi
done

# ------------------------------------------------------------------------------------------------------------
# 5.-6. The simulated flight, exported, replayed by every build; SIMD line; comparison with x86-64.
# ------------------------------------------------------------------------------------------------------------
FLIGHT=$CROSS_DIR/flight-$FLIGHT_PRESET-${FLIGHT_SECONDS}s-seed$FLIGHT_SEED
SEQ=$FLIGHT/sequence
# The flight and its export are kept between runs (they do not depend on the core); the catkin runner's own
# estimates are made anew each time (they do).
rm -rf "$FLIGHT/runner"
(
  set -e +u  # ROS's setup files read unset variables
  # shellcheck disable=SC1091
  source "$DIEKF_WS/devel/setup.bash"
  lib=$DIEKF_WS/devel/lib/diekf
  if [ ! -f "$SEQ/.complete" ]; then
    log "simulating $FLIGHT_PRESET, $FLIGHT_SECONDS s (native diekf_simulate) and exporting it (diekf_bag_runner)"
    rm -rf "$FLIGHT"
    mkdir -p "$FLIGHT"
    $NICE "$lib/diekf_simulate" --preset "$FLIGHT_PRESET" --duration "$FLIGHT_SECONDS" --seed "$FLIGHT_SEED" \
      --output "$FLIGHT/sim" > "$FLIGHT/simulate.log" 2>&1
    $NICE "$lib/diekf_bag_runner" --bag "$FLIGHT/sim/sequence.bag" --camchain "$FLIGHT/sim/camchain.yaml" \
      --imu "$FLIGHT/sim/imu.yaml" --output "$FLIGHT/runner" --export-sequence "$SEQ" --quiet \
      > "$FLIGHT/runner.txt"
    touch "$SEQ/.complete"
  else
    $NICE "$lib/diekf_bag_runner" --bag "$FLIGHT/sim/sequence.bag" --camchain "$FLIGHT/sim/camchain.yaml" \
      --imu "$FLIGHT/sim/imu.yaml" --output "$FLIGHT/runner" --quiet > "$FLIGHT/runner.txt"
  fi
) || fail "simulation, export or catkin runner failed ($FLIGHT/simulate.log)"
if [ ! -f "$SEQ/.complete" ]; then
  note "no exported flight: no SIMD line, comparison or instruction counts"
  note "== cross-check: $((SECONDS - START)) s; cross-check FAILED"
  exit 1
fi
# The runner read the simulator's IMU calibration; so do the replays.
IMU_ARGS="--imu $FLIGHT/sim/imu.yaml"

note "== the flight: $FLIGHT_PRESET, $FLIGHT_SECONDS s, seed $FLIGHT_SEED; the estimator's own errors at 180 px (catkin runner):"
sed -n '2,3p' "$FLIGHT/runner.txt" | tee -a "$SUMMARY"

note "== photometric sweep SIMD (diekf_replay start-up line)"
for b in $BUILDS; do
  emu=$(emulator_of "$b")
  line=$($emu "$CROSS_DIR/build-$b/diekf_replay" --sequence "$SEQ" --max-images 0 2>&1 | grep "photometric sweep SIMD")
  note "$b: ${line:-no SIMD line}"
  case "$b:$line" in
    x86_64:*"SIMD: SSE2"*|arm64:*"SIMD: NEON (AArch64"*|armhf:*"SIMD: NEON (ARMv7"*) ;;
    *) fail "$b: unexpected SIMD instruction set" ;;
  esac
done

note "== the same flight ($FLIGHT_PRESET, $FLIGHT_SECONDS s) on each build vs the x86-64 build"
note "tolerance from 3 s after the first update: distance and height $TOL_D_M m, velocity $TOL_V_MPS m/s, normal and gravity $TOL_ANGLE_DEG deg; whole flight: same status, finite"
COMPARE_JSON=()
for w in $WIDTHS; do
  for b in $BUILDS; do
    emu=$(emulator_of "$b")
    t0=$SECONDS
    # shellcheck disable=SC2086
    if ! $NICE $emu "$CROSS_DIR/build-$b/diekf_replay" --sequence "$SEQ" --width "$w" $IMU_ARGS --quiet \
        --output "$FLIGHT/replay-$b-$w" > "$FLIGHT/replay-$b-$w.log" 2>&1; then
      fail "$b: replay at $w px failed ($FLIGHT/replay-$b-$w.log)"
      continue
    fi
    log "$b: replay at $w px: $((SECONDS - t0)) s"
  done
  # The ROS-free x86-64 replay against the catkin runner at its default width: the same estimates.
  if [ "$w" = 180 ] && [ -f "$FLIGHT/runner/estimates.csv" ] && [ -f "$FLIGHT/replay-x86_64-180/estimates.csv" ]; then
    strip() { awk -F, 'BEGIN{OFS=","} {$(NF-1)=""; print}' "$1"; }
    if diff <(strip "$FLIGHT/runner/estimates.csv") <(strip "$FLIGHT/replay-x86_64-180/estimates.csv") >/dev/null; then
      note "x86_64 ROS-free replay vs catkin diekf_bag_runner at 180 px: identical estimates.csv (update_ms aside)"
    else
      fail "x86_64 ROS-free replay differs from the catkin diekf_bag_runner at 180 px"
    fi
  fi
  for b in $BUILDS; do
    [ "$b" = x86_64 ] && continue
    [ -f "$FLIGHT/replay-$b-$w/states.csv" ] && [ -f "$FLIGHT/replay-x86_64-$w/states.csv" ] || continue
    python3 "$REPO/cross/compare_states.py" "$FLIGHT/replay-x86_64-$w/states.csv" "$FLIGHT/replay-$b-$w/states.csv" \
      --label "$b vs x86_64, $w px" --json "$FLIGHT/compare-$b-$w.json" --tol-d-m "$TOL_D_M" \
      --tol-v-mps "$TOL_V_MPS" --tol-angle-deg "$TOL_ANGLE_DEG" --window-start-s 3 | tee -a "$SUMMARY"
    [ "${PIPESTATUS[0]}" = 0 ] || fail "$b at $w px: outside the tolerance"
    COMPARE_JSON+=("$FLIGHT/compare-$b-$w.json")
  done
done
if [ ${#COMPARE_JSON[@]} -gt 0 ]; then
  python3 -c 'import json, sys; json.dump([json.load(open(f)) for f in sys.argv[2:]], open(sys.argv[1], "w"), indent=1)' \
    "$OUT/comparisons.json" "${COMPARE_JSON[@]}"
fi

# ------------------------------------------------------------------------------------------------------------
# 7. Instructions per frame (qemu plugin; the x86-64 build under qemu-x86_64 for reference).
# ------------------------------------------------------------------------------------------------------------
PLUGIN=$CROSS_DIR/libdiekf_insn.so
if [ ! -f "$PLUGIN" ] || [ "$REPO/cross/qemu_insn_count.c" -nt "$PLUGIN" ]; then
  gcc -shared -fPIC -O2 -Wall -o "$PLUGIN" "$REPO/cross/qemu_insn_count.c" || fail "qemu plugin: build failed"
fi
count_insns() {  # build, width, images, tag, extra replay arguments -> instruction count on stdout
  local b=$1 w=$2 m=$3 emu
  local f=$CROSS_DIR/insns-$1-$2-$3-$4.txt
  shift 4
  if [ "$b" = x86_64 ]; then emu="qemu-x86_64"; else emu=$(emulator_of "$b"); fi
  # shellcheck disable=SC2086
  $NICE $emu -plugin "$PLUGIN,outfile=$f" "$CROSS_DIR/build-$b/diekf_replay" --sequence "$SEQ" --width "$w" \
    $IMU_ARGS --quiet --preload --max-images "$m" "$@" > /dev/null 2>&1 || return 1
  awk '/^insns /{print $2}' "$f"
}
note "== instructions per frame (images $COUNT_FROM..$COUNT_TO of the flight; qemu instruction-count plugin)"
note "mean: the flight as it runs (iekf, mostly 1 pass once converged); 3 passes: every image forced to 3 passes"
note "(photometric/max_passes=3, stop_threshold=1e-9), the iekf's most expensive frame"
HEADER="build,width_px,insns_per_frame_mean,insns_per_frame_3_passes,frames"
note "$HEADER"
echo "$HEADER" > "$OUT/instructions.csv"
FORCE3="--set photometric/max_passes=3 --set photometric/stop_threshold=1e-9"
if [ -f "$PLUGIN" ]; then
  for b in $BUILDS; do
    for w in $WIDTHS; do
      # shellcheck disable=SC2086
      l2=$(count_insns "$b" "$w" "$COUNT_TO" load --load-only) &&
        l1=$(count_insns "$b" "$w" "$COUNT_FROM" load --load-only) &&
        p2=$(count_insns "$b" "$w" "$COUNT_TO" mean) && p1=$(count_insns "$b" "$w" "$COUNT_FROM" mean) &&
        f2=$(count_insns "$b" "$w" "$COUNT_TO" 3passes $FORCE3) &&
        f1=$(count_insns "$b" "$w" "$COUNT_FROM" 3passes $FORCE3)
      if [ -z "${l1:-}" ] || [ -z "${l2:-}" ] || [ -z "${p1:-}" ] || [ -z "${p2:-}" ] || [ -z "${f1:-}" ] ||
          [ -z "${f2:-}" ]; then
        fail "$b at $w px: instruction count failed"
        continue
      fi
      n=$((COUNT_TO - COUNT_FROM))
      row="$b,$w,$(( ((p2 - l2) - (p1 - l1)) / n )),$(( ((f2 - l2) - (f1 - l1)) / n )),$n"
      note "$row"
      echo "$row" >> "$OUT/instructions.csv"
      unset l1 l2 p1 p2 f1 f2
    done
  done
  python3 - "$OUT/instructions.csv" <<'EOF' | tee -a "$SUMMARY"
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
# Boards: Odroid XU4 (Exynos 5422: Cortex-A15 at 2.0 GHz), N2 / N2+ (S922X: Cortex-A73 at 1.8 / 2.2 GHz).
clocks = {"armhf": [("XU4 A15 2.0 GHz", 2.0e9)], "arm64": [("N2 A73 1.8 GHz", 1.8e9), ("N2+ A73 2.2 GHz", 2.2e9)]}
budget_s = 1.0 / 30.0
print("budget 33.3 ms per frame (30 fps). Time = instructions / (IPC x clock) with an ASSUMED IPC of 1 (0.5 in")
print("brackets); 'fits from IPC' = the IPC at which the frame takes exactly 33.3 ms")
for r in rows:
    for name, hz in clocks.get(r["build"], []):
        for what, key in (("mean    ", "insns_per_frame_mean"), ("3 passes", "insns_per_frame_3_passes")):
            n = float(r[key])
            print("%s %4s px %s on %s: %6.2f M instr -> %5.1f ms (%5.1f ms) = %3.0f %% (%3.0f %%) of 33 ms; "
                  "fits from IPC %.2f" % (r["build"], r["width_px"], what, name, n / 1e6, 1e3 * n / hz,
                                          2e3 * n / hz, 100.0 * n / hz / budget_s, 200.0 * n / hz / budget_s,
                                          n / hz / budget_s))
EOF
fi

note "== cross-check: $((SECONDS - START)) s, builds:${BUILDS:+ }$BUILDS; requested architectures: $ARCHES"
[ "$FAILED" = 0 ] && note "cross-check passed" || note "cross-check FAILED (see above)"
exit "$FAILED"
