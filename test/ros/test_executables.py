#!/usr/bin/env python3
"""Every executable of the package resolves to exactly one file, the one in the sourced workspace, for roslaunch
(<node pkg="diekf" type=...>), for rosrun, and for the tests' own helper (diekf_rostest_utils.executable).

rosrun searches the catkin libexec folders *and* the package's source directory (find -L, following links); a
build tree inside the package directory therefore makes every executable ambiguous, and rosrun then stops at an
interactive "non-unique executable" prompt (with no terminal it runs an empty command). So the sourced workspace
and the build directory must lie outside the package directory. Build trees that an older Makefile left inside
the package directory (.ws, .ws-sanitize) are reported, not failed on: they are the user's to remove, and `make`
warns about them.

Run by `make test` through rosunit (JUnit XML); by hand, from a sourced workspace:
    python3 test/ros/test_executables.py --text [--build-dir=BUILD]
"""
import os
import subprocess
import sys
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import diekf_rostest_utils as util  # noqa: E402

PACKAGE = "diekf"
# Executables a build of the package always has (the tests' binaries and the benchmark come on top).
REQUIRED = ["diekf_node", "diekf_simulate", "diekf_import", "diekf_bag_runner", "diekf_replay"]
BUILD_DIR = None  # --build-dir: the catkin build directory (make test passes it)


def realpath(p):
    return os.path.realpath(p)


def inside(path, directory):
    path, directory = realpath(path), realpath(directory)
    return path == directory or path.startswith(directory.rstrip("/") + "/")


def package_dir():
    out = subprocess.run(["rospack", "find", PACKAGE], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         timeout=60, check=True).stdout.decode().strip()
    return out


def libexec_dirs():
    from catkin.find_in_workspaces import find_in_workspaces
    return find_in_workspaces(search_dirs=["libexec"], project=PACKAGE)


def package_executables():
    """Names of the executable files in the first workspace's libexec folder of the package."""
    dirs = libexec_dirs()
    if not dirs:
        return []
    return sorted(f for f in os.listdir(dirs[0])
                  if os.path.isfile(os.path.join(dirs[0], f)) and os.access(os.path.join(dirs[0], f), os.X_OK))


def rosrun_candidates(names, pkg_dir):
    """For each name, the files rosrun chooses from (its own search: the catkin libexec folders and the package
    directory, following links), in one walk."""
    pattern = []
    for n in names:
        pattern += (["-o"] if pattern else []) + ["-name", n]
    cmd = ["find", "-L"] + libexec_dirs() + [pkg_dir, "(", ] + pattern + [")", "-type", "f", "-perm", "/111",
                                             "!", "-regex", ".*%s/build/.*" % pkg_dir]
    out = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, timeout=300).stdout.decode()
    found = {n: set() for n in names}
    for p in out.split("\n"):
        if p and os.path.basename(p) in found:
            found[os.path.basename(p)].add(realpath(p))
    return {n: sorted(v) for n, v in found.items()}


def legacy_trees(pkg_dir):
    """Folders directly in the package directory that are catkin workspaces or build trees but hold none of the
    sourced workspaces (left over from an older Makefile or a manual build)."""
    active = libexec_dirs() + ([BUILD_DIR] if BUILD_DIR else [])
    trees = []
    for entry in sorted(os.listdir(pkg_dir)):
        d = os.path.join(pkg_dir, entry)
        if not os.path.isdir(d) or os.path.islink(d):
            continue
        is_tree = any(os.path.exists(os.path.join(d, m)) for m in
                      (".catkin_workspace", "CMakeCache.txt", os.path.join("devel", ".catkin"), ".catkin"))
        if is_tree and not any(inside(a, d) for a in active):
            trees.append(realpath(d))
    return trees


