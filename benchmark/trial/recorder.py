"""Rerun recordings of episodes: the robot and terrain in 3D, joint and base time series, and
for LLM runs the prompt's newest lines, the raw replies, the parsed actions and what the seed
policy would have done at the same moment.

Everything per step is buffered in numpy and written with `send_columns` once the trial ends
(one `rr.log` per value per step is ~40x slower). Geometry is static, read from the robot's
URDF; body poses come from the engine, so the recorder works the same for every engine.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from benchmark.trial.control import ControlLoop
from benchmark.trial.runner import TrialResult
from benchmark.trial.video import Track, track_labels
from robots import CANONICAL_JOINTS, LEGS, Robot, load_robot
from robots.derive_urdf import rpy_to_matrix
from sims.terrain import Terrain

TIMELINE = "sim_time"
META_ENTITY = "meta"  # a static JSON text: the cell a recording was made in, and its outcome
RESULT_FIELDS = ("nwt", "success", "distance_m", "fall_time", "fall_reason", "stop_time")
AXES = ("x", "y", "z")
ROBOT_COLOR = (200, 170, 90)
TERRAIN_COLOR = (110, 120, 130)


@dataclass(frozen=True)
class Shape:
    link: str
    kind: str  # box, cylinder or sphere
    size: tuple[float, ...]  # box: full sizes; cylinder: (radius, length); sphere: (radius,)
    position: np.ndarray
    quat_xyzw: np.ndarray


def _quat_xyzw(m: np.ndarray) -> np.ndarray:
    w = np.sqrt(max(0.0, 1.0 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    if w > 1e-6:
        return np.array([(m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w), w])
    i = int(np.argmax(np.diag(m)))
    j, k = (i + 1) % 3, (i + 2) % 3
    q = np.zeros(4)
    q[i] = np.sqrt(max(0.0, 1.0 + m[i, i] - m[j, j] - m[k, k])) / 2
    q[j] = (m[j, i] + m[i, j]) / (4 * q[i])
    q[k] = (m[k, i] + m[i, k]) / (4 * q[i])
    q[3] = (m[k, j] - m[j, k]) / (4 * q[i])
    return q


@cache
def urdf_shapes(urdf: Path) -> list[Shape]:
    """The collision primitives of every link, in link coordinates (parsed once per file)."""
    shapes = []
    for link in ET.parse(urdf).getroot().findall("link"):
        for collision in link.findall("collision"):
            geometry = collision.find("geometry")[0]
            origin = collision.find("origin")
            xyz = np.array([float(v) for v in origin.get("xyz", "0 0 0").split()]) if origin is not None else np.zeros(3)
            rpy = np.array([float(v) for v in origin.get("rpy", "0 0 0").split()]) if origin is not None else np.zeros(3)
            if geometry.tag == "box":
                size = tuple(float(v) for v in geometry.get("size").split())
            elif geometry.tag == "cylinder":
                size = (float(geometry.get("radius")), float(geometry.get("length")))
            elif geometry.tag == "sphere":
                size = (float(geometry.get("radius")),)
            else:
                continue
            shapes.append(Shape(link.get("name"), geometry.tag, size, xyz, _quat_xyzw(rpy_to_matrix(rpy))))
    return shapes


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of x, y, z, w quaternions, broadcast over leading axes."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(np.broadcast_to(b, a.shape), -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v by x, y, z, w quaternions q, broadcast over leading axes."""
    u, w = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(u, np.broadcast_to(v, u.shape))
    return v + w * t + np.cross(u, t)


