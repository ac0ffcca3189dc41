"""Recordings read back: entity paths, one row per simulated control step, the runner's values."""

from __future__ import annotations

import subprocess
import sys
from collections import defaultdict

from pathlib import Path

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


def listening_addresses(port: int) -> set[str]:
    """The addresses a TCP socket listens on at `port`, read from the kernel's tables (/proc/net/tcp, tcp6)."""
    import ipaddress

    found = set()
    for table, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            local, state = line.split()[1], line.split()[3]
            address, _, hex_port = local.partition(":")
            if state == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
                raw = bytes.fromhex(address)
                raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))  # host-order words
                found.add(str(ipaddress.ip_address(raw)) if len(address) == width else address)
    return found


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def walk_rrd(tmp_path_factory) -> Path:
    """`bench run --record walk.rrd` as the README says: two trials in one file."""
    path = tmp_path_factory.mktemp("walk") / "walk.rrd"
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "run", "--policy", "rl", "--trials", "2",
                          "--duration", "1", "--record", str(path)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return path


def test_the_readme_recording_recipe_writes_one_file(walk_rrd):
    from rerun.chunk import RrdReader

    ids = [e.recording_id for e in RrdReader(walk_rrd).recordings()]
    assert ids == ["mujoco-a1-flat-rl-seed0", "mujoco-a1-flat-rl-seed1"]
    assert not list(walk_rrd.parent.glob("walk-seed*.rrd"))


@pytest.mark.parametrize("bind, expected", [(None, "127.0.0.1"), ("127.0.0.2", "127.0.0.2")])
def test_the_web_viewer_listens_on_loopback_unless_told_otherwise(walk_rrd, bind, expected):
    """Both of Rerun's ports (the page and its data) listen only where `--bind` says, 127.0.0.1 by default."""
    import time
    import urllib.request

    port = _free_port()
    extra = ["--bind", bind] if bind else []
    view = subprocess.Popen([sys.executable, "-m", "benchmark.cli", "view", str(walk_rrd), "--web", "--port", str(port),
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        page, deadline = "", time.monotonic() + 60
        while time.monotonic() < deadline and "<html" not in page:
            try:
                page = urllib.request.urlopen(f"http://{expected}:{port}/", timeout=2).read().decode()
            except OSError:
                time.sleep(0.5)
        assert "<html" in page and "Rerun" in page
        assert listening_addresses(port) == {expected} and listening_addresses(port + 1) == {expected}
    finally:
        view.terminate()
        _, err = view.communicate(timeout=30)
    assert f"http://localhost:{port}/" in err and f"on {expected}" in err
    time.sleep(1)
    leftovers = subprocess.run(["pgrep", "-f", f"web-viewer-port {port}"], capture_output=True, text=True).stdout
    assert leftovers == "", "the viewer outlived bench view"


def test_a_bind_address_that_is_not_one_is_one_line(walk_rrd):
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "view", str(walk_rrd), "--web", "--bind", "everywhere"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and "not an IP address" in out.stderr, out.stderr
