"""Export a trained deterministic actor for on-robot inference.

    python -m unilab_jax.export --logdir DIR [--checkpoint STEP] --format onnx|numpy --out PATH

The actor of a checkpoint (``unilab_jax.apps.saved_run``), observation normalisation included, is first written
as a small graph of array operations (:class:`Graph`: one builder per actor kind, reading the published
numpy weights exactly as the worker's ``act(weights, obs, noise, deterministic=True)`` does), then emitted as

* ``onnx``: an ONNX model (opset 17) built with the ``onnx`` library's helper API: input ``obs``
  ``[batch, obs_dim]`` float32, output ``action`` ``[batch, action_dim]``; run it with onnxruntime or any
  ONNX runtime on the robot;
* ``numpy``: one Python file that imports only numpy (``PATH``, ``.py`` added if missing) and the weights
  beside it (same name, ``.npz``); ``Policy()(obs)`` gives the action, for one observation ``[obs_dim]`` or
  a batch.

Actor kinds (``ACTORS``): PPO / APPO (Gaussian mean of the MLP), HIM-PPO (the history encoder's velocity
estimate and unit latent feed the MLP), HORA teacher (``tanh`` latent of the extrinsics) and student (the
adaptation module's temporal convolutions as im2col, then the teacher's head), SAC / FastSAC (``tanh`` of
the mean half), FlashSAC (its norm-bounded layers: constant feature, RMSNorm, residuals) and TD3
(``tanh`` of the MLP). Actions are the policy's raw output, as the trainer's evaluation feeds the task
(PPO's Gaussian mean is unbounded; the tasks clip to [-1, 1]).
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

FORMATS = ("onnx", "numpy")
OPSET = 17
_NORM_EPS, _NORM_CLIP = 1e-8, 10.0  # core.normalizer.normalize's defaults (what every act uses)


class Graph:
    """A straight-line program of array operations on the input ``obs`` [N, D] (``N`` any batch size).

    Nodes are ``(op, output, inputs, attrs)``; inputs name earlier outputs, ``obs`` or constants (float32
    arrays in ``consts``). Ops: add, sub, mul, div, max, matmul (broadcasting), clip(lo, hi), elu, relu,
    tanh, sigmoid, sqrt, slice(axis, start, stop, step), concat(axis), reshape(tail: the shape after the
    batch axis), reduce_mean / reduce_sum(axis=-1, keepdims).
    """

    def __init__(self) -> None:
        self.nodes: list[tuple[str, str, list[str], dict[str, Any]]] = []
        self.consts: dict[str, np.ndarray] = {}

    def const(self, name: str, value: Any) -> str:
        name = f"c_{name}".replace("/", "_")
        if name in self.consts:
            raise ValueError(f"constant {name} defined twice")
        self.consts[name] = np.asarray(value, np.float32)
        return name

    def op(self, op: str, *inputs: str, **attrs: Any) -> str:
        out = f"t{len(self.nodes)}"
        self.nodes.append((op, out, list(inputs), attrs))
        return out


# -- building blocks (each mirrors the function named in its docstring) ---------------------------------
def normalize(g: Graph, x: str, mean: np.ndarray, var: np.ndarray, name: str) -> str:
    """``core.normalizer.normalize``: ``clip((x - mean) / sqrt(var + eps), -10, 10)``."""
    std = np.sqrt(np.asarray(var, np.float32) + np.float32(_NORM_EPS))
    y = g.op("div", g.op("sub", x, g.const(f"{name}_mean", mean)), g.const(f"{name}_std", std))
    return g.op("clip", y, lo=-_NORM_CLIP, hi=_NORM_CLIP)


def _act(g: Graph, x: str, activation: str) -> str:
    if activation == "silu":
        return g.op("mul", x, g.op("sigmoid", x))
    if activation == "identity":
        return x
    if activation not in ("elu", "relu", "tanh"):
        raise ValueError(f"activation {activation!r} cannot be exported")
    return g.op(activation, x)


def _last_axis(g: Graph, x: str, op: str) -> str:
    return g.op(op, x, axis=-1, keepdims=True)


def layer_norm(g: Graph, x: str, gain: np.ndarray, offset: np.ndarray, name: str, eps: float = 1e-5) -> str:
    """``xp.Backend.layer_norm``."""
    centred = g.op("sub", x, _last_axis(g, x, "reduce_mean"))
    var = _last_axis(g, g.op("mul", centred, centred), "reduce_mean")
    y = g.op("div", centred, g.op("sqrt", g.op("add", var, g.const(f"{name}_eps", eps))))
    return g.op("add", g.op("mul", y, g.const(f"{name}_g", gain)), g.const(f"{name}_o", offset))


def mlp(g: Graph, x: str, layers: Sequence[dict], name: str, activation: str = "elu") -> str:
    """``nets.apply``: dense layers, LayerNorm where a layer carries ``g``/``o``, ``activation`` between."""
    for i, layer in enumerate(layers):
        x = g.op("add", g.op("matmul", x, g.const(f"{name}_{i}_w", layer["w"])), g.const(f"{name}_{i}_b", layer["b"]))
        if i < len(layers) - 1:
            if "g" in layer:
                x = layer_norm(g, x, layer["g"], layer["o"], f"{name}_{i}_ln")
            x = _act(g, x, activation)
    return x


def _rms_norm(g: Graph, x: str, name: str) -> str:
    """``flashsac._rms_norm`` (eps 1e-6 inside the root)."""
    ms = _last_axis(g, g.op("mul", x, x), "reduce_mean")
    return g.op("div", x, g.op("sqrt", g.op("add", ms, g.const(f"{name}_eps", 1e-6))))


def flash_mlp(g: Graph, x: str, layers: Sequence[dict], name: str) -> str:
    """``flashsac.flash_apply`` for one member: constant feature 1 appended (as ``x[:, :1] * 0 + 1``, exact
    for the finite normalised inputs it gets), then ``relu(g * rmsnorm(h W) + o)`` with residuals where the
    width is unchanged, RMSNorm and the head ``(h W) * s + b``."""
    ones = g.op("add", g.op("mul", g.op("slice", x, axis=-1, start=0, stop=1, step=1), g.const(f"{name}_zero", 0.0)),
                g.const(f"{name}_one", 1.0))
    h, width = g.op("concat", x, ones, axis=-1), None
    for i, layer in enumerate(layers[:-1]):
        z = _rms_norm(g, g.op("matmul", h, g.const(f"{name}_{i}_w", layer["w"])), f"{name}_{i}")
        z = g.op("relu", g.op("add", g.op("mul", z, g.const(f"{name}_{i}_g", layer["g"])),
                              g.const(f"{name}_{i}_o", layer["o"])))
        out_width = int(np.shape(layer["w"])[-1])
        h = g.op("add", h, z) if (i > 0 and width == out_width) else z
        width = out_width
    head = layers[-1]
    y = g.op("matmul", _rms_norm(g, h, f"{name}_head"), g.const(f"{name}_head_w", head["w"]))
    return g.op("add", g.op("mul", y, g.const(f"{name}_head_s", head["s"])), g.const(f"{name}_head_b", head["b"]))


def _cols(g: Graph, x: str, start: int, stop: int) -> str:
    return g.op("slice", x, axis=-1, start=int(start), stop=int(stop), step=1)


def l2_normalize(g: Graph, x: str, name: str, eps: float = 1e-12) -> str:
    """``core.him.l2_normalize``: ``x / max(||x||, eps)``."""
    norm = g.op("sqrt", _last_axis(g, g.op("mul", x, x), "reduce_sum"))
    return g.op("div", x, g.op("max", norm, g.const(f"{name}_eps", eps)))


# -- actor kinds: (graph, obs) -> action, from the published weights --------------------------------------
def _obs_norm(g: Graph, w: dict) -> str:
    return normalize(g, "obs", w["obs_norm"].mean, w["obs_norm"].var, "obs")


def _ppo(g: Graph, w: dict, obs_dim: int) -> str:
    """``ppo._actor``: the Gaussian mean."""
    return mlp(g, _obs_norm(g, w), w["actor"], "actor")


def _him_ppo(g: Graph, w: dict, obs_dim: int) -> str:
    """``him_ppo.actor``: [current frame, v_hat, unit latent] into the MLP."""
    x = _obs_norm(g, w)
    out = mlp(g, x, w["estimator"]["encoder"], "encoder")
    lat = int(np.shape(w["estimator"]["prototypes"])[1])
    width = int(np.shape(w["estimator"]["encoder"][-1]["w"])[1])
    v = width - lat
    d = int(np.shape(w["actor"][0]["w"])[0]) - width
    inp = g.op("concat", _cols(g, x, obs_dim - d, obs_dim), _cols(g, out, 0, v),
               l2_normalize(g, _cols(g, out, v, width), "latent"), axis=-1)
    return mlp(g, inp, w["actor"], "actor")


def _hora_teacher(g: Graph, w: dict, obs_dim: int) -> str:
    """``hora.common.teacher_actor``: the last frame and ``tanh(mlp(extrinsics))`` into the head."""
    p = int(np.shape(w["encoder"][0]["w"])[0])
    z = int(np.shape(w["encoder"][-1]["w"])[1])
    d = int(np.shape(w["actor"][0]["w"])[0]) - z
    mean, var, n = w["obs_norm"].mean, w["obs_norm"].var, obs_dim
    frame = normalize(g, _cols(g, "obs", n - p - d, n - p), mean[n - p - d:n - p], var[n - p - d:n - p], "frame")
    ext = normalize(g, _cols(g, "obs", n - p, n), mean[n - p:], var[n - p:], "ext")
    latent = g.op("tanh", mlp(g, ext, w["encoder"], "encoder"))
    return mlp(g, g.op("concat", frame, latent, axis=-1), w["actor"], "actor")


def _hora_student(g: Graph, w: dict, obs_dim: int) -> str:
    """``student.act``: ``hora.common.student_latent`` (``nets_temporal.adaptation_apply`` written as im2col,
    as there) and the teacher's head on [last normalised frame, z_hat]; the extrinsics are never read."""
    h, d = (int(s) for s in np.shape(w["history_norm"].mean))
    frames = g.op("reshape", _cols(g, "obs", 0, h * d), tail=(h, d))
    x = normalize(g, frames, w["history_norm"].mean, w["history_norm"].var, "history")
    adapt = w["adapt"]
    y = g.op("relu", mlp(g, x, adapt["embed"], "embed", activation="relu"))
    length = h
    for i, conv in enumerate(adapt["convs"]):
        k, c_in, c_out = (int(s) for s in np.shape(conv["w"]))
        stride = 2 if i == 0 else 1
        out_len = (length - k) // stride + 1
        span = stride * (out_len - 1) + 1
        patches = g.op("concat", *[g.op("slice", y, axis=-2, start=j, stop=j + span, step=stride) for j in range(k)],
                       axis=-1)
        wk = g.const(f"conv{i}_w", np.reshape(conv["w"], (k * c_in, c_out)))
        y = g.op("relu", g.op("add", g.op("matmul", patches, wk), g.const(f"conv{i}_b", conv["b"])))
        length = out_len
    z_hat = g.op("tanh", mlp(g, g.op("reshape", y, tail=(-1,)), adapt["proj"], "proj"))
    last = g.op("reshape", g.op("slice", x, axis=-2, start=h - 1, stop=h, step=1), tail=(d,))
    return mlp(g, g.op("concat", last, z_hat, axis=-1), w["actor"], "actor")


