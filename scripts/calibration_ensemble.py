#!/usr/bin/env python3
"""Consistency of the reported uncertainty over the calibration's own prior (docs/evaluation.md, "Calibration
ensemble").

One flight has one calibration error. Its coverage and NEES therefore say little about an uncertainty that is
mostly the calibration's: a focal length 1.5 % off against a prior of 2 % gives every frame the same error of 0.75
of its sigma (coverage 100 %, NEES below 1), one 4 % off gives 2 sigma on every frame. What the filter promises is
that over the calibrations its prior allows, the truth lies within 2 sigma on 95 % of the frames.

This script checks that promise. For each sequence and draw it takes the true calibration, turns it into one the
prior allows, and runs diekf_bag_runner with it:
- focal lengths times (1 + e), e ~ N(0, sigma_focal^2), both axes alike (init/sigma_focal_scale);
- the camera-IMU rotation turned by a small rotation, N(0, sigma_rotation^2) per axis of the camera frame
  (init/sigma_camera_rotation_rad; the lever arm turned with it).
The same two sigmas are passed to the runner, so the draws and the filter's prior agree (a sigma of 0 draws
nothing and leaves the runner's prior as configured). The true calibration is the simulator's (realism.yaml:
true_intrinsics, true_T_cam_imu); without realism.yaml the sequence's camchain is taken as true. Everything else (distortion, time shift, the image effects of a realistic render) is kept as
written, so a realistic render keeps its time offset, rolling shutter, blur and exposure steps.

Which calibration error matters (--restore): the draws are then made around the camchain as written with only the
listed parts of the true calibration restored (focal_lengths, principal_point, rotation: the camera-IMU transform;
or none). With --draws 1 --sigma-focal 0 --sigma-rotation-deg 0 each run is the runner on that camchain: e.g. a
realistic render with its principal point restored (docs/results.md "What the focal-length state needs: the
principal point").

Printed and written under --output: per run the draw, d / v RMSE, d and v within 2 sigma, NEES (each run's folder
also holds the runner's files, frames.csv included); pooled over the runs (weighted by their evaluated frames) the
fractions within 2 sigma (0.95 if consistent) and the mean NEES of (d, v) (4 if consistent; lower when the
uncertainty is wider than the errors in some direction). Also per sequence the same pooled over its draws.

    calibration_ensemble.py --sequences SEQ_DIR [SEQ_DIR ...] [--draws 4] [--seed 1] [--output results/ensemble]
                            [--tag NAME] [--sigma-focal 0.02] [--sigma-rotation-deg 0.5] [--threads 2]
                            [--restore PARTS] [--set KEY=VALUE ...] [--runner-args "..."]
"""

import argparse
import json
import math
import os
import sys
import zlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import yaml

from diekf_tools import find_bin_dir, run


def rotation_matrix(rotvec):
    """Rodrigues: the rotation by the vector `rotvec` (rad)."""
    a = float(np.linalg.norm(rotvec))
    if a == 0.0:
        return np.eye(3)
    k = np.asarray(rotvec, float) / a
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * K @ K


def true_calibration(seq_dir):
    """(camchain dict as written, true intrinsics, true T_cam_imu) of a sequence folder."""
    with open(os.path.join(seq_dir, "camchain.yaml")) as f:
        chain = yaml.safe_load(f)
    if not isinstance(chain, dict) or "cam0" not in chain:
        sys.exit("calibration_ensemble.py: %s/camchain.yaml has no cam0" % seq_dir)
    cam = chain["cam0"]
    intrinsics = [float(v) for v in cam["intrinsics"]]
    T = np.array(cam["T_cam_imu"], float)
    realism = os.path.join(seq_dir, "realism.yaml")
    if os.path.isfile(realism):
        with open(realism) as f:
            r = yaml.safe_load(f)
        intrinsics = [float(v) for v in r.get("true_intrinsics", intrinsics)]
        T = np.array(r.get("true_T_cam_imu", T.tolist()), float)
    return chain, intrinsics, T


RESTORABLE = ("focal_lengths", "principal_point", "rotation")


def restored_calibration(seq_dir, parts):
    """(camchain dict as written, intrinsics, T_cam_imu): the camchain as written with `parts` (a subset of
    RESTORABLE) taken from the true calibration in realism.yaml."""
    chain, true_intrinsics, true_T = true_calibration(seq_dir)
    if parts and not os.path.isfile(os.path.join(seq_dir, "realism.yaml")):
        sys.exit("calibration_ensemble.py: --restore needs %s/realism.yaml (the true calibration)" % seq_dir)
    cam = chain["cam0"]
    intrinsics = [float(v) for v in cam["intrinsics"]]
    T = np.array(cam["T_cam_imu"], float)
    if "focal_lengths" in parts:
        intrinsics[0:2] = true_intrinsics[0:2]
    if "principal_point" in parts:
        intrinsics[2:4] = true_intrinsics[2:4]
    if "rotation" in parts:
        T = true_T
    return chain, intrinsics, T


