#!/usr/bin/env python3
"""Compares the states.csv of two diekf_replay runs of the same sequence (e.g. the x86-64 build and an ARM build
under qemu): the largest differences of distance, height, velocity, plane normal, gravity direction and biases,
the frames whose status or number of passes differ, and a verdict against tolerances.

    compare_states.py REFERENCE/states.csv OTHER/states.csv [--label L] [--json OUT.json]
                      [--tol-d-m 0.001] [--tol-v-mps 0.001] [--tol-angle-deg 0.01] [--tol-t-s 1e-4]
                      [--window-start-s 3]

The tolerances apply from --window-start-s after the first frame with an applied update (the evaluation window
of docs/conventions.md section 5): before that the filter is converging from its prior, the plane normal is not
yet observed (1-sigma of tens of degrees) and rounding differences move it by up to a few tenths of a degree.
The differences over the whole flight are reported too; there only the status must agree and every value be
finite. Exit status 0 when both files have the same frames (times within 1 ms) and the differences are within the
tolerances, 1 otherwise, 2 on unreadable input."""

import argparse
import csv
import json
import math
import sys


# Frames are the same image when their times agree to this, s: far below the frame spacing (tens of ms), far above
# the builds' floating-point difference of the estimated time offset (a few us over a 10 s flight); the offset's
# own difference is reported as t_s and judged with --tol-t-s.
kStampToleranceS = 1e-3


# The compared quantities, in the order they are reported (frame_diffs' keys).
kKeys = ("d_m", "h_m", "v_mps", "mu_deg", "g_deg", "ba_mps2", "bw_radps", "t_s")


