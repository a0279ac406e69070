"""Shared helpers of the diekf rostests: simulated bag, estimator start-up, bag replay, ground truth.

Ground truth follows docs/conventions.md section 2: /mocap/pose is T_W_I, /ground_truth/plane gives (a, b, c, e);
p_WC = p_WI + R_WI t_IC, R_WC = R_WI R_IC, d = n . p_WC + e, v = R_WC^T dp_WC/dt (central differences).
"""
import os
import shutil
import subprocess
import tempfile
import time

import numpy as np
import rosbag
import rosgraph
import rosparam
import rospy
import yaml


def executable(name, package="diekf", required=False):
    """Path of `package`'s executable `name` in the sourced workspaces, or None: the first workspace of
    CMAKE_PREFIX_PATH that has it, as catkin resolves it. Not rosrun, which also searches the package's source
    directory and, when it finds more than one file (a second build tree), stops at an interactive prompt."""
    from catkin.find_in_workspaces import find_in_workspaces
    for path in find_in_workspaces(search_dirs=["libexec"], project=package, path=name):
        if os.path.isfile(path) and os.access(path, os.X_OK):
            return path
    if required:
        raise RuntimeError("no executable %s of package %s in the sourced workspaces" % (name, package))
    return None


def simulator_available():
    exe = executable("diekf_simulate")
    if exe is None:
        return False
    proc = subprocess.run([exe, "--help"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=60)
    return proc.returncode == 0


def simulate(preset, duration_s, seed=1):
    """Writes a simulated sequence into a fresh temporary directory; returns (dir, bag, camchain, imu_yaml).

    Uses diekf_simulate (preset as given) when it is built, else the small generator make_test_bag.py.
    """
    out = tempfile.mkdtemp(prefix="diekf_rostest_")
    if simulator_available():
        cmd = [executable("diekf_simulate"), "--preset", preset, "--duration", str(duration_s),
               "--seed", str(seed), "--output", out]
    else:
        rospy.logwarn("diekf_simulate is not built: using test/ros/make_test_bag.py instead of preset %s", preset)
        cmd = [os.path.join(os.path.dirname(os.path.abspath(__file__)), "make_test_bag.py"),
               "--duration", str(duration_s), "--seed", str(seed), "--output", out]
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=180)
    log = proc.stdout.decode(errors="replace")
    if proc.returncode != 0:
        raise RuntimeError("%s failed (%d): %s" % (os.path.basename(cmd[0]), proc.returncode, log))
    rospy.loginfo("%s: %s", os.path.basename(cmd[0]), log.strip().replace("\n", " | ")[-400:])
    paths = [os.path.join(out, f) for f in ("sequence.bag", "camchain.yaml", "imu.yaml")]
    for p in paths:
        if not os.path.isfile(p):
            raise RuntimeError("diekf_simulate did not write " + p)
    return [out] + paths


def cleanup(directory):
    shutil.rmtree(directory, ignore_errors=True)


def package_file(*parts):
    """A file of this package (the test runs from the source tree's test/ros directory)."""
    here = os.path.dirname(os.path.abspath(__file__))
    return os.path.join(here, "..", "..", *parts)


def upload_params(namespace, yaml_file=None, values=None):
    if yaml_file:
        for params, ns in rosparam.load_file(yaml_file, default_namespace=namespace):
            rosparam.upload_params(ns, params)
    for key, value in (values or {}).items():
        rospy.set_param(namespace + "/" + key, value)


def wait_for(predicate, timeout_s, period_s=0.1):
    deadline = time.time() + timeout_s
    while time.time() < deadline and not rospy.is_shutdown():
        if predicate():
            return True
        time.sleep(period_s)
    return predicate()


def has_subscriber(topic):
    _, subscribers, _ = rosgraph.Master(rospy.get_name()).getSystemState()
    return any(name == topic and nodes for name, nodes in subscribers)


def has_publisher(topic):
    publishers, _, _ = rosgraph.Master(rospy.get_name()).getSystemState()
    return any(name == topic and nodes for name, nodes in publishers)


def start(cmd):
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)


def stop(proc):
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def play(bag, timeout_s):
    """rosbag play of the whole bag (wall-clock rate); returns its exit code."""
    proc = subprocess.Popen(["rosbag", "play", "--quiet", bag], stdout=subprocess.DEVNULL,
                            stderr=subprocess.STDOUT)
    try:
        return proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise


def _quat_to_rot(x, y, z, w):
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


class GroundTruth(object):
    """Camera distance, velocity (in C) and base_link height from the bag's mocap and plane messages."""

    def __init__(self, bag_path, camchain_path, camera="cam0"):
        with open(camchain_path) as f:
            cam = yaml.safe_load(f)[camera]
        T_cam_imu = np.array(cam["T_cam_imu"], dtype=float)
        T_IC = np.linalg.inv(T_cam_imu)
        self.R_IC = T_IC[:3, :3]
        self.t_IC = T_IC[:3, 3]
        self.plane = np.array([0.0, 0.0, 1.0, 0.0])
        t, p, q = [], [], []
        with rosbag.Bag(bag_path) as bag:
            for topic, msg, _ in bag.read_messages(topics=["/mocap/pose", "/ground_truth/plane"]):
                if topic == "/ground_truth/plane":
                    self.plane = np.array(msg.coef, dtype=float)
                else:
                    t.append(msg.header.stamp.to_sec())
                    p.append([msg.pose.position.x, msg.pose.position.y, msg.pose.position.z])
                    o = msg.pose.orientation
                    q.append([o.x, o.y, o.z, o.w])
        if len(t) < 10:
            raise RuntimeError("bag has no /mocap/pose stream")
        self.t = np.array(t)
        self.R_WI = np.array([_quat_to_rot(*qq) for qq in q])
        p_WI = np.array(p)
        self.p_WC = p_WI + np.einsum("kij,j->ki", self.R_WI, self.t_IC)
        self.p_WI = p_WI
        self.v_WC = np.gradient(self.p_WC, self.t, axis=0)  # central differences inside, one-sided at the ends

    def _index(self, t):
        k = int(np.clip(np.searchsorted(self.t, t), 1, len(self.t) - 1))
        return k - 1 if abs(self.t[k - 1] - t) < abs(self.t[k] - t) else k

    def covers(self, t):
        return self.t[0] <= t <= self.t[-1]

    def at(self, t):
        """(d, v_C, h_base) at time t: position/velocity interpolated linearly, rotation of the nearest pose."""
        n, e = self.plane[:3], self.plane[3]
        p_WC = np.array([np.interp(t, self.t, self.p_WC[:, i]) for i in range(3)])
        v_WC = np.array([np.interp(t, self.t, self.v_WC[:, i]) for i in range(3)])
        p_WI = np.array([np.interp(t, self.t, self.p_WI[:, i]) for i in range(3)])
        R_WC = self.R_WI[self._index(t)].dot(self.R_IC)
        d = n.dot(p_WC) + e
        v_C = R_WC.T.dot(v_WC)
        # Height of base_link (IMU origin) above the plane along gravity (world z).
        h_base = (n.dot(p_WI) + e) / n[2]
        return d, v_C, h_base
