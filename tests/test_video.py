"""Clips: every engine's trial drawn headless, not blank, the robot in frame; a clip drawn from a recording equals
the one drawn while the trial ran; bad paths are one line."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from benchmark.trial.policies import SeedPolicy
from benchmark.trial.runner import EpisodeConfig, run_trial
from benchmark.trial.video import Scene, TrackHook, VideoConfig, render_frames
from sims import available_sims

BENCH = [sys.executable, "-m", "benchmark.cli"]
SMALL = VideoConfig(width=240, height=136)


@pytest.mark.parametrize("sim_name, robot_name, terrain", [(s, "a1", "flat") for s in available_sims()]
                         + [("mujoco", "anymal", "rough")])
def test_every_engines_trial_draws_frames_that_show_the_robot(make, sim_name, robot_name, terrain):
    sim = make(sim_name, robot_name, terrain)
    robot = sim.robot
    hook = TrackHook()
    result = run_trial(sim, robot, sim.terrain, SeedPolicy(robot), EpisodeConfig(duration=1.0, eval_start=0.5), seed=1,
                       on_step=hook.on_step)
    track = hook.track(eval_start=0.5, acting="the model", fall_time=result.fall_time)
    assert len(track.times) == result.control_steps == 10
    frames = render_frames(track, robot, sim.terrain, SMALL)
    assert len(frames) == 10 and frames[0].shape == (136, 240, 3) and frames[0].dtype == np.uint8
    scene = Scene(robot, sim.terrain, SMALL)
    try:
        for i in (0, 5, 9):
            scene.reset_camera()
            scene.pose(track.base_pos[i], track.base_quat[i], track.joint_pos[i])
            image, mask = scene.draw(), scene.draw(segmentation=True)
            assert image.std() > 10, "a blank frame"
            share = mask.mean()
            assert 0.01 < share < 0.5, f"the robot covers {share:.1%} of the frame"
            rows, cols = np.nonzero(mask)
            assert 0.25 < cols.mean() / mask.shape[1] < 0.75 and 0.25 < rows.mean() / mask.shape[0] < 0.8, \
                "the robot is not near the middle of the frame"
            floor = image[~mask].astype(float).mean(axis=0)
            robot_pixels = image[mask].astype(float).mean(axis=0)
            assert np.abs(robot_pixels - floor).max() > 20, "the robot's pixels look like the floor's"
    finally:
        scene.close()
    # the frames move: the robot walks and the banner's clock runs
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1.0


def test_the_banner_says_who_acts_and_marks_a_fall():
    """The takeover changes the banner's colour; after a fall a red line is added."""
    from benchmark.trial.video import FALL_COLOR, MODEL_COLOR, SEED_COLOR, Track
    from robots import load_robot
    from sims.terrain import Terrain

    robot = load_robot("a1")
    n = 4
    track = Track(np.arange(1, n + 1) * 0.1, np.tile([0.0, 0.0, 0.3], (n, 1)), np.tile([1.0, 0, 0, 0], (n, 1)),
                  np.tile(robot.default_pose, (n, 1)), eval_start=0.2, acting="the model", fall_time=0.4)
    frames = render_frames(track, robot, Terrain("flat"), SMALL)

    def has(frame, color):
        return bool(np.any(np.all(frame[:30, :120] == color, axis=-1)))

    assert has(frames[0], SEED_COLOR) and not has(frames[0], MODEL_COLOR)
    assert has(frames[2], MODEL_COLOR) and not has(frames[2], FALL_COLOR)
    assert has(frames[3], FALL_COLOR)


def test_a_clip_drawn_from_the_recording_equals_the_one_drawn_during_the_run(tmp_path):
    import imageio.v3 as iio

    run = subprocess.run([*BENCH, "run", "--policy", "rl", "--trials", "1", "--duration", "1.5", "--record",
                          str(tmp_path / "walk.rrd"), "--video", str(tmp_path / "live.gif"), "--video-width", "200",
                          "--video-height", "120"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "clip: " in run.stderr and (tmp_path / "live.gif").is_file()
    again = subprocess.run([*BENCH, "render", str(tmp_path / "walk.rrd"), "--out", str(tmp_path / "again.gif"),
                            "--video-width", "200", "--video-height", "120"], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    live, redrawn = iio.imread(tmp_path / "live.gif"), iio.imread(tmp_path / "again.gif")
    assert live.shape == redrawn.shape == (15, 120, 200, 3)
    # Rerun keeps the base pose in float32: a few edge pixels may differ, nothing more
    differing = np.any(live != redrawn, axis=-1).mean(axis=(1, 2))
    assert differing.max() < 0.005, differing
    mp4 = subprocess.run([*BENCH, "render", str(tmp_path / "walk.rrd"), "--out", str(tmp_path / "part.mp4"),
                          "--video-from", "0.5", "--video-to", "1.0"], capture_output=True, text=True, timeout=300)
    assert mp4.returncode == 0, mp4.stderr
    frames = _mp4_frames(tmp_path / "part.mp4")
    assert len(frames) == 6 and frames[0].shape == (270, 480, 3) and frames[0].std() > 10


def _mp4_frames(path) -> list[np.ndarray]:
    """Every frame of an MP4, decoded by ffmpeg."""
    import imageio.v2 as imageio

    with imageio.get_reader(path, format="FFMPEG") as reader:
        return [reader.get_data(i) for i in range(reader.count_frames())]


@pytest.mark.parametrize("argv, message", [
    (["run", "--policy", "rl", "--video", "walk.avi"], "unknown format '.avi'; valid: .gif, .mp4"),
    (["render", "missing.rrd", "--out", "x.gif"], "recording 'missing.rrd' not found"),
    (["render", "NOT_AN_RRD", "--out", "x.gif"], "is not a Rerun recording"),
    (["render", "NOT_AN_RRD", "--out", "x.gif", "--video-width", "0"], "must be > 0"),
])
def test_bad_clip_input_is_one_line_and_exit_2(argv, message, tmp_path):
    (tmp_path / "NOT_AN_RRD").write_text("hello")
    out = subprocess.run([*BENCH, *argv], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and message in out.stderr, out.stderr
