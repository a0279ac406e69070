# diekf: one-command set-up on a fresh Debian 12 machine.
#   make demo   -- the main job (see README)
#   make test   -- build everything and run every test
# A catkin workspace is created in $(WS), outside this directory, with src/diekf pointing here (`make ws-path`
# prints it).

SHELL := /bin/bash
# Debian's python3 first: catkin's helper scripts import Debian's Python modules.
export PATH := /usr/bin:/bin:/usr/sbin:/sbin:$(PATH)
export PYTHONNOUSERSITE := 1
unexport PYTHONPATH PYTHONHOME VIRTUAL_ENV

# Build trees live outside the package directory: rosrun looks for an executable in the package directory too
# (find -L), so a workspace inside it would make every executable ambiguous (an interactive "non-unique
# executable" prompt). Default: the user's cache, one folder per checkout (its name and a hash of its path).
BUILD_ROOT ?= $(or $(XDG_CACHE_HOME),$(HOME)/.cache)/diekf/$(notdir $(CURDIR))-$(shell printf '%s' '$(CURDIR)' | md5sum | cut -c1-8)
WS ?= $(BUILD_ROOT)/ws
SANITIZE_WS ?= $(BUILD_ROOT)/ws-sanitize
# Workspaces an older Makefile put inside the package directory.
LEGACY_TREES := $(wildcard $(CURDIR)/.ws $(CURDIR)/.ws-sanitize)
ifneq ($(LEGACY_TREES),)
ifeq ($(MAKELEVEL)$(filter clean ws-path,$(MAKECMDGOALS)),0)
$(warning build trees inside the package directory (from an older Makefile): $(LEGACY_TREES). rosrun finds the \
  executables there too and asks which one to run; remove them (make clean, or rm -rf))
endif
endif
JOBS ?= 2
BUILD_TYPE ?= Release
CMAKE_ARGS ?=
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

APT_PACKAGES := build-essential cmake catkin ros-base-dev libnodeletlib-dev libcv-bridge-dev \
  libimage-transport-dev librosbag-dev librostest-dev libtf2-ros-dev libopencv-dev libeigen3-dev \
  libyaml-cpp-dev libgtest-dev libgmock-dev libbenchmark-dev python3-matplotlib python3-numpy python3-scipy python3-yaml \
  ros-message-generation ros-message-runtime libdiagnostic-updater-dev libstd-srvs-dev \
  libnav-msgs-dev libshape-msgs-dev libvisualization-msgs-dev libdiagnostic-msgs-dev \
  libtf2-geometry-msgs-dev libtf2-eigen-dev python3-rosbag python3-rostest python3-roslaunch libnodeletlib-tools ros-base-python-dev rosbash valgrind \
  python3-tf2-msgs image-transport-tools clang libclang-rt-14-dev

.PHONY: all deps workspace ws-path build test demo benchmark benchmark-core benchmark-callgrind fuzz sanitize soak rviz-check \
  cross-check clean

all: build

# Install what is missing (apt-get; sudo when not root). Quiet when everything is there.
deps:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q '^install ok installed' || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "Installing: $$missing"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; \
	fi

