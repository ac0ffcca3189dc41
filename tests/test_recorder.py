"""Recordings read back: entity paths, one row per simulated control step, the runner's values."""

from __future__ import annotations

import subprocess
import sys
from collections import defaultdict

import numpy as np
import pytest

from benchmark.trial.policies import SeedPolicy
from benchmark.trial.recorder import Recorder, urdf_shapes
from benchmark.trial.runner import EpisodeConfig, run_trial
from robots import load_robot
from sims import available_sims


def read_back(path) -> dict[str, list]:
    """Entity path -> record batches, from the file."""
    from rerun.chunk import RrdReader

    entities: dict[str, list] = defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        entities[chunk.entity_path].append(chunk.to_record_batch())
    return entities


def _column(batches, suffix: str) -> list:
    rows = []
    for batch in batches:
        name = next((n for n in batch.schema.names if n.endswith(suffix)), None)
        if name is not None:
            rows += batch.column(name).to_pylist()
    return rows


@pytest.mark.parametrize("sim_name", available_sims())
def test_recording_holds_what_the_runner_saw(make, sim_name, tmp_path):
    sim = make(sim_name, "a1", "rough")
    robot, terrain = sim.robot, sim.terrain
    seen = []
    recorder = Recorder(tmp_path / "trial.rrd", robot, terrain, sim, SeedPolicy(robot))

    def hook(loop):
        seen.append((loop.time, loop.state.joint_pos.copy(), loop.state.base_pos.copy(), loop.targets.copy()))
        recorder.on_step(loop)

    result = run_trial(sim, robot, terrain, SeedPolicy(robot), EpisodeConfig(duration=2.0), seed=4, on_step=hook)
    path = recorder.write(result)
    entities = read_back(path)
    steps = result.control_steps
    assert steps == len(seen) >= 5  # 20 unless the robot fell: a fall ends the trial early
    for static in ("/world/terrain", "/world/robot/box", "/world/robot/sphere"):
        assert static in entities, sorted(entities)
    positions = _column(entities["/joints/position"], "Scalars:scalars")
    assert len(positions) == steps
    np.testing.assert_allclose(np.array(positions), np.array([s[1] for s in seen]), atol=1e-9)
    np.testing.assert_allclose(np.array(_column(entities["/joints/target"], "Scalars:scalars")),
                               np.array([s[3] for s in seen]), atol=1e-9)
    base = _column(entities[f"/world/robot/{robot.base_link}"], "Transform3D:translation")
    assert len(base) == steps
    np.testing.assert_allclose(np.array(base).reshape(steps, 3), np.array([s[2] for s in seen]), atol=1e-5)
    for entity in ("/joints/torque", "/base/linear_velocity", "/feet/contact"):
        assert len(_column(entities[entity], "Scalars:scalars")) == steps, entity
    # Shapes move with their links: each foot sphere's centre is that foot link's position.
    spheres = np.array(_column(entities["/world/robot/sphere"], "Ellipsoids3D:centers"))
    poses = sim.body_poses()
    feet = np.array([poses.positions[poses.names.index(f)] for f in robot.foot_links])
    np.testing.assert_allclose(spheres[-1], feet, atol=1e-6)
    assert "/joints/seed_policy_action" not in entities  # only LLM runs have a seed policy beside them
    texts = [text for row in _column(entities["/events"], "TextLog:text") for text in row]
    assert any("trial done" in t for t in texts)
    verify = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(path)], capture_output=True, text=True)
    assert verify.returncode == 0, verify.stderr


def test_urdf_shapes_cover_every_collision_primitive():
    shapes = urdf_shapes(load_robot("anymal").urdf)
    kinds = {s.kind for s in shapes}
    assert kinds == {"cylinder", "sphere"} and sum(s.kind == "sphere" for s in shapes) == 4
    q = np.array([s.quat_xyzw for s in shapes])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)


def test_cli_records_one_file_per_trial(tmp_path):
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "run", "--policy", "stand", "--trials", "2",
                          "--duration", "1", "--record-dir", str(tmp_path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    names = sorted(p.name for p in tmp_path.glob("*.rrd"))
    assert names == ["mujoco-a1-flat-stand-seed0.rrd", "mujoco-a1-flat-stand-seed1.rrd"]
    assert len(_column(read_back(tmp_path / names[1])["/joints/torque"], "Scalars:scalars")) == 10


def test_the_readme_recording_recipe_writes_one_file_and_serves_it_on_loopback(tmp_path):
    """`bench run --record walk.rrd && bench view walk.rrd` as the README says, then the web viewer."""
    import socket
    import time
    import urllib.request

    from rerun.chunk import RrdReader

    path = tmp_path / "walk.rrd"
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "run", "--policy", "rl", "--trials", "2",
                          "--duration", "1", "--record", str(path)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    ids = [e.recording_id for e in RrdReader(path).recordings()]
    assert ids == ["mujoco-a1-flat-rl-seed0", "mujoco-a1-flat-rl-seed1"]
    assert not list(tmp_path.glob("walk-seed*.rrd"))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    view = subprocess.Popen([sys.executable, "-m", "benchmark.cli", "view", str(path), "--web", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        page, deadline = "", time.monotonic() + 60
        while time.monotonic() < deadline and "<html" not in page:
            try:
                page = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2).read().decode()
            except OSError:
                time.sleep(0.5)
        assert "<html" in page and "Rerun" in page
    finally:
        view.terminate()
        _, err = view.communicate(timeout=30)
    assert f"http://localhost:{port}/" in err
    time.sleep(1)
    leftovers = subprocess.run(["pgrep", "-f", f"web-viewer-port {port}"], capture_output=True, text=True).stdout
    assert leftovers == "", "the viewer outlived bench view"
