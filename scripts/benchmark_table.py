#!/usr/bin/env python3
"""The paper's Table I on simulated flights, plus inclined planes (docs/evaluation.md, `make benchmark`).

For each of the simulator's presets flight1..flight7 (imitating the paper's seven flights), simulate one sequence
and run it through diekf_bag_runner with the iterated filter (iekf), the one-pass EKF (ekf) and the feature
baseline (lk). Then simulate the `incline` preset over planes tilted by 0, 10, 20 and 30 degrees and run the
iterated filter. With --realistic (the default), each flight is also simulated with `--realism realistic` (rolling
shutter, time offset, calibration errors, defocus, exposure steps, non-Lambertian patches) and run through the
default estimator as an extra row labelled "realistic"; a simulator without that flag skips these rows with a
message. With --clutter (the default), one flight (--clutter-flight, flight4) is simulated twice more, once with a
moving object crossing the view and once with boxes standing on the ground (docs/simulator.md, "Moving objects and
clutter"), and run through the default estimator: a table with the covered fraction of the image next to the
errors, and the same flight without them. With --timing (the default), one flight (--timing-flight, flight7) is
simulated with a camera-IMU time offset of 10 and 20 ms unknown to the camchain and with a 16 ms rolling shutter,
each run through the default estimator (the offset also not estimated; the readout also ignored and given). Every table also gives the consistency of the reported uncertainty: the fractions of the distance and
velocity errors inside the filter's 2-sigma (95 % for a consistent filter), the mean NEES (4 if consistent) and, in
the flights' and inclines' tables, the frames of the whole run that said tracking with the distance beyond 3 sigma.
Prints Markdown tables side by side with the paper's figures and writes, under --output:
  benchmark.md     the tables
  benchmark.json   every evaluation.json, keyed by run
  runs/NAME/MODE/  each run's outputs (estimates.csv, groundtruth.csv, evaluation.json)
Sequences are simulated into runs/NAME/sequence/ and deleted after their runs unless --keep-bags.

    benchmark_table.py [--output DIR] [--duration S] [--flights 1,2,...] [--modes iekf,ekf,lk]
                       [--inclines 0,10,20,30] [--seed N] [--runner-args "..."] [--keep-bags] [--plots]
                       [--realistic | --no-realistic] [--clutter | --no-clutter] [--clutter-flight K]
                       [--timing | --no-timing] [--timing-flight K]
"""

import argparse
import datetime
import json
import math
import os
import sys
import time

from diekf_tools import find_bin_dir, run

# The paper (Zhong & Chirarattananon, RA-L 2020), Table I: distance RMSE (cm) and velocity RMSE (cm/s) for
# D-IEKF / D-EKF / LK; None = diverged. docs/algorithm.md section 5.
PAPER = {
    1: {"speed": "24 / 83", "texture": "checkerboard", "d": (2.2, 2.3, 4.9), "v": (2.0, 2.0, 1.4)},
    2: {"speed": "21 / 113", "texture": "checkerboard", "d": (3.7, 3.7, 7.3), "v": (1.2, 1.2, 1.8)},
    3: {"speed": "24 / 94", "texture": "checkerboard", "d": (3.2, 3.2, 73.6), "v": (2.2, 2.2, 118.5)},
    4: {"speed": "21 / 64", "texture": "vegetation", "d": (2.9, 3.6, 5.5), "v": (1.4, 1.4, 1.4)},
    5: {"speed": "22 / 86", "texture": "vegetation", "d": (3.2, 5.7, 29.7), "v": (2.0, 2.2, 35.4)},
    6: {"speed": "44 / 194", "texture": "vegetation", "d": (5.9, 6.1, 85.1), "v": (6.1, 6.3, 145.0)},
    7: {"speed": "57 / 275", "texture": "vegetation", "d": (5.8, None, 75.3), "v": (7.0, None, 146.2)},
}
PAPER_MS = {"iekf": "1.36-1.44", "ekf": "1.33", "lk": "7"}
MODE_INDEX = {"iekf": 0, "ekf": 1, "lk": 2}
MODE_NAME = {"iekf": "D-IEKF", "ekf": "D-EKF", "lk": "LK"}


def simulate(bin_dir, preset, duration_s, seed, out_dir, extra, required=True):
    """Simulates one sequence into out_dir. Exits on failure when `required`, else returns False."""
    os.makedirs(out_dir, exist_ok=True)
    cmd = [os.path.join(bin_dir, "diekf_simulate"), "--preset", preset, "--duration", str(duration_s),
           "--seed", str(seed), "--output", out_dir] + extra
    log_path = os.path.join(out_dir, "simulate.log")
    rc = run(cmd, log_path)
    if rc != 0 or not os.path.isfile(os.path.join(out_dir, "sequence.bag")):
        if required:
            sys.exit("benchmark_table.py: simulation failed, see %s" % log_path)
        return False
    return True