def _tanh_mean(apply: Callable[[Graph, str, Sequence[dict], str], str]) -> Callable[[Graph, dict, int], str]:
    def build(g: Graph, w: dict, obs_dim: int) -> str:
        """``sac.tanh_gaussian_act`` (deterministic): ``tanh`` of the mean half of the actor's output."""
        out = apply(g, _obs_norm(g, w), w["actor"], "actor")
        a = int(np.shape(w["actor"][-1]["b"])[-1]) // 2
        return g.op("tanh", _cols(g, out, 0, a))

    return build


def _td3(g: Graph, w: dict, obs_dim: int) -> str:
    """``td3.policy_mean``: ``tanh(mlp(normalize(obs)))``."""
    return g.op("tanh", mlp(g, _obs_norm(g, w), w["actor"], "actor", activation="relu"))


ACTORS: dict[str, Callable[[Graph, dict, int], str]] = {
    "ppo": _ppo, "appo": _ppo, "him_ppo": _him_ppo, "hora_teacher": _hora_teacher, "hora_student": _hora_student,
    "sac": _tanh_mean(lambda g, x, p, n: mlp(g, x, p, n, activation="relu")),
    "fastsac": _tanh_mean(lambda g, x, p, n: mlp(g, x, p, n, activation="relu")),
    "flashsac": _tanh_mean(flash_mlp), "td3": _td3,
}


