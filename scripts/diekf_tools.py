"""Helpers shared by the evaluation scripts (benchmark_table.py, texture_sweep.py): locating the built tools and
running one of them with its output in a log file."""
import os
import subprocess
import sys


def find_bin_dir(script_name, tools=("diekf_bag_runner", "diekf_simulate")):
    """Folder holding the `tools` (by default diekf_simulate and diekf_bag_runner), the first of: $DIEKF_BIN_DIR,
    $DIEKF_WS/devel/lib/diekf, this script's own folder (an install space puts the scripts next to the tools), the
    sourced catkin workspaces (catkin_find), the workspace `make build` uses (`make ws-path`). Exits with a message
    naming `script_name` when none has them all."""
    here = os.path.dirname(os.path.abspath(__file__))
    pkg_dir = os.path.dirname(here)
    candidates = []
    if os.environ.get("DIEKF_BIN_DIR"):
        candidates.append(os.environ["DIEKF_BIN_DIR"])
    if os.environ.get("DIEKF_WS"):
        candidates.append(os.path.join(os.environ["DIEKF_WS"], "devel", "lib", "diekf"))
    candidates.append(here)
    try:
        from catkin.find_in_workspaces import find_in_workspaces
        candidates += find_in_workspaces(search_dirs=["libexec"], project="diekf")
    except Exception:  # catkin's Python module missing or no workspace sourced
        pass
    if os.path.isfile(os.path.join(pkg_dir, "Makefile")):
        try:
            ws = subprocess.run(["make", "-s", "--no-print-directory", "-C", pkg_dir, "ws-path"],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, timeout=30).stdout.decode().strip()
            if ws:
                candidates.append(os.path.join(ws, "devel", "lib", "diekf"))
        except (OSError, subprocess.SubprocessError):
            pass
    for c in candidates:
        if all(os.path.isfile(os.path.join(c, tool)) for tool in tools):
            return c
    sys.exit("%s: %s not found in %s; build first (make build) "
             "or set DIEKF_BIN_DIR" % (script_name, " / ".join(tools), ", ".join(candidates)))


def run(cmd, log_path):
    """Runs `cmd` with stdout and stderr into `log_path` (which starts with the command line); returns its exit code."""
    with open(log_path, "w") as log:
        log.write("$ " + " ".join(cmd) + "\n")
        log.flush()
        return subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
