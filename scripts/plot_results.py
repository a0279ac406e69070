#!/usr/bin/env python3
"""Plots of one diekf_bag_runner output folder (PNG, matplotlib Agg backend).

    plot_results.py RUN_DIR [--output DIR] [--title TEXT]

Reads RUN_DIR/estimates.csv and, when present, RUN_DIR/groundtruth.csv and RUN_DIR/evaluation.json
(docs/evaluation.md). Writes into RUN_DIR (or --output):
  distance.png      distance d and height h against truth, 2-sigma band on d (the paper's Fig. 3, top)
  velocity.png      the three velocity axes in C against truth with 2-sigma bands
  normal_gravity.png  plane normal and gravity direction components against truth
  errors.png        distance error and the three velocity-axis errors over time, each with the filter's +-2-sigma
                    band around zero (the truth is inside the band where the error is), then the normal and
                    gravity angle errors (evaluation window shaded; 2-sigma coverage and NEES in the title)
  consistency.png   NEES per frame (z_d^2 + sum z_v,i^2) against the chi-square(4) mean and 95 % interval
  update_time.png   histogram of the per-frame update time
  timing.png        with RUN_DIR/frames.csv (--frames-csv): the estimated camera-IMU time offset and rolling-shutter
                    readout time with their 2-sigma bands (docs/algorithm.md sections 3.6, 3.7); --true-offset-ms
                    and --true-readout-ms draw the truth (e.g. realism.yaml's values)
"""

import argparse
import csv
import json
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after the backend choice)
import numpy as np  # noqa: E402

EST_COLUMNS = ["t", "d", "h", "vx", "vy", "vz", "mux", "muy", "muz", "gx", "gy", "gz", "sigma_d", "sigma_vx",
               "sigma_vy", "sigma_vz", "iterations", "update_ms", "status"]
GT_COLUMNS = ["t", "d", "h", "vx", "vy", "vz", "mux", "muy", "muz", "gx", "gy", "gz"]


