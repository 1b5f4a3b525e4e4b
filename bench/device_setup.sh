# Sourced at the start of each command on the GPU machine: installs the offline bundle made by
# ../shared/device/prepare.sh (MuJoCo wheels + robots) and puts the checkout on the path.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .device/whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD MENAGERIE_ROOT=$PWD/.device/robots PYTHONUNBUFFERED=1
nproc; nvidia-smi -L; python3 -c "import jax, mujoco; print('jax', jax.__version__, jax.devices(), 'mujoco', mujoco.__version__)"