class Executables(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        cls.pkg_dir = package_dir()
        cls.names = package_executables()

    def test_required_executables_built(self):
        self.assertTrue(libexec_dirs(), "no sourced workspace has a lib/%s folder" % PACKAGE)
        for name in REQUIRED:
            self.assertIn(name, self.names)

    def test_workspace_outside_package_directory(self):
        for d in libexec_dirs() + ([BUILD_DIR] if BUILD_DIR else []):
            self.assertFalse(inside(d, self.pkg_dir),
                             "%s is inside the package directory %s: rosrun would find the executables twice"
                             % (d, self.pkg_dir))

    def test_helper_resolves_to_sourced_workspace(self):
        first = libexec_dirs()[0]
        for name in self.names:
            path = util.executable(name)
            self.assertIsNotNone(path, name)
            self.assertEqual(realpath(path), realpath(os.path.join(first, name)))

    def test_roslaunch_resolves_once(self):
        import roslib.packages
        import rospkg
        rospack = rospkg.RosPack()
        for name in self.names:
            found = roslib.packages.find_node(PACKAGE, name, rospack=rospack)
            self.assertEqual([realpath(p) for p in found], [realpath(util.executable(name))],
                             "roslaunch finds %s as %s" % (name, found))

    def test_rosrun_resolves_once(self):
        stale = legacy_trees(self.pkg_dir)
        if stale:
            sys.stderr.write("WARNING: build trees inside the package directory: %s; rosrun may ask which "
                             "executable to run until they are removed\n" % ", ".join(stale))
        all_candidates = rosrun_candidates(self.names, self.pkg_dir)
        for name in self.names:
            expected = realpath(util.executable(name))
            candidates = all_candidates[name]
            self.assertIn(expected, candidates, "rosrun does not see " + expected)
            unexplained = [c for c in candidates if c != expected and not any(inside(c, t) for t in stale)]
            self.assertEqual(unexplained, [], "rosrun %s %s finds more than one file" % (PACKAGE, name))
            if len(candidates) == 1 and name in REQUIRED:
                # rosrun itself, with no terminal: it prints the file it would run (empty when it would ask).
                proc = subprocess.run(["rosrun", "--prefix", "echo", PACKAGE, name], stdin=subprocess.DEVNULL,
                                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=120)
                lines = proc.stdout.decode(errors="replace").strip().split("\n")
                self.assertEqual(proc.returncode, 0, proc.stdout)
                self.assertEqual(realpath(lines[-1]) if lines[-1] else "", expected,
                                 "rosrun %s %s: %s" % (PACKAGE, name, proc.stdout))

    def test_checker_can_fail(self):
        # On a stand-in package directory (not the real one: others may be running rosrun from it): a file named
        # like an executable anywhere inside is a second rosrun candidate; only one in a build tree is stale.
        import shutil
        import tempfile
        name = "diekf_node"
        fake = realpath(tempfile.mkdtemp(prefix="diekf_fake_pkg_"))
        try:
            for sub in (os.path.join(".ws", "devel", "lib", PACKAGE), "misc"):
                os.makedirs(os.path.join(fake, sub))
                with open(os.path.join(fake, sub, name), "w") as f:
                    f.write("#!/bin/sh\n")
                os.chmod(os.path.join(fake, sub, name), 0o755)
            open(os.path.join(fake, ".ws", ".catkin_workspace"), "w").close()
            candidates = rosrun_candidates([name], fake)[name]
            self.assertIn(os.path.join(fake, ".ws", "devel", "lib", PACKAGE, name), candidates)
            self.assertIn(os.path.join(fake, "misc", name), candidates)
            self.assertEqual(legacy_trees(fake), [os.path.join(fake, ".ws")])
            self.assertTrue(inside(os.path.join(fake, "misc"), fake))
            self.assertFalse(inside(fake + "-ws", fake))
        finally:
            shutil.rmtree(fake, ignore_errors=True)


def main():
    global BUILD_DIR
    args = []
    for a in sys.argv[1:]:
        if a.startswith("--build-dir="):
            BUILD_DIR = a.split("=", 1)[1]
        else:
            args.append(a)
    sys.argv = [sys.argv[0]] + args
    if "--text" in args or not any(a.startswith("--gtest_output") for a in args):
        unittest.main(argv=[sys.argv[0]], verbosity=2)
    else:
        import rosunit
        rosunit.unitrun(PACKAGE, "executables", Executables)


if __name__ == "__main__":
    main()
