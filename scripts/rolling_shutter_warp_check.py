#!/usr/bin/env python3
"""Checks the photometric warp's rolling-shutter rows against exact correspondences (docs/algorithm.md section 3.7).

For every image pair of a simulated sequence in a time window, each working pixel p of the current image is taken
at its own raw row's time, intersected with the ground-truth plane at the ground-truth pose of that time, and found
in the reference image at the raw row whose time sees it there (solved by iteration): the exact rolling-shutter
correspondence. The warp's rolling-shutter approximations are then evaluated with the *true* motion (homographies
from the ground-truth poses, not the filter's state), so that only the approximations differ:

  before   the pair shifted by the pixel's time to first order (H + tau Hm), the reference pixel's time from the
           raw row's gradient, the flow scaled by the lengthened interval (the mean flow; until session 52)
  now      the same shift, the reference pixel's time to second order in the raw row (gradient and Hessian), the
           reference pixel moved by the flow's rate at the reference image's end (Hx), solved for its own effect
  partial variants: each of the two changes alone

Per variant it prints the RMS pixel error against the exact correspondence (working pixels) and the state error a
least-squares fit of the error field gives: the velocity over distance along the camera's x, y, z in % of the
speed, and the plane normal about the camera's x and y axes in mrad (RMS over the frames, then the mean).

Usage: rolling_shutter_warp_check.py SEQUENCE_DIR [--from 12] [--to 16] [--width 180] [--step 3] [--json FILE]
SEQUENCE_DIR holds sequence.bag (ground truth /mocap/pose, /ground_truth/plane, the image stamps), camchain.yaml
(Kalibr, radtan or no distortion) and realism.yaml (rolling_shutter_line_time_s), as diekf_simulate writes them.
"""
import argparse
import json
import os
import sys

import numpy as np
import yaml

