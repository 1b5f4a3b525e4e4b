#!/usr/bin/env bash
# Makes a compressed GPU-machine bundle in .devr/ (git-ignored): the py3.12 wheels of ../shared/device/prepare.sh
# plus pyzmq/msgpack/tensorboardX, PyOpenGL (MuJoCo's EGL renderer for the robots' cameras) and py-spy (the sampling
# profiler of bench/p31_pyspy.sh, 3 MB; installed there as /tmp/site/bin/py-spy), and each robot
# of ../shared/robots as its own .tar.xz (franka 33 -> 3 MB, unitree_g1 18 -> 6 MB), so every robot fits the
# device's 64 MiB transfer beside the checkout. Carry ".devr";
# bench/device_setup.sh unpacks the robots a command names:  ROBOTS="franka_emika_panda" source bench/device_setup.sh
set -eu
cd "$(git rev-parse --show-toplevel)"
grep -qx '/.devr/' .git/info/exclude 2>/dev/null || echo '/.devr/' >> .git/info/exclude
bash ../shared/device/prepare.sh pyzmq msgpack tensorboardX PyOpenGL py-spy==0.4.3 >/dev/null
mkdir -p .devr && rm -rf .devr/whl && cp -r .device/whl .devr/whl
for r in ../shared/robots/*/; do
  tar cJf ".devr/$(basename "$r").tar.xz" -C ../shared/robots "$(basename "$r")"
done
du -sh .devr