def simulator_rejected(log_path, flag):
    """True when the simulator's log says it does not know `flag` (an older diekf_simulate)."""
    try:
        with open(log_path) as f:
            lines = f.read().splitlines()[1:]  # the first line is the command
    except OSError:
        return False
    return any(flag in line and ("unknown" in line.lower() or "unrecognized" in line.lower()) for line in lines)


def run_estimator(bin_dir, seq_dir, mode, name, out_dir, runner_args, plots):
    """Runs diekf_bag_runner on a simulated sequence; `mode` None runs the default estimator (the config's mode)."""
    os.makedirs(out_dir, exist_ok=True)
    cmd = [os.path.join(bin_dir, "diekf_bag_runner"), "--bag", os.path.join(seq_dir, "sequence.bag"),
           "--camchain", os.path.join(seq_dir, "camchain.yaml"), "--imu", os.path.join(seq_dir, "imu.yaml"),
           "--sequence", name, "--output", out_dir, "--quiet"] + (["--mode", mode] if mode else []) + runner_args
    label = mode or "default"
    t0 = time.time()
    rc = run(cmd, os.path.join(out_dir, "runner.log"))
    ev_path = os.path.join(out_dir, "evaluation.json")
    if rc != 0 or not os.path.isfile(ev_path):
        print("  %-10s %-4s FAILED (exit %d), see %s" % (name, label, rc, os.path.join(out_dir, "runner.log")),
              flush=True)
        return {"failed": True, "exit_code": rc}
    with open(ev_path) as f:
        ev = json.load(f)
    print("  %-10s %-4s d %s cm, v %s cm/s, normal %s deg, %s ms/frame; inside 2σ d %s %%, v %s %%, NEES %s; "
          "tracking beyond 3σ d %s / v %s frames%s  (%.0f s)" % (
              name, label, cm(ev.get("rmse_distance_m")), cm(ev.get("rmse_velocity_mps")),
              num(ev.get("rms_normal_deg")), num(ev.get("update_ms_mean"), 2), pct(ev.get("coverage2_d")),
              pct(ev.get("coverage2_v")), num(ev.get("nees_mean")), ev.get("tracking_beyond3_d", "n/a"),
              ev.get("tracking_beyond3_v", "n/a"),
              ", DIVERGED" if ev.get("diverged") else "", time.time() - t0), flush=True)
    if plots:
        plot = os.path.join(os.path.dirname(os.path.abspath(__file__)), "plot_results.py")
        run([sys.executable, plot, out_dir, "--title", "%s (%s)" % (name, label)], os.path.join(out_dir, "plot.log"))
    return ev


def num(v, decimals=1):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return "%.*f" % (decimals, v)


def cm(v):
    return num(None if v is None else 100.0 * v)


def pct(v):
    return num(None if v is None else 100.0 * v)


def consistency_cells(ev):
    """2-sigma coverage of distance and velocity (%) and mean NEES of one run (also for a diverged run: the
    figures then say how badly its reported sigma understated the error), and the frames of the whole run, start
    included, whose status said tracking with the distance / a velocity axis more than 3 sigma off."""
    if ev is None:
        return ["–"] * 4
    if ev.get("failed"):
        return ["failed"] * 4
    beyond = ["n/a" if ev.get(k) is None else str(ev.get(k)) for k in ("tracking_beyond3_d", "tracking_beyond3_v")]
    return [pct(ev.get("coverage2_d")), pct(ev.get("coverage2_v")), num(ev.get("nees_mean")), " / ".join(beyond)]


def ours(ev, key, scale=100.0):
    """Our figure for a table cell: value, 'diverged', or 'failed'."""
    if ev is None:
        return "–"
    if ev.get("failed"):
        return "failed"
    if ev.get("diverged"):
        return "diverged"
    v = ev.get(key)
    return num(None if v is None else scale * v)


def paper_cell(value):
    return "diverged" if value is None else num(value)


