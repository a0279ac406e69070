#!/usr/bin/env python3
"""The install space works on its own: what `catkin_make install` (or a Debian package built from it) gives.

Driver (run by `make test` through rosunit, in the devel environment): installs the already-built build directory
into a temporary folder (`cmake --install BUILD` with DESTDIR: nothing is rebuilt, nothing is written to the
workspace's own install prefix), checks the installed layout, removes this build's own devel space from the
workspaces the install space chains (catkin records the CMAKE_PREFIX_PATH of the configure step, and `make test`
configures with the devel space sourced; a release build has no devel space), then runs this same file with
`--inside` in a clean environment (env -i) where only the temporary install space's setup.bash is sourced. There it checks that
nothing of the devel space or the source tree is visible, that every installed binary finds its libraries,
that rosrun resolves the executables to the install space, and then, with the installed tools only:
  - simulates a short bag (diekf_simulate),
  - runs diekf_bag_runner on it with its default (installed) config and checks estimates.csv and evaluation.json,
  - starts launch/mynteye.launch (own nodelet manager, the nodelet loaded from nodelet_plugins.xml) on its own
    ROS master, replays the bag with rosbag play and checks that ~state and ~odometry are published and finite,
  - builds a small downstream CMake package against diekf_core (find_package(catkin COMPONENTS diekf)).

By hand, from a sourced devel space after a build:
    python3 test/install/test_install_space.py --text --build-dir=WS/build --devel-dir=WS/devel
"""
import csv
import json
import math
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import unittest

PACKAGE = "diekf"
HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE_DIR = os.path.dirname(os.path.dirname(HERE))
OPTIONS = {"build-dir": None, "devel-dir": None, "keep": None}

LIBRARIES = ["libdiekf_core.so", "libdiekf_sim.so", "libdiekf_ros_helpers.so", "libdiekf_nodelet.so",
             "libdiekf_mynteye_standin.so"]
EXECUTABLES = ["diekf_node", "diekf_bag_runner", "diekf_replay", "diekf_simulate", "diekf_import",
               "mynteye_standin_node"]
SCRIPTS = ["load_nodelet_after.py", "plot_results.py", "calibration_ensemble.py"]  # installed programs that are not ELF files
SHARE_FILES = ["package.xml", "nodelet_plugins.xml", "launch/mynteye.launch", "launch/replay.launch",
               "launch/mynteye_driver.launch", "launch/mynteye_standin.launch",
               "launch/include/mynteye_driver_params.launch", "launch/include/mynteye_standin_device.launch",
               "config/estimator.yaml", "config/mynteye.yaml", "rviz/diekf.rviz", "msg/PlanarState.msg",
               "cmake/diekfConfig.cmake"]
HEADERS = ["diekf/estimator.h", "diekf/param_source.h", "diekf/params.h", "diekf/types.h", "diekf/ros/conversions.h",
           "diekf/PlanarState.h"]
# Environment variables passed into the clean environment (sanitizer settings of `make sanitize`).
PASS_THROUGH = ["ASAN_OPTIONS", "UBSAN_OPTIONS", "LSAN_OPTIONS", "TMPDIR"]


def log(msg):
    sys.stderr.write("[install_space] %s\n" % msg)
    sys.stderr.flush()


def run(cmd, timeout, env=None, cwd=None):
    """Runs cmd; returns (exit code, combined output)."""
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                          timeout=timeout, env=env, cwd=cwd)
    return proc.returncode, proc.stdout.decode(errors="replace")


def inside(path, directory):
    path, directory = os.path.realpath(path), os.path.realpath(directory)
    return path == directory or path.startswith(directory.rstrip("/") + "/")


