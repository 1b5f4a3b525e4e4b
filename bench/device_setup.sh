# Sourced at the start of each command on the GPU machine: installs the offline bundle and puts the checkout on the path.
# The bundle: .devr (bench/device_bundle.sh: wheels in .devr/whl, each robot a .tar.xz; the robots in $ROBOTS are
# unpacked) or .device (../shared/device/prepare.sh, uncompressed). Wheels go to /tmp/site and robots to
# /tmp/unilab_robots, outside the checkout: on a warm machine they stay for the next call (the checkout's ignored
# folders do not), so a later call may carry only the robots it adds, or no bundle at all. A call that carries wheels
# installs them into an emptied /tmp/site (pip --target skips a package folder that exists: mujoco-mjx's files
# would never join an installed mujoco).
robots=/tmp/unilab_robots; mkdir -p "$robots"
wheels=$( { ls .devr/whl/*.whl || ls .device/whl/*.whl; } 2>/dev/null)
if [ -n "$wheels" ]; then
  rm -rf /tmp/site
  # shellcheck disable=SC2086
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site $wheels || exit 1
fi
[ -d /tmp/site/mujoco ] || { echo "device_setup: no wheels carried and none installed by an earlier call"; exit 1; }
[ -d .device/robots ] && cp -r .device/robots/. "$robots/"
for r in ${ROBOTS:-unitree_go1}; do
  if [ -e ".devr/$r.tar.xz" ]; then tar xJf ".devr/$r.tar.xz" -C "$robots" || exit 1
  elif [ ! -d "$robots/$r" ]; then echo "device_setup: robot $r neither carried nor unpacked by an earlier call"; exit 1
  fi
done
# With the GL libraries carried (.gl: Debian's libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 .debs, see
# docs/dev/GPU_RUNS.md), the robots' cameras render through the NVIDIA driver's EGL.
if [ -d .gl ]; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; export MUJOCO_GL=egl
fi
export PYTHONPATH=/tmp/site:$PWD MENAGERIE_ROOT=$robots PYTHONUNBUFFERED=1
nproc; nvidia-smi -L; python3 -c "import jax, mujoco; print('jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__)"