try:
    import rosbag
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import Rotation, RotationSpline
except ImportError as e:  # pragma: no cover
    sys.exit('rolling_shutter_warp_check.py needs rosbag and scipy: %s' % e)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('sequence')
    ap.add_argument('--from', dest='t_from', type=float, default=12.0, help='window start, s from the first pose')
    ap.add_argument('--to', dest='t_to', type=float, default=16.0, help='window end, s')
    ap.add_argument('--width', type=int, default=180, help='working width, px')
    ap.add_argument('--step', type=int, default=3, help='every step-th working pixel in x and y')
    ap.add_argument('--image-topic', default='/mynteye/left/image_raw')
    ap.add_argument('--json', help='also write the table to this file (per variant: px_rms, bias_rms, bias_mean)')
    a = ap.parse_args()

    cc = yaml.safe_load(open(os.path.join(a.sequence, 'camchain.yaml')))['cam0']
    fx, fy, cx, cy = cc['intrinsics']
    k1, k2, p1, p2 = (list(cc.get('distortion_coeffs') or []) + [0.0] * 4)[:4]
    if cc.get('distortion_model', 'radtan') not in ('radtan', None):
        sys.exit('only radtan distortion (or none) is supported, got %s' % cc.get('distortion_model'))
    Wr, Hr = cc['resolution']
    T = np.array(cc['T_cam_imu'])
    R_IC = T[:3, :3].T
    r_I = -R_IC @ T[:3, 3]
    realism = yaml.safe_load(open(os.path.join(a.sequence, 'realism.yaml')))
    line_s = float(realism.get('rolling_shutter_line_time_s') or 0.0)
    if line_s <= 0.0:
        sys.exit('realism.yaml has no rolling_shutter_line_time_s: a global-shutter sequence')
    v_mid = 0.5 * (Hr - 1)

    ts, P, Q, img_t, plane = [], [], [], [], None
    for topic, m, _ in rosbag.Bag(os.path.join(a.sequence, 'sequence.bag')).read_messages(
            ['/mocap/pose', a.image_topic, '/ground_truth/plane']):
        if topic == '/mocap/pose':
            ts.append(m.header.stamp.to_sec())
            P.append([m.pose.position.x, m.pose.position.y, m.pose.position.z])
            o = m.pose.orientation
            Q.append([o.x, o.y, o.z, o.w])
        elif topic == '/ground_truth/plane':
            plane = np.array(m.coef)
        else:
            img_t.append(m.header.stamp.to_sec())
    if plane is None:
        plane = np.array([0.0, 0.0, 1.0, 0.0])
    ts = np.array(ts)
    t0 = ts[0]
    ts -= t0
    img_t = np.array(img_t) - t0
    pos = CubicSpline(ts, np.array(P))
    rot = RotationSpline(ts, Rotation.from_quat(np.array(Q)))
    nW, eW = plane[:3], plane[3]

    def poses(t):  # camera poses (N, 3, 3), (N, 3) at the times t (s from the first pose)
        R_WI = rot(t).as_matrix()
        return R_WI @ R_IC, pos(t) + np.einsum('nij,j->ni', R_WI, r_I)

    def pose(t):
        R, p = poses(np.array([t]))
        return R[0], p[0]

    def raw_row(x, y):  # raw (distorted) row of the normalised undistorted point (x, y)
        r2 = x * x + y * y
        return fy * (y * (1 + k1 * r2 + k2 * r2 * r2) + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y) + cy

    s = a.width / Wr
    fxw, fyw, cxw, cyw = fx * s, fy * s, (cx + 0.5) * s - 0.5, (cy + 0.5) * s - 0.5
    Hw = int(round(Hr * s))
    uu, vv = np.meshgrid(np.arange(2, a.width - 2, a.step), np.arange(2, Hw - 2, a.step))
    xq, yq = ((uu - cxw) / fxw).ravel(), ((vv - cyw) / fyw).ravel()
    vr = raw_row(xq, yq)
    inside = (vr > 0) & (vr < Hr - 1)
    xq, yq, vr = xq[inside], yq[inside], vr[inside]
    q = np.stack([xq, yq, np.ones_like(xq)])
    pw = np.stack([xq * fxw + cxw, yq * fyw + cyw])
    tau_p = line_s * (vr - v_mid)
    # The raw row's derivatives over working pixels (the estimator's readoutPixelWeights, times rows - 1).
    def rr(du, dv):
        return raw_row(xq + du / fxw, yq + dv / fyw)
    h = 0.5
    gx, gy = (rr(h, 0) - rr(-h, 0)) / (2 * h), (rr(0, h) - rr(0, -h)) / (2 * h)
    gxx = (rr(h, 0) - 2 * vr + rr(-h, 0)) / h ** 2
    gyy = (rr(0, h) - 2 * vr + rr(0, -h)) / h ** 2
    gxy = (rr(h, h) - rr(h, -h) - rr(-h, h) + rr(-h, -h)) / (4 * h * h)

    def homography(ta, tb):  # current (tb) -> reference (ta), for the plane
        Ra, pa = pose(ta)
        Rb, pb = pose(tb)
        return Ra.T @ Rb - np.outer(Ra.T @ (pb - pa), Rb.T @ nW) / (nW @ pb + eW)

    def project(Qv):
        return np.stack([Qv[0] / Qv[2] * fxw + cxw, Qv[1] / Qv[2] * fyw + cyw])

    def exact(ta, tb):
        R1, c1 = poses(tb + tau_p)
        ray = np.einsum('nij,jn->ni', R1, q)
        X = c1 + (-(c1 @ nW + eW) / (ray @ nW))[:, None] * ray
        tau_r = tau_p.copy()
        for _ in range(6):
            R0, c0 = poses(ta + tau_r)
            Xc = np.einsum('nji,nj->ni', R0, X - c0)
            xr, yr = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
            tau_r = line_s * (raw_row(xr, yr) - v_mid)
        return np.stack([xr * fxw + cxw, yr * fyw + cyw])

    def state_basis(ta, tb):
        # d p_r / d(v/d along x, y, z in % of the speed; normal about x, y in mrad), global-shutter pair
        Ra, pa = pose(ta)
        Rb, pb = pose(tb)
        nC, d = Rb.T @ nW, nW @ pb + eW
        E = Ra.T @ Rb

        def warp(pa_, n_):
            return project((E - np.outer(Ra.T @ (pb - pa_), n_) / d) @ q)
        base = warp(pa, nC)
        speed = np.linalg.norm(pb - pa) / (tb - ta)
        cols = []
        for k in range(3):
            dv = np.zeros(3)
            dv[k] = 0.01 * speed
            cols.append((warp(pa - Rb @ dv * (tb - ta), nC) - base).ravel())
        for k in range(2):
            ax = np.zeros(3)
            ax[k] = 1e-3
            cols.append((warp(pa, Rotation.from_rotvec(ax).as_matrix() @ nC) - base).ravel())
        return np.array(cols).T

    frames = [k for k in range(1, len(img_t)) if a.t_from <= img_t[k] <= a.t_to]
    print('%s: line delay %.4g s, %d working pixels, %d pairs from %.1f to %.1f s' %
          (a.sequence, line_s, q.shape[1], len(frames), a.t_from, a.t_to))
    stats = {}
    for k in frames:
        ta, tb = img_t[k - 1], img_t[k]
        dt = tb - ta
        truth = exact(ta, tb)
        hs = 1e-4
        H0 = homography(ta, tb)
        Hm = (homography(ta + hs, tb + hs) - homography(ta - hs, tb - hs)) / (2 * hs)
        Hx = (homography(ta - hs, tb) - homography(ta + hs, tb)) / (2 * hs)
        Q0 = H0 @ q + tau_p * (Hm @ q)
        F = project(Q0)
        D = F - pw

        def delta_w(hessian):  # raw rows from p to the reference pixel (first warp), second order or first
            dw = gx * D[0] + gy * D[1]
            if hessian:
                dw = dw + 0.5 * (gxx * D[0] ** 2 + 2 * gxy * D[0] * D[1] + gyy * D[1] ** 2)
            return dw

        def mean_flow(hessian):
            return pw + D * (1 - line_s * delta_w(hessian) / dt)

        def reference_rate(hessian):
            U = Hx @ q
            u = np.stack([(fxw * U[0] - (F[0] - cxw) * U[2]) / Q0[2], (fyw * U[1] - (F[1] - cyw) * U[2]) / Q0[2]])
            g1x = gx + (gxx * D[0] + gxy * D[1] if hessian else 0)
            g1y = gy + (gxy * D[0] + gyy * D[1] if hessian else 0)
            delta = -line_s * delta_w(hessian) / (1 + line_s * (g1x * u[0] + g1y * u[1]))
            return F + delta * u

        variants = {'before': mean_flow(False), 'mean_flow_second_order': mean_flow(True),
                    'rate_gradient': reference_rate(False), 'now': reference_rate(True),
                    'global_shutter': project(H0 @ q)}
        B = state_basis(ta, tb)
        for name, p_r in variants.items():
            e = (p_r - truth).ravel()
            c = np.linalg.lstsq(B, -e, rcond=None)[0]
            stats.setdefault(name, []).append(np.r_[np.sqrt(np.mean(e ** 2)), c])
    if not stats:
        sys.exit('no image pair between %.1f and %.1f s' % (a.t_from, a.t_to))
    labels = {'before': 'before (mean flow, gradient)', 'mean_flow_second_order': 'mean flow, second order',
              'rate_gradient': 'rate at the reference, gradient', 'now': 'now (rate, second order)',
              'global_shutter': 'global-shutter warp'}
    print('%-34s %9s | %-26s | %-16s' % ('variant', 'px RMS', 'v/d bias x y z, % (RMS)', 'normal x y, mrad'))
    table = {}
    for name, rows in stats.items():
        r = np.array(rows)
        rms, mean = np.sqrt(np.mean(r ** 2, 0)), np.mean(r, 0)
        table[name] = {'px_rms': float(rms[0]), 'bias_rms': [float(x) for x in rms[1:]],
                       'bias_mean': [float(x) for x in mean[1:]]}
        print('%-34s %9.4f | %7.3f %7.3f %7.3f    | %6.2f %6.2f  (mean %+.2f %+.2f)' %
              (labels[name], rms[0], rms[1], rms[2], rms[3], rms[4], rms[5], mean[4], mean[5]))
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'pairs': len(frames), 'pixels': int(q.shape[1]), 'variants': table}, f, indent=1)


if __name__ == '__main__':
    main()
