#!/usr/bin/env python3
"""The estimator on natural ground textures at several heights and working widths (docs/results.md).

For each texture (default grass, leaves, dirt, natural) and mean height (default 0.4, 0.8, 1.3 m; the slow height
changes are kept to +-0.1 m), simulate one sequence with flight5-like motion (RMS / max speed 0.22 / 0.86 m/s,
20 s), run diekf_bag_runner with the iterated filter at each working width (default 90 and 180 px) and print a
Markdown table: distance, height and velocity RMSE, normal error, divergence, mean update time, the consistency of
the reported uncertainty (fractions of the distance and velocity errors inside the filter's 2-sigma, 95 % if
consistent, and the mean NEES, 4 if consistent), and from the runner's per-frame diagnostics (--frames-csv) the
photometric residual RMS, the valid-pixel ratio, skipped updates and restarts over the evaluated part of the flight.

Output under --output (default results/textures):
  bags/TEXTURE_hH/                  the simulated sequences (kept; --reuse-bags uses them again; --bags names
                                    another folder, e.g. for sequences simulated with other --sim-args)
  runs/TAG/TEXTURE_hH_wW/           each run's estimates.csv, groundtruth.csv, frames.csv, evaluation.json
  TAG.md, TAG.json                  the table and every evaluation, keyed by run

Settings are compared by running again with --set KEY=VALUE (passed to the runner, repeatable) under another
--tag, e.g.
    texture_sweep.py --reuse-bags --tag huber --set photometric/huber_threshold=2

    texture_sweep.py [--output DIR] [--textures grass,leaves,dirt,natural] [--heights 0.4,0.8,1.3]
                     [--widths 90,180] [--preset flight5] [--duration 20] [--seed 1] [--height-amplitude 0.1]
                     [--tag NAME] [--set KEY=VALUE ...] [--reuse-bags] [--threads 1] [--steady-window 8]
                     [--bags FOLDER --sim-args "..."]
    texture_sweep.py --compare TAG,TAG,...     # side-by-side summary of earlier sweeps
"""

import argparse
import csv
import json
import math
import os
import sys
import time

from diekf_tools import find_bin_dir, run


def height_label(h):
    return ("%g" % h).replace(".", "")


def simulate(bin_dir, a, texture, height, seq_dir):
    bag = os.path.join(seq_dir, "sequence.bag")
    if a.reuse_bags and os.path.isfile(bag) and os.path.isfile(os.path.join(seq_dir, "camchain.yaml")):
        return True
    os.makedirs(seq_dir, exist_ok=True)
    cmd = [os.path.join(bin_dir, "diekf_simulate"), "--preset", a.preset, "--duration", str(a.duration),
           "--seed", str(a.seed), "--texture", texture, "--height", str(height),
           "--height-amplitude", str(a.height_amplitude), "--threads", str(a.threads), "--output", seq_dir]
    cmd += a.sim_args.split()
    t0 = time.time()
    rc = run(cmd, os.path.join(seq_dir, "simulate.log"))
    print("  simulated %s at %.2f m in %.0f s%s" % (texture, height, time.time() - t0,
                                                   "" if rc == 0 else " FAILED (exit %d)" % rc), flush=True)
    return rc == 0 and os.path.isfile(bag)