# ------------------------------------------------------------------------------------------------------------
# Driver: install into a temporary folder, check the layout, run the checks below in a clean environment.
# ------------------------------------------------------------------------------------------------------------
class InstallSpace(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="diekf_install_test_")
        cls.destdir = os.path.join(cls.tmp, "root")
        build_dir = OPTIONS["build-dir"]
        prefix = None
        with open(os.path.join(build_dir, "CMakeCache.txt")) as f:
            for line in f:
                if line.startswith("CMAKE_INSTALL_PREFIX:"):
                    prefix = line.split("=", 1)[1].strip()
        cls.install_prefix = prefix
        cls.prefix = os.path.join(cls.destdir, prefix.lstrip("/")) if prefix else None
        env = dict(os.environ, DESTDIR=cls.destdir)
        start = time.time()
        cls.install_rc, cls.install_log = run(["cmake", "--install", build_dir], timeout=600, env=env)
        log("cmake --install into %s: exit %d, %.1f s" % (cls.destdir, cls.install_rc, time.time() - start))
        cls.parents_dropped = None
        if cls.install_rc == 0:
            cls.parents_dropped = drop_own_parents(os.path.join(cls.prefix, "_setup_util.py"), forbidden_dirs())

    @classmethod
    def tearDownClass(cls):
        if OPTIONS["keep"]:
            log("kept " + cls.tmp)
        else:
            shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_1_layout(self):
        self.assertIsNotNone(self.install_prefix, "no CMAKE_INSTALL_PREFIX in the build directory's cache")
        self.assertEqual(self.install_rc, 0, self.install_log[-3000:])
        # Nothing may land outside DESTDIR (catkin installs its setup files to an absolute destination).
        self.assertTrue(os.path.isfile(os.path.join(self.prefix, "setup.bash")), self.install_log[-3000:])
        for lib in LIBRARIES:
            self.assertTrue(os.path.isfile(os.path.join(self.prefix, "lib", lib)), lib)
        for exe in EXECUTABLES + SCRIPTS:
            path = os.path.join(self.prefix, "lib", PACKAGE, exe)
            self.assertTrue(os.path.isfile(path) and os.access(path, os.X_OK), path)
        for f in SHARE_FILES:
            self.assertTrue(os.path.isfile(os.path.join(self.prefix, "share", PACKAGE, f)), f)
        for h in HEADERS:
            self.assertTrue(os.path.isfile(os.path.join(self.prefix, "include", h)), h)
        # The plugin description names libraries that are installed.
        with open(os.path.join(self.prefix, "share", PACKAGE, "nodelet_plugins.xml")) as f:
            xml = f.read()
        libs = [part.split('"', 1)[0] for part in xml.split('library path="')[1:]]
        self.assertEqual(len(libs), 2, xml)
        for lib in libs:
            self.assertTrue(os.path.isfile(os.path.join(self.prefix, lib + ".so")), lib)

    def test_1_parents(self):
        self.assertIsNotNone(self.parents_dropped, "no parent workspace list in the installed _setup_util.py")
        log("parent workspaces of this build dropped from the install space: %s" % (self.parents_dropped or "none"))

    def test_2_works_alone(self):
        self.assertEqual(self.install_rc, 0, self.install_log[-3000:])
        env = {"PATH": "/usr/bin:/bin", "HOME": os.path.join(self.tmp, "home"), "LANG": "C.UTF-8",
               "ROS_HOME": os.path.join(self.tmp, "ros_home"), "PYTHONNOUSERSITE": "1"}
        for k in PASS_THROUGH:
            if k in os.environ:
                env[k] = os.environ[k]
        os.makedirs(env["HOME"])
        forbidden = forbidden_dirs()
        script = ('source "$1/setup.bash" && shift && exec python3 "$@"')
        cmd = ["env", "-i"] + ["%s=%s" % kv for kv in env.items()] + [
            "bash", "--noprofile", "--norc", "-c", script, "bash", self.prefix, os.path.abspath(__file__),
            "--inside", "--prefix=" + self.prefix, "--work=" + os.path.join(self.tmp, "work")] + [
            "--forbid=" + d for d in forbidden]
        start = time.time()
        rc, out = run(cmd, timeout=900)
        log("checks in the install space's environment: exit %d, %.1f s\n%s" % (rc, time.time() - start, out))
        self.assertEqual(rc, 0, out[-6000:])
        self.assertIn("ALL INSTALL-SPACE CHECKS PASSED", out)


def forbidden_dirs():
    """This build's devel space, build directory and sources: none may be visible from the install space."""
    return [d for d in (OPTIONS["devel-dir"], OPTIONS["build-dir"], SOURCE_DIR) if d]