def draw_calibration(seq_dir, rng, sigma_focal, sigma_rotation_rad, restore=None):
    """A camchain (dict) with the true calibration (or the one written with the parts `restore` restored) turned by
    one draw from the prior, and the draw."""
    if restore is None:
        chain, intrinsics, T = true_calibration(seq_dir)
    else:
        chain, intrinsics, T = restored_calibration(seq_dir, restore)
    e = float(rng.normal(0.0, sigma_focal))
    theta = rng.normal(0.0, sigma_rotation_rad, 3)
    fx, fy, cx, cy = intrinsics[:4]
    cam = chain["cam0"]
    cam["intrinsics"] = [fx * (1.0 + e), fy * (1.0 + e), cx, cy]
    R = rotation_matrix(theta)
    T = T.copy()
    T[:3, :3] = R @ T[:3, :3]  # R_CI_written = R(theta) R_CI_true: the camera frame turned by theta
    T[:3, 3] = R @ T[:3, 3]
    cam["T_cam_imu"] = T.tolist()
    draw = {"focal_error": e, "rotation_deg": [math.degrees(t) for t in theta]}
    if restore is not None:
        draw["restored"] = list(restore)
    return chain, draw


def pooled(evals):
    """Frame-weighted fractions within 2 sigma and mean NEES over evaluation dicts."""
    n = sum(e.get("consistency_frames", e.get("frames", 0)) for e in evals)
    if n == 0:
        return {"frames": 0}
    w = lambda e: e.get("consistency_frames", e.get("frames", 0))
    return {
        "runs": len(evals),
        "frames": n,
        "coverage2_d": sum(w(e) * e["coverage2_d"] for e in evals) / n,
        "coverage2_v": sum(w(e) * e["coverage2_v"] for e in evals) / n,
        "nees_mean": sum(w(e) * e["nees_mean"] for e in evals) / n,
        "rmse_distance_m": math.sqrt(sum(w(e) * e["rmse_distance_m"] ** 2 for e in evals) / n),
        "rmse_velocity_mps": math.sqrt(sum(w(e) * e["rmse_velocity_mps"] ** 2 for e in evals) / n),
    }


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequences", nargs="+", required=True, help="sequence folders (sequence.bag, camchain.yaml, imu.yaml)")
    p.add_argument("--draws", type=int, default=4, help="calibrations drawn per sequence [4]")
    p.add_argument("--seed", type=int, default=1, help="random seed of the draws [1]")
    p.add_argument("--output", default="results/ensemble", help="output folder [results/ensemble]")
    p.add_argument("--tag", default="default", help="name of this setting's runs [default]")
    p.add_argument("--sigma-focal", type=float, default=0.02,
                   help="relative 1-sigma of the focal lengths, also init/sigma_focal_scale [0.02]")
    p.add_argument("--sigma-rotation-deg", type=float, default=0.5,
                   help="1-sigma per axis of the camera-IMU rotation, deg, also init/sigma_camera_rotation_rad [0.5]")
    p.add_argument("--restore", default=None, metavar="PARTS",
                   help="draw around the camchain as written with these parts of the true calibration restored, "
                        "comma-separated: focal_lengths, principal_point, rotation, or none [the true calibration]")
    p.add_argument("--threads", type=int, default=2, help="runs at once [2]")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="runner parameter (repeatable)")
    p.add_argument("--runner-args", default="", help="extra diekf_bag_runner arguments, e.g. --runner-args='--width 90'")
    a = p.parse_args()
    if a.draws < 1 or not (a.sigma_focal >= 0.0) or not (a.sigma_rotation_deg >= 0.0):
        sys.exit("calibration_ensemble.py: --draws must be >= 1 and the sigmas >= 0")
    restore = None
    if a.restore is not None:
        restore = [] if a.restore.strip() == "none" else [s.strip() for s in a.restore.split(",") if s.strip()]
        unknown = [s for s in restore if s not in RESTORABLE]
        if unknown or not (restore or a.restore.strip() == "none"):
            sys.exit("calibration_ensemble.py: --restore %r: expected none or a comma-separated list of %s" % (
                a.restore, ", ".join(RESTORABLE)))
    bin_dir = find_bin_dir("calibration_ensemble.py", tools=("diekf_bag_runner",))
    sigma_rot = math.radians(a.sigma_rotation_deg)
    out_root = os.path.join(a.output, a.tag)
    os.makedirs(out_root, exist_ok=True)

    jobs = []
    for seq in a.sequences:
        seq = seq.rstrip("/")
        name = os.path.basename(seq)
        for k in range(a.draws):
            # One generator per (sequence, draw): the same draws whatever the order, the threads or the other sequences.
            rng = np.random.default_rng([a.seed, zlib.crc32(name.encode()), k])
            chain, draw = draw_calibration(seq, rng, a.sigma_focal, sigma_rot, restore)
            run_dir = os.path.join(out_root, "%s_d%d" % (name, k))
            os.makedirs(run_dir, exist_ok=True)
            with open(os.path.join(run_dir, "camchain.yaml"), "w") as f:
                yaml.safe_dump(chain, f, default_flow_style=None)
            with open(os.path.join(run_dir, "draw.json"), "w") as f:
                json.dump(draw, f, indent=1)
            cmd = [os.path.join(bin_dir, "diekf_bag_runner"), "--bag", os.path.join(seq, "sequence.bag"),
                   "--camchain", os.path.join(run_dir, "camchain.yaml"), "--output", run_dir, "--frames-csv"]
            if os.path.isfile(os.path.join(seq, "imu.yaml")):
                cmd += ["--imu", os.path.join(seq, "imu.yaml")]
            if a.sigma_focal > 0.0:
                cmd += ["--set", "init/sigma_focal_scale=%.17g" % a.sigma_focal]
            if sigma_rot > 0.0:
                cmd += ["--set", "init/sigma_camera_rotation_rad=%.17g" % sigma_rot]
            for kv in a.set:
                cmd += ["--set", kv]
            cmd += a.runner_args.split()
            jobs.append((name, k, run_dir, draw, cmd))

    def work(job):
        name, k, run_dir, draw, cmd = job
        rc = run(cmd, os.path.join(run_dir, "runner.log"))
        path = os.path.join(run_dir, "evaluation.json")
        if rc != 0 or not os.path.isfile(path):
            return job, None
        with open(path) as f:
            return job, json.load(f)

    with ThreadPoolExecutor(max_workers=max(1, a.threads)) as pool:
        results = list(pool.map(work, jobs))

    lines = ["| run | focal error | rotation (deg) | d / v RMSE (cm, cm/s) | d within 2σ | v within 2σ | NEES |",
             "|---|---|---|---|---|---|---|"]
    per_seq, all_evals, failed, table = {}, [], [], {}
    for (name, k, run_dir, draw, cmd), e in results:
        label = "%s_d%d" % (name, k)
        if e is None:
            failed.append(label)
            lines.append("| %s | %+.2f %% | | FAILED (see %s/runner.log) | | | |" % (label, 100 * draw["focal_error"], run_dir))
            continue
        table[label] = {"draw": draw, "evaluation": e}
        keys = ("rmse_distance_m", "rmse_velocity_mps", "coverage2_d", "coverage2_v", "nees_mean")
        if any(not isinstance(e.get(k), (int, float)) for k in keys):
            # Too short to evaluate (no frame after the start-up): listed, not pooled.
            lines.append("| %s | %+.2f %% | %s | no evaluated frames | | | |" % (
                label, 100 * draw["focal_error"], ", ".join("%+.2f" % t for t in draw["rotation_deg"])))
            continue
        per_seq.setdefault(name, []).append(e)
        all_evals.append(e)
        lines.append("| %s | %+.2f %% | %s | %.2f / %.2f | %.1f %% | %.1f %% | %.2f |" % (
            label, 100 * draw["focal_error"], ", ".join("%+.2f" % t for t in draw["rotation_deg"]),
            100 * e["rmse_distance_m"], 100 * e["rmse_velocity_mps"], 100 * e["coverage2_d"],
            100 * e["coverage2_v"], e["nees_mean"]))
    lines += ["", "| pooled | runs | d / v RMSE (cm, cm/s) | d within 2σ | v within 2σ | NEES |", "|---|---|---|---|---|---|"]
    summary = {name: pooled(ev) for name, ev in per_seq.items()}
    summary["all"] = pooled(all_evals)
    for name, s in summary.items():
        if s.get("frames", 0) == 0:
            continue
        lines.append("| %s | %d | %.2f / %.2f | %.1f %% | %.1f %% | %.2f |" % (
            name, s["runs"], 100 * s["rmse_distance_m"], 100 * s["rmse_velocity_mps"], 100 * s["coverage2_d"],
            100 * s["coverage2_v"], s["nees_mean"]))
    text = "\n".join(lines) + "\n"
    print(text)
    with open(os.path.join(a.output, a.tag + ".md"), "w") as f:
        base = "" if restore is None else ", around the camchain as written with %s restored" % (
            ", ".join(restore) if restore else "nothing")
        f.write("Calibration ensemble, sigma_focal %g, sigma_rotation %g deg, %d draws, seed %d%s\n\n" % (
            a.sigma_focal, a.sigma_rotation_deg, a.draws, a.seed, base) + text)
    with open(os.path.join(a.output, a.tag + ".json"), "w") as f:
        json.dump({"runs": table, "pooled": summary, "failed": failed}, f, indent=1)
    if failed:
        sys.exit("calibration_ensemble.py: %d run(s) failed: %s" % (len(failed), ", ".join(failed)))


if __name__ == "__main__":
    main()
