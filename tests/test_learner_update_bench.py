"""bench/learner_update.py's image option: its FLOP count of the encoder's convolutions, and its input checks."""

import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, "bench", "learner_update.py")


def test_conv_flops_of_an_encoder_gradient():
    """The encoder's parameter gradient on [B, 16, 16, 12] images, channels (8, 8), strides (2, 1): the forward
    convolutions and both weight gradients, each 2 x B x output pixels x 9 x Cin x Cout, and the second layer's
    input gradient (the image gets none), a convolution over the zero-padded cotangent: 2 x B x its 7 x 7 output
    pixels x 9 x 8 x 8. The linear layer's matmuls apart."""
    jax = pytest.importorskip("jax")
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    from learner_update import jaxpr_flops

    from unilab_jax import xp as shim
    from unilab_jax.core import pixels

    b = 4
    params = pixels.encoder_init(jax.random.PRNGKey(0), (16, 16, 12), (8, 8), (2, 1), 10, shim.get("jax"))
    image = jax.numpy.zeros((b, 16, 16, 12), jax.numpy.uint8)
    jaxpr = jax.make_jaxpr(jax.grad(lambda p, x: pixels.encode(p, x, (2, 1)).sum()))(params, image).jaxpr
    layer1, layer2 = 2 * b * 7 * 7 * 9 * 12 * 8, 2 * b * 5 * 5 * 9 * 8 * 8  # 16 -> 7 (stride 2) -> 5
    linear = 2 * b * 200 * 10  # forward and weight gradient (its input gradient flows back into layer 2)
    layer2_dx = 2 * b * 7 * 7 * 9 * 8 * 8
    np.testing.assert_allclose(jaxpr_flops(jaxpr), [3 * linear, 2 * layer1 + 2 * layer2 + layer2_dx])


@pytest.mark.parametrize("args, message", [(["--images", "64x64"], "--images must be HxWxC"),
                                           (["--images", "8x8x3", "--algos", "fastsac"], "fastsac learn no images")])
def test_bad_image_options_exit_2(args, message):
    res = subprocess.run([sys.executable, SCRIPT, "--platforms", "jax", *args], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": ROOT})
    assert res.returncode == 2 and message in res.stderr, res.stderr
