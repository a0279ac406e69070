#!/usr/bin/env python3
"""Small stand-alone sequence generator for the rostests, used only when diekf_simulate is not built.

A downward camera (pinhole, no distortion, MYNT EYE S size) on a body starting at rest and moving smoothly 0.75-0.95 m above a level,
band-pass-noise-textured plane (rendered in 2x2 pixel blocks); IMU at 500 Hz from the analytic trajectory (small white noise), mocap at 200 Hz,
images at 30 Hz. Writes DIR/sequence.bag, DIR/camchain.yaml and DIR/imu.yaml with the topics and conventions of
docs/conventions.md (the same files diekf_simulate writes).

usage: make_test_bag.py --duration S --output DIR
"""
import argparse
import math
import os

import numpy as np
import rosbag
import rospy
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import CameraInfo, Image, Imu
from shape_msgs.msg import Plane

T0_S = 1600000000.0
W, H = 752, 480
FX = FY = 365.0
CX, CY = 376.0, 240.0
# T_cam_imu: x_C = y_I, y_C = -x_I, z_C = z_I; IMU origin at t_CI in the camera frame (m).
R_CI = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
T_CI = np.array([0.048, -0.004, -0.012])
R_IC = R_CI.T
T_IC = -R_IC.dot(T_CI)
# Camera looking straight down at rest: x_C = X_W, y_C = -Y_W, z_C = -Z_W.
R_WC0 = np.diag([1.0, -1.0, -1.0])
R_WI0 = R_WC0.dot(R_CI)
GRAVITY = 9.81
TEXTURE_PX = 1024
TEXTURE_M = 4.0
ACC_NOISE, GYRO_NOISE = 2.0e-3, 2.0e-4  # per-sample 1-sigma at 500 Hz, m/s^2 and rad/s


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# Body motion p_WI = P0 + A (1 - cos(w t)) per axis: starts at rest, strongest acceleration at the start.
AMPLITUDE_M = np.array([0.25, 0.20, 0.10])
OMEGA_RADPS = 2 * math.pi * np.array([0.40, 0.30, 0.25])
P0_M = np.array([0.0, 0.0, 0.75])


def position(t):
    """p_WI (m)."""
    return P0_M + AMPLITUDE_M * (1.0 - np.cos(OMEGA_RADPS * t))


def acceleration(t):
    """d^2 p_WI / dt^2 (m/s^2)."""
    return AMPLITUDE_M * OMEGA_RADPS ** 2 * np.cos(OMEGA_RADPS * t)


def rotation(t):
    """R_WI: a few degrees of roll and pitch and a slow yaw around the downward-looking rest attitude."""
    w = 2 * math.pi
    roll = math.radians(4.0) * math.sin(w * 0.3 * t)
    pitch = math.radians(3.0) * math.sin(w * 0.23 * t + 1.0)
    yaw = 0.2 * math.sin(w * 0.1 * t)
    return rot_z(yaw).dot(rot_y(pitch)).dot(rot_x(roll)).dot(R_WI0)


def log_so3(R):
    c = max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))
    angle = math.acos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return v * 0.5 if angle < 1e-9 else v * angle / (2.0 * math.sin(angle))