def actor_graph(algo: str, weights: dict, obs_dim: int) -> tuple[Graph, str]:
    """(graph, name of its action output) of ``algo``'s deterministic actor with these numpy weights."""
    if algo not in ACTORS:
        raise ValueError(f"no exporter for algorithm {algo!r}; exportable: {sorted(ACTORS)}")
    g = Graph()
    return g, ACTORS[algo](g, weights, obs_dim)


# -- emitters ---------------------------------------------------------------------------------------------
def to_onnx(g: Graph, output: str, obs_dim: int, action_dim: int, doc: str = "") -> Any:
    """The graph as an ``onnx.ModelProto`` (checked)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    inits = [numpy_helper.from_array(v, k) for k, v in g.consts.items()]
    nodes = []

    def ints(name: str, values: Sequence[int]) -> str:
        inits.append(numpy_helper.from_array(np.asarray(values, np.int64), name))
        return name

    binary = {"add": "Add", "sub": "Sub", "mul": "Mul", "div": "Div", "max": "Max", "matmul": "MatMul"}
    unary = {"elu": "Elu", "relu": "Relu", "tanh": "Tanh", "sigmoid": "Sigmoid", "sqrt": "Sqrt"}
    for op, out, ins, at in g.nodes:
        if op in binary:
            nodes.append(helper.make_node(binary[op], ins, [out]))
        elif op in unary:
            nodes.append(helper.make_node(unary[op], ins, [out], **({"alpha": 1.0} if op == "elu" else {})))
        elif op == "clip":
            lo, hi = f"{out}_lo", f"{out}_hi"
            inits += [numpy_helper.from_array(np.asarray(at[k], np.float32), n) for k, n in (("lo", lo), ("hi", hi))]
            nodes.append(helper.make_node("Clip", [ins[0], lo, hi], [out]))
        elif op == "slice":
            args = [ints(f"{out}_{k}", [at[key]]) for k, key in (("s", "start"), ("e", "stop"), ("a", "axis"),
                                                                  ("p", "step"))]
            nodes.append(helper.make_node("Slice", [ins[0], *args], [out]))
        elif op == "concat":
            nodes.append(helper.make_node("Concat", ins, [out], axis=at["axis"]))
        elif op == "reshape":
            nodes.append(helper.make_node("Reshape", [ins[0], ints(f"{out}_shape", [0, *at["tail"]])], [out]))
        elif op == "reduce_mean":
            nodes.append(helper.make_node("ReduceMean", ins, [out], axes=[at["axis"]], keepdims=int(at["keepdims"])))
        elif op == "reduce_sum":
            nodes.append(helper.make_node("ReduceSum", [ins[0], ints(f"{out}_axes", [at["axis"]])], [out],
                                          keepdims=int(at["keepdims"])))
        else:
            raise ValueError(f"op {op!r} has no ONNX form")
    nodes.append(helper.make_node("Identity", [output], ["action"]))
    io = [helper.make_tensor_value_info(name, TensorProto.FLOAT, ["batch", dim])
          for name, dim in (("obs", obs_dim), ("action", action_dim))]
    graph = helper.make_graph(nodes, "actor", io[:1], io[1:], initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="unilab_jax.export",
                              doc_string=doc)
    model.ir_version = min(model.ir_version, 9)  # readable by onnxruntime releases older than the onnx library
    onnx.checker.check_model(model)
    return model


_NUMPY_FORMS = {"add": "{0} + {1}", "sub": "{0} - {1}", "mul": "{0} * {1}", "div": "{0} / {1}", "matmul": "{0} @ {1}",
                "max": "np.maximum({0}, {1})", "relu": "np.maximum({0}, 0)", "tanh": "np.tanh({0})",
                "sqrt": "np.sqrt({0})", "sigmoid": "1 / (1 + np.exp(-{0}))",
                "elu": "np.where({0} > 0, {0}, np.expm1(np.minimum({0}, 0)))"}  # the shim's numpy elu


def _numpy_line(op: str, out: str, ins: list[str], at: dict[str, Any], ref: Callable[[str], str]) -> str:
    a = [ref(i) for i in ins]
    if op in _NUMPY_FORMS:
        return f"{out} = " + _NUMPY_FORMS[op].format(*a)
    if op == "clip":
        return f"{out} = np.clip({a[0]}, {at['lo']!r}, {at['hi']!r})"
    if op == "slice":
        index = f"{at['start']}:{at['stop']}" + (f":{at['step']}" if at["step"] != 1 else "")
        return f"{out} = {a[0]}[..., {index}{', :' if at['axis'] == -2 else ''}]"
    if op == "concat":
        return f"{out} = np.concatenate([{', '.join(a)}], axis={at['axis']})"
    if op == "reshape":
        return f"{out} = {a[0]}.reshape({a[0]}.shape[0], {', '.join(str(int(s)) for s in at['tail'])})"
    if op in ("reduce_mean", "reduce_sum"):
        return f"{out} = np.{op[7:]}({a[0]}, axis={at['axis']}, keepdims={bool(at['keepdims'])})"
    raise ValueError(f"op {op!r} has no numpy form")


_NUMPY_MODULE = '''"""{doc}