def frame_stats(frames_csv, eval_start_s):
    """Means over the evaluated frames (t >= eval_start) of the runner's per-frame diagnostics."""
    out = {"residual_rms": None, "valid_ratio": None, "skipped_pct": None, "resets": None}
    if not os.path.isfile(frames_csv):
        return out
    rms, valid, n, skipped, resets = [], [], 0, 0, 0
    with open(frames_csv) as f:
        for row in csv.DictReader(f):
            if float(row["t"]) < eval_start_s:
                continue
            n += 1
            if row["status"] == "reset":
                resets += 1
            if row["applied"] == "1":
                rms.append(float(row["photometric_rms"]))
                valid.append(float(row["valid_ratio"]))
            else:
                skipped += 1
    if n:
        out["skipped_pct"] = 100.0 * skipped / n
        out["resets"] = resets
    if rms:
        out["residual_rms"] = sum(rms) / len(rms)
        out["valid_ratio"] = sum(valid) / len(valid)
    return out


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def steady_stats(out_dir, window_s):
    """RMSE of distance and velocity and RMS normal-angle error over the last `window_s` seconds of the run (after
    the start-up transient), matching estimates to ground truth by stamp."""
    out = {"steady_rmse_distance_m": None, "steady_rmse_velocity_mps": None, "steady_rms_normal_deg": None}
    est_path, gt_path = os.path.join(out_dir, "estimates.csv"), os.path.join(out_dir, "groundtruth.csv")
    if not (os.path.isfile(est_path) and os.path.isfile(gt_path)):
        return out
    truth = {r["t"]: r for r in read_csv(gt_path)}
    est = read_csv(est_path)
    if not est:
        return out
    t_end = float(est[-1]["t"])
    d2, v2, n2, n = 0.0, 0.0, 0.0, 0
    for e in est:
        g = truth.get(e["t"])
        if g is None or float(e["t"]) < t_end - window_s:
            continue
        d2 += (float(e["d"]) - float(g["d"])) ** 2
        v2 += sum((float(e[k]) - float(g[k])) ** 2 for k in ("vx", "vy", "vz"))
        mu_e = [float(e[k]) for k in ("mux", "muy", "muz")]
        mu_g = [float(g[k]) for k in ("mux", "muy", "muz")]
        c = sum(a * b for a, b in zip(mu_e, mu_g)) / math.sqrt(sum(a * a for a in mu_e) * sum(b * b for b in mu_g))
        n2 += math.degrees(math.acos(max(-1.0, min(1.0, c)))) ** 2
        n += 1
    if n:
        out["steady_rmse_distance_m"] = math.sqrt(d2 / n)
        out["steady_rmse_velocity_mps"] = math.sqrt(v2 / n)
        out["steady_rms_normal_deg"] = math.sqrt(n2 / n)
    return out


def run_estimator(bin_dir, a, seq_dir, width, name, out_dir):
    os.makedirs(out_dir, exist_ok=True)
    cmd = [os.path.join(bin_dir, "diekf_bag_runner"), "--bag", os.path.join(seq_dir, "sequence.bag"),
           "--camchain", os.path.join(seq_dir, "camchain.yaml"), "--imu", os.path.join(seq_dir, "imu.yaml"),
           "--mode", "iekf", "--width", str(width), "--sequence", name, "--output", out_dir, "--quiet",
           "--frames-csv"]
    for s in a.set:
        cmd += ["--set", s]
    rc = run(cmd, os.path.join(out_dir, "runner.log"))
    ev_path = os.path.join(out_dir, "evaluation.json")
    if rc != 0 or not os.path.isfile(ev_path):
        return {"failed": True, "exit_code": rc}
    with open(ev_path) as f:
        ev = json.load(f)
    ev.update(frame_stats(os.path.join(out_dir, "frames.csv"), ev.get("eval_start_s", 0.0)))
    ev.update(steady_stats(out_dir, a.steady_window))
    return ev


def num(v, decimals=1, scale=1.0):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return "%.*f" % (decimals, scale * v)


HEADER = ("| texture | height (m) | width (px) | distance RMSE (cm) | velocity RMSE (cm/s) | normal error RMS (deg) | "
          "diverged | mean update (ms) | last %gs: distance / velocity / normal | residual RMS | valid ratio | "
          "skipped updates (%%) / restarts | d within 2σ (%%) | v within 2σ (%%) | NEES mean |")