def read_table(path, expected):
    """CSV with a header -> dict of numpy arrays (strings for 'status')."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader, None)
        if header != expected:
            raise ValueError("%s: unexpected header %s" % (path, header))
        rows = [r for r in reader if r]
    table = {}
    for i, name in enumerate(expected):
        values = [r[i] for r in rows]
        table[name] = np.array(values) if name == "status" else np.array([float(v) for v in values])
    return table


def match_truth(est, gt, tolerance_s=1e-6):
    """Index into gt for every estimate row (or -1 when there is no true value at that stamp)."""
    idx = np.full(len(est["t"]), -1, dtype=int)
    if gt is None or len(gt["t"]) == 0:
        return idx
    pos = np.clip(np.searchsorted(gt["t"], est["t"]), 0, len(gt["t"]) - 1)
    for k, p in enumerate(pos):
        for q in (p - 1, p):
            if 0 <= q < len(gt["t"]) and abs(gt["t"][q] - est["t"][k]) <= tolerance_s:
                idx[k] = q
    return idx


def angle_deg(a, b):
    cross = np.linalg.norm(np.cross(a, b), axis=1)
    dot = np.sum(a * b, axis=1)
    return np.degrees(np.arctan2(cross, dot))


# 2.5 % and 97.5 % quantiles of the chi-square distribution with 4 degrees of freedom.
CHI2_4_95 = (0.4844, 11.1433)


def fmt(v, decimals=1):
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else "%.*f" % (decimals, v)


def pct(v):
    return "n/a" if v is None else fmt(100.0 * v) + " %"


def shade_eval_window(ax, t_eval_start, t_end):
    if t_eval_start is not None and math.isfinite(t_eval_start):
        ax.axvspan(t_eval_start, t_end, color="0.93", zorder=0, lw=0)


def save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print("wrote", path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", help="diekf_bag_runner output folder")
    parser.add_argument("--output", help="where the PNGs go (default: RUN_DIR)")
    parser.add_argument("--title", help="figure title prefix (default: the sequence name)")
    parser.add_argument("--true-offset-ms", type=float, help="true time offset on top of the camchain's, ms")
    parser.add_argument("--true-readout-ms", type=float, help="true rolling-shutter readout time, ms")
    args = parser.parse_args(argv)

    est_path = os.path.join(args.run_dir, "estimates.csv")
    if not os.path.isfile(est_path):
        print("plot_results.py: no estimates.csv in %s" % args.run_dir, file=sys.stderr)
        return 1
    try:
        est = read_table(est_path, EST_COLUMNS)
    except (ValueError, IndexError) as e:
        print("plot_results.py: %s" % e, file=sys.stderr)
        return 1
    if len(est["t"]) == 0:
        print("plot_results.py: %s has no rows" % est_path, file=sys.stderr)
        return 1
    gt_path = os.path.join(args.run_dir, "groundtruth.csv")
    gt = read_table(gt_path, GT_COLUMNS) if os.path.isfile(gt_path) else None
    ev_path = os.path.join(args.run_dir, "evaluation.json")
    evaluation = None
    if os.path.isfile(ev_path):
        with open(ev_path) as f:
            evaluation = json.load(f)
    out_dir = args.output or args.run_dir
    os.makedirs(out_dir, exist_ok=True)
    title = args.title or (evaluation or {}).get("sequence") or os.path.basename(os.path.abspath(args.run_dir))

    t0 = est["t"][0]
    t = est["t"] - t0
    t_end = t[-1]
    t_eval = None
    if evaluation and evaluation.get("eval_start_s") is not None:
        t_eval = evaluation["eval_start_s"] - t0
    idx = match_truth(est, gt)
    has = idx >= 0
    tg = t[has]

    def truth(name):
        return gt[name][idx[has]]

    # Distance and height (Fig. 3 top).
    fig, ax = plt.subplots(figsize=(9, 4))
    shade_eval_window(ax, t_eval, t_end)
    band = 2.0 * est["sigma_d"]
    ax.fill_between(t, est["d"] - band, est["d"] + band, color="tab:blue", alpha=0.2, lw=0, label="d ± 2σ")
    ax.plot(t, est["d"], color="tab:blue", lw=1.2, label="d estimate")
    ax.plot(t, est["h"], color="tab:orange", lw=0.9, ls="--", label="h estimate")
    if has.any():
        ax.plot(tg, truth("d"), color="k", lw=1.0, label="d true")
        ax.plot(tg, truth("h"), color="0.45", lw=0.8, ls=":", label="h true")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("distance (m)")
    ax.set_title("%s: distance to the plane" % title)
    finite = est["d"][np.isfinite(est["d"])]
    if finite.size:
        lo, hi = np.percentile(finite, [1, 99])
        if has.any():
            lo, hi = min(lo, truth("d").min()), max(hi, truth("d").max())
        pad = 0.15 * max(hi - lo, 0.1)
        ax.set_ylim(lo - pad, hi + pad)
    ax.legend(loc="best", fontsize=8, ncol=3)
    ax.grid(alpha=0.3)
    save(fig, os.path.join(out_dir, "distance.png"))

    # Velocity axes (Fig. 3).
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for k, axis in enumerate("xyz"):
        ax = axes[k]
        shade_eval_window(ax, t_eval, t_end)
        v = est["v" + axis]
        s = 2.0 * est["sigma_v" + axis]
        ax.fill_between(t, v - s, v + s, color="tab:blue", alpha=0.2, lw=0, label="± 2σ")
        ax.plot(t, v, color="tab:blue", lw=1.0, label="estimate")
        if has.any():
            ax.plot(tg, truth("v" + axis), color="k", lw=0.9, label="true")
        ax.set_ylabel("v%s (m/s)" % axis)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[0].set_title("%s: velocity in the camera frame" % title)
    axes[-1].set_xlabel("time (s)")
    save(fig, os.path.join(out_dir, "velocity.png"))

    # Normal and gravity directions.
    fig, axes = plt.subplots(3, 2, figsize=(11, 7), sharex=True)
    for col, (prefix, label) in enumerate((("mu", "normal μ"), ("g", "gravity g"))):
        for k, axis in enumerate("xyz"):
            ax = axes[k][col]
            shade_eval_window(ax, t_eval, t_end)
            ax.plot(t, est[prefix + axis], color="tab:blue", lw=1.0, label="estimate")
            if has.any():
                ax.plot(tg, truth(prefix + axis), color="k", lw=0.9, label="true")
            ax.set_ylabel("%s %s" % (label, axis))
            ax.grid(alpha=0.3)
        axes[0][col].set_title("%s: %s in C" % (title, label))
        axes[-1][col].set_xlabel("time (s)")
    axes[0][0].legend(loc="best", fontsize=8)
    save(fig, os.path.join(out_dir, "normal_gravity.png"))

    # Errors over time, the distance and velocity errors inside the filter's +-2-sigma band.
    if has.any():
        e = {name: est[name][has] for name in EST_COLUMNS if name != "status"}
        fig, axes = plt.subplots(6, 1, figsize=(9, 11), sharex=True)
        err_d = e["d"] - truth("d")
        err_mu = angle_deg(np.stack([e["mux"], e["muy"], e["muz"]], axis=1),
                           np.stack([truth("mux"), truth("muy"), truth("muz")], axis=1))
        err_g = angle_deg(np.stack([e["gx"], e["gy"], e["gz"]], axis=1),
                          np.stack([truth("gx"), truth("gy"), truth("gz")], axis=1))
        series = [(100.0 * err_d, "d error (cm)", 200.0 * e["sigma_d"])]
        for axis in "xyz":
            series.append((100.0 * (e["v" + axis] - truth("v" + axis)), "v%s error (cm/s)" % axis,
                           200.0 * e["sigma_v" + axis]))
        series += [(err_mu, "normal error (deg)", None), (err_g, "gravity error (deg)", None)]
        in_window = tg >= t_eval if t_eval is not None and math.isfinite(t_eval) else np.ones(tg.size, dtype=bool)
        for ax, (y, label, band) in zip(axes, series):
            shade_eval_window(ax, t_eval, t_end)
            if band is not None:
                ax.fill_between(tg, -band, band, color="tab:blue", alpha=0.2, lw=0, label="± 2σ (filter)")
            ax.plot(tg, y, color="tab:red", lw=0.9, label="error")
            ax.axhline(0.0, color="0.5", lw=0.6)
            if band is not None:
                # Same frames as the metrics: evaluation window, positive finite sigma.
                ok = in_window & np.isfinite(band) & (band > 0)
                if ok.any():
                    inside = 100.0 * np.mean(np.abs(y[ok]) <= band[ok])
                    ax.text(0.01, 0.95, "inside ±2σ: %.1f %%" % inside, transform=ax.transAxes, fontsize=8,
                            va="top", bbox=dict(facecolor="white", alpha=0.7, lw=0))
                ax.legend(loc="upper right", fontsize=8, ncol=2)
                # Scale to the error and the band over the evaluation window, not to a start-up transient.
                sel = in_window if in_window.any() else np.ones(tg.size, dtype=bool)
                vals = np.concatenate([np.abs(y[sel]), band[sel]])
                vals = vals[np.isfinite(vals)]
                if vals.size:
                    lim = 1.15 * max(np.percentile(vals, 99.5), 1e-6)
                    ax.set_ylim(-lim, lim)
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
        heading = "%s: errors (shaded: evaluation window)" % title
        if evaluation:
            def cm(key):
                v = evaluation.get(key)
                return "n/a" if v is None else "%.2f" % (100.0 * v)
            heading += "\nRMSE distance %s cm, velocity %s cm/s%s" % (
                cm("rmse_distance_m"), cm("rmse_velocity_mps"), ", DIVERGED" if evaluation.get("diverged") else "")
            if "coverage2_d" in evaluation:
                heading += "\ninside ±2σ: d %s, v %s (consistent: 95 %%); NEES mean %s (consistent: 4)" % (
                    pct(evaluation.get("coverage2_d")), pct(evaluation.get("coverage2_v")),
                    fmt(evaluation.get("nees_mean"), 2))
        axes[0].set_title(heading, fontsize=10)
        axes[-1].set_xlabel("time (s)")
        save(fig, os.path.join(out_dir, "errors.png"))

        # NEES per frame (distance and the three velocity axes: chi-square with 4 degrees of freedom if consistent).
        with np.errstate(divide="ignore", invalid="ignore"):
            sig = np.stack([e["sigma_d"], e["sigma_vx"], e["sigma_vy"], e["sigma_vz"]], axis=1)
            err = np.stack([err_d] + [e["v" + a] - truth("v" + a) for a in "xyz"], axis=1)
            usable = np.all(np.isfinite(sig) & (sig > 0), axis=1)
            nees = np.sum((err / np.where(usable[:, None], sig, 1.0)) ** 2, axis=1)
        fig, ax = plt.subplots(figsize=(9, 4))
        shade_eval_window(ax, t_eval, t_end)
        ax.axhspan(CHI2_4_95[0], CHI2_4_95[1], color="tab:green", alpha=0.15, lw=0,
                   label="χ²(4) 95 %% interval %.2f–%.2f" % CHI2_4_95)
        ax.axhline(4.0, color="tab:green", lw=1.0, label="consistent mean 4")
        ax.plot(tg[usable], nees[usable], color="tab:red", lw=0.7, label="NEES per frame")
        ax.set_yscale("log")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("NEES")
        heading = "%s: normalised estimation error squared (d, vx, vy, vz)" % title
        if evaluation and "nees_mean" in evaluation:
            heading += "\nmean %s, median %s; last half of the window: mean %s" % (
                fmt(evaluation.get("nees_mean"), 2), fmt(evaluation.get("nees_median"), 2),
                fmt(evaluation.get("nees_mean_last_half"), 2))
        ax.set_title(heading, fontsize=10)
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3, which="both")
        save(fig, os.path.join(out_dir, "consistency.png"))

    # Update time histogram.
    updated = est["iterations"] > 0
    ms = est["update_ms"][updated & np.isfinite(est["update_ms"])]
    fig, ax = plt.subplots(figsize=(7, 4))
    if ms.size:
        ax.hist(ms, bins=min(60, max(10, ms.size // 20)), color="tab:blue", alpha=0.8)
        ax.axvline(np.mean(ms), color="k", lw=1.0, label="mean %.3f ms" % np.mean(ms))
        ax.axvline(np.percentile(ms, 99), color="tab:red", lw=1.0, ls="--",
                   label="99th pct. %.3f ms" % np.percentile(ms, 99))
        ax.legend(fontsize=8)
    ax.set_xlabel("update time per frame (ms)")
    ax.set_ylabel("frames")
    ax.set_title("%s: image update time (%d frames)" % (title, ms.size))
    ax.grid(alpha=0.3)
    save(fig, os.path.join(out_dir, "update_time.png"))
    plot_timing(args, title, t0, out_dir)
    return 0


def plot_timing(args, title, t0, out_dir):
    """timing.png from frames.csv: the estimated time offset and readout with their 2-sigma bands."""
    path = os.path.join(args.run_dir, "frames.csv")
    if not os.path.isfile(path):
        return
    with open(path) as f:
        rows = list(csv.DictReader(f))
    keys = ["time_offset_ms", "sigma_time_offset_ms", "readout_ms", "sigma_readout_ms"]
    if not rows or any(k not in rows[0] for k in keys):
        return
    t = np.array([float(r["t"]) for r in rows]) - t0
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for ax, (key, sigma_key, truth, label) in zip(axes, [
            ("time_offset_ms", "sigma_time_offset_ms", args.true_offset_ms, "time offset (ms)"),
            ("readout_ms", "sigma_readout_ms", args.true_readout_ms, "readout time (ms)")]):
        v = np.array([float(r[key]) for r in rows])
        s = np.array([float(r[sigma_key]) for r in rows])
        ax.fill_between(t, v - 2 * s, v + 2 * s, color="tab:blue", alpha=0.2, lw=0, label="±2σ")
        ax.plot(t, v, color="tab:blue", lw=1.0, label="estimate")
        if truth is not None:
            ax.axhline(truth, color="k", lw=1.0, ls="--", label="truth %g ms" % truth)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[0].set_title("%s: image timing estimated by the filter" % title)
    axes[1].set_xlabel("time (s)")
    save(fig, os.path.join(out_dir, "timing.png"))


if __name__ == "__main__":
    sys.exit(main())