Deterministic actor exported by ``python -m unilab_jax.export``; needs numpy only. The weights are
``{weights}`` beside this file.

    from {stem} import Policy
    policy = Policy()
    action = policy(obs)   # obs [{obs_dim}] or [N, {obs_dim}] float32 -> action [{action_dim}] or [N, {action_dim}]
"""

import os

import numpy as np

OBS_DIM = {obs_dim}
ACTION_DIM = {action_dim}
WEIGHTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "{weights}")


class Policy:
    def __init__(self, weights=WEIGHTS):
        with np.load(weights) as f:
            self.w = {{k: f[k] for k in f.files}}

    def __call__(self, obs):
        w = self.w
        obs = np.asarray(obs, dtype=np.float32)
        single = obs.ndim == 1
        if single:
            obs = obs[None]
        if obs.shape[-1] != OBS_DIM:
            raise ValueError(f"expected observations of {{OBS_DIM}} features, got shape {{obs.shape}}")
{body}
        action = {output}.astype(np.float32)
        return action[0] if single else action
'''


def to_numpy_module(g: Graph, output: str, obs_dim: int, action_dim: int, path: str, doc: str = "") -> tuple[str, str]:
    """Writes the graph as a numpy-only module ``path`` (.py) and its weights beside it (.npz); returns both paths."""
    base = path[:-3] if path.endswith(".py") else path
    py, npz = base + ".py", base + ".npz"
    ref = lambda name: f'w["{name}"]' if name in g.consts else name
    body = "\n".join(" " * 8 + _numpy_line(op, out, ins, at, ref) for op, out, ins, at in g.nodes)
    text = _NUMPY_MODULE.format(doc=doc, weights=os.path.basename(npz), stem=os.path.basename(base), obs_dim=obs_dim,
                                action_dim=action_dim, body=body, output=ref(output))
    os.makedirs(os.path.dirname(os.path.abspath(py)), exist_ok=True)
    np.savez(npz, **g.consts)
    with open(py, "w") as f:
        f.write(text)
    return py, npz


def export(run: Any, fmt: str, out: str) -> list[str]:
    """Writes ``run``'s (a ``saved_run.SavedRun``) actor in format ``fmt`` to ``out``; returns the files written."""
    if fmt not in FORMATS:
        raise ValueError(f"--format={fmt!r}: choose one of {FORMATS}")
    obs_dim, action_dim = run.spec.obs_dim, run.spec.action_dim
    g, output = actor_graph(run.algo, run.weights, obs_dim)
    doc = f"{run.algo} actor for {run.task}, checkpoint {run.step} of {run.logdir}"
    if fmt == "numpy":
        return list(to_numpy_module(g, output, obs_dim, action_dim, out, doc))
    import onnx

    model = to_onnx(g, output, obs_dim, action_dim, doc)
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    onnx.save(model, out)
    return [out]


def main(argv: list[str] | None = None) -> int:
    import argparse

    from unilab_jax.apps import saved_run

    parser = argparse.ArgumentParser(prog="python -m unilab_jax.export", description=__doc__.split("\n")[0])
    parser.add_argument("--logdir", required=True, help="the training run's logdir")
    parser.add_argument("--checkpoint", type=int, default=None, help="env step of the checkpoint (default: latest)")
    parser.add_argument("--format", required=True, help=f"one of {', '.join(FORMATS)}")
    parser.add_argument("--out", required=True, help="output file (numpy: the .py; its .npz goes beside it)")
    args = parser.parse_args(argv)
    if args.format not in FORMATS:
        print(f"error: --format={args.format!r}: choose one of {', '.join(FORMATS)}", file=sys.stderr)
        return 2
    try:
        run = saved_run.load(args.logdir, args.checkpoint)
        files = export(run, args.format, args.out)
    except (FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps({"algo": run.algo, "task": run.task, "checkpoint": run.step, "format": args.format,
                      "obs_dim": run.spec.obs_dim, "action_dim": run.spec.action_dim, "files": files}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
