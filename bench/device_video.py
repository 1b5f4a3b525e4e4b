"""A policy's video on the GPU machine, which has OpenCV but not imageio-ffmpeg (the device's package list,
KINDS.md): the frames of ``unilab_jax.play.rollout_frames`` written by OpenCV's MPEG-4 Part 2 encoder, then
re-encoded to H.264 here, where imageio-ffmpeg brings ffmpeg:

    python3 bench/device_video.py --logdir RUN --out stairs_up.mp4 --steps 400 \
        --task_config "terrain_columns=('stairs_up',)"
    python bench/device_video.py --transcode stairs_up.mp4 docs/go1_stairs_up.mp4      # here
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys


def write_mp4v(frames, path: str, fps: int) -> None:
    """Frames [T, H, W, 3] uint8 (RGB) as an MPEG-4 Part 2 mp4 through OpenCV."""
    import cv2

    t, h, w, _ = frames.shape
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path}")
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()


def transcode(src: str, dst: str) -> None:
    """``src`` re-encoded as H.264 (yuv420p: browsers and players), by imageio-ffmpeg's ffmpeg."""
    import imageio_ffmpeg

    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-loglevel", "error", "-y", "-i", src, "-c:v", "libx264",
                    "-pix_fmt", "yuv420p", dst], check=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--logdir", help="the training run's logdir")
    parser.add_argument("--out", help="the mp4 to write (MPEG-4 Part 2)")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--task_config", action="append", default=[], help="task override key=value (repeatable)")
    parser.add_argument("--transcode", nargs=2, metavar=("SRC", "DST"), help="re-encode SRC as H.264 into DST")
    args = parser.parse_args(argv)
    if args.transcode:
        transcode(*args.transcode)
        return 0
    if not (args.logdir and args.out):
        parser.error("--logdir and --out are required (or --transcode SRC DST)")
    from unilab_jax.apps.play import rollout_frames
    from unilab_jax.config import parse_overrides

    frames, stats = rollout_frames(args.logdir, steps=args.steps, width=args.width, height=args.height,
                                   task_overrides=parse_overrides(args.task_config))
    write_mp4v(frames, args.out, stats["fps"])
    print(json.dumps({**stats, "video": args.out, "frames": int(frames.shape[0])}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
