#!/usr/bin/env python3
"""launch/px4_mavros.launch against the nodelet and mavros's topics (offline: no mavros, no master).

mavros is not a dependency of diekf, so the example launch file cannot be started here. What can go wrong without
anyone noticing is checked instead: the topics mavros's plugins subscribe to (from their source, mavros 1.x: the
odometry plugin `~odometry/out` of type nav_msgs/Odometry, sent as ODOMETRY with the velocity in the body frame;
the distance_sensor plugin's subscriber items `~distance_sensor/NAME` of type sensor_msgs/Range, configured by
`subscriber`, `id`, `orientation`) are remapped to outputs the nodelet advertises with those types (read from
src/ros/estimator_nodelet.cpp as test_rviz_config.py does); the distance sensor item is a downward subscriber;
diekf is started with its IMU-rate odometry; the frames mavros looks up (odom, base_link) are diekf's defaults.

Run by `make test` through rosunit; by hand: python3 test/ros/test_px4_launch.py --text
"""
import os
import sys
import unittest
import xml.etree.ElementTree as ET

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import test_rviz_config as rc  # noqa: E402

LAUNCH = os.path.join(rc.PKG_DIR, "launch", "px4_mavros.launch")
# mavros 1.x (mavros_extras): subscriber topics and types of the plugins the launch file feeds.
MAVROS_ODOMETRY = ("/mavros/odometry/out", "nav_msgs/Odometry")
MAVROS_DISTANCE_SENSOR_NS = "/mavros/distance_sensor/"


def arg_defaults(root):
    return {a.get("name"): a.get("default") for a in root.iter("arg") if a.get("default") is not None}


def resolve(text, args):
    """$(arg NAME) substitutions with the launch file's defaults."""
    while "$(arg " in text:
        start = text.index("$(arg ")
        end = text.index(")", start)
        text = text[:start] + args[text[start + 6:end].strip()] + text[end + 1:]
    return text


class Px4Launch(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        cls.root = ET.parse(LAUNCH).getroot()
        cls.args = arg_defaults(cls.root)
        cls.outputs = rc.nodelet_outputs(rc.read(rc.NODELET_SOURCE), rc.node_name())
        cls.remaps = {resolve(r.get("from"), cls.args): resolve(r.get("to"), cls.args) for r in cls.root.iter("remap")}

    def test_odometry_goes_to_mavros_odometry_plugin(self):
        topic, msg_type = MAVROS_ODOMETRY
        self.assertIn(topic, self.remaps, "no remap of mavros's %s" % topic)
        source = self.remaps[topic]
        self.assertEqual(self.outputs.get(source), msg_type, "%s is not a %s output of the nodelet (%s)" %
                         (source, msg_type, sorted(self.outputs)))
        self.assertTrue(source.endswith("/odometry_imu_rate"), source)
        includes = [i for i in self.root.iter("include") if "mynteye_driver.launch" in i.get("file")]
        self.assertEqual(len(includes), 1)
        passed = {a.get("name"): a.get("value") for a in includes[0].iter("arg")}
        self.assertEqual(passed.get("odometry_imu_rate"), "true", "the IMU-rate odometry is not switched on")
        # mavros rotates the message from its frame_id / child_frame_id into odom_ned / base_link_frd, which it
        # publishes under the names odom and base_link: diekf's defaults.
        settings = rc.settings()
        self.assertEqual((settings["odom_frame"], settings["base_frame"]), ("odom", "base_link"))

    def test_range_goes_to_a_downward_distance_sensor_item(self):
        items = [t for t in self.remaps if t.startswith(MAVROS_DISTANCE_SENSOR_NS)]
        self.assertEqual(len(items), 1, self.remaps)
        source = self.remaps[items[0]]
        self.assertEqual(self.outputs.get(source), "sensor_msgs/Range", source)
        self.assertTrue(source.endswith("/range"), "the along-the-body range, not ~height: %s" % source)
        name = items[0][len(MAVROS_DISTANCE_SENSOR_NS):]
        groups = [g for g in self.root.iter("group") if (g.get("ns") or "").strip("/") ==
                  ("mavros/distance_sensor/" + name)]
        self.assertEqual(len(groups), 1, "no parameters for the distance sensor item %s" % name)
        params = {p.get("name"): resolve(p.get("value"), self.args) for p in groups[0].iter("param")}
        self.assertEqual(params.get("subscriber"), "true")
        self.assertEqual(params.get("orientation"), "PITCH_270")  # pointing down
        self.assertTrue(params.get("id", "").isdigit(), params)
        self.assertTrue(0 < int(params.get("covariance", "0")) < 256, "uint8 covariance in cm: %s" % params)

    def test_mavros_started_for_px4(self):
        includes = [i.get("file") for i in self.root.iter("include")]
        self.assertTrue(any(f.endswith("mavros)/launch/px4.launch") for f in includes), includes)


if __name__ == "__main__":
    if "--text" in sys.argv or not any(a.startswith("--gtest_output") for a in sys.argv):
        unittest.main(argv=[sys.argv[0]], verbosity=2)
    else:
        import rosunit
        rosunit.unitrun("diekf", "px4_launch", Px4Launch)
