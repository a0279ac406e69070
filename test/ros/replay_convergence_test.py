#!/usr/bin/env python3
"""rostest (a): a short simulated bag replayed with rosbag play into diekf/EstimatorNodelet, loaded into a real
nodelet manager; the published distance, velocity and odometry height must converge to the bag's ground truth.

Private parameters: preset (simulator preset), duration_s (bag length, s), settle_s (errors are evaluated from
this long after the first estimate, s, docs/conventions.md section 5 uses 3 s), max_rmse_distance_m,
max_rmse_velocity_mps, max_rmse_height_m (tolerances), manager (nodelet manager name).
"""
import math
import os
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from diekf.msg import PlanarState
from nav_msgs.msg import Odometry

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import diekf_rostest_utils as util  # noqa: E402

NODELET = "/diekf"


class ReplayConvergence(unittest.TestCase):

    def setUp(self):
        self.lock = threading.Lock()
        self.states = []
        self.odometry = []
        self.loader = None
        self.tmp = None

    def tearDown(self):
        util.stop(self.loader)
        if self.tmp:
            util.cleanup(self.tmp)

    def on_state(self, msg):
        with self.lock:
            self.states.append(msg)

    def on_odometry(self, msg):
        with self.lock:
            self.odometry.append(msg)

    def test_distance_and_velocity_converge(self):
        preset = rospy.get_param("~preset", "flight1")
        duration_s = float(rospy.get_param("~duration_s", 10.0))
        settle_s = float(rospy.get_param("~settle_s", 3.0))
        tol_d = float(rospy.get_param("~max_rmse_distance_m", 0.10))
        tol_v = float(rospy.get_param("~max_rmse_velocity_mps", 0.10))
        tol_h = float(rospy.get_param("~max_rmse_height_m", 0.12))
        manager = rospy.get_param("~manager", "/diekf_manager")

        self.tmp, bag, camchain, imu_yaml = util.simulate(preset, duration_s)
        truth = util.GroundTruth(bag, camchain)

        util.upload_params(NODELET, util.package_file("config", "estimator.yaml"))
        util.upload_params(NODELET, util.package_file("config", "mynteye.yaml"),
                           {"camchain_file": camchain, "imu_file": imu_yaml})
        rospy.Subscriber(NODELET + "/state", PlanarState, self.on_state, queue_size=1000)
        rospy.Subscriber(NODELET + "/odometry", Odometry, self.on_odometry, queue_size=1000)

        rospy.wait_for_service(manager + "/load_nodelet", timeout=20.0)
        self.loader = util.start([util.executable("nodelet", "nodelet", required=True), "load", "diekf/EstimatorNodelet", manager,
                                  "__name:=diekf"])
        self.assertTrue(util.wait_for(lambda: util.has_subscriber("/mynteye/imu/data_raw") and
                                      util.has_subscriber("/mynteye/left/image_raw"), 20.0),
                        "the nodelet did not subscribe to the MYNT EYE topics")
        time.sleep(1.0)  # let our subscriptions connect to the nodelet's publishers

        wall0 = time.time()
        self.assertEqual(util.play(bag, timeout_s=4 * duration_s + 30), 0, "rosbag play failed")
        rospy.loginfo("replayed %.1f s of data in %.1f s wall time", duration_s, time.time() - wall0)
        time.sleep(1.0)

        with self.lock:
            states = list(self.states)
            odometry = list(self.odometry)
        n_images = int(duration_s * 30)
        self.assertGreater(len(states), 0.8 * n_images, "too few estimates: %d of ~%d images" % (len(states), n_images))
        self.assertEqual(len(odometry), len(states), "one odometry message per processed image")

        t0 = states[0].header.stamp.to_sec()
        err_d, err_v, err_h, tracking, converged = [], [], [], 0, 0
        for s in states:
            t = s.header.stamp.to_sec()
            values = [s.distance, s.height, s.velocity.x, s.velocity.y, s.velocity.z]
            self.assertTrue(all(math.isfinite(x) for x in values), "non-finite value published")
            if t < t0 + settle_s or not truth.covers(t):
                continue
            d, v, _ = truth.at(t)
            err_d.append(s.distance - d)
            err_v.append(np.linalg.norm(np.array([s.velocity.x, s.velocity.y, s.velocity.z]) - v))
            tracking += s.status == PlanarState.STATUS_TRACKING
            converged += s.status in (PlanarState.STATUS_TRACKING, PlanarState.STATUS_DEGRADED)
            if s.status == PlanarState.STATUS_DEGRADED:
                self.assertTrue(s.status_text, "degraded without a reason")
        for o in odometry:
            t = o.header.stamp.to_sec()
            if t >= t0 + settle_s and truth.covers(t):
                err_h.append(o.pose.pose.position.z - truth.at(t)[2])

        self.assertGreater(len(err_d), 0.5 * n_images * (duration_s - settle_s) / duration_s)
        rmse_d = float(np.sqrt(np.mean(np.square(err_d))))
        rmse_v = float(np.sqrt(np.mean(np.square(err_v))))
        rmse_h = float(np.sqrt(np.mean(np.square(err_h))))
        mean_d = float(np.mean([truth.at(s.header.stamp.to_sec())[0] for s in states if truth.covers(s.header.stamp.to_sec())]))
        summary = ("preset %s, %d estimates, evaluated %d from %.1f s: distance RMSE %.4f m (mean distance %.2f m), "
                   "velocity RMSE %.4f m/s, odometry height RMSE %.4f m, tracking %d/%d"
                   % (preset, len(states), len(err_d), settle_s, rmse_d, mean_d, rmse_v, rmse_h, tracking, len(err_d)))
        rospy.loginfo(summary)
        print("\n[diekf rostest] " + summary)
        # Converged on every evaluated frame; 'degraded' (a consistency check failed, e.g. an update gated at the
        # flight's fastest dash) is allowed, but most frames must pass every check.
        self.assertEqual(converged, len(err_d), "filter not converged (tracking or degraded) on every evaluated frame")
        self.assertGreaterEqual(tracking, 0.5 * len(err_d), "filter degraded on most frames")
        self.assertLess(rmse_d, tol_d, summary)
        self.assertLess(rmse_v, tol_v, summary)
        self.assertLess(rmse_h, tol_h, summary)


if __name__ == "__main__":
    rospy.init_node("replay_convergence_test")
    rostest.rosrun("diekf", "replay_convergence", ReplayConvergence, sys.argv)
