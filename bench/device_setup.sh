# Sourced at the start of each command on the GPU machine: installs the offline bundle made by
# ../shared/device/prepare.sh (MuJoCo wheels + robots) and puts the checkout on the path.
# With the compressed bundle of bench/device_bundle.sh (.devr carried): wheels copied, the robots in $ROBOTS unpacked;
# a later call on the same warm machine may carry robots alone (.device/whl and unpacked robots stay there).
if [ -d .devr ]; then
  mkdir -p .device/robots .device/whl; [ -d .devr/whl ] && cp .devr/whl/*.whl .device/whl/
  for r in ${ROBOTS:-unitree_go1}; do tar xJf ".devr/$r.tar.xz" -C .device/robots || exit 1; done
fi
# With the GL libraries carried (.gl: Debian's libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 .debs, see
# docs/dev/GPU_RUNS.md), the robots' cameras render through the NVIDIA driver's EGL.
if [ -d .gl ]; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; export MUJOCO_GL=egl
fi
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .device/whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD MENAGERIE_ROOT=$PWD/.device/robots PYTHONUNBUFFERED=1
nproc; nvidia-smi -L; python3 -c "import jax, mujoco; print('jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__)"