def drop_own_parents(setup_util, forbidden):
    """An install space chains the workspaces that CMAKE_PREFIX_PATH held when the build was configured (catkin
    bakes them into _setup_util.py). `make test` configures with the devel space sourced, so this build's own
    devel space is one of them; a release build (e.g. a Debian package) is configured without it. Removes the
    entries inside `forbidden` from the installed copy; returns them, or None when the list is not found."""
    pattern = re.compile(r"^(\s*CMAKE_PREFIX_PATH = r')([^']*)('\.split\(';'\))", re.M)
    with open(setup_util) as f:
        text = f.read()
    match = pattern.search(text)
    if not match:
        return None
    entries = [e for e in match.group(2).split(";") if e]
    dropped = [e for e in entries if any(inside(e, d) for d in forbidden)]
    kept = [e for e in entries if e not in dropped]
    text = text[:match.start(2)] + ";".join(kept) + text[match.end(2):]
    with open(setup_util, "w") as f:
        f.write(text)
    return dropped


# ------------------------------------------------------------------------------------------------------------
# Inside: only the install space is sourced.
# ------------------------------------------------------------------------------------------------------------
def check(condition, message):
    if not condition:
        raise AssertionError(message)


def finite(values):
    return all(math.isfinite(v) for v in values)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def inside_main(prefix, work, forbidden):
    prefix = os.path.realpath(prefix)
    os.makedirs(work)
    share = os.path.join(prefix, "share", PACKAGE)
    libexec = os.path.join(prefix, "lib", PACKAGE)

    # 1. Nothing of the devel space or the source tree is visible.
    for var in ("ROS_PACKAGE_PATH", "CMAKE_PREFIX_PATH", "LD_LIBRARY_PATH", "PYTHONPATH", "PATH", "PKG_CONFIG_PATH"):
        for entry in filter(None, os.environ.get(var, "").split(":")):
            for d in forbidden:
                check(not inside(entry, d), "%s contains %s (from %s)" % (var, entry, d))
    rc, out = run(["rospack", "find", PACKAGE], 60)
    check(rc == 0 and os.path.realpath(out.strip()) == os.path.realpath(share), "rospack find diekf: " + out)
    log("environment: only %s" % prefix)

    # 2. Every installed binary finds its libraries, the package's own in the install space.
    for path in [os.path.join(prefix, "lib", l) for l in LIBRARIES] + [os.path.join(libexec, e) for e in EXECUTABLES]:
        rc, out = run(["ldd", path], 60)
        check(rc == 0 and "not found" not in out, "ldd %s:\n%s" % (path, out))
        for line in out.split("\n"):
            if line.strip().startswith("libdiekf_"):
                resolved = line.split("=>", 1)[1].strip().split(" ")[0]
                check(inside(resolved, prefix), "%s: %s" % (path, line.strip()))
    log("ldd: every library found")

    # 3. rosrun and the message module come from the install space.
    for exe in EXECUTABLES + SCRIPTS:
        rc, out = run(["rosrun", "--prefix", "echo", PACKAGE, exe], 120)
        last = out.strip().split("\n")[-1] if out.strip() else ""
        check(rc == 0 and last and os.path.realpath(last) == os.path.realpath(os.path.join(libexec, exe)),
              "rosrun %s %s resolves to '%s'" % (PACKAGE, exe, out.strip()))
    import diekf.msg
    check(inside(diekf.msg.__file__, prefix), "diekf.msg from " + diekf.msg.__file__)
    log("rosrun and diekf.msg: install space")

    # 4. A short simulated bag from the installed simulator.
    seq = os.path.join(work, "seq")
    rc, out = run([os.path.join(libexec, "diekf_simulate"), "--preset", "flight1", "--duration", "4", "--seed", "3",
                   "--output", seq], 300)
    check(rc == 0, "diekf_simulate: " + out[-3000:])
    bag, camchain, imu = (os.path.join(seq, f) for f in ("sequence.bag", "camchain.yaml", "imu.yaml"))
    check(all(os.path.isfile(p) for p in (bag, camchain, imu)), "diekf_simulate wrote " + str(os.listdir(seq)))
    log("diekf_simulate: %s" % out.strip().split("\n")[-1][:200])

    # 5. The installed offline runner, with its default config: the installed one.
    run_dir = os.path.join(work, "run")
    rc, out = run(["rosrun", PACKAGE, "diekf_bag_runner", "--bag", bag, "--camchain", camchain, "--imu", imu,
                   "--output", run_dir], 300)
    check(rc == 0, "diekf_bag_runner: " + out[-3000:])
    check(os.path.join(share, "config", "estimator.yaml") in out,
          "diekf_bag_runner did not use the installed config/estimator.yaml: " + out[-2000:])
    with open(os.path.join(run_dir, "estimates.csv")) as f:
        rows = list(csv.DictReader(f))
    check(len(rows) >= 60, "estimates.csv: %d rows for 4 s at 30 Hz" % len(rows))
    for r in rows:
        check(finite(float(r[k]) for k in ("t", "d", "h", "vx", "vy", "vz", "sigma_d")), "non-finite row %s" % r)
    with open(os.path.join(run_dir, "evaluation.json")) as f:
        ev = json.load(f)
    check(ev["frames_total"] >= 60 and ev["frames"] >= 1 and not ev["diverged"] and
          math.isfinite(ev["rmse_distance_m"]) and ev["rmse_distance_m"] < 0.5,
          "evaluation.json: %s" % ev)
    log("diekf_bag_runner: %d estimates, distance RMSE %.3f m" % (len(rows), ev["rmse_distance_m"]))

    # 6. The nodelet from the installed launch file and plugin description, fed by rosbag play.
    port = free_port()
    os.environ["ROS_MASTER_URI"] = "http://127.0.0.1:%d" % port
    os.environ["ROS_IP"] = "127.0.0.1"
    launch = subprocess.Popen(["roslaunch", "-p", str(port), PACKAGE, "mynteye.launch",
                               "camchain:=" + camchain, "imu_calib:=" + imu, "output:=log"],
                              stdout=open(os.path.join(work, "roslaunch.log"), "w"), stderr=subprocess.STDOUT)
    try:
        nodelet_results(launch, bag, work)
    finally:
        if launch.poll() is None:
            launch.send_signal(2)
            try:
                launch.wait(timeout=30)
            except subprocess.TimeoutExpired:
                launch.kill()

    # 7. A downstream package builds against diekf_core and its message.
    downstream(work, prefix)
    print("ALL INSTALL-SPACE CHECKS PASSED")