def table_one(results, flights, modes):
    """Table I, one row per simulated flight; with a realistic-camera run of the flight, a second row labelled
    "realistic" (default estimator, the iterated filter: its figures in the D-IEKF columns, "–" in the others).
    The consistency columns give every filter's figure, joined by " / " in the order of the modes."""
    lines = []
    names = " / ".join(MODE_NAME[m] for m in modes)
    head = ["flight", "sequence", "texture", "paper RMS/max speed (cm/s)"]
    for quantity in ("distance RMSE (cm)", "velocity RMSE (cm/s)"):
        for m in modes:
            head.append("%s %s: ours / paper" % (quantity.split(" ")[0], MODE_NAME[m]))
    head += ["d within 2σ (%%): %s" % names, "v within 2σ (%%): %s" % names, "NEES mean: %s" % names,
             "frames tracking beyond 3σ, d / v: %s" % names]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    for k in flights:
        p = PAPER[k]
        variants = [("simulated", {m: results.get("flight%d/%s" % (k, m)) for m in modes})]
        realistic = results.get("flight%d/realistic" % k)
        if realistic is not None:
            # The default estimator is the iterated filter (config/estimator.yaml); shown in its columns.
            variants.append(("simulated, realistic", {m: (realistic if m == "iekf" else None) for m in modes}))
        for label, evs in variants:
            row = [str(k) if label == "simulated" else "%d realistic" % k, label, p["texture"], p["speed"]]
            for key, pk in (("rmse_distance_m", "d"), ("rmse_velocity_mps", "v")):
                for m in modes:
                    if evs[m] is None and label != "simulated":
                        row.append("–")
                    else:
                        row.append("%s / %s" % (ours(evs[m], key), paper_cell(p[pk][MODE_INDEX[m]])))
            cells = [consistency_cells(evs[m]) for m in modes]
            for i in range(4):
                row.append(" / ".join(c[i] for c in cells))
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def table_timing(results, flights, modes):
    lines = ["| filter | mean update (ms), ours | median (ms) | p99 (ms) | real-time factor | paper (ms, i5-8250U) |",
             "|---|---|---|---|---|---|"]
    for m in modes:
        evs = [results.get("flight%d/%s" % (k, m)) for k in flights]
        evs = [e for e in evs if e and not e.get("failed")]

        def mean_of(key):
            vals = [e[key] for e in evs if e.get(key) is not None]
            return sum(vals) / len(vals) if vals else None

        lines.append("| %s | %s | %s | %s | %s | %s |" % (
            MODE_NAME[m], num(mean_of("update_ms_mean"), 2), num(mean_of("update_ms_median"), 2),
            num(mean_of("update_ms_p99"), 2), num(mean_of("realtime_factor"), 3), PAPER_MS[m]))
    return "\n".join(lines)