workspace:
	@case "$(abspath $(WS))/" in "$(CURDIR)"/*) \
	  echo "WS=$(WS) is inside the package directory: rosrun would find every executable twice; use a folder" \
	    "outside it" >&2; exit 1;; esac
	@mkdir -p $(WS)/src
	@ln -sfn $(CURDIR) $(WS)/src/diekf

ws-path:
	@echo $(abspath $(WS))

build: deps workspace
	cd $(WS) && catkin_make -DCMAKE_BUILD_TYPE=$(BUILD_TYPE) $(CMAKE_ARGS) -j$(JOBS)

test: build
	cd $(WS) && catkin_make -DCMAKE_BUILD_TYPE=$(BUILD_TYPE) $(CMAKE_ARGS) -j$(JOBS) tests
	rm -rf $(WS)/build/test_results
	cd $(WS) && source devel/setup.bash && catkin_make -j1 run_tests
	cd $(WS) && catkin_test_results build/test_results

# Simulated flight -> offline estimator -> evaluation + plots in demo_output/ (docs/evaluation.md).
demo: build
	cd $(WS) && source devel/setup.bash && DIEKF_WS=$(WS) bash $(CURDIR)/scripts/demo.sh $(CURDIR)/demo_output

# The paper's Table I on simulated flights (+ inclined planes) into results/; long (tens of minutes).
# Arguments for scripts/benchmark_table.py via BENCH_ARGS, e.g. make benchmark BENCH_ARGS="--duration 30".
BENCH_ARGS ?=
benchmark: build
	cd $(WS) && source devel/setup.bash && DIEKF_WS=$(WS) python3 $(CURDIR)/scripts/benchmark_table.py \
	  --output $(CURDIR)/results $(BENCH_ARGS)

benchmark-core: build
	cd $(WS) && catkin_make -j$(JOBS) diekf_benchmark && ./devel/lib/diekf/diekf_benchmark

# libFuzzer target of the core's input handling (test/fuzz/fuzz_ingest.cpp), built with clang outside the catkin
# tree into $(FUZZ_DIR), then run for FUZZ_SECONDS (docs/robustness.md).
FUZZ_DIR ?= $(CURDIR)/.fuzz
FUZZ_SECONDS ?= 120
FUZZ_FLAGS := -std=c++17 -O1 -g -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
  -fno-omit-frame-pointer -Iinclude -I/usr/include/eigen3 -I/usr/include/opencv4
fuzz: deps
	mkdir -p $(FUZZ_DIR)/corpus
	clang++ $(FUZZ_FLAGS) test/fuzz/fuzz_ingest.cpp $(wildcard src/core/*.cpp) \
	  -lopencv_imgproc -lopencv_video -lopencv_calib3d -lopencv_core -lyaml-cpp -o $(FUZZ_DIR)/fuzz_ingest
	cd $(FUZZ_DIR) && ./fuzz_ingest -max_total_time=$(FUZZ_SECONDS) -max_len=4096 -rss_limit_mb=2048 \
	  -print_final_stats=1 corpus

# The whole test suite under AddressSanitizer + UndefinedBehaviorSanitizer, in its own workspace ($(SANITIZE_WS)).
sanitize:
	$(MAKE) test WS=$(SANITIZE_WS) BUILD_TYPE=RelWithDebInfo CMAKE_ARGS="-DDIEKF_SANITIZE=ON" \
	  ASAN_OPTIONS=detect_leaks=0:verify_asan_link_order=0 UBSAN_OPTIONS=print_stacktrace=1

# 30 minutes of simulated flight through diekf_bag_runner: peak RSS and growth (scripts/soak.sh).
soak: build
	cd $(WS) && source devel/setup.bash && DIEKF_WS=$(WS) bash $(CURDIR)/scripts/soak.sh

# Instruction counts per call of the same cases under valgrind's callgrind (repeatable; docs/performance.md).
benchmark-callgrind: build
	cd $(WS) && catkin_make -j$(JOBS) diekf_benchmark && \
	  bash $(CURDIR)/scripts/callgrind_core.sh devel/lib/diekf/diekf_benchmark

# rviz on a virtual X server over a simulated flight (replay.launch rviz:=true): screenshots and a log scan in
# results/rviz/ (docs/ros.md, "rviz"). Not part of `make test`: CI has no rviz.
RVIZ_APT_PACKAGES := rviz xvfb imagemagick
rviz-check: build
	@missing=$$(for p in $(RVIZ_APT_PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q '^install ok installed' || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "Installing: $$missing"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; \
	fi
	cd $(WS) && source devel/setup.bash && bash $(CURDIR)/scripts/rviz_check.sh $(CURDIR)/results/rviz

# The ROS-free core on ARM: cross builds for aarch64 and armhf (NEON) against private sysroots of Debian packages,
# the core's unit tests under qemu-user, the SIMD line, one simulated flight replayed on x86-64 and ARM and compared,
# instructions per frame (cross/cross_check.sh; docs/performance.md, "ARM"). Not part of `make test`: about
# 30 minutes the first time (packages, three builds, tests under emulation); less once built. Results in results/cross-check/.
CROSS_DIR ?= $(BUILD_ROOT)/cross
CROSS_ARCHES ?= arm64 armhf
cross-check: build
	DIEKF_WS=$(WS) CROSS_DIR=$(CROSS_DIR) CROSS_ARCHES="$(CROSS_ARCHES)" JOBS=$(JOBS) SUDO=$(SUDO) \
	  bash $(CURDIR)/cross/cross_check.sh $(CURDIR)/results/cross-check

# Both workspaces of this checkout, and the ones an older Makefile put inside the package directory.
clean:
	rm -rf $(WS) $(SANITIZE_WS) $(CROSS_DIR) $(LEGACY_TREES)