def wait_for(predicate, timeout_s):
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        if predicate():
            return True
        time.sleep(0.2)
    return predicate()


def nodelet_results(launch, bag, work):
    import rosgraph
    import rospy
    from diekf.msg import PlanarState
    from nav_msgs.msg import Odometry

    def launch_log():
        with open(os.path.join(work, "roslaunch.log")) as f:
            return f.read()[-3000:]

    master = rosgraph.Master("/install_space_check")
    check(wait_for(lambda: launch.poll() is None and master.is_online(), 60),
          "no ROS master from roslaunch:\n" + launch_log())
    rospy.init_node("install_space_check", disable_signals=True)
    states, odoms = [], []
    rospy.Subscriber("/diekf/state", PlanarState, states.append, queue_size=1000)
    rospy.Subscriber("/diekf/odometry", Odometry, odoms.append, queue_size=1000)

    def subscribed():
        _, subscribers, _ = master.getSystemState()
        names = {name for name, nodes in subscribers if nodes}
        return {"/mynteye/imu/data_raw", "/mynteye/left/image_raw"} <= names

    check(wait_for(subscribed, 90), "the nodelet did not subscribe to the MYNT EYE topics:\n" + launch_log())
    check(wait_for(lambda: any(n == "/diekf/state" and nodes for n, nodes in master.getSystemState()[0]), 30),
          "no publisher of /diekf/state")
    time.sleep(1.0)  # let our subscriptions connect
    rc, out = run(["rosbag", "play", "--quiet", bag], 300)
    check(rc == 0, "rosbag play: " + out)
    wait_for(lambda: False, 3.0)  # the last images are still being processed
    check(launch.poll() is None, "roslaunch ended:\n" + launch_log())
    check(len(states) >= 10, "%d ~state messages for a 4 s bag:\n%s" % (len(states), launch_log()))
    check(len(odoms) >= 10, "%d ~odometry messages" % len(odoms))
    for s in states:
        check(finite([s.distance, s.height, s.inverse_distance, s.sigma_distance] + list(s.covariance)),
              "non-finite ~state: %s" % s)
    for o in odoms:
        p, q = o.pose.pose.position, o.pose.pose.orientation
        check(finite([p.x, p.y, p.z, q.x, q.y, q.z, q.w] + list(o.pose.covariance) + list(o.twist.covariance)),
              "non-finite ~odometry: %s" % o)
    check(0.05 < states[-1].distance < 10.0, "last distance %.3f m" % states[-1].distance)
    log("nodelet: %d ~state, %d ~odometry messages, last distance %.3f m"
        % (len(states), len(odoms), states[-1].distance))
    rospy.signal_shutdown("done")


