"""Two-stage HORA runs from one command: the privileged teacher, then the student, resumable per stage.

An experiment script calls :func:`run_hora` with its recipes; the shared flags of
``unilab_jax.apps.cli`` apply to both stages, plus::

    --teacher_steps / --student_steps   env-step budgets of the two stages (--total_steps is refused)
    --history_len                       frames the student's adaptation module sees (HORA: 30)
    --student_config key=value          hora_student overrides (--config goes to the teacher)

Layout under ``--logdir``: ``teacher/`` and ``student/`` (each an ordinary run folder: events,
``metrics.jsonl``, checkpoints, ``summary.json``) and ``hora_summary.json``. The teacher trains on the
task variant with ``history_len=1``; the student on the same variant and overrides with
``history_len=--history_len``, starting from the teacher's last checkpoint. With ``--resume`` a teacher
whose ``summary.json`` shows its budget done (not interrupted) is skipped, an unfinished one continues,
then the student continues from its own checkpoints if it has any (keeping the teacher it started from)
or starts. At the end both policies are evaluated on the student's task with the same seeds (the
teacher reads the extrinsics, the student never does): ``hora_summary.json`` and
``hora/{teacher,student}_eval_return``, ``hora/student_to_teacher`` in the student's logs (the ratio of
the script's ``compare_metric``: the evaluation return by default; the Allegro script compares rotation rates).
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from typing import Any

from absl import flags

from unilab_jax.apps import cli
from unilab_jax.training.evaluation import evaluate_policy

FLAGS = flags.FLAGS
flags.DEFINE_integer("teacher_steps", None, "env steps of stage 1, the privileged teacher (default: the script's)")
flags.DEFINE_integer("student_steps", None, "env steps of stage 2, the student (default: the script's)")
flags.DEFINE_integer("history_len", 30, "history frames the student's adaptation module sees")
flags.DEFINE_multi_string("student_config", [], "hora_student override key=value (repeatable)")


def _has_checkpoints(logdir: str) -> bool:
    d = os.path.join(logdir, "checkpoints")
    return os.path.isdir(d) and any(n.isdigit() for n in os.listdir(d))


def _finished(logdir: str, budget: int) -> bool:
    path = os.path.join(logdir, "summary.json")
    if not os.path.isfile(path):
        return False
    with open(path) as f:
        summary = json.load(f)
    return not summary.get("interrupted", True) and summary.get("env_steps", 0) >= budget


def _plan(task: str, teacher_recipe: Mapping[str, Any], student_recipe: Mapping[str, Any],
          task_recipe: Mapping[str, Any], teacher_steps: int, student_steps: int) -> dict[str, Any]:
    """Validates every flag of both stages (FlagError / ConfigError) before anything starts."""
    import tasks
    from unilab_jax import algos, nets_temporal
    from unilab_jax.config import apply_overrides, parse_overrides

    if FLAGS.total_steps is not None:
        raise cli.FlagError("--total_steps: a HORA run has two budgets, use --teacher_steps and --student_steps")
    t_steps = FLAGS.teacher_steps if FLAGS.teacher_steps is not None else teacher_steps
    s_steps = FLAGS.student_steps if FLAGS.student_steps is not None else student_steps
    if t_steps < 1 or s_steps < 1:
        raise cli.FlagError(f"--teacher_steps and --student_steps must be positive, got {t_steps}, {s_steps}")
    root = FLAGS.logdir or os.path.join("runs", f"hora_{FLAGS.task or task}_s{FLAGS.seed}")
    teacher_dir, student_dir = os.path.join(root, "teacher"), os.path.join(root, "student")
    resume = FLAGS.resume
    if resume and not (_has_checkpoints(teacher_dir) or _has_checkpoints(student_dir)):
        raise cli.FlagError(f"--resume: no checkpoints under {root!r} (teacher/ or student/)")
    teacher_done = resume and _finished(teacher_dir, t_steps)
    # The teacher's run, validated by the shared code with its own folder, budget and resume state.
    FLAGS.logdir, FLAGS.total_steps = teacher_dir, t_steps
    FLAGS.resume = resume and _has_checkpoints(teacher_dir)
    try:
        t_run, t_mod, t_cfg, t_over = cli.build_run("hora_teacher", task, teacher_recipe,
                                                    {**task_recipe, "history_len": 1}, t_steps)
    finally:
        FLAGS.logdir, FLAGS.total_steps, FLAGS.resume = root, None, resume
    t_over = {**t_over, "history_len": 1}  # also when --task picks a task the recipe is not for
    s_mod = algos.get("hora_student")
    s_cfg = apply_overrides(s_mod.Config(), {**student_recipe, "teacher_checkpoint":
                                             os.path.join(os.path.abspath(teacher_dir), "checkpoints")})
    s_cfg = apply_overrides(s_cfg, parse_overrides(FLAGS.student_config))
    s_over = {**t_over, "history_len": FLAGS.history_len}
    s_task_config = apply_overrides(tasks.default_config(t_run.task), s_over)
    try:
        s_mod.check_run(FLAGS.platform, s_task_config, s_cfg)
        length = FLAGS.history_len
        for i, k in enumerate(s_cfg.conv_kernels):
            length = nets_temporal.conv_length(length, k, 2 if i == 0 else 1)
        if length < 1:
            raise ValueError(f"--history_len={FLAGS.history_len} is too short for conv_kernels {s_cfg.conv_kernels}")
    except ValueError as e:
        raise cli.FlagError(str(e)) from e
    if s_cfg.horizon * FLAGS.num_workers * FLAGS.envs_per_worker < s_cfg.num_minibatches:
        raise cli.FlagError(f"a student batch cannot make {s_cfg.num_minibatches} minibatches")
    s_run = dataclasses.replace(t_run, algo="hora_student", logdir=student_dir, total_steps=s_steps,
                                resume=resume and _has_checkpoints(student_dir))
    return {"root": root, "teacher": (t_run, t_mod, t_cfg, t_over), "student": (s_run, s_mod, s_cfg, s_over),
            "teacher_done": teacher_done}


def _compare(plan: dict[str, Any]) -> dict[str, Any]:
    """Teacher and student evaluated on the student's task with the same seeds."""
    import jax

    from unilab_jax import nets
    from unilab_jax import xp as shim
    from unilab_jax.algos.hora import teacher as hora_teacher
    from unilab_jax.algos.hora.learner_jax import StudentLearner, load_teacher
    from unilab_jax.checkpoint import Checkpointer
    from unilab_jax.metrics import MetricLogger

    s_run, s_mod, s_cfg, s_over = plan["student"]
    learner = StudentLearner(s_cfg, _spec(s_run.task, s_over))
    ckpt = Checkpointer(os.path.join(s_run.logdir, "checkpoints"))
    try:
        template = learner.init(shim.get("jax").random.key(0))
        state, meta = ckpt.restore(template, lambda a, like: jax.numpy.asarray(a))
    finally:
        ckpt.close()
    teacher, obs_norm, _ = load_teacher(s_cfg.teacher_checkpoint, learner.spec)
    t_weights = nets.to_numpy({"actor": teacher["actor"], "encoder": teacher["encoder"],
                               "log_std": teacher["log_std"], "obs_norm": obs_norm})
    s_weights = nets.to_numpy(learner.weights(state))
    seed = int(meta["counters"]["updates"])
    t_eval = evaluate_policy(hora_teacher, t_weights, s_run.task, s_over, s_run.eval_envs, seed)
    s_eval = evaluate_policy(s_mod, s_weights, s_run.task, s_over, s_run.eval_envs, seed)
    with open(os.path.join(s_run.logdir, "metrics.jsonl")) as f:
        rows = [json.loads(line) for line in f]
    z_rows = [r for r in rows if "loss/z_mse" in r]
    t_ret, s_ret = t_eval["eval/return"], s_eval["eval/return"]
    key = f"eval/{plan['compare_metric']}"
    ratio = s_eval[key] / t_eval[key] if t_eval[key] > 0 else float("nan")
    result = {"student_to_teacher": ratio, "compared_metric": plan["compare_metric"], "eval_envs": s_run.eval_envs,
              "eval_seed": 10_000 + seed,
              "student_env_steps": int(meta["counters"]["env_steps"]),
              "z_mse_first": z_rows[0]["loss/z_mse"] if z_rows else None,
              "z_mse_last": z_rows[-1]["loss/z_mse"] if z_rows else None,
              "z_mse_ratio_last": z_rows[-1]["loss/z_mse_ratio"] if z_rows else None,
              **{f"teacher_eval_{k[5:]}": v for k, v in t_eval.items()},
              **{f"student_eval_{k[5:]}": v for k, v in s_eval.items()}}
    logger = MetricLogger(s_run.logdir)
    logger.log(result["student_env_steps"], {"hora/teacher_eval_return": t_ret, "hora/student_eval_return": s_ret,
                                             "hora/student_to_teacher": ratio})
    logger.close()
    with open(os.path.join(plan["root"], "hora_summary.json"), "w") as f:
        json.dump(result, f, indent=2)
    return result


