#!/usr/bin/env python3
"""rostest (b): the ROS interface of diekf, run through the standalone node diekf_node (which loads the same
nodelet in process) on a short simulated bag replayed with rosbag play.

Checks: every advertised output topic publishes with its documented type; the TF tree odom -> base_link ->
camera exists and the static part matches the calibration; /diagnostics carries the filter status; the ~reset
service (std_srvs/Trigger) brings the filter back to initializing, then tracking again; keys of the node's
namespace that nothing reads are warned about with the namespace, the key and the closest known key; an IMU sample
and an image older than the last of their input are dropped, counted on /diagnostics and named in a warning.
"""
import math
import os
import subprocess
import sys
import threading
import time
import unittest

import numpy as np
import rosbag
import rospy
import rostest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from diekf.msg import PlanarState
from geometry_msgs.msg import TwistWithCovarianceStamped
from nav_msgs.msg import Odometry, Path
from sensor_msgs.msg import Image, Imu, Range
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import diekf_rostest_utils as util  # noqa: E402

NODE = "/diekf"
# Documented outputs (docs/ros.md): topic -> (type name, message class).
OUTPUTS = {
    NODE + "/state": ("diekf/PlanarState", PlanarState),
    NODE + "/odometry": ("nav_msgs/Odometry", Odometry),
    NODE + "/odometry_imu_rate": ("nav_msgs/Odometry", Odometry),
    NODE + "/twist": ("geometry_msgs/TwistWithCovarianceStamped", TwistWithCovarianceStamped),
    NODE + "/height": ("sensor_msgs/Range", Range),
    NODE + "/range": ("sensor_msgs/Range", Range),
    NODE + "/path": ("nav_msgs/Path", Path),
    NODE + "/markers": ("visualization_msgs/MarkerArray", MarkerArray),
    NODE + "/residual_image": ("sensor_msgs/Image", Image),
}
FRAMES = ("odom", "base_link", "mynteye_left_frame")