def read_states(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError("%s: no rows" % path)
    return rows


def vec(row, prefix):
    return [float(row[prefix + "_" + c]) for c in "xyz"]


def angle_deg(a, b):
    """Angle between two directions, accurate for tiny angles (unlike acos of the dot product)."""
    na = math.sqrt(sum(x * x for x in a))
    nb = math.sqrt(sum(x * x for x in b))
    chord = math.sqrt(sum((x / na - y / nb) ** 2 for x, y in zip(a, b)))
    return math.degrees(2.0 * math.asin(min(1.0, chord / 2.0)))


def frame_diffs(a, b):
    return {
        "d_m": abs(float(a["d"]) - float(b["d"])),
        "h_m": abs(float(a["h"]) - float(b["h"])),
        "v_mps": math.sqrt(sum((float(a[k]) - float(b[k])) ** 2 for k in ("vx", "vy", "vz"))),
        "mu_deg": angle_deg(vec(a, "mu"), vec(b, "mu")),
        "g_deg": angle_deg(vec(a, "g"), vec(b, "g")),
        "ba_mps2": math.sqrt(sum((x - y) ** 2 for x, y in zip(vec(a, "ba"), vec(b, "ba")))),
        "bw_radps": math.sqrt(sum((x - y) ** 2 for x, y in zip(vec(a, "bw"), vec(b, "bw")))),
        "t_s": abs(float(a["t"]) - float(b["t"])),
    }


def summarise(pairs, t0):
    """Largest and RMS difference per quantity over (reference row, other row) pairs; time of the largest."""
    keys = kKeys
    worst = dict((k, 0.0) for k in keys)
    at = dict((k, None) for k in keys)
    sq = dict((k, 0.0) for k in keys)
    for a, b in pairs:
        for k, v in frame_diffs(a, b).items():
            if not math.isfinite(v):
                v = math.inf
            sq[k] += v * v
            if at[k] is None or v > worst[k]:
                worst[k], at[k] = v, float(a["t"]) - t0
    n = max(1, len(pairs))
    return {"frames": len(pairs), "max": worst, "rms": dict((k, math.sqrt(v / n)) for k, v in sq.items()),
            "max_at_s": at}


def compare(ref, other, window_start_s):
    if len(ref) != len(other):
        return {"error": "different number of frames: %d vs %d" % (len(ref), len(other))}
    # The same images in the same order. A frame's time is its stamp on the IMU clock plus the estimated camera-IMU
    # offset (docs/algorithm.md section 3.6), a state, so the builds' times differ by floating point once the offset
    # is estimated: they must agree to kStampToleranceS, not bit for bit; the difference is judged as t_s.
    for a, b in zip(ref, other):
        if not abs(float(a["t"]) - float(b["t"])) <= kStampToleranceS:
            return {"error": "frame times differ: %s vs %s" % (a["t"], b["t"])}
    t0 = float(ref[0]["t"])
    applied = [float(a["t"]) for a in ref if a["applied"] == "1"]
    start = (applied[0] if applied else t0) + window_start_s
    pairs = list(zip(ref, other))
    return {
        "all": summarise(pairs, t0),
        "window": summarise([(a, b) for a, b in pairs if float(a["t"]) >= start], t0),
        "window_start_s": start - t0,
        "status_differs": sum(a["status"] != b["status"] for a, b in pairs),
        "passes_differ": sum(a["passes"] != b["passes"] for a, b in pairs),
        "bit_identical": all(a == b for a, b in pairs),
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("reference")
    p.add_argument("other")
    p.add_argument("--label", default="")
    p.add_argument("--json", help="write the result as JSON")
    p.add_argument("--tol-d-m", type=float, default=1e-3, help="distance and height, m")
    p.add_argument("--tol-v-mps", type=float, default=1e-3, help="velocity, m/s")
    p.add_argument("--tol-angle-deg", type=float, default=0.01, help="normal and gravity direction, deg")
    p.add_argument("--tol-t-s", type=float, default=1e-4,
                   help="frame time (stamp plus the estimated camera-IMU offset, whose 1-sigma is about 0.5 ms), s")
    p.add_argument("--window-start-s", type=float, default=3.0,
                   help="tolerances apply from this long after the first applied update, s")
    a = p.parse_args()
    try:
        r = compare(read_states(a.reference), read_states(a.other), a.window_start_s)
    except (OSError, ValueError, KeyError) as e:
        print("compare_states: %s" % e, file=sys.stderr)
        return 2
    r["label"] = a.label
    r["tolerance"] = {"d_m": a.tol_d_m, "v_mps": a.tol_v_mps, "angle_deg": a.tol_angle_deg, "t_s": a.tol_t_s}
    if "error" in r:
        r["ok"] = False
        print("%s: %s" % (a.label, r["error"]))
    else:
        w, f = r["window"]["max"], r["all"]["max"]
        r["ok"] = (r["window"]["frames"] > 0 and w["d_m"] <= a.tol_d_m and w["h_m"] <= a.tol_d_m
                   and w["v_mps"] <= a.tol_v_mps and w["mu_deg"] <= a.tol_angle_deg
                   and w["g_deg"] <= a.tol_angle_deg and w["t_s"] <= a.tol_t_s and r["status_differs"] == 0
                   and all(math.isfinite(v) for v in f.values()))
        fmt = ("distance %.1e m, height %.1e m, velocity %.1e m/s, normal %.1e deg, gravity %.1e deg, "
               "b_a %.1e m/s^2, b_w %.1e rad/s, frame time %.1e s")
        print("%s: %d frames%s; max |difference| from %.1f s (%d frames): %s; whole flight: %s; passes differ on %d, "
              "status on %d frames: %s"
              % (a.label, r["all"]["frames"], " (bit-identical)" if r["bit_identical"] else "", r["window_start_s"],
                 r["window"]["frames"],
                 fmt % tuple(w[k] for k in kKeys),
                 fmt % tuple(f[k] for k in kKeys),
                 r["passes_differ"], r["status_differs"],
                 "within tolerance" if r["ok"] else "OUTSIDE tolerance (%g m, %g m/s, %g deg, %g s)"
                 % (a.tol_d_m, a.tol_v_mps, a.tol_angle_deg, a.tol_t_s)))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(r, f, indent=1)
    return 0 if r["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