class Recorder:
    """Collects one trial through the runner's `on_step` hook and writes it to an .rrd file."""

    def __init__(self, path: Path, robot: Robot, terrain: Terrain, sim, policy=None, name: str = "",
                 meta: dict | None = None) -> None:
        self.path, self.robot, self.terrain, self.sim, self.policy = Path(path), robot, terrain, sim, policy
        self.name = name or self.path.stem
        self.meta = meta or {}  # the trial's cell (engine, robot, terrain, policy, takeover): read back by `bench render`
        self.times: list[float] = []
        self.body_pos: list[np.ndarray] = []
        self.body_quat: list[np.ndarray] = []
        self.rows: dict[str, list] = {k: [] for k in ("lin_vel", "ang_vel", "joint_pos", "targets",
                                                      "torques", "contacts", "actions", "seed_actions")}
        self.body_names: tuple[str, ...] = ()
        self.events: list[tuple[float, str]] = []

    def on_step(self, loop: ControlLoop) -> None:
        poses = self.sim.body_poses()
        self.body_names = poses.names
        s = loop.state
        self.times.append(loop.time)
        self.body_pos.append(poses.positions)
        self.body_quat.append(poses.quats[:, [1, 2, 3, 0]])  # w,x,y,z -> Rerun's x,y,z,w
        # State arrays are fresh each step; the action may be a policy's reused buffer: copy it.
        for key, value in (("lin_vel", s.base_lin_vel), ("ang_vel", s.base_ang_vel),
                           ("joint_pos", s.joint_pos), ("targets", loop.targets), ("torques", s.joint_torque),
                           ("contacts", s.foot_contact), ("actions", np.array(loop.action, dtype=float))):
            self.rows[key].append(value)
        seed_action = getattr(self.policy, "seed_action", None)
        if seed_action is not None:
            self.rows["seed_actions"].append(np.array(seed_action, dtype=float))
        if loop.fall is not None:
            self.events.append((loop.time, f"fall: {loop.fall}"))

    def write(self, result: TrialResult | None = None) -> Path:
        import rerun as rr
        import rerun.blueprint as rrb

        rec = rr.RecordingStream("promptwalk", recording_id=self.name)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        rec.save(self.path, default_blueprint=self._blueprint(rrb))
        self._log_static(rec, rr)
        outcome = {} if result is None else {"result": {k: getattr(result, k) for k in RESULT_FIELDS}}
        rec.log(META_ENTITY, rr.TextDocument(json.dumps({"name": self.name, **self.meta, **outcome}, default=str),
                                             media_type="text/plain"), static=True)
        if self.times:
            self._log_series(rec, rr)
        rec.set_time(TIMELINE, duration=0.0)
        rec.log("events", rr.TextLog(f"{self.name}: {self.robot.title}, terrain {self.terrain.kind}"))
        for t, text in self.events:
            rec.set_time(TIMELINE, duration=t)
            rec.log("events", rr.TextLog(text, level="WARN"))
        for query in getattr(self.policy, "queries", []):
            rec.set_time(TIMELINE, duration=query.time)
            rec.log("llm/prompt", rr.TextLog(query.prompt_tail))
            rec.log("llm/reply", rr.TextLog(query.reply.text, level="INFO" if query.parsed else "ERROR"))
        if result is not None:
            rec.set_time(TIMELINE, duration=self.times[-1] if self.times else 0.0)
            rec.log("events", rr.TextLog(f"trial done: NWT {result.nwt:.3f}, success {result.success}, "
                                         f"distance {result.distance_m:.2f} m"))
        rec.disconnect()  # flushes the file
        return self.path


    def _blueprint(self, rrb):
        """3D view following the base, beside joint, torque and base-velocity plots and the text logs."""
        base = f"/world/robot/{self.robot.base_link}"
        height = self.robot.init_height
        eye = rrb.EyeControls3D(position=(-4 * height, -5 * height, 2.5 * height), look_target=(0.0, 0.0, height / 2),
                                tracking_entity=base)
        text = [rrb.TextLogView(origin="/events", name="events")]
        if hasattr(self.policy, "queries"):
            text.append(rrb.TextLogView(origin="/llm", name="LLM dialogue"))
        joints = ["/joints/position", "/joints/target"] + (["/joints/seed_policy_action", "/joints/action"]
                                                            if hasattr(self.policy, "queries") else [])
        return rrb.Blueprint(rrb.Horizontal(
            rrb.Spatial3DView(origin="/world", name="robot", eye_controls=eye),
            rrb.Vertical(rrb.TimeSeriesView(origin="/joints", contents=joints, name="joint position and target (rad)"),
                         rrb.TimeSeriesView(origin="/joints/torque", name="joint torque (N m)"),
                         rrb.TimeSeriesView(origin="/base/linear_velocity", name="base velocity (m/s)"), *text),
            column_shares=[3, 2]))

    def _log_static(self, rec, rr) -> None:
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        t = self.terrain
        if t.is_flat:
            rec.log("world/terrain", rr.Boxes3D(centers=[[*t.center, -0.005]], half_sizes=[[t.length / 2, t.width / 2,
                                                                                             0.005]],
                                                colors=[TERRAIN_COLOR], fill_mode="solid"), static=True)
        else:  # the core where robots walk at full resolution; the margin around it every MARGIN_STRIDE points
            rows, cols = t.core
            rec.log("world/terrain", _grid_mesh(rr, t.grid_x[cols], t.grid_y[rows], t.heights[rows, cols]),
                    static=True)
            k = MARGIN_STRIDE
            rec.log("world/terrain_margin", _grid_mesh(rr, t.grid_x[::k], t.grid_y[::k], t.heights[::k, ::k] - 0.002),
                    static=True)
        for kind, shapes in self._shapes_by_kind().items():  # sizes are static; poses come per step
            colors = [ROBOT_COLOR] * len(shapes)
            if kind == "box":
                archetype = rr.Boxes3D(half_sizes=[np.array(sh.size) / 2 for sh in shapes], colors=colors,
                                       fill_mode="solid")
            elif kind == "cylinder":
                archetype = rr.Cylinders3D(radii=[sh.size[0] for sh in shapes], lengths=[sh.size[1] for sh in shapes],
                                           colors=colors, fill_mode="solid")
            else:
                archetype = rr.Ellipsoids3D(half_sizes=[[sh.size[0]] * 3 for sh in shapes], colors=colors,
                                            fill_mode="solid")
            rec.log(f"world/robot/{kind}", archetype, static=True)

    def _shapes_by_kind(self) -> dict[str, list[Shape]]:
        by_kind: dict[str, list[Shape]] = {}
        for shape in urdf_shapes(self.robot.urdf):
            by_kind.setdefault(shape.kind, []).append(shape)
        return by_kind

    def _log_series(self, rec, rr) -> None:
        """One entity per quantity, one instance per joint/axis: a few dozen send_columns in all."""
        times = rr.TimeColumn(TIMELINE, duration=np.array(self.times))
        n = len(self.times)
        positions, quats = np.stack(self.body_pos), np.stack(self.body_quat)
        base = self.body_names.index(self.robot.base_link)
        rec.send_columns(f"world/robot/{self.robot.base_link}", indexes=[times],
                         columns=rr.Transform3D.columns(translation=positions[:, base], quaternion=quats[:, base]))
        # Every shape in world coordinates, one entity per shape kind: three calls, not one per link.
        columns = {"box": rr.Boxes3D.columns, "cylinder": rr.Cylinders3D.columns, "sphere": rr.Ellipsoids3D.columns}
        for kind, shapes in self._shapes_by_kind().items():
            links = [self.body_names.index(sh.link) for sh in shapes]
            link_q = quats[:, links]  # (steps, shapes, 4) x, y, z, w
            centers = positions[:, links] + _rotate(link_q, np.array([sh.position for sh in shapes]))
            world_q = _quat_mul(link_q, np.array([sh.quat_xyzw for sh in shapes]))
            fields = dict(centers=centers.reshape(-1, 3))
            if kind != "sphere":
                fields["quaternions"] = world_q.reshape(-1, 4)
            rec.send_columns(f"world/robot/{kind}", indexes=[times],
                             columns=columns[kind](**fields).partition([len(shapes)] * n))
        series = [("base/linear_velocity", "lin_vel", AXES), ("base/angular_velocity", "ang_vel", AXES),
                  ("joints/position", "joint_pos", CANONICAL_JOINTS),
                  ("joints/target", "targets", CANONICAL_JOINTS), ("joints/torque", "torques", CANONICAL_JOINTS),
                  ("joints/action", "actions", CANONICAL_JOINTS),
                  ("joints/seed_policy_action", "seed_actions", CANONICAL_JOINTS), ("feet/contact", "contacts", LEGS)]
        for entity, key, names in series:
            if not self.rows[key]:
                continue
            values = np.stack(self.rows[key]).astype(float)
            rec.log(entity, rr.SeriesLines(names=list(names)), static=True)
            rec.send_columns(entity, indexes=[times],
                             columns=rr.Scalars.columns(scalars=values.ravel()).partition([values.shape[1]] * n))


