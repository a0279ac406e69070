#!/usr/bin/env python3
"""Offline check of rviz/diekf.rviz against the nodelet's interface: no rviz, no ROS master, no display.

Every topic a display of the rviz layout subscribes to must be one the nodelet advertises (read from
src/ros/estimator_nodelet.cpp, cross-checked with the published-topics table of docs/ros.md) or one of its inputs
(config/mynteye.yaml), with the message type the display expects; the fixed frame and every frame the layout names
must be one of the frame parameters' defaults; the marker namespaces it lists must be ones the nodelet sends; every
visualisation output must be shown; the launch files must offer rviz:=true with this layout. The last test feeds
the checker broken layouts and requires it to complain, so that a checker that accepts anything fails too.

Run by `make test` (catkin run_tests, JUnit XML through rosunit); alone: python3 test/ros/test_rviz_config.py --text
"""
import copy
import os
import re
import sys
import unittest
import xml.etree.ElementTree as ET

import yaml

PKG_DIR = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
RVIZ_FILE = os.path.join(PKG_DIR, "rviz", "diekf.rviz")
NODELET_SOURCE = os.path.join(PKG_DIR, "src", "ros", "estimator_nodelet.cpp")
MARKER_SOURCE = os.path.join(PKG_DIR, "src", "ros", "conversions.cpp")
SETTINGS_FILE = os.path.join(PKG_DIR, "config", "mynteye.yaml")
DOCS_FILE = os.path.join(PKG_DIR, "docs", "ros.md")
LAUNCH_FILES = [os.path.join(PKG_DIR, "launch", name) for name in ("mynteye.launch", "replay.launch")]

# rviz display class -> message type it subscribes to. A display class missing here (and from NO_TOPIC) fails the
# test: add it with its type rather than letting it through unchecked.
DISPLAY_TYPES = {
    "rviz/Odometry": "nav_msgs/Odometry",
    "rviz/Path": "nav_msgs/Path",
    "rviz/MarkerArray": "visualization_msgs/MarkerArray",
    "rviz/Marker": "visualization_msgs/Marker",
    "rviz/Image": "sensor_msgs/Image",
    "rviz/Camera": "sensor_msgs/Image",
    "rviz/Range": "sensor_msgs/Range",
    "rviz/Pose": "geometry_msgs/PoseStamped",
    "rviz/PoseWithCovariance": "geometry_msgs/PoseWithCovarianceStamped",
    "rviz/Imu": "sensor_msgs/Imu",
}
NO_TOPIC = {"rviz/Grid", "rviz/TF", "rviz/Axes"}
TOPIC_KEYS = ("Topic", "Marker Topic", "Image Topic")
# Outputs that exist for visualisation and must be shown (plus the input image).
MUST_SHOW = ("odometry", "path", "markers", "residual_image")


def read(path):
    with open(path) as f:
        return f.read()


def node_name():
    """Name of the nodelet in the launch files (its outputs live under /NAME/)."""
    root = ET.parse(LAUNCH_FILES[0]).getroot()
    for arg in root.iter("arg"):
        if arg.get("name") == "name":
            return arg.get("default")
    raise AssertionError("launch/mynteye.launch has no 'name' argument")


def nodelet_outputs(source, node):
    """{resolved topic: message type} of the publishers the nodelet advertises in its private namespace."""
    out = {}
    for cpp_type, name in re.findall(r"pnh_\.advertise<([\w:]+)>\(\s*\"(\w+)\"", source):
        out["/%s/%s" % (node, name)] = cpp_type.replace("::", "/")
    for name in re.findall(r"pit_->advertise\(\s*\"(\w+)\"", source):  # image_transport: sensor_msgs/Image
        out["/%s/%s" % (node, name)] = "sensor_msgs/Image"
    return out


def documented_outputs(docs, node):
    """{resolved topic: type} from the `~topic` rows of the published-topics table in docs/ros.md."""
    section = docs.split("## Published topics", 1)[1].split("\n## ", 1)[0]
    return {"/%s/%s" % (node, name): msg_type
            for name, msg_type in re.findall(r"^\| `~(\w+)` \| `([\w/]+)`", section, re.M)}


def settings():
    with open(SETTINGS_FILE) as f:
        return yaml.safe_load(f)