def _spec(task: str, overrides: Mapping[str, Any]) -> Any:
    import tasks

    probe = tasks.make(task, num_envs=1, seed=0, overrides=overrides)
    probe.close()
    return probe.spec


def run_hora(task: str, teacher_recipe: Mapping[str, Any], student_recipe: Mapping[str, Any],
             task_recipe: Mapping[str, Any], default_teacher_steps: int, default_student_steps: int,
             compare_metric: str = "return") -> None:
    """Parses the flags, validates both stages, trains what is left to train, compares the two policies.

    ``compare_metric``: the evaluation metric (``eval/<name>``, e.g. a task tracker's ``rotation_rate``)
    whose student / teacher ratio is ``student_to_teacher``."""

    def train(plan: dict[str, Any]) -> None:
        from unilab_jax.training.trainer import Trainer

        if plan["teacher_done"]:
            print(f"teacher: finished run found in {plan['teacher'][0].logdir}, skipped")
        else:
            summary = cli.new_trainer(Trainer, *plan["teacher"], start_time=cli.PROCESS_START).train()
            print("teacher:", json.dumps(summary, indent=2))
            if summary["interrupted"]:
                print("interrupted during the teacher stage; rerun with --resume to continue")
                return
        summary = cli.new_trainer(Trainer, *plan["student"], start_time=cli.PROCESS_START).train()
        print("student:", json.dumps(summary, indent=2))
        if summary["interrupted"]:
            print("interrupted during the student stage; rerun with --resume to continue")
            return
        print("hora:", json.dumps(_compare(plan), indent=2))
        print(f"logs: {os.path.abspath(plan['root'])}")

    def help_text() -> str:
        from unilab_jax.apps import cli_help

        task_name = cli_help.requested_task(task)
        names = [*cli.run_flags("hora_teacher"), *cli_help.flags_of(__name__)]
        return cli_help.text(cli_help.main_doc(), [
            cli_help.flag_lines("flags", names, {"task": task, "teacher_steps": default_teacher_steps,
                                                 "student_steps": default_student_steps}),
            cli_help.algorithm_lines("hora_teacher", teacher_recipe, "stage 1: hora_teacher"),
            cli_help.algorithm_lines("hora_student", student_recipe, "stage 2: hora_student", "--student_config"),
            cli_help.task_lines(task_name, task_recipe if task_name == task else {})])

    cli.launch(lambda: {**_plan(task, teacher_recipe, student_recipe, task_recipe, default_teacher_steps,
                                default_student_steps), "compare_metric": compare_metric}, train, help=help_text)
