"""Helpers shared by the evaluation scripts (benchmark_table.py, texture_sweep.py): locating the built tools and
running one of them with its output in a log file."""
import os
import subprocess
import sys


def find_bin_dir(script_name):
    """Folder holding diekf_simulate and diekf_bag_runner: $DIEKF_BIN_DIR, else $DIEKF_WS/devel/lib/diekf, else the
    package's own workspace (.ws). Exits with a message naming `script_name` when none has both tools."""
    pkg_dir = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    candidates = []
    if os.environ.get("DIEKF_BIN_DIR"):
        candidates.append(os.environ["DIEKF_BIN_DIR"])
    if os.environ.get("DIEKF_WS"):
        candidates.append(os.path.join(os.environ["DIEKF_WS"], "devel", "lib", "diekf"))
    candidates.append(os.path.join(pkg_dir, ".ws", "devel", "lib", "diekf"))
    for c in candidates:
        if os.path.isfile(os.path.join(c, "diekf_bag_runner")) and os.path.isfile(os.path.join(c, "diekf_simulate")):
            return c
    sys.exit("%s: diekf_simulate / diekf_bag_runner not found in %s; build first (make build) "
             "or set DIEKF_BIN_DIR" % (script_name, ", ".join(candidates)))


def run(cmd, log_path):
    """Runs `cmd` with stdout and stderr into `log_path` (which starts with the command line); returns its exit code."""
    with open(log_path, "w") as log:
        log.write("$ " + " ".join(cmd) + "\n")
        log.flush()
        return subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