def input_topics(s):
    topics = {s["image_topic"]: "sensor_msgs/Image", s["imu_topic"]: "sensor_msgs/Imu"}
    if s.get("camera_info_topic"):
        topics[s["camera_info_topic"]] = "sensor_msgs/CameraInfo"
    return topics


def marker_namespaces(source):
    """Namespaces the marker builder uses (first string argument of its marker()/arrow() helpers)."""
    return set(re.findall(r"\b(?:marker|arrow)\(\s*\"(\w+)\"", source))


def check_config(cfg, outputs, inputs, frames, namespaces, image_topic):
    """Every problem of an rviz layout (parsed YAML) as a list of messages; empty when it is right."""
    errors = []
    manager = cfg.get("Visualization Manager") or {}
    fixed = (manager.get("Global Options") or {}).get("Fixed Frame")
    if fixed not in frames:
        errors.append("fixed frame %r is not one of the frame parameters' defaults %s" % (fixed, sorted(frames)))
    known = dict(outputs)
    known.update(inputs)
    shown = set()
    names = []
    for display in manager.get("Displays") or []:
        cls, name = display.get("Class"), display.get("Name")
        names.append(name)
        where = "display %r (%s)" % (name, cls)
        if not cls or not name:
            errors.append("a display without Class or Name: %r" % display)
            continue
        topics = [display[k] for k in TOPIC_KEYS if k in display]
        if cls in NO_TOPIC:
            if topics:
                errors.append("%s should not subscribe to a topic" % where)
        elif cls not in DISPLAY_TYPES:
            errors.append("%s: unknown display class (add its message type to this test)" % where)
        elif len(topics) != 1:
            errors.append("%s needs exactly one topic key, has %d" % (where, len(topics)))
        elif topics[0] not in known:
            errors.append("%s subscribes to %s, which the nodelet does not publish (it publishes %s; inputs %s)"
                          % (where, topics[0], sorted(outputs), sorted(inputs)))
        elif known[topics[0]] != DISPLAY_TYPES[cls]:
            errors.append("%s expects %s but %s carries %s" % (where, DISPLAY_TYPES[cls], topics[0], known[topics[0]]))
        elif cls == "rviz/Range" and known[topics[0]] == "sensor_msgs/Range" and topics[0] in outputs:
            # rviz draws a Range as a cone along the x axis of its frame; ~height is in the camera's optical frame
            # (z along the optical axis) and measured along gravity: the cone would point sideways.
            errors.append("%s would draw %s as a cone along the camera's x axis (sideways); the height is shown "
                          "by the `height` marker" % (where, topics[0]))
        else:
            shown.add(topics[0])
        ref = display.get("Reference Frame")
        if ref is not None and ref not in frames and ref != "<Fixed Frame>":
            errors.append("%s: reference frame %r is not published" % (where, ref))
        if cls == "rviz/MarkerArray" or cls == "rviz/Marker":
            unknown = set((display.get("Namespaces") or {}).keys()) - namespaces
            if unknown:
                errors.append("%s lists marker namespaces the nodelet never sends: %s" % (where, sorted(unknown)))
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        errors.append("display names must be unique (rviz keys panels and window state by name): %s" % duplicated)
    for name in MUST_SHOW:
        topic = [t for t in outputs if t.endswith("/" + name)]
        if topic and topic[0] not in shown:
            errors.append("output %s is not shown" % topic[0])
    if image_topic not in shown:
        errors.append("the input image %s is not shown" % image_topic)
    view = ((manager.get("Views") or {}).get("Current")) or {}
    target = view.get("Target Frame")
    if target not in (None, "", "<Fixed Frame>") and target not in frames:
        errors.append("view target frame %r is not published" % target)
    return errors