class Interface(unittest.TestCase):

    def setUp(self):
        self.lock = threading.Lock()
        self.count = {topic: 0 for topic in OUTPUTS}
        self.statuses = []  # (wall time, status)
        self.tf = {}
        self.tf_static = {}
        self.diagnostics = []
        self.odom_frames = []
        self.odom_fast = []
        self.node = None
        self.player = None
        self.node_log = None  # the node's console output (file)
        self.tmp = None

    def tearDown(self):
        util.stop(self.player)
        util.stop(self.node)
        if self.node_log is not None:
            self.node_log.close()
        if self.tmp:
            util.cleanup(self.tmp)

    def counter(self, topic):
        def callback(msg):
            with self.lock:
                self.count[topic] += 1
                if topic.endswith("/odometry"):
                    self.odom_frames.append(msg)
                elif topic.endswith("/odometry_imu_rate"):
                    self.odom_fast.append(msg)
                if topic.endswith("/state"):
                    self.statuses.append((time.time(), msg.status))
        return callback

    def on_tf(self, store):
        def callback(msg):
            with self.lock:
                for t in msg.transforms:
                    store[(t.header.frame_id, t.child_frame_id)] = t
        return callback

    def on_diagnostics(self, msg):
        with self.lock:
            self.diagnostics.extend(s for s in msg.status if "filter" in s.name and "diekf" in s.name)

    def statuses_after(self, wall_t):
        with self.lock:
            return [s for t, s in self.statuses if t > wall_t]

    def test_interface(self):
        duration_s = float(rospy.get_param("~duration_s", 8.0))
        self.tmp, bag, camchain, imu_yaml = util.simulate(rospy.get_param("~preset", "flight1"), duration_s)
        util.upload_params(NODE, util.package_file("config", "estimator.yaml"))
        util.upload_params(NODE, util.package_file("config", "mynteye.yaml"),
                           {"camchain_file": camchain, "imu_file": imu_yaml, "publish_odometry_imu_rate": True})
        # A misspelt estimator key and a key the nodelet no longer reads (now the estimator's input/...).
        util.upload_params(NODE, None, {"photometric/max_pases": 2, "time_jump_reset_s": 1.0})
        for topic, (_, cls) in OUTPUTS.items():
            rospy.Subscriber(topic, cls, self.counter(topic), queue_size=100)
        rospy.Subscriber("/tf", TFMessage, self.on_tf(self.tf), queue_size=100)
        rospy.Subscriber("/tf_static", TFMessage, self.on_tf(self.tf_static), queue_size=10)
        rospy.Subscriber("/diagnostics", DiagnosticArray, self.on_diagnostics, queue_size=10)

        log_path = os.path.join(self.tmp, "node.log")
        self.node_log = open(log_path, "w")
        self.node = subprocess.Popen([util.executable("diekf_node", required=True), "__name:=diekf"],
                                     stdout=self.node_log, stderr=subprocess.STDOUT)
        self.assertTrue(util.wait_for(lambda: util.has_subscriber("/mynteye/imu/data_raw") and
                                      util.has_subscriber("/mynteye/left/image_raw"), 20.0),
                        "diekf_node did not subscribe to the MYNT EYE topics")
        rospy.wait_for_service(NODE + "/reset", timeout=10.0)
        time.sleep(1.0)

        # Unknown keys: one warning each, naming the namespace, the key and the closest known key.
        def warned(key, closest):
            with open(log_path) as f:
                text = f.read()
            return "%s: unknown parameter key '%s' ignored (closest known key: '%s')" % (NODE, key, closest) in text
        self.assertTrue(util.wait_for(lambda: warned("photometric/max_pases", "photometric/max_passes") and
                                      warned("time_jump_reset_s", "input/time_jump_reset_s"), 10.0),
                        "no unknown-key warnings in the node's output:\n" + open(log_path).read()[-2000:])

        # Types of everything the node advertises, as the master sees them.
        advertised = dict(rospy.get_published_topics(NODE))
        for topic, (type_name, _) in OUTPUTS.items():
            self.assertEqual(advertised.get(topic), type_name, "%s not advertised as %s" % (topic, type_name))
        for topic in advertised:
            documented = topic in OUTPUTS or topic.startswith(NODE + "/residual_image/")
            self.assertTrue(documented, "undocumented output topic " + topic)

        self.player = subprocess.Popen(["rosbag", "play", "--quiet", bag], stdout=subprocess.DEVNULL,
                                       stderr=subprocess.STDOUT)
        # Tracking first, then reset, then initializing followed by tracking again.
        self.assertTrue(util.wait_for(lambda: PlanarState.STATUS_TRACKING in self.statuses_after(0.0), 20.0),
                        "never tracking before the reset")
        time.sleep(1.0)
        reset = rospy.ServiceProxy(NODE + "/reset", Trigger)
        t_reset = time.time()
        response = reset()
        self.assertTrue(response.success, response.message)

        def reinitialised_then_tracking():
            after = self.statuses_after(t_reset)
            if PlanarState.STATUS_INITIALIZING not in after:
                return False
            return PlanarState.STATUS_TRACKING in after[after.index(PlanarState.STATUS_INITIALIZING):]
        self.assertTrue(util.wait_for(reinitialised_then_tracking, 10.0),
                        "after ~reset: statuses %s" % self.statuses_after(t_reset)[:20])

        self.player.wait(timeout=duration_s + 30)
        time.sleep(1.5)  # at least one /diagnostics period after the end

        with self.lock:
            counts = dict(self.count)
            tf, tf_static, diagnostics = dict(self.tf), dict(self.tf_static), list(self.diagnostics)
        rospy.loginfo("messages per output: %s", counts)
        print("\n[diekf rostest] messages per output: %s" % counts)
        n_state = counts[NODE + "/state"]
        self.assertGreater(n_state, 0.5 * 30 * duration_s)
        for topic in (NODE + "/odometry", NODE + "/twist", NODE + "/height", NODE + "/range"):
            self.assertGreater(counts[topic], 0.9 * n_state, topic + " not published for every image")
        # ~odometry_imu_rate: the filter state predicted to every filtered IMU sample (100 Hz, 3.3 per image).
        self.assertGreater(counts[NODE + "/odometry_imu_rate"], 2.5 * n_state, "IMU-rate odometry too rare")
        with self.lock:
            frame_odom, fast_odom = list(self.odom_frames), list(self.odom_fast)
        stamps = np.array([m.header.stamp.to_sec() for m in fast_odom])
        # The prediction nearest an image's stamp is made from the previous frame's posterior (the image's update
        # needs IMU samples after its stamp), so it differs from that image's posterior by the update's correction:
        # within a few sigma of the predicted height (pose covariance z-z), and small in the median. A frame or sign
        # error between the two outputs would show on every frame. (The wall-clock reset above falls at a different
        # point of the flight on every run; the frames compared may include its re-convergence.)
        gaps, sigmas = [], []
        for m in frame_odom[len(frame_odom) // 2:]:
            t = m.header.stamp.to_sec()
            k = int(np.argmin(np.abs(stamps - t)))
            if abs(stamps[k] - t) < 0.006:  # a prediction within one 100 Hz period of the image
                gaps.append(abs(fast_odom[k].pose.pose.position.z - m.pose.pose.position.z))
                sigmas.append(math.sqrt(fast_odom[k].pose.covariance[14]))
        self.assertGreater(len(gaps), 10, "no IMU-rate odometry near the images' stamps")
        gaps, sigmas = np.array(gaps), np.array(sigmas)
        self.assertTrue(np.all(sigmas < 0.2), "IMU-rate odometry height 1-sigma implausible: %s" % sigmas)
        self.assertTrue(np.all(gaps < 3.0 * sigmas),
                        "IMU-rate odometry z departs from the image-rate odometry's by more than 3 sigma: %s" %
                        list(zip(gaps, sigmas)))
        self.assertLess(np.median(gaps), 0.005, "IMU-rate odometry z departs from the image-rate odometry's: %s" % gaps)
        for topic in (NODE + "/path", NODE + "/markers", NODE + "/residual_image"):
            self.assertGreater(counts[topic], 0, topic + " never published while subscribed")

        # TF tree odom -> base_link -> camera; the static part is T_cam_imu^-1 of the calibration.
        self.assertIn((FRAMES[0], FRAMES[1]), tf, "no odom -> base_link on /tf: %s" % list(tf))
        self.assertIn((FRAMES[1], FRAMES[2]), tf_static, "no base_link -> camera on /tf_static: %s" % list(tf_static))
        with open(camchain) as f:
            T_cam_imu = np.array(yaml.safe_load(f)["cam0"]["T_cam_imu"], dtype=float)
        t_IC = np.linalg.inv(T_cam_imu)[:3, 3]
        tr = tf_static[(FRAMES[1], FRAMES[2])].transform.translation
        np.testing.assert_allclose([tr.x, tr.y, tr.z], t_IC, atol=1e-9)

        self.assertTrue(diagnostics, "no diekf filter status on /diagnostics")
        keys = {kv.key for kv in diagnostics[-1].values}
        for key in ("status", "mean update time (ms)", "frames published", "filter restarts"):
            self.assertIn(key, keys)
        restarts = [int(kv.value) for kv in diagnostics[-1].values if kv.key == "filter restarts"]
        self.assertGreaterEqual(restarts[0], 1, "the reset is not counted in /diagnostics")

        # Out-of-order inputs: an IMU sample and an image 0.5 s older than the bag's last of each (less than
        # input/time_jump_reset_s back, so no restart) are dropped, counted and warned about, each input on its own.
        def dropped():
            with self.lock:
                values = {kv.key: kv.value for kv in self.diagnostics[-1].values}
            return int(values["IMU messages dropped"]), int(values["images dropped"])
        before = dropped()
        last = {}
        with rosbag.Bag(bag) as b:
            for topic, msg, _ in b.read_messages(topics=["/mynteye/imu/data_raw", "/mynteye/left/image_raw"]):
                last[topic] = max(last.get(topic, 0.0), msg.header.stamp.to_sec())
        imu_pub = rospy.Publisher("/mynteye/imu/data_raw", Imu, queue_size=1)
        image_pub = rospy.Publisher("/mynteye/left/image_raw", Image, queue_size=1)
        self.assertTrue(util.wait_for(lambda: imu_pub.get_num_connections() > 0 and
                                      image_pub.get_num_connections() > 0, 10.0), "the node never connected")
        imu = Imu()
        imu.header.stamp = rospy.Time.from_sec(last["/mynteye/imu/data_raw"] - 0.5)
        imu.linear_acceleration.z = 9.81
        image = Image()
        image.header.stamp = rospy.Time.from_sec(last["/mynteye/left/image_raw"] - 0.5)
        with open(camchain) as f:
            image.width, image.height = yaml.safe_load(f)["cam0"]["resolution"]
        image.encoding, image.step = "mono8", image.width
        image.data = bytes(image.width * image.height)
        imu_pub.publish(imu)
        image_pub.publish(image)
        self.assertTrue(util.wait_for(lambda: all(a > b for a, b in zip(dropped(), before)), 10.0),
                        "dropped counts on /diagnostics (IMU, images) %s, before %s" % (dropped(), before))

        def warned_dropped(what):
            with open(log_path) as f:
                return "diekf: out-of-order %s (stamp" % what in f.read()
        self.assertTrue(util.wait_for(lambda: warned_dropped("IMU message") and warned_dropped("image"), 5.0),
                        "no out-of-order warnings in the node's output:\n" + open(log_path).read()[-2000:])


if __name__ == "__main__":
    rospy.init_node("interface_test")
    rostest.rosrun("diekf", "interface", Interface, sys.argv)