def read_tracks(path: Path) -> list[Track]:
    """Every trial of a recording (`bench run --record`) as a `Track`: base pose and joint angles per control step,
    the cell it ran in (`track.meta`), who acted and when, read back from the file."""
    from rerun.chunk import RrdReader

    try:
        reader = RrdReader(path)
        entries = reader.recordings()
    except Exception as err:  # noqa: BLE001 - rerun raises its own errors for a file that is not an .rrd
        raise ValueError(f"'{path}' is not a Rerun recording ({str(err).splitlines()[0] if str(err) else err})") from None
    tracks = []
    for entry in entries:
        by_entity: dict[str, list] = {}
        for chunk in reader.stream(store=entry).to_chunks():
            by_entity.setdefault(chunk.entity_path.lstrip("/"), []).append(chunk.to_record_batch())
        if META_ENTITY not in by_entity:
            raise ValueError(f"'{path}' ({entry.recording_id}) was not written by bench run --record of this version: "
                             "it names no cell to draw")
        meta = json.loads(_values(by_entity[META_ENTITY], "TextDocument:text")[0][0])
        robot = load_robot(meta["robot"])
        base = by_entity.get(f"world/robot/{robot.base_link}", [])
        times = np.array([t.total_seconds() for t in _values(base, TIMELINE)])
        order = np.argsort(times, kind="stable")
        joint_batches = [b for b in by_entity.get("joints/position", []) if TIMELINE in b.schema.names]
        joint_times = np.array([t.total_seconds() for t in _values(joint_batches, TIMELINE)])
        joints = np.array(_values(joint_batches, "Scalars:scalars"), dtype=float)[np.argsort(joint_times, kind="stable")]
        xyzw = np.array(_values(base, "Transform3D:quaternion"), dtype=float).reshape(-1, 4)[order]
        result = meta.get("result", {})
        tracks.append(Track(times[order], np.array(_values(base, "Transform3D:translation"), dtype=float)
                            .reshape(-1, 3)[order], xyzw[:, [3, 0, 1, 2]], joints.reshape(len(times), -1),
                            meta=meta, **track_labels(meta, robot, result.get("fall_time"))))
    return tracks