def table_incline(results, inclines, modes):
    lines = ["| plane incline (deg) | sequence | filter | distance RMSE (cm) | height RMSE (cm) | velocity RMSE (cm/s) | "
             "normal error RMS / max (deg) | gravity error RMS (deg) | d within 2σ (%) | v within 2σ (%) | NEES mean | "
             "frames tracking beyond 3σ, d / v |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for a in inclines:
        for m in modes:
            ev = results.get("incline%g/%s" % (a, m))
            if ev is None:
                continue
            if ev.get("failed"):
                lines.append("| %g | simulated | %s | failed | | | | | | | | |" % (a, MODE_NAME[m]))
                continue
            lines.append("| %g | simulated | %s | %s | %s | %s | %s / %s | %s | %s |" % (
                a, MODE_NAME[m], ours(ev, "rmse_distance_m") if not ev.get("diverged") else "diverged",
                cm(ev.get("rmse_height_m")), cm(ev.get("rmse_velocity_mps")), num(ev.get("rms_normal_deg"), 2),
                num(ev.get("max_normal_deg"), 2), num(ev.get("rms_gravity_deg"), 2),
                " | ".join(consistency_cells(ev))))
    return "\n".join(lines)


def run_realistic(bin_dir, args, k, runs_dir, sim_extra, runner_args, results):
    """Simulates flight k again with `--realism realistic` and runs the default estimator on it
    (results["flightK/realistic"]). Returns False when the simulator does not support the flag (no more realistic
    rows are tried), True otherwise; a failure never stops the benchmark."""
    name = "flight%d_realistic" % k
    seq_dir = os.path.join(runs_dir, name, "sequence")
    if not (args.reuse_bags and os.path.isfile(os.path.join(seq_dir, "sequence.bag"))):
        if not simulate(bin_dir, "flight%d" % k, args.duration, args.seed, seq_dir,
                        ["--realism", "realistic"] + sim_extra, required=False):
            log_path = os.path.join(seq_dir, "simulate.log")
            if simulator_rejected(log_path, "--realism"):
                print("benchmark_table.py: this diekf_simulate has no --realism option yet (see %s); skipping the "
                      "realistic rows (rebuild the simulator once it has the option, or use --no-realistic)"
                      % log_path, flush=True)
                return False
            print("benchmark_table.py: realistic simulation of flight%d failed, see %s; row skipped" % (k, log_path),
                  flush=True)
            return True
    results["flight%d/realistic" % k] = run_estimator(bin_dir, seq_dir, None, name,
                                                      os.path.join(runs_dir, name, "default"), runner_args,
                                                      args.plots)
    if not args.keep_bags:
        os.remove(os.path.join(seq_dir, "sequence.bag"))
    return True


# The clutter rows: (label, diekf_simulate options). About 12 % of the image covered while the mover is in view,
# and 10-20 % by the boxes on flight4 (docs/simulator.md, "Moving objects and clutter").
CLUTTER_RUNS = [
    ("movers", ["--movers", "1"]),
    ("boxes", ["--boxes", "5"]),
]


# The camera-fixed pattern rows (issue 13): (label, diekf_simulate options) on the clutter flight, default estimator
# with the pattern removal on (docs/noise_model.md section 11); coverage from the simulation's patterns.yaml.
PATTERN_RUNS = [
    ("shadow", ["--shadow"]),
    ("projector", ["--projector-dots", "1500"]),
    ("lens dirt", ["--lens-dirt", "6"]),
    ("vignetting 0.6", ["--vignetting", "0.6"]),
]


def run_pattern(bin_dir, args, k, label, extra, runs_dir, sim_extra, runner_args, results):
    """Simulates flight k with a camera-fixed pattern and runs the default estimator on it
    (results["patternK/label"], with patterns.yaml's coverage under "pattern"). Returns False when the simulator
    does not know the options (no more pattern rows are tried)."""
    name = "flight%d_%s" % (k, label.replace(" ", "_").replace(".", ""))
    seq_dir = os.path.join(runs_dir, name, "sequence")
    if not (args.reuse_bags and os.path.isfile(os.path.join(seq_dir, "sequence.bag"))):
        if not simulate(bin_dir, "flight%d" % k, args.duration, args.seed, seq_dir, extra + sim_extra, required=False):
            log_path = os.path.join(seq_dir, "simulate.log")
            if simulator_rejected(log_path, extra[0]):
                print("benchmark_table.py: this diekf_simulate has no %s option (see %s); skipping the pattern rows "
                      "(or use --no-patterns)" % (extra[0], log_path), flush=True)
                return False
            print("benchmark_table.py: %s simulation of flight%d failed, see %s; row skipped" % (label, k, log_path),
                  flush=True)
            return True
    ev = run_estimator(bin_dir, seq_dir, None, name, os.path.join(runs_dir, name, "default"), runner_args, args.plots)
    ev["pattern"] = read_simple_yaml(os.path.join(seq_dir, "patterns.yaml"))
    ev["pattern"]["options"] = " ".join(extra)
    results["pattern%d/%s" % (k, label)] = ev
    if not args.keep_bags:
        os.remove(os.path.join(seq_dir, "sequence.bag"))
    return True


def table_patterns(results, k):
    """One row per camera-fixed pattern run of flight k, and the flight without one (its iekf run)."""
    lines = ["| flight | pattern (diekf_simulate options) | image covered, mean (%) | distance RMSE (cm) | "
             "velocity RMSE (cm/s) | normal error RMS (deg) | diverged |",
             "|---|---|---|---|---|---|---|"]
    rows = [("clean", results.get("flight%d/iekf" % k))]
    rows += [(label, results.get("pattern%d/%s" % (k, label))) for label, _ in PATTERN_RUNS]
    for label, ev in rows:
        if not ev:
            continue
        if ev.get("failed"):
            lines.append("| %d | %s | – | failed | failed | – | – |" % (k, label))
            continue
        p = ev.get("pattern", {})
        cover = "–" if label == "clean" else (pct(p["pattern_coverage_mean"]) if "pattern_coverage_mean" in p else "–")
        opts = label if label == "clean" else "%s (`%s`)" % (label, p.get("options", ""))
        lines.append("| %d | %s | %s | %s | %s | %s | %s |" % (
            k, opts, cover, cm(ev.get("rmse_distance_m")), cm(ev.get("rmse_velocity_mps")),
            num(ev.get("rms_normal_deg")), "yes" if ev.get("diverged") else "no"))
    return "\n".join(lines)


def read_simple_yaml(path):
    """The top-level `key: number` lines of a YAML file (enough for clutter.yaml's summary)."""
    out = {}
    try:
        with open(path) as f:
            for line in f:
                if line.startswith((" ", "#", "-")) or ":" not in line:
                    continue
                key, value = line.split(":", 1)
                value = value.split("#", 1)[0].strip()
                try:
                    out[key.strip()] = float(value)
                except ValueError:
                    pass
    except OSError:
        pass
    return out


def run_clutter(bin_dir, args, k, label, extra, runs_dir, sim_extra, runner_args, results):
    """Simulates flight k with movers or boxes and runs the default estimator on it (results["clutterK/label"],
    with the coverage summary of clutter.yaml under "clutter"). Returns False when the simulator does not know the
    options (no more clutter rows are tried)."""
    name = "flight%d_%s" % (k, label)
    seq_dir = os.path.join(runs_dir, name, "sequence")
    if not (args.reuse_bags and os.path.isfile(os.path.join(seq_dir, "sequence.bag"))):
        if not simulate(bin_dir, "flight%d" % k, args.duration, args.seed, seq_dir, extra + sim_extra, required=False):
            log_path = os.path.join(seq_dir, "simulate.log")
            if simulator_rejected(log_path, extra[0]):
                print("benchmark_table.py: this diekf_simulate has no %s option (see %s); skipping the clutter rows "
                      "(or use --no-clutter)" % (extra[0], log_path), flush=True)
                return False
            print("benchmark_table.py: %s simulation of flight%d failed, see %s; row skipped" % (label, k, log_path),
                  flush=True)
            return True
    ev = run_estimator(bin_dir, seq_dir, None, name, os.path.join(runs_dir, name, "default"), runner_args, args.plots)
    ev["clutter"] = read_simple_yaml(os.path.join(seq_dir, "clutter.yaml"))
    ev["clutter"]["options"] = " ".join(extra)
    results["clutter%d/%s" % (k, label)] = ev
    if not args.keep_bags:
        os.remove(os.path.join(seq_dir, "sequence.bag"))
    return True


def table_clutter(results, k):
    """One row per clutter run of flight k, and the flight without clutter (its iekf run) for comparison."""
    lines = ["| flight | scene (diekf_simulate options) | image covered: mean / max (%) | covered while present (%) | "
             "distance RMSE (cm) | velocity RMSE (cm/s) | normal error RMS (deg) | diverged | d within 2σ (%) | "
             "NEES mean |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    rows = [("clean", results.get("flight%d/iekf" % k))]
    rows += [(label, results.get("clutter%d/%s" % (k, label))) for label, _ in CLUTTER_RUNS]
    for label, ev in rows:
        if ev is None:
            continue
        if ev.get("failed"):
            lines.append("| %d | %s | | | failed | | | | | |" % (k, label))
            continue
        c = ev.get("clutter", {})
        if label == "clean":
            cov, present, scene = "0 / 0", "–", "clean"
        elif label == "movers":
            cov = "%s / %s" % (pct(c.get("mover_coverage_mean")), pct(c.get("mover_coverage_max")))
            present = pct(c.get("mover_coverage_mean_when_present"))
            scene = "`%s`" % c.get("options", label)
        else:
            cov = "%s / %s" % (pct(c.get("box_coverage_mean")), pct(c.get("box_coverage_max")))
            present = "–"
            scene = "`%s`" % c.get("options", label)
        lines.append("| %d | %s | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            k, scene, cov, present, cm(ev.get("rmse_distance_m")), cm(ev.get("rmse_velocity_mps")),
            num(ev.get("rms_normal_deg"), 2), "yes" if ev.get("diverged") else "no", pct(ev.get("coverage2_d")),
            num(ev.get("nees_mean"))))
    return "\n".join(lines)


# The timing rows (issue 16): (label, diekf_simulate options, extra diekf_bag_runner options). A camera-IMU time
# offset that the camchain does not know, estimated online and not, and a 16 ms rolling-shutter readout estimated
# online, ignored, and given as the line delay (the simulator's, from realism.yaml).
TIMING_RUNS = [
    ("time offset 10 ms", ["--time-offset-ms", "10"], []),
    ("time offset 20 ms", ["--time-offset-ms", "20"], []),
    ("time offset 20 ms, not estimated", ["--time-offset-ms", "20"], ["--set", "estimate_time_offset=false"]),
    ("rolling shutter 16 ms, readout estimated from 0", ["--rolling-shutter-ms", "16"], []),
    ("rolling shutter 16 ms, readout ignored", ["--rolling-shutter-ms", "16"], ["--set", "estimate_readout=false"]),
    ("rolling shutter 16 ms, line delay given", ["--rolling-shutter-ms", "16"], ["line_delay"]),
]


def run_timing(bin_dir, args, k, label, sim_opts, run_opts, runs_dir, sim_extra, runner_args, results):
    """Simulates flight k with a timing error and runs the default estimator (results["timingK/label"]). The
    sequence is shared by the rows with the same simulator options. Returns False when the simulator does not know
    the options."""
    name = "flight%d_%s" % (k, "_".join(o.strip("-") for o in sim_opts))
    seq_dir = os.path.join(runs_dir, name, "sequence")
    bag = os.path.join(seq_dir, "sequence.bag")
    if not os.path.isfile(bag):
        if not simulate(bin_dir, "flight%d" % k, args.duration, args.seed, seq_dir, sim_opts + sim_extra,
                        required=False):
            log_path = os.path.join(seq_dir, "simulate.log")
            if simulator_rejected(log_path, sim_opts[0]):
                print("benchmark_table.py: this diekf_simulate has no %s option; skipping the timing rows" %
                      sim_opts[0], flush=True)
                return False
            print("benchmark_table.py: timing simulation %s failed, see %s; row skipped" % (name, log_path), flush=True)
            return True
    extra = list(run_opts)
    if "line_delay" in extra:
        line_time = read_simple_yaml(os.path.join(seq_dir, "realism.yaml")).get("rolling_shutter_line_time_s", 0.0)
        extra = ["--set", "line_delay_s=%.6g" % line_time]
    tag = label.replace(" ", "_").replace(",", "")
    ev = run_estimator(bin_dir, seq_dir, None, name, os.path.join(runs_dir, name, tag),
                       list(runner_args) + extra, args.plots)
    ev["timing"] = {"simulator": " ".join(sim_opts), "runner": " ".join(extra)}
    results["timing%d/%s" % (k, label)] = ev
    return True


def table_timing_rows(results, k):
    """One row per timing run of flight k, and the flight without timing errors (its iekf run) for comparison."""
    lines = ["| flight | case (diekf_simulate options; estimator options) | distance RMSE (cm) | velocity RMSE (cm/s) | "
             "d within 2σ (%) | v within 2σ (%) | NEES mean |",
             "|---|---|---|---|---|---|---|"]
    rows = [("clean", results.get("flight%d/iekf" % k))]
    rows += [(label, results.get("timing%d/%s" % (k, label))) for label, _, _ in TIMING_RUNS]
    for label, ev in rows:
        if ev is None:
            continue
        if ev.get("failed"):
            lines.append("| %d | %s | failed | | | | |" % (k, label))
            continue
        t = ev.get("timing", {})
        case = label if label == "clean" else "%s (`%s`%s)" % (
            label, t.get("simulator", ""), "; `%s`" % t["runner"] if t.get("runner") else "")
        lines.append("| %d | %s | %s | %s | %s | %s | %s |" % (
            k, case, cm(ev.get("rmse_distance_m")), cm(ev.get("rmse_velocity_mps")), pct(ev.get("coverage2_d")),
            pct(ev.get("coverage2_v")), num(ev.get("nees_mean"))))
    return "\n".join(lines)


def parse_list(text, cast):
    return [cast(x) for x in text.split(",") if x.strip()] if text else []


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    pkg_dir = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    parser.add_argument("--output", default=os.path.join(pkg_dir, "results"), help="results folder [results/]")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per simulated flight [60]")
    parser.add_argument("--flights", default="1,2,3,4,5,6,7", help="which of flight1..7 [all]")
    parser.add_argument("--modes", default="iekf,ekf,lk", help="filters for Table I [iekf,ekf,lk]")
    parser.add_argument("--inclines", default="0,10,20,30", help="plane inclines in degrees ('' to skip)")
    parser.add_argument("--incline-modes", default="iekf", help="filters for the incline runs [iekf]")
    parser.add_argument("--incline-duration", type=float, default=None, help="seconds per incline run [--duration]")
    parser.add_argument("--seed", type=int, default=1, help="simulation seed [1]")
    parser.add_argument("--sim-args", default="", help="extra diekf_simulate arguments")
    parser.add_argument("--runner-args", default="", help="extra diekf_bag_runner arguments, e.g. '--width 90'")
    parser.add_argument("--keep-bags", action="store_true", help="keep the simulated bags")
    parser.add_argument("--reuse-bags", action="store_true",
                        help="use the sequences already in OUTPUT/runs (same presets, duration and seed) instead of "
                             "simulating them again; implies --keep-bags")
    parser.add_argument("--plots", action="store_true", help="also write each run's plots")
    parser.add_argument("--realistic", dest="realistic", action="store_true", default=True,
                        help="also simulate each flight with '--realism realistic' and run the default estimator on "
                             "it, as an extra row labelled 'realistic' [on]")
    parser.add_argument("--no-realistic", dest="realistic", action="store_false", help="skip the realistic rows")
    parser.add_argument("--clutter", dest="clutter", action="store_true", default=True,
                        help="also simulate one flight with a moving object and one with boxes on the ground and run "
                             "the default estimator on them (two extra flights) [on]")
    parser.add_argument("--no-clutter", dest="clutter", action="store_false", help="skip the clutter rows")
    parser.add_argument("--clutter-flight", type=int, default=4, help="the flight of the clutter rows [4]")
    parser.add_argument("--no-patterns", dest="patterns", action="store_false",
                        help="skip the camera-fixed pattern rows (shadow, projector, lens dirt, vignetting)")
    parser.add_argument("--timing", dest="timing", action="store_true", default=True,
                        help="time-offset and rolling-shutter rows on --timing-flight (default)")
    parser.add_argument("--no-timing", dest="timing", action="store_false", help="skip the timing rows")
    parser.add_argument("--timing-flight", type=int, default=7, help="the flight of the timing rows [7]")
    args = parser.parse_args(argv)
    if args.reuse_bags:
        args.keep_bags = True

    flights = parse_list(args.flights, int)
    modes = parse_list(args.modes, str)
    inclines = parse_list(args.inclines, float)
    incline_modes = parse_list(args.incline_modes, str)
    for m in modes + incline_modes:
        if m not in MODE_INDEX:
            sys.exit("benchmark_table.py: unknown mode '%s' (iekf, ekf, lk)" % m)
    for k in flights:
        if k not in PAPER:
            sys.exit("benchmark_table.py: flights are 1..7, got %d" % k)
    bin_dir = find_bin_dir("benchmark_table.py")
    runs_dir = os.path.join(args.output, "runs")
    os.makedirs(runs_dir, exist_ok=True)
    sim_extra = args.sim_args.split()
    runner_args = args.runner_args.split()
    results = {}
    started = time.time()
    # Realistic rows for the flights that the iterated filter runs on (see run_realistic).
    realistic = args.realistic and "iekf" in modes
    if args.realistic and not realistic and flights:
        print("benchmark_table.py: no realistic rows: they accompany the iterated filter's (--modes without iekf)",
              flush=True)

    print("Table I: %d flights x %s, %g s each (seed %d)" % (len(flights), ",".join(modes), args.duration, args.seed),
          flush=True)
    for k in flights:
        name = "flight%d" % k
        seq_dir = os.path.join(runs_dir, name, "sequence")
        if not (args.reuse_bags and os.path.isfile(os.path.join(seq_dir, "sequence.bag"))):
            simulate(bin_dir, name, args.duration, args.seed, seq_dir, sim_extra)
        for m in modes:
            results["%s/%s" % (name, m)] = run_estimator(bin_dir, seq_dir, m, name, os.path.join(runs_dir, name, m),
                                                         runner_args, args.plots)
        if not args.keep_bags:
            os.remove(os.path.join(seq_dir, "sequence.bag"))
        if realistic:
            realistic = run_realistic(bin_dir, args, k, runs_dir, sim_extra, runner_args, results)

    if args.clutter:
        if args.clutter_flight not in PAPER:
            sys.exit("benchmark_table.py: --clutter-flight is 1..7, got %d" % args.clutter_flight)
        print("Moving objects and clutter: flight%d with %s, default estimator" % (
            args.clutter_flight, " / ".join(label for label, _ in CLUTTER_RUNS)), flush=True)
        for label, extra in CLUTTER_RUNS:
            if not run_clutter(bin_dir, args, args.clutter_flight, label, extra, runs_dir, sim_extra, runner_args,
                               results):
                break

    if args.patterns:
        if args.clutter_flight not in PAPER:
            sys.exit("benchmark_table.py: --clutter-flight is 1..7, got %d" % args.clutter_flight)
        print("Camera-fixed patterns: flight%d with %s, default estimator" % (
            args.clutter_flight, " / ".join(label for label, _ in PATTERN_RUNS)), flush=True)
        for label, extra in PATTERN_RUNS:
            if not run_pattern(bin_dir, args, args.clutter_flight, label, extra, runs_dir, sim_extra, runner_args,
                               results):
                break

    if args.timing:
        if args.timing_flight not in PAPER:
            sys.exit("benchmark_table.py: --timing-flight is 1..7, got %d" % args.timing_flight)
        print("Timing: flight%d with a time offset and a rolling shutter, default estimator" % args.timing_flight,
              flush=True)
        for label, sim_opts, run_opts in TIMING_RUNS:
            if not run_timing(bin_dir, args, args.timing_flight, label, sim_opts, run_opts, runs_dir, sim_extra,
                              runner_args, results):
                break
        if not args.keep_bags:
            for label, sim_opts, _ in TIMING_RUNS:
                bag = os.path.join(runs_dir, "flight%d_%s" % (args.timing_flight, "_".join(
                    o.strip("-") for o in sim_opts)), "sequence", "sequence.bag")
                if os.path.isfile(bag):
                    os.remove(bag)

    incline_duration = args.incline_duration or args.duration
    if inclines:
        print("Inclined planes: %s deg, %s, %g s each" % (",".join("%g" % a for a in inclines),
                                                          ",".join(incline_modes), incline_duration), flush=True)
    for a in inclines:
        name = "incline%g" % a
        seq_dir = os.path.join(runs_dir, name, "sequence")
        if not (args.reuse_bags and os.path.isfile(os.path.join(seq_dir, "sequence.bag"))):
            simulate(bin_dir, "incline", incline_duration, args.seed, seq_dir, ["--incline-deg", "%g" % a] + sim_extra)
        for m in incline_modes:
            results["%s/%s" % (name, m)] = run_estimator(bin_dir, seq_dir, m, name, os.path.join(runs_dir, name, m),
                                                         runner_args, args.plots)
        if not args.keep_bags:
            os.remove(os.path.join(seq_dir, "sequence.bag"))

    try:
        cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), "?")
    except OSError:
        cpu = "?"
    md = ["# diekf benchmark: the paper's Table I on simulated flights", "",
          "Generated %s by scripts/benchmark_table.py (%g s per flight, seed %d%s%s); CPU: %s. "
          "Simulated flights imitate the paper's speeds and textures; they are not its recordings, so the figures "
          "compare behaviour, not identical data; every row is simulated, rows labelled \"realistic\" with the "
          "simulator's realistic camera (`--realism realistic`) and the default estimator. Errors from 3 s after "
          "the first image update (docs/conventions.md section 5). Consistency of the reported uncertainty: "
          "\"within 2σ\" is the fraction of frames (distance) or of frame-axis pairs (velocity) whose error lies "
          "inside the filter's ±2σ, about 95 %% for a consistent filter; NEES is the mean over frames of the squared "
          "normalised distance and velocity errors, about 4 for a consistent filter. \"Frames tracking beyond 3σ\" "
          "counts, over the whole run with its start, the frames whose status said tracking with the distance / "
          "the largest velocity axis more than 3σ off (evaluation.json `tracking_beyond3_d`, `tracking_beyond3_v`; "
          "about 0.3 %% / 0.8 %% of the frames for consistent Gaussian errors)." % (
              datetime.datetime.now().strftime("%Y-%m-%d %H:%M"), args.duration, args.seed,
              ", simulator args '%s'" % args.sim_args if args.sim_args else "",
              ", runner args '%s'" % args.runner_args if args.runner_args else "", cpu), ""]
    if flights and modes:
        md += ["## Table I: distance and velocity RMSE (ours / paper), consistency of the reported sigma", "", table_one(results, flights, modes), "",
               "## Time per frame (mean over the flights)", "", table_timing(results, flights, modes), ""]
    if inclines:
        md += ["## Inclined planes (preset `incline`)", "",
               "The paper reports no visible loss of accuracy up to 30 degrees.", "",
               table_incline(results, inclines, incline_modes), ""]
    if args.clutter and any(key.startswith("clutter") for key in results):
        md += ["## Moving objects and clutter (flight%d)" % args.clutter_flight, "",
               "Outliers of the single-plane model (issue 14): a textured object crossing the view on its own, and "
               "boxes standing on the ground; the ground truth is the ground plane. Covered: the fraction of the "
               "image whose nearest surface is a mover or a box (occlusion.csv / clutter.yaml of the simulation); "
               "\"while present\": over the images more than 1 % covered by the mover. Default estimator; the "
               "clean row is the flight's D-IEKF run of Table I.", "", table_clutter(results, args.clutter_flight), ""]
    if args.patterns and any(key.startswith("pattern") for key in results):
        md += ["## Camera-fixed patterns (flight%d)" % args.clutter_flight, "",
               "Issue 13: photometric patterns that travel with the camera (docs/simulator.md, \"Camera-fixed "
               "patterns\"): the drone's shadow (moving with the attitude), an IR projector's 1500 dots, out-of-focus "
               "lens dirt, strong vignetting. Covered: the image share whose fixed gain is off 1 by more than 10 %% "
               "(patterns.yaml). Default estimator with the online pattern removal (docs/noise_model.md section 11); "
               "the clean row is the flight's D-IEKF run of Table I.", "",
               table_patterns(results, args.clutter_flight), ""]
    if args.timing and any(key.startswith("timing") for key in results):
        md += ["## Timing: camera-IMU time offset and rolling shutter (flight%d)" % args.timing_flight, "",
               "Issue 16: images taken later than their stamps say by an offset the camchain does not know "
               "(`timeshift_cam_imu` 0), estimated online (docs/algorithm.md section 3.6) and not; a rolling shutter "
               "reading the frame out in 16 ms (stamp at the middle row), its readout estimated online from 0, "
               "ignored, and given as the line delay (`line_delay_s`, section 3.7). Default estimator otherwise; the "
               "clean row is the flight's D-IEKF run of Table I.", "", table_timing_rows(results, args.timing_flight), ""]
    text = "\n".join(md)
    print()
    print(text)
    with open(os.path.join(args.output, "benchmark.md"), "w") as f:
        f.write(text)
    with open(os.path.join(args.output, "benchmark.json"), "w") as f:
        json.dump(results, f, indent=2, sort_keys=True)
    print("wrote %s and benchmark.json (%.0f s)" % (os.path.join(args.output, "benchmark.md"), time.time() - started))
    return 0


if __name__ == "__main__":
    sys.exit(main())
