#!/usr/bin/env bash
# rviz on a virtual X server, fed by a simulated flight through launch/replay.launch rviz:=true; screenshots of
# the window and a scan of the logs for display problems (docs/ros.md, "rviz"). Run from a sourced workspace:
#   bash scripts/rviz_check.sh OUT_DIR            (make rviz-check writes to results/rviz)
# Environment: RVIZ_CONFIG (layout, default the package's rviz/diekf.rviz), RVIZ_BAG_DIR (a diekf_simulate output
# folder to replay instead of simulating one), RVIZ_PRESET (flight4), RVIZ_DURATION (20 s), RVIZ_SHOTS (seconds
# after the start of playback at which to take screenshots, "6 14"). Writes OUT_DIR/rviz_tN.png per shot,
# OUT_DIR/rviz.png (the last), OUT_DIR/log/ (ROS logs) and OUT_DIR/summary.txt. Exits non-zero when rviz dies,
# a screenshot is blank, or the logs show a type mismatch, a missing frame or an rviz error.
set -euo pipefail

OUT=${1:?usage: rviz_check.sh OUT_DIR}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
rm -f "$OUT"/rviz_t*.png "$OUT/rviz.png" "$OUT/summary.txt"
PKG_DIR=$(cd "$(dirname "$0")/.." && pwd)
CONFIG=${RVIZ_CONFIG:-$PKG_DIR/rviz/diekf.rviz}
PRESET=${RVIZ_PRESET:-flight4}
DURATION=${RVIZ_DURATION:-20}
SHOTS=${RVIZ_SHOTS:-6 14}
DELAY=2  # replay.launch's default delay between advertising and playing, s

for tool in rviz Xvfb import roslaunch; do
  command -v "$tool" >/dev/null || { echo "rviz_check: '$tool' not found (make rviz-check installs it)" >&2; exit 2; }
done

if [ -n "${RVIZ_BAG_DIR:-}" ]; then
  SIM=$RVIZ_BAG_DIR
else
  SIM=$OUT/sim
  if [ ! -f "$SIM/sequence.bag" ]; then
    echo "rviz_check: simulating $PRESET for $DURATION s into $SIM"
    # The sourced workspace's simulator (not rosrun: it also searches the package directory and asks when it
    # finds more than one file).
    SIMULATE=$(catkin_find --first-only --libexec diekf diekf_simulate 2>/dev/null || true)
    [ -x "$SIMULATE" ] || { echo "rviz_check: diekf_simulate not found in the sourced workspace" >&2; exit 2; }
    "$SIMULATE" --preset "$PRESET" --duration "$DURATION" --threads 1 --output "$SIM" \
      > "$OUT/simulate.log" 2>&1
  fi
fi

XVFB_PID=""
LAUNCH_PID=""
cleanup() {
  if [ -n "$LAUNCH_PID" ] && kill -0 "$LAUNCH_PID" 2>/dev/null; then
    kill -INT "$LAUNCH_PID" 2>/dev/null || true
    for _ in $(seq 1 30); do kill -0 "$LAUNCH_PID" 2>/dev/null || break; sleep 0.5; done
    kill -TERM "$LAUNCH_PID" 2>/dev/null || true
  fi
  if [ -n "$XVFB_PID" ]; then kill "$XVFB_PID" 2>/dev/null || true; fi
}
trap cleanup EXIT

# A virtual screen on the first free display number (Xvfb writes it to fd 3), a ROS master on a free port.
Xvfb -displayfd 3 -screen 0 1280x1024x24 -nolisten tcp 3> "$OUT/display" 2> "$OUT/xvfb.log" &
XVFB_PID=$!
for _ in $(seq 1 50); do [ -s "$OUT/display" ] && break; sleep 0.1; done
[ -s "$OUT/display" ] || { echo "rviz_check: Xvfb did not start (see $OUT/xvfb.log)" >&2; exit 1; }
export DISPLAY=:$(head -n1 "$OUT/display")
PORT=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI=http://localhost:$PORT
export ROS_LOG_DIR=$OUT/log
rm -rf "$ROS_LOG_DIR"
imu_arg=()
[ -f "$SIM/imu.yaml" ] && imu_arg=(imu_calib:="$SIM/imu.yaml")
roslaunch -p "$PORT" diekf replay.launch bag:="$SIM/sequence.bag" camchain:="$SIM/camchain.yaml" "${imu_arg[@]}" \
  rviz:=true rviz_config:="$CONFIG" > "$OUT/launch.log" 2>&1 &
LAUNCH_PID=$!
echo "rviz_check: rviz on $DISPLAY, master $ROS_MASTER_URI, layout $CONFIG"

start=$(date +%s.%N)
last=""
for t in $SHOTS; do
  # seconds since launch = master and nodes start-up (about 2 s) + replay delay + t
  wait_s=$(python3 -c "import time; print(max(0.0, $start + 2 + $DELAY + $t - time.time()))")
  sleep "$wait_s"
  kill -0 "$LAUNCH_PID" 2>/dev/null || { echo "rviz_check: roslaunch ended early (see $OUT/launch.log)" >&2; exit 1; }
  last=$OUT/$(printf 'rviz_t%02d.png' "$t")
  import -window root "$last"
done
cp "$last" "$OUT/rviz.png"
cleanup
LAUNCH_PID=""

# What went wrong, if anything: rviz dying, blank screenshots, rviz's own errors and warnings, type mismatches
# reported by the publishers, TF lookups that failed.
status=0
{
  echo "layout: $CONFIG"
  echo "bag: $SIM/sequence.bag"
  if grep -q "\[rviz-[0-9]*\] process has died" "$OUT/launch.log"; then
    echo "FAIL: rviz died:"; grep "process has died" "$OUT/launch.log"; status=1
  fi
  for png in "$OUT"/rviz_t*.png; do
    sd=$(convert "$png" -colorspace Gray -format '%[fx:standard_deviation]' info:)
    echo "$(basename "$png"): grey standard deviation $sd"
    if python3 -c "import sys; sys.exit(0 if float('$sd') < 0.02 else 1)"; then
      echo "FAIL: $(basename "$png") is blank"; status=1
    fi
  done
  problems=$(cat "$ROS_LOG_DIR"/*/rviz-*-stdout.log "$ROS_LOG_DIR"/*/rosout.log 2>/dev/null |
             grep -E "wants topic|does not exist|No transform|ERROR|WARN.*rviz|\[ WARN\]" | sort -u || true)
  if [ -n "$problems" ]; then
    echo "FAIL: problems in the logs:"; echo "$problems"; status=1
  else
    echo "logs: no rviz error or warning, no type mismatch, no missing frame"
  fi
} | tee "$OUT/summary.txt"
grep -q '^FAIL' "$OUT/summary.txt" && status=1
echo "rviz_check: screenshot $OUT/rviz.png"
exit $status