def quaternion(R):
    w = math.sqrt(max(0.0, 1.0 + np.trace(R))) / 2.0
    x = math.copysign(math.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2.0, R[2, 1] - R[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2.0, R[0, 2] - R[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2.0, R[1, 0] - R[0, 1])
    return x, y, z, w


def make_texture(rng):
    """Band-pass noise (wavelengths about 1.5-15 cm), grey levels 20..235."""
    noise = rng.standard_normal((TEXTURE_PX, TEXTURE_PX))
    f = np.fft.fftfreq(TEXTURE_PX, d=TEXTURE_M / TEXTURE_PX)  # cycles per metre
    fr = np.hypot(f[:, None], f[None, :])
    band = np.exp(-(fr / 30.0) ** 2) * (1.0 - np.exp(-(fr / 4.0) ** 2))
    tex = np.real(np.fft.ifft2(np.fft.fft2(noise) * band))
    tex = (tex - tex.mean()) / tex.std()
    return np.clip(128.0 + 45.0 * tex, 20.0, 235.0).astype(np.float32)


def render(texture, R_WC, p_WC, rays_C):
    r_W = rays_C.dot(R_WC.T.astype(np.float32))
    s = np.float32(-p_WC[2]) / r_W[:, 2]
    scale = np.float32(TEXTURE_PX / TEXTURE_M)
    u = np.mod((np.float32(p_WC[0]) + s * r_W[:, 0]) * scale, TEXTURE_PX)
    v = np.mod((np.float32(p_WC[1]) + s * r_W[:, 1]) * scale, TEXTURE_PX)
    u0 = u.astype(np.int32)
    v0 = v.astype(np.int32)
    a, b = u - u0, v - v0
    u1, v1 = (u0 + 1) % TEXTURE_PX, (v0 + 1) % TEXTURE_PX
    u0 %= TEXTURE_PX
    v0 %= TEXTURE_PX
    val = ((1 - a) * (1 - b) * texture[v0, u0] + a * (1 - b) * texture[v0, u1] +
           (1 - a) * b * texture[v1, u0] + a * b * texture[v1, u1])
    half = np.clip(val + 0.5, 0, 255).astype(np.uint8).reshape(H // 2, W // 2)
    return np.repeat(np.repeat(half, 2, axis=0), 2, axis=1)  # rendered at half size (speed), shown at full size


def stamp(t):
    return rospy.Time.from_sec(T0_S + t)


def write(duration_s, out_dir, seed=1):
    os.makedirs(out_dir, exist_ok=True)
    rng = np.random.default_rng(seed)
    texture = make_texture(rng)
    # Rays through the centres of 2x2 pixel blocks.
    xs, ys = np.meshgrid((np.arange(0, W, 2) + 0.5 - CX) / FX, (np.arange(0, H, 2) + 0.5 - CY) / FY)
    rays_C = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)], axis=1).astype(np.float32)

    with open(os.path.join(out_dir, "camchain.yaml"), "w") as f:
        f.write("cam0:\n  camera_model: pinhole\n  intrinsics: [%g, %g, %g, %g]\n" % (FX, FY, CX, CY))
        f.write("  distortion_model: radtan\n  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]\n")
        f.write("  resolution: [%d, %d]\n  T_cam_imu:\n" % (W, H))
        for r in range(3):
            f.write("  - [%r, %r, %r, %r]\n" % (R_CI[r, 0], R_CI[r, 1], R_CI[r, 2], T_CI[r]))
        f.write("  - [0.0, 0.0, 0.0, 1.0]\n  timeshift_cam_imu: 0.0\n  rostopic: /mynteye/left/image_raw\n")
    with open(os.path.join(out_dir, "imu.yaml"), "w") as f:
        f.write("accelerometer_noise_density: %g\naccelerometer_random_walk: 2.0e-4\n"
                "gyroscope_noise_density: %g\ngyroscope_random_walk: 2.0e-6\nupdate_rate: 500.0\n"
                "rostopic: /mynteye/imu/data_raw\n" % (ACC_NOISE / math.sqrt(500.0), GYRO_NOISE / math.sqrt(500.0)))

    with rosbag.Bag(os.path.join(out_dir, "sequence.bag"), "w") as bag:
        plane = Plane(coef=[0.0, 0.0, 1.0, 0.0])
        bag.write("/ground_truth/plane", plane, stamp(0.0))
        h = 1e-4
        for k in range(int(round(duration_s * 500)) + 1):
            t = k / 500.0
            R = rotation(t)
            w_I = log_so3(rotation(t - h).T.dot(rotation(t + h))) / (2 * h)
            f_I = R.T.dot(acceleration(t) + np.array([0.0, 0.0, GRAVITY]))
            m = Imu()
            m.header.stamp = stamp(t)
            m.header.frame_id = "mynteye_imu_frame"
            m.orientation_covariance[0] = -1.0
            f_I = f_I + rng.normal(0.0, ACC_NOISE, 3)
            w_I = w_I + rng.normal(0.0, GYRO_NOISE, 3)
            m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = f_I
            m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = w_I
            bag.write("/mynteye/imu/data_raw", m, m.header.stamp)
            if k % 5 == 0:  # motion capture at 100 Hz
                p = PoseStamped()
                p.header.stamp = m.header.stamp
                p.header.frame_id = "world"
                p.pose.position.x, p.pose.position.y, p.pose.position.z = position(t)
                (p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z,
                 p.pose.orientation.w) = quaternion(R)
                bag.write("/mocap/pose", p, p.header.stamp)
        info = CameraInfo(width=W, height=H, distortion_model="plumb_bob", D=[0.0] * 5,
                          K=[FX, 0, CX, 0, FY, CY, 0, 0, 1])
        for k in range(int(duration_s * 30)):
            t = k / 30.0
            R_WI = rotation(t)
            img = render(texture, R_WI.dot(R_IC), position(t) + R_WI.dot(T_IC), rays_C)
            m = Image(height=H, width=W, encoding="mono8", step=W, data=img.tobytes())
            m.header.stamp = stamp(t)
            m.header.frame_id = "mynteye_left_frame"
            bag.write("/mynteye/left/image_raw", m, m.header.stamp)
            info.header = m.header
            bag.write("/mynteye/left/camera_info", info, m.header.stamp)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=10.0, help="sequence length, s")
    parser.add_argument("--output", required=True, help="output directory")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    write(args.duration, args.output, args.seed)
