#!/usr/bin/env python3
"""Load a nodelet into a manager once other nodelets are loaded there (a `nodelet load` that waits its turn).

usage: load_nodelet_after.py TYPE MANAGER [--after NAME ...] [--timeout S] [__name:=NODELET_NAME] [remappings]

The nodelet gets this node's name and remappings, and reads its parameters from this node's private namespace,
as with `nodelet load`. Meant for drivers whose onInit() never returns, such as the MYNT EYE S wrapper's nodelet:
the manager serves load requests in one thread, so once such a driver is loading, nothing else can be loaded into
that manager. launch/mynteye_driver.launch therefore loads diekf first and the driver with this script, after
diekf. The load request of such a driver never gets an answer; this node then stays up until shutdown (no bond:
the manager of that launch file goes down with it).
"""
import argparse
import sys
import threading

import rospy
from nodelet.srv import NodeletList, NodeletLoad


def main():
    argv = rospy.myargv(argv=sys.argv)
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("type", help="nodelet type, e.g. mynteye/ROSWrapperNodelet")
    parser.add_argument("manager", help="nodelet manager, e.g. /mynteye/mynteye_nodelet_manager")
    parser.add_argument("--after", nargs="*", default=[], help="nodelets that must be loaded first (names)")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for them (and the manager)")
    args = parser.parse_args(argv[1:])

    rospy.init_node("load_nodelet_after", disable_signals=False)
    name = rospy.get_name()
    manager = args.manager.rstrip("/")
    after = [rospy.names.resolve_name(n) for n in args.after]
    try:
        rospy.wait_for_service(manager + "/list", timeout=args.timeout)
    except rospy.ROSException:
        rospy.logfatal("%s: no nodelet manager %s (service %s/list) after %.0f s", name, manager, manager,
                       args.timeout)
        return 1
    listing = rospy.ServiceProxy(manager + "/list", NodeletList)
    deadline = rospy.Time.now() + rospy.Duration(args.timeout)
    loaded = []
    while not rospy.is_shutdown():
        try:
            loaded = listing().nodelets
        except rospy.ServiceException as e:
            rospy.logwarn_throttle(5.0, "%s: %s/list failed: %s", name, manager, e)
        missing = [n for n in after if n not in loaded]
        if not missing:
            break
        if rospy.Time.now() > deadline:
            rospy.logfatal("%s: %s not loaded into %s after %.0f s (loaded: %s); not loading %s", name,
                           ", ".join(missing), manager, args.timeout, ", ".join(loaded) or "none", args.type)
            return 1
        rospy.sleep(0.2)
    if rospy.is_shutdown():
        return 0

    mappings = {k: v for k, v in rospy.names.get_mappings().items() if not k.startswith("__")}  # no __name etc.
    request = dict(name=name, type=args.type, remap_source_args=list(mappings.keys()),
                   remap_target_args=list(mappings.values()), my_argv=[], bond_id="")
    result = {}

    def load():
        try:
            result["success"] = rospy.ServiceProxy(manager + "/load_nodelet", NodeletLoad)(**request).success
        except (rospy.ServiceException, rospy.ROSException) as e:
            result["error"] = str(e)

    rospy.loginfo("%s: loading %s into %s (after %s)", name, args.type, manager, ", ".join(after) or "nothing")
    thread = threading.Thread(target=load, daemon=True)
    thread.start()
    while not rospy.is_shutdown() and thread.is_alive():
        rospy.sleep(0.2)
    if rospy.is_shutdown():
        return 0  # a driver that never returns from onInit: its load request ends with the shutdown
    if "error" in result or result.get("success") is False:
        rospy.logfatal("%s: loading %s into %s failed: %s", name, args.type, manager,
                       result.get("error", "the manager refused it (see its log)"))
        return 1
    if result.get("success"):
        rospy.loginfo("%s: %s loaded", name, args.type)
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())