DOWNSTREAM_CMAKE = """cmake_minimum_required(VERSION 3.10)
project(diekf_downstream)
set(CMAKE_CXX_STANDARD 17)
find_package(catkin REQUIRED COMPONENTS diekf)
include_directories(${catkin_INCLUDE_DIRS})
add_executable(use_core main.cpp)
target_link_libraries(use_core ${catkin_LIBRARIES})
"""
DOWNSTREAM_MAIN = """#include <diekf/PlanarState.h>
#include <diekf/estimator.h>
#include <diekf/param_source.h>
#include <iostream>
int main() {
  diekf::PlanarState msg;
  msg.status = diekf::PlanarState::STATUS_TRACKING;
  std::cout << diekf::estimatorParamKeys().size() << " keys, status " << int(msg.status) << std::endl;
  return diekf::estimatorParamKeys().empty() ? 1 : 0;
}
"""


def downstream(work, prefix):
    src = os.path.join(work, "downstream")
    build = os.path.join(src, "build")
    os.makedirs(build)
    with open(os.path.join(src, "CMakeLists.txt"), "w") as f:
        f.write(DOWNSTREAM_CMAKE)
    with open(os.path.join(src, "main.cpp"), "w") as f:
        f.write(DOWNSTREAM_MAIN)
    cmake = ["cmake", "-DCMAKE_BUILD_TYPE=Release"]
    # A build of the library under the sanitizers (make sanitize) needs a downstream built the same way: the
    # sanitizer runtime must be the first library of the program.
    _, ldd_core = run(["ldd", os.path.join(prefix, "lib", "libdiekf_core.so")], 60)
    if "libasan" in ldd_core:
        cmake.append("-DCMAKE_CXX_FLAGS=-fsanitize=address,undefined")
    rc, out = run(cmake + [src], 300, cwd=build)
    check(rc == 0, "downstream cmake:\n" + out[-4000:])
    rc, out = run(["make", "-j1"], 600, cwd=build)
    check(rc == 0, "downstream build:\n" + out[-4000:])
    rc, out = run([os.path.join(build, "use_core")], 60)
    check(rc == 0 and " keys, status 1" in out, "downstream program: " + out)
    log("downstream package: built and ran against diekf_core (%s)" % out.strip())


def main():
    args = []
    forbidden = []
    inside_mode = False
    for a in sys.argv[1:]:
        if a == "--inside":
            inside_mode = True
        elif a.startswith("--forbid="):
            forbidden.append(a.split("=", 1)[1])
        elif a == "--keep":
            OPTIONS["keep"] = True
        elif a.startswith("--") and "=" in a and a[2:].split("=", 1)[0] in ("build-dir", "devel-dir", "prefix",
                                                                          "work"):
            key, value = a[2:].split("=", 1)
            OPTIONS[key] = value
        else:
            args.append(a)
    if inside_mode:
        inside_main(OPTIONS["prefix"], OPTIONS["work"], forbidden)
        return
    if not OPTIONS["build-dir"]:
        sys.exit("usage: test_install_space.py --build-dir=BUILD [--devel-dir=DEVEL] [--keep] [--text]")
    sys.argv = [sys.argv[0]] + args
    if "--text" in args or not any(a.startswith("--gtest_output") for a in args):
        unittest.main(argv=[sys.argv[0]], verbosity=2)
    else:
        import rosunit
        rosunit.unitrun(PACKAGE, "install_space", InstallSpace)


if __name__ == "__main__":
    main()