class RvizConfig(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        with open(RVIZ_FILE) as f:
            cls.cfg = yaml.safe_load(f)
        cls.node = node_name()
        cls.outputs = nodelet_outputs(read(NODELET_SOURCE), cls.node)
        cls.settings = settings()
        cls.inputs = input_topics(cls.settings)
        cls.frames = {cls.settings[k] for k in ("odom_frame", "base_frame", "camera_frame")}
        cls.namespaces = marker_namespaces(read(MARKER_SOURCE))

    def check(self, cfg):
        return check_config(cfg, self.outputs, self.inputs, self.frames, self.namespaces,
                            self.settings["image_topic"])

    def test_sources_parsed(self):
        # If the nodelet or the marker builder is rewritten so that these patterns no longer match, the other
        # tests would compare against nothing: fail here instead.
        n = "/" + self.node + "/"
        for topic in ("state", "odometry", "twist", "height", "path", "markers", "residual_image"):
            self.assertIn(n + topic, self.outputs)
        self.assertEqual(self.outputs[n + "odometry"], "nav_msgs/Odometry")
        self.assertEqual(self.outputs[n + "residual_image"], "sensor_msgs/Image")
        self.assertTrue({"normal", "gravity", "velocity", "plane"} <= self.namespaces, self.namespaces)

    def test_docs_list_the_nodelet_outputs(self):
        self.assertEqual(documented_outputs(read(DOCS_FILE), self.node), self.outputs)

    def test_layout_matches_the_interface(self):
        self.assertEqual(self.check(self.cfg), [])

    def test_fixed_frame_is_odom(self):
        # docs/ros.md: the layout's fixed frame is the odometry frame (x, y, z of base_link, the path in it).
        fixed = self.cfg["Visualization Manager"]["Global Options"]["Fixed Frame"]
        self.assertEqual(fixed, self.settings["odom_frame"])
        self.assertIn("fixed frame `%s`" % fixed, read(DOCS_FILE))

    def test_launch_files_offer_rviz(self):
        for path in LAUNCH_FILES:
            root = ET.parse(path).getroot()
            args = {a.get("name"): a.get("default") for a in root.iter("arg")}
            self.assertEqual(args.get("rviz"), "false", path)
            self.assertEqual(args.get("rviz_config"), "$(find diekf)/rviz/diekf.rviz", path)
            nodes = [n for n in root.iter("node") if n.get("pkg") == "rviz"]
            self.assertEqual(len(nodes), 1, path)
            self.assertEqual(nodes[0].get("if"), "$(arg rviz)", path)
            self.assertIn("-d $(arg rviz_config)", nodes[0].get("args"), path)

    def test_checker_catches_broken_layouts(self):
        def displays(cfg):
            return cfg["Visualization Manager"]["Displays"]

        def by_class(cfg, cls):
            return [d for d in displays(cfg) if d["Class"] == cls][0]

        def broken(mutate):
            cfg = copy.deepcopy(self.cfg)
            mutate(cfg)
            return " | ".join(self.check(cfg))

        n = "/" + self.node + "/"
        self.assertIn("does not publish",
                      broken(lambda c: by_class(c, "rviz/Odometry").update({"Topic": n + "odom"})))
        self.assertIn("expects nav_msgs/Odometry",
                      broken(lambda c: by_class(c, "rviz/Odometry").update({"Topic": n + "state"})))
        self.assertIn("expects sensor_msgs/Range",
                      broken(lambda c: displays(c).append({"Class": "rviz/Range", "Name": "r", "Topic": n + "twist"})))
        self.assertIn("sideways",
                      broken(lambda c: displays(c).append({"Class": "rviz/Range", "Name": "h", "Topic": n + "height"})))
        self.assertIn("fixed frame",
                      broken(lambda c: c["Visualization Manager"]["Global Options"].update({"Fixed Frame": "map"})))
        self.assertIn("unknown display class",
                      broken(lambda c: displays(c).append({"Class": "rviz/Foo", "Name": "f", "Topic": n + "path"})))
        self.assertIn("is not shown",
                      broken(lambda c: displays(c).remove(by_class(c, "rviz/Path"))))
        self.assertIn("marker namespaces",
                      broken(lambda c: by_class(c, "rviz/MarkerArray").update({"Namespaces": {"arrows": True}})))
        self.assertIn("view target frame",
                      broken(lambda c: c["Visualization Manager"]["Views"]["Current"].update({"Target Frame": "x"})))
        self.assertIn("unique", broken(lambda c: displays(c).append(copy.deepcopy(by_class(c, "rviz/Path")))))


if __name__ == "__main__":
    if "--text" in sys.argv or not any(a.startswith("--gtest_output") for a in sys.argv):
        unittest.main(argv=[sys.argv[0]], verbosity=2)
    else:
        import rosunit
        rosunit.unitrun("diekf", "rviz_config", RvizConfig)