def _values(batches: list, column: str) -> list:
    out = []
    for batch in batches:
        if column in batch.schema.names:
            out += batch.column(column).to_pylist()
    return out


def rerun_command() -> str:
    """The `rerun` executable installed with rerun-sdk (beside this Python, or on PATH)."""
    beside = Path(sys.executable).parent / "rerun"
    found = str(beside) if beside.is_file() else shutil.which("rerun")
    if found is None:
        raise FileNotFoundError("the 'rerun' command of rerun-sdk is not installed; pip install -e .")
    return found


def merge_recordings(parts: list[Path], path: Path) -> Path:
    """One .rrd holding every part as its own recording (`rerun rrd merge` keeps recording ids apart)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    done = subprocess.run([rerun_command(), "rrd", "merge", *map(str, parts), "-o", str(path)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"merging recordings into {path} failed: {done.stderr.strip().splitlines()[-1:]}")
    return path


MARGIN_STRIDE = 5  # grid points: the margin's mesh is drawn at 0.5 m, the core at the grid's 0.1 m


def _grid_mesh(rr, xs: np.ndarray, ys: np.ndarray, heights: np.ndarray):
    """A heightfield patch as a triangle mesh (two triangles a grid cell)."""
    gx, gy = np.meshgrid(xs, ys)
    vertices = np.stack([gx.ravel(), gy.ravel(), heights.ravel()], axis=1)
    idx = np.arange(heights.size).reshape(heights.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    triangles = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return rr.Mesh3D(vertex_positions=vertices, triangle_indices=triangles, albedo_factor=TERRAIN_COLOR)
