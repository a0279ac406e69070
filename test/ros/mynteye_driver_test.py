#!/usr/bin/env python3
"""rostest: diekf next to the MYNT EYE S driver, with the README's commands for the robot as they are written.

The driver is diekf's stand-in (diekf/MyntEyeStandin: the driver's node name, topics, frames, encodings, IMU layout
and static TF, fed from a simulated bag; docs/ros.md). The README block "On the robot" is read and every
`roslaunch diekf ...` command in it is run as written, /path/to/camchain.yaml replaced by the bag's calibration:
 - launch files that expect the driver to be running already get the stand-in, started with
   launch/mynteye_standin.launch (the layout of the driver's stock launch file);
 - mynteye_driver.launch, which starts the driver itself, gets `standin_bag:=BAG` (the README says so).
Without `camchain:=` the calibration comes from the stand-in's camera_info and TF. For every command: the combined
TF tree (/tf and /tf_static of every process) is a tree: one parent per frame, no cycle, one root (odom), base_link
an ancestor of the camera's frames; base_link -> camera through that tree equals the calibration's T_cam_imu^-1;
/diagnostics reports the attachment, the calibration's source, the measured IMU rate and the driver's IR projector
setting; and the estimator tracks:
~state reaches `tracking` and its distance follows the bag's truth (RMSE below max_rmse_distance_m at the best
clock offset: the stand-in, like the driver, stamps with ROS time). A second test runs the stand-in at the device's
IMU rates of 100 and 200 Hz.

Private parameters: preset, duration_s (bag length, s), timeout_s (per command, s), max_rmse_distance_m (m).
"""
import os
import re
import signal
import subprocess
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from diekf.msg import PlanarState
from tf2_msgs.msg import TFMessage

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import diekf_rostest_utils as util  # noqa: E402

CAMCHAIN_PLACEHOLDER = "/path/to/camchain.yaml"
CAMERA_FRAMES = ("mynteye_left_frame", "mynteye_right_frame", "camera_imu_frame")


def readme_robot_commands(readme_path):
    """The `roslaunch diekf ...` commands of the README's "On the robot" paragraph (continuation lines joined,
    comments dropped)."""
    with open(readme_path) as f:
        text = f.read()
    start = text.index("**On the robot**")
    end = text.index("**Replaying a bag**", start)
    block = text[start:end].replace("\\\n", " ")
    commands = []
    for line in block.split("\n"):
        line = line.split("#")[0].strip()
        if line.startswith("roslaunch diekf "):
            commands.append(re.sub(r"\s+", " ", line))
    return commands


def quat_to_rot(q):
    x, y, z, w = q.x, q.y, q.z, q.w
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def to_matrix(transform):
    T = np.eye(4)
    T[:3, :3] = quat_to_rot(transform.rotation)
    T[:3, 3] = [transform.translation.x, transform.translation.y, transform.translation.z]
    return T


class TfTree(object):
    """Every parent -> child transform seen on /tf and /tf_static, with the publishers' disagreements kept."""

    def __init__(self):
        self.lock = threading.Lock()
        self.parents = {}     # child -> set of parents
        self.transforms = {}  # (parent, child) -> last geometry_msgs/Transform

    def add(self, msg):
        with self.lock:
            for t in msg.transforms:
                parent, child = t.header.frame_id.lstrip("/"), t.child_frame_id.lstrip("/")
                self.parents.setdefault(child, set()).add(parent)
                self.transforms[(parent, child)] = t.transform

    def snapshot(self):
        with self.lock:
            return {c: set(p) for c, p in self.parents.items()}, dict(self.transforms)

    @staticmethod
    def ancestors(parents, frame):
        chain = [frame]
        while chain[-1] in parents and len(parents[chain[-1]]) == 1:
            p = next(iter(parents[chain[-1]]))
            if p in chain:
                raise AssertionError("TF cycle through %s" % " -> ".join(chain + [p]))
            chain.append(p)
        return chain