def table_row(texture, height, width, ev):
    if ev.get("failed"):
        return "| %s | %.1f | %d | failed (exit %s) | | | | | | | | | | | |" % (
            texture, height, width, ev.get("exit_code"))
    return "| %s | %.1f | %d | %s | %s | %s | %s | %s | %s / %s / %s | %s | %s | %s / %s | %s | %s | %s |" % (
        texture, height, width, num(ev.get("rmse_distance_m"), 1, 100), num(ev.get("rmse_velocity_mps"), 1, 100),
        num(ev.get("rms_normal_deg"), 2), "yes" if ev.get("diverged") else "no", num(ev.get("update_ms_mean"), 2),
        num(ev.get("steady_rmse_distance_m"), 1, 100), num(ev.get("steady_rmse_velocity_mps"), 1, 100),
        num(ev.get("steady_rms_normal_deg"), 2), num(ev.get("residual_rms"), 3), num(ev.get("valid_ratio"), 2),
        num(ev.get("skipped_pct"), 1), "n/a" if ev.get("resets") is None else str(ev.get("resets")),
        num(ev.get("coverage2_d"), 1, 100), num(ev.get("coverage2_v"), 1, 100), num(ev.get("nees_mean"), 1))


def compare(a, tags):
    """Per configuration and working width: the mean over heights of each texture's distance RMSE (whole
    evaluation / last window), velocity RMSE and normal error, from TAG.json files written earlier."""
    data = {}
    for tag in tags:
        path = os.path.join(a.output, "%s.json" % tag)
        if not os.path.isfile(path):
            sys.exit("texture_sweep.py: %s not found (run the sweep with --tag %s first)" % (path, tag))
        with open(path) as f:
            data[tag] = json.load(f)["runs"]
    textures = [t for t in a.textures.split(",") if t]
    widths = [int(w) for w in a.widths.split(",") if w]
    heights = [float(h) for h in a.heights.split(",") if h]
    head = ("| configuration | width (px) | " + " | ".join(textures) +
            " | all textures: distance all / last (cm), velocity (cm/s), normal (deg), diverged"
            " | all textures: d / v within 2σ (%), NEES mean |")
    lines = ["Simulated sequences. Mean over heights %s m of distance RMSE whole evaluation / last %g s (cm), "
             "velocity RMSE (cm/s) and normal error RMS (deg); over every run: the fractions of distance and velocity "
             "errors inside the filter's 2σ (95 %% if consistent) and the NEES (4 if consistent):" % (
                 ", ".join("%g" % h for h in heights), a.steady_window), "", head,
             "|" + "---|" * (head.count("|") - 1)]

    def mean(vals):
        vals = [v for v in vals if v is not None and math.isfinite(v)]
        return sum(vals) / len(vals) if vals else None

    for tag in tags:
        for width in widths:
            cells, every = [], []
            for texture in textures:
                evs = [data[tag].get("%s_h%s_w%d" % (texture, height_label(h), width)) for h in heights]
                evs = [e for e in evs if e and not e.get("failed")]
                every += evs
                cells.append("%s / %s, %s, %s" % (
                    num(mean([e.get("rmse_distance_m") for e in evs]), 1, 100),
                    num(mean([e.get("steady_rmse_distance_m") for e in evs]), 1, 100),
                    num(mean([e.get("rmse_velocity_mps") for e in evs]), 1, 100),
                    num(mean([e.get("rms_normal_deg") for e in evs]), 2)))
            cells.append("%s / %s, %s, %s, %d" % (
                num(mean([e.get("rmse_distance_m") for e in every]), 1, 100),
                num(mean([e.get("steady_rmse_distance_m") for e in every]), 1, 100),
                num(mean([e.get("rmse_velocity_mps") for e in every]), 1, 100),
                num(mean([e.get("rms_normal_deg") for e in every]), 2), sum(1 for e in every if e.get("diverged"))))
            cells.append("%s / %s, %s" % (
                num(mean([e.get("coverage2_d") for e in every]), 1, 100),
                num(mean([e.get("coverage2_v") for e in every]), 1, 100),
                num(mean([e.get("nees_mean") for e in every]), 1)))
            lines.append("| %s | %d | %s |" % (tag, width, " | ".join(cells)))
    text = "\n".join(lines) + "\n"
    print(text)
    return text


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    pkg_dir = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    ap.add_argument("--output", default=os.path.join(pkg_dir, "results", "textures"))
    ap.add_argument("--textures", default="grass,leaves,dirt,natural")
    ap.add_argument("--heights", default="0.4,0.8,1.3", help="mean IMU heights above the ground (m)")
    ap.add_argument("--widths", default="90,180", help="working widths (px)")
    ap.add_argument("--preset", default="flight5", help="motion preset (speeds of the paper's flight 5)")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--height-amplitude", type=float, default=0.1, help="slow height changes (m)")
    ap.add_argument("--threads", type=int, default=1, help="render threads of the simulator")
    ap.add_argument("--tag", default="default", help="name of this configuration (runs/TAG, TAG.md)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="estimator parameter override passed to the runner (repeatable)")
    ap.add_argument("--steady-window", type=float, default=8.0,
                    help="also report errors over the last S seconds (after the start-up transient)")
    ap.add_argument("--compare", metavar="TAG,TAG,...",
                    help="print a summary of earlier sweeps (TAG.json) side by side and exit")
    ap.add_argument("--bags", default="bags", help="folder of the sequences under --output")
    ap.add_argument("--sim-args", default="", help="extra diekf_simulate arguments, e.g. \"--vignetting 0\" "
                    "(use another --bags folder)")
    ap.add_argument("--reuse-bags", action="store_true", help="use sequences already simulated under bags/")
    a = ap.parse_args()
    if a.compare:
        compare(a, [t for t in a.compare.split(",") if t])
        return

    bin_dir = find_bin_dir("texture_sweep.py")
    textures = [t for t in a.textures.split(",") if t]
    heights = [float(h) for h in a.heights.split(",") if h]
    widths = [int(w) for w in a.widths.split(",") if w]
    os.makedirs(a.output, exist_ok=True)
    results, rows = {}, []
    t_start = time.time()
    for texture in textures:
        for height in heights:
            seq_dir = os.path.join(a.output, a.bags, "%s_h%s" % (texture, height_label(height)))
            if not simulate(bin_dir, a, texture, height, seq_dir):
                sys.exit("texture_sweep.py: simulation failed, see %s" % os.path.join(seq_dir, "simulate.log"))
            for width in widths:
                name = "%s_h%s_w%d" % (texture, height_label(height), width)
                ev = run_estimator(bin_dir, a, seq_dir, width, name, os.path.join(a.output, "runs", a.tag, name))
                results[name] = ev
                rows.append(table_row(texture, height, width, ev))
                print("  " + rows[-1], flush=True)

    cmd = "scripts/texture_sweep.py" + (" --reuse-bags" if a.reuse_bags else "") + " --tag %s" % a.tag + "".join(
        " --set %s" % s for s in a.set) + ("" if a.bags == "bags" else " --bags %s" % a.bags) + (
        " --sim-args \"%s\"" % a.sim_args if a.sim_args else "")
    md = ["Configuration `%s`, simulated sequences: preset %s (motion only), %g s, seed %d, heights +-%g m%s, "
          "iterated filter%s. Within 2σ: fraction of distance / velocity errors inside the filter's ±2σ (95 %% if "
          "consistent); NEES: mean normalised squared error of distance and velocity (4 if consistent)." % (
        a.tag, a.preset, a.duration, a.seed, a.height_amplitude,
        ", simulator %s" % a.sim_args if a.sim_args else "",
        (", " + ", ".join("`%s`" % s for s in a.set)) if a.set else ", config/estimator.yaml defaults"),
        "", HEADER % a.steady_window, "|" + "---|" * (HEADER.count("|") - 1)] + rows + ["", "Command: `%s`" % cmd]
    text = "\n".join(md) + "\n"
    print()
    print(text)
    with open(os.path.join(a.output, "%s.md" % a.tag), "w") as f:
        f.write(text)
    with open(os.path.join(a.output, "%s.json" % a.tag), "w") as f:
        json.dump({"tag": a.tag, "set": a.set, "preset": a.preset, "duration_s": a.duration, "seed": a.seed,
                   "height_amplitude_m": a.height_amplitude, "runs": results}, f, indent=1, sort_keys=True)
    print("(%.0f s)" % (time.time() - t_start))


if __name__ == "__main__":
    main()
