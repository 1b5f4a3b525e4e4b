"""unilab_mlx (and the shim's mlx backend) must import and work on a machine without jax/optax."""

from __future__ import annotations

from mlx_helpers import run_python

CODE = (
    "import sys; sys.modules['jax'] = None; sys.modules['optax'] = None; "
    "import unilab_mlx, unilab_mlx.optim; from unilab_jax import xp; xp.get('mlx')"
)

# A small end-to-end use of the optimizers without jax: one adam step on a tiny tree.
CODE_STEP = CODE + (
    "\nimport mlx.core as mx\nfrom unilab_mlx import optim\n"
    "p = {'w': mx.ones((2, 2))}\nopt = optim.inject_hyperparams(optim.adamw)(learning_rate=0.1)\n"
    "s = opt.init(p)\nu, s = opt.update({'w': mx.ones((2, 2))}, s, p)\np = optim.apply_updates(p, u)\n"
    "mx.eval(p, s)\nassert abs(p['w'][0, 0].item() - (1 - 0.1 * (1 + 1e-4))) < 1e-5, p\n"
    "loaded = [m for m, v in sys.modules.items() if v and m.split('.')[0] in ('jax', 'jaxlib', 'optax')]\n"
    "assert not loaded, loaded\n"
)


def _run(code: str) -> None:
    res = run_python(code, timeout=120)
    assert res.returncode == 0, f"exit {res.returncode}\nstdout:\n{res.stdout}\nstderr:\n{res.stderr}"


def test_import_without_jax():
    _run(CODE)


def test_optimizer_step_without_jax():
    _run(CODE_STEP)