class MyntEyeDriver(unittest.TestCase):

    def setUp(self):
        self.lock = threading.Lock()
        self.tree = TfTree()
        self.states = []
        self.tf_diag = []
        self.imu_diag = (None, None)
        self.calibration_diag = ""
        self.ir_diag = ""
        self.procs = []
        self.tmp = None
        self.subscribers = []

    def tearDown(self):
        self.stop_all()
        for sub in self.subscribers:
            sub.unregister()
        if self.tmp:
            util.cleanup(self.tmp)

    def stop_all(self):
        for proc in reversed(self.procs):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)  # roslaunch shuts its nodes down on SIGINT
        for proc in reversed(self.procs):
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self.procs = []

    def launch(self, args, log_name):
        log = open(os.path.join(self.tmp, log_name), "w")
        proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        self.procs.append(proc)
        return proc

    def on_state(self, msg):
        with self.lock:
            self.states.append(msg)

    def on_diagnostics(self, msg):
        for s in msg.status:
            if "diekf" in s.name and s.name.endswith("filter"):
                values = {kv.key: kv.value for kv in s.values}
                with self.lock:
                    if "TF base_link to camera" in values:
                        self.tf_diag.append(values["TF base_link to camera"])
                    self.imu_diag = (values.get("IMU rate (Hz, measured; 0 = not measured)"),
                                     values.get("IMU preprocessing"))
                    self.calibration_diag = values.get("calibration", "")
                    self.ir_diag = values.get("camera driver IR projector", "")

    def tracking_states(self):
        with self.lock:
            return [s for s in self.states if s.status == PlanarState.STATUS_TRACKING]

    def log_tail(self, name, n=40):
        try:
            with open(os.path.join(self.tmp, name)) as f:
                return "".join(f.readlines()[-n:])
        except IOError:
            return ""

    def run_command(self, command, bag, camchain, truth, T_cam_imu, timeout_s, max_rmse_m, standin_args=()):
        """Runs one README command against the stand-in (started with `standin_args` too), asserts; returns the
        IMU rate (Hz) and preprocessing /diagnostics reported."""
        with self.tree.lock:
            self.tree.parents.clear()
            self.tree.transforms.clear()
        with self.lock:
            del self.states[:]
            del self.tf_diag[:]
            self.imu_diag = (None, None)
        args = command.replace(CAMCHAIN_PLACEHOLDER, camchain).split()
        self.assertNotIn("/path/to", " ".join(args), "README command with a placeholder left: " + command)
        label = re.sub(r"[^A-Za-z0-9]+", "_", " ".join(args[2:] + list(standin_args)).replace(camchain, "CAMCHAIN"))[:80]
        if "mynteye_driver.launch" in command:
            args.append("standin_bag:=" + bag)  # the driver itself is the stand-in
            args += list(standin_args)
        else:
            # What the README assumes to be running: the driver's stock launch file. Its stand-in:
            self.launch(["roslaunch", "diekf", "mynteye_standin.launch", "bag:=" + bag, "camchain:=" + camchain] +
                        list(standin_args), "standin_%s.log" % label)
            self.assertTrue(util.wait_for(lambda: util.has_publisher("/mynteye/imu/data_raw"), 30.0),
                            "the stand-in did not come up:\n" + self.log_tail("standin_%s.log" % label))
        rospy.loginfo("running: %s", " ".join(args))
        print("\n[diekf rostest] running: %s" % " ".join(args))
        self.launch(args, "diekf_%s.log" % label)

        def enough():
            return len(self.tracking_states()) >= 150 and self.tf_decided()
        ok = util.wait_for(enough, timeout_s)
        time.sleep(1.0)
        parents, transforms = self.tree.snapshot()
        states = self.tracking_states()
        with self.lock:
            first_stamp = self.states[0].header.stamp.to_sec() if self.states else None
        diag = list(self.tf_diag)
        imu_diag = self.imu_diag
        calibration = self.calibration_diag
        ir = self.ir_diag
        self.stop_all()
        logs = self.log_tail("diekf_%s.log" % label) + self.log_tail("standin_%s.log" % label, 10)
        self.assertTrue(ok, "%s: %d tracking states within %.0f s, TF %s; log:\n%s" %
                        (command, len(states), timeout_s, parents, logs))

        # One parent per frame, no cycle, one root: odom.
        several = {c: sorted(p) for c, p in parents.items() if len(p) > 1}
        self.assertFalse(several, "%s: frames with more than one parent: %s" % (command, several))
        frames = set(parents) | {p for ps in parents.values() for p in ps}
        roots = {TfTree.ancestors(parents, f)[-1] for f in frames}
        self.assertEqual(roots, {"odom"}, "%s: not one tree rooted at odom, roots %s (parents %s)" %
                         (command, roots, parents))
        for frame in CAMERA_FRAMES:
            self.assertIn(frame, frames, "%s: the driver's frame %s missing from TF" % (command, frame))
            self.assertIn("base_link", TfTree.ancestors(parents, frame),
                          "%s: base_link is not an ancestor of %s: %s" % (command, frame, parents))
        # base_link -> camera through the tree = T_cam_imu^-1 of the calibration.
        chain = TfTree.ancestors(parents, "mynteye_left_frame")
        T_base_cam = np.eye(4)
        for child, parent in zip(chain[:chain.index("base_link")], chain[1:chain.index("base_link") + 1]):
            T_base_cam = to_matrix(transforms[(parent, child)]).dot(T_base_cam)
        np.testing.assert_allclose(T_base_cam, np.linalg.inv(T_cam_imu), atol=1e-6,
                                   err_msg="%s: base_link -> camera through %s" % (command, chain))
        self.assertTrue(any("attached" in d for d in diag),
                        "%s: /diagnostics does not report the attachment to the driver's tree: %s" %
                        (command, diag[-1:] or "nothing"))
        # The estimator tracks: its distance follows the truth. The stand-in maps the bag's clock onto ROS time
        # at its start (as the driver maps the device clock), so the offset is found by fitting, from 3 s before
        # to 1 s after that of the first estimate (the driver drops the first 10 images, diekf those of its IMU
        # rate measurement); then the RMSE of the distance after the first 2 s of tracking must be small.
        t = np.array([s.header.stamp.to_sec() for s in states])
        d = np.array([s.distance for s in states])
        self.assertTrue(np.all(np.isfinite(d)))
        keep = t > t[0] + 2.0
        self.assertGreater(np.count_nonzero(keep), 20, "%s: too few tracking states after 2 s" % command)
        guess = first_stamp - (truth.t[0] + 10.0 / 30.0)
        best = (np.inf, 0.0)
        for offset in guess + np.arange(-3.0, 1.0, 0.005):
            tb = t[keep] - offset
            if tb[0] < truth.t[0] or tb[-1] > truth.t[-1]:
                continue
            rmse = np.sqrt(np.mean((d[keep] - np.interp(tb, truth.t, truth.d)) ** 2))
            best = min(best, (rmse, offset))
        self.assertLess(best[0], max_rmse_m, "%s: distance RMSE %.3f m against the truth (at the best clock offset)"
                        % (command, best[0]))
        print("[diekf rostest] %s %s: %d tracking states, distance RMSE %.4f m, TF chain %s, IMU %s Hz: %s" %
              (command, " ".join(standin_args), len(states), best[0], " <- ".join(chain), imu_diag[0], imu_diag[1]))
        self.assertIsNotNone(imu_diag[0], "%s: no IMU rate in /diagnostics" % command)
        # Kalibr camchain when given, else the driver's camera_info and TF (docs/ros.md, "Calibration").
        expected = "Kalibr camchain" if "camchain:=" in command else "camera_info on /mynteye/left/camera_info"
        self.assertTrue(calibration.startswith(expected), "%s: calibration '%s'" % (command, calibration))
        # The driver's IR projector parameter is read: on (its stock files set 80) unless the stand-in was told 0.
        if "ir_control:=0" in standin_args:
            self.assertEqual(ir, "IR projector off", command)
        else:
            self.assertIn("IR projector on (/mynteye/mynteye_wrapper_node/standard/ir_control = 80)", ir, command)
        return float(imu_diag[0]), imu_diag[1]

    def tf_decided(self):
        with self.lock:
            return any(not d.startswith("waiting") for d in self.tf_diag)

    def prepare(self):
        """Simulates the flight, subscribes; returns (bag, camchain, truth, T_cam_imu, timeout_s, max_rmse_m)."""
        duration_s = float(rospy.get_param("~duration_s", 12.0))
        self.tmp, bag, camchain, _ = util.simulate(rospy.get_param("~preset", "flight1"), duration_s)
        with open(camchain) as f:
            T_cam_imu = np.array(yaml.safe_load(f)["cam0"]["T_cam_imu"], dtype=float)
        truth = util.GroundTruth(bag, camchain)
        truth.d = np.array([truth.at(t)[0] for t in truth.t])
        self.subscribers = [
            rospy.Subscriber("/tf", TFMessage, self.tree.add, queue_size=1000),
            rospy.Subscriber("/tf_static", TFMessage, self.tree.add, queue_size=100),
            rospy.Subscriber("/diekf/state", PlanarState, self.on_state, queue_size=100),
            rospy.Subscriber("/diagnostics", DiagnosticArray, self.on_diagnostics, queue_size=100)]
        return (bag, camchain, truth, T_cam_imu, float(rospy.get_param("~timeout_s", 90.0)),
                float(rospy.get_param("~max_rmse_distance_m", 0.05)))

    def test_readme_commands_against_the_driver_standin(self):
        commands = readme_robot_commands(util.package_file("README.md"))
        self.assertGreaterEqual(len(commands), 3, "README's robot commands not found: %s" % commands)
        self.assertTrue(any("mynteye_driver.launch" in c for c in commands), commands)
        setup = self.prepare()
        for command in commands:
            rate_hz, design = self.run_command(command, *setup)
            # The simulated IMU runs at 500 Hz: measured, decimated by 5 to the 100 Hz prediction.
            self.assertAlmostEqual(rate_hz, 500.0, delta=5.0)
            self.assertIn("decimation 5", design)

    def test_imu_rates_of_the_device(self):
        """The stand-in at the device's standard/imu_frequency of 100 and 200 Hz (500 Hz: the test above), next
        to diekf in its own manager (the README's second command): the rate is measured from the stamps, the
        preprocessing designed for it (decimation 1 and 2 to the 100 Hz prediction), and the estimator tracks."""
        commands = [c for c in readme_robot_commands(util.package_file("README.md"))
                    if "mynteye.launch" in c and "standalone" not in c]
        self.assertTrue(commands, "README has no command for diekf next to the driver's own launch file")
        setup = self.prepare()
        for rate, decimation in ((100, 1), (200, 2)):
            args = ("imu_frequency:=%d" % rate,) + (("ir_control:=0",) if rate == 200 else ())
            rate_hz, design = self.run_command(commands[0], *setup, standin_args=args)
            self.assertAlmostEqual(rate_hz, rate, delta=0.01 * rate)
            self.assertIn("decimation %d " % decimation, design)


if __name__ == "__main__":
    rospy.init_node("mynteye_driver_test")
    rostest.rosrun("diekf", "mynteye_driver", MyntEyeDriver, sys.argv)
