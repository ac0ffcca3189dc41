"""Clips of trials: a robot's recorded states drawn headless by MuJoCo's renderer, written as GIF or MP4.

    bench run --llm knn --trials 1 --video walk.gif       record a trial's states, then draw them
    bench render walk.rrd --out walk.mp4                  draw a trial from its Rerun recording

Every engine's trial is drawn the same way: the base pose and the 12 joint angles of each control step (10 Hz)
are put into one MuJoCo model of the robot, built from the same URDF the engines load, on the same terrain, and
drawn from a camera that follows the base. One frame per control step, played in real time (10 frames a
second): what is shown is what the engine computed at those instants, nothing interpolated. A banner names who
acts (the seed policy, then the model from its takeover), a bar along the bottom marks the takeover, and a fall
is named where it happens. Drawing uses OpenGL without a display: EGL (Mesa's software rasterizer where there
is no GPU), else OSMesa (`MUJOCO_GL` chooses when set). Encoding is Pillow's for GIF (one palette
per clip) and imageio's ffmpeg for MP4 (H.264).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmark.common.settings import setting
from robots import Robot
from sims.terrain import Terrain

FORMATS = (".gif", ".mp4")
SEED_COLOR = (70, 130, 200)  # banner and bar: the seed policy acts
MODEL_COLOR = (230, 140, 40)  # the evaluated policy (an LLM from its takeover) acts
FALL_COLOR = (200, 50, 50)
CAPTION_COLOR = (60, 60, 60)
ROBOT_RGBA = (0.78, 0.67, 0.35, 1.0)
FOOT_RGBA = (0.15, 0.15, 0.15, 1.0)


class VideoError(ValueError):
    """A clip that cannot be made (format, size, no OpenGL): one line for the user."""


@dataclass(frozen=True)
class VideoConfig:
    """How a clip looks."""

    width: int = setting(480, "clip width in pixels", positive=True, flag="--video-width")
    height: int = setting(270, "clip height in pixels", positive=True, flag="--video-height")
    start: float = setting(0.0, "s of the episode the clip starts at", minimum=0.0, flag="--video-from")
    end: float | None = setting(None, "s of the episode the clip ends at (default: the trial's end)", positive=True,
                                flag="--video-to")
    distance: float = setting(2.6, "camera distance from the base, in robot heights (twice its init_height)",
                              positive=True, flag="--camera-distance")
    azimuth: float = setting(135.0, "camera azimuth in degrees about the world z axis (90: from the robot's left "
                                    "at the start, 180: from behind)", flag="--camera-azimuth")
    elevation: float = setting(-18.0, "camera elevation in degrees (negative: looking down)", flag="--camera-elevation")
    follow: float = setting(0.3, "fraction of the way the camera's target moves to the base each frame (1: locked "
                                 "on the base; lower smooths bumps)", positive=True, flag="--camera-follow")


@dataclass
class Track:
    """What a clip shows of one trial: the states of every control step and who acted."""

    times: np.ndarray  # (n,) s
    base_pos: np.ndarray  # (n, 3) world
    base_quat: np.ndarray  # (n, 4) w, x, y, z
    joint_pos: np.ndarray  # (n, 12) canonical order
    eval_start: float = 0.0  # s: the evaluated policy's takeover (0: it acts throughout)
    acting: str = "policy"  # who acts from eval_start, for the banner
    seeding: str = "seed policy (PPO)"  # who acts before it
    fall_time: float | None = None
    caption: str = ""  # e.g. "MuJoCo / A1 / flat / seed 0"
    meta: dict = field(default_factory=dict)


class TrackHook:
    """A `TrialHooks`-style collector: the states of every control step of one trial."""

    def __init__(self) -> None:
        self.rows: list[tuple] = []

    def on_step(self, loop) -> None:
        s = loop.state
        self.rows.append((loop.time, s.base_pos.copy(), s.base_quat.copy(), s.joint_pos.copy()))

    def track(self, **labels) -> Track:
        times, pos, quat, joints = zip(*self.rows) if self.rows else ((), (), (), ())
        return Track(np.array(times), np.array(pos).reshape(-1, 3), np.array(quat).reshape(-1, 4),
                     np.array(joints).reshape(len(times), -1), **labels)


def acting_label(params: dict) -> str:
    """Who acts in the evaluated phase, from a cell's parameters: a model and its prompt, else the policy."""
    if params.get("model"):
        return f"LLM: {params['model']} ({params.get('prompt_strategy', 'chronological')})"
    return {"rl": "seed policy (PPO)"}.get(params.get("policy", ""), str(params.get("policy", "policy")))


def caption(params: dict, robot: Robot) -> str:
    """The cell and seed in one line, e.g. 'mujoco / Unitree A1 / flat / seed 0'."""
    return f"{params.get('sim', '?')} / {robot.title} / {params.get('terrain', '?')} / seed {params.get('seed', '?')}"


def track_labels(params: dict, robot: Robot, fall_time: float | None) -> dict:
    """A `Track`'s labels from a trial's cell parameters with its `seed` and `eval_start` (as a recording's meta
    holds them): when the evaluated policy takes over, who it is, the caption, and the fall."""
    return {"eval_start": float(params.get("eval_start", 0.0)), "acting": acting_label(params),
            "caption": caption(params, robot), "fall_time": fall_time}


def clip_path(path: Path, seed: int, many: bool) -> Path:
    """`path` itself for a single trial; `stem-seedN.ext` beside it when a run has several."""
    return path.with_name(f"{path.stem}-seed{seed}{path.suffix}") if many else path


def check_video_path(path: Path) -> None:
    """Fail before a trial runs on a clip format nobody can write."""
    if Path(path).suffix.lower() not in FORMATS:
        raise VideoError(f"clip '{path}': unknown format '{Path(path).suffix}'; valid: {', '.join(FORMATS)}")


def _gl_context(width: int, height: int):
    """An offscreen OpenGL context: MUJOCO_GL's choice when set, else EGL, else OSMesa."""
    chosen = os.environ.get("MUJOCO_GL", "").lower()
    errors = []
    for backend in ([chosen] if chosen in ("egl", "osmesa", "glfw") else ["egl", "osmesa"]):
        try:
            if backend == "egl":
                from mujoco.egl import GLContext
            elif backend == "osmesa":
                from mujoco.osmesa import GLContext
            else:
                from mujoco.glfw import GLContext
            context = GLContext(width, height)
            context.make_current()
            return context
        except Exception as err:  # noqa: BLE001 - a missing library shows as ImportError, OSError or RuntimeError
            errors.append(f"{backend}: {str(err).splitlines()[0] if str(err) else type(err).__name__}")
    raise VideoError("no offscreen OpenGL for MuJoCo's renderer (" + "; ".join(errors) + "); on Debian: "
                     "apt-get install libegl-mesa0 (or libosmesa6 and MUJOCO_GL=osmesa)")


class Scene:
    """One robot on one terrain in MuJoCo, drawn offscreen from a camera that follows its base."""

    def __init__(self, robot: Robot, terrain: Terrain, config: VideoConfig = VideoConfig()) -> None:
        import mujoco

        from sims.base import PhysicsConfig
        from sims.mujoco import build_spec

        self.mujoco, self.robot, self.config = mujoco, robot, config
        spec = build_spec(robot, terrain, PhysicsConfig())
        spec.compiler.discardvisual = False  # keep the textures and materials added here (the URDFs have no visuals)
        spec.visual.global_.offwidth, spec.visual.global_.offheight = config.width, config.height
        spec.visual.quality.shadowsize = 2048
        spec.add_texture(name="sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX, builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                         rgb1=[0.85, 0.9, 0.95], rgb2=[0.55, 0.65, 0.8], width=64, height=64)
        spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
                         rgb1=[0.42, 0.45, 0.5], rgb2=[0.55, 0.58, 0.62], width=256, height=256)
        material = spec.add_material(name="grid", texrepeat=[1, 1], texuniform=True)
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
        feet = set(robot.foot_links)
        for geom in spec.geoms:
            if geom.name == "terrain":
                geom.material = "grid"
            else:
                geom.rgba = FOOT_RGBA if geom.parent.name in feet else ROBOT_RGBA
        spec.worldbody.add_light(pos=[0, 0, 4], dir=[0.3, 0.2, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, castshadow=True,
                                 diffuse=[0.7, 0.7, 0.7], ambient=[0.3, 0.3, 0.3])
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in robot.joints]
        self._qpos_idx = np.array([m.jnt_qposadr[j] for j in ids])
        self._robot_geoms = np.flatnonzero(m.geom_bodyid > 0)
        self._context = _gl_context(config.width, config.height)
        self._mjr = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._mjr)
        self._scene = mujoco.MjvScene(m, maxgeom=2000)
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._camera.distance = config.distance * robot.init_height * 2
        self._camera.azimuth, self._camera.elevation = config.azimuth, config.elevation
        self._viewport = mujoco.MjrRect(0, 0, config.width, config.height)
        self._target: np.ndarray | None = None

    def pose(self, base_pos: np.ndarray, base_quat: np.ndarray, joint_pos: np.ndarray) -> None:
        """Put the robot where the engine had it."""
        d = self.data
        d.qpos[:3], d.qpos[3:7] = base_pos, base_quat
        d.qpos[self._qpos_idx] = joint_pos
        self.mujoco.mj_kinematics(self.model, d)

    def draw(self, segmentation: bool = False) -> np.ndarray:
        """The current pose as an (h, w, 3) uint8 image; with `segmentation`, a boolean (h, w) mask of the robot."""
        mj, c = self.mujoco, self.config
        base = self.data.qpos[:3].copy()
        self._target = base if self._target is None else self._target + c.follow * (base - self._target)
        self._camera.lookat[:] = self._target
        flags = self._scene.flags
        flags[mj.mjtRndFlag.mjRND_SEGMENT] = flags[mj.mjtRndFlag.mjRND_IDCOLOR] = segmentation
        mj.mjv_updateScene(self.model, self.data, self._option, None, self._camera, mj.mjtCatBit.mjCAT_ALL, self._scene)
        mj.mjr_render(self._viewport, self._scene, self._mjr)
        rgb = np.zeros((c.height, c.width, 3), dtype=np.uint8)
        mj.mjr_readPixels(rgb, None, self._viewport, self._mjr)
        rgb = np.flipud(rgb)
        if not segmentation:
            return rgb
        ids = rgb[..., 0].astype(np.int32) + (rgb[..., 1].astype(np.int32) << 8) + (rgb[..., 2].astype(np.int32) << 16)
        segids = ids - 1  # 0 is the background; segid k + 1 is the scene's geom k
        geom_of = np.array([g.objid if g.objtype == mj.mjtObj.mjOBJ_GEOM else -1
                            for g in self._scene.geoms[:self._scene.ngeom]] + [-1])
        geoms = np.where(segids >= 0, geom_of[np.clip(segids, 0, len(geom_of) - 1)], -1)
        return np.isin(geoms, self._robot_geoms)

    def reset_camera(self) -> None:
        self._target = None

    def close(self) -> None:
        self._mjr.free()
        self._context.free()


def _banner(image: np.ndarray, lines: list[tuple[str, tuple[int, int, int]]], progress: float, mark: float | None,
            phase_color: tuple[int, int, int]) -> np.ndarray:
    """Text lines at the top left (each on its own colour) and a progress bar along the bottom."""
    from PIL import Image, ImageDraw, ImageFont

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    font = ImageFont.load_default(size=max(11, image.shape[0] // 20))
    y = 4
    for text, color in lines:
        left, top, right, bottom = draw.textbbox((6, y), text, font=font)
        draw.rectangle((left - 3, top - 2, right + 3, bottom + 2), fill=color)
        draw.text((6, y), text, fill=(255, 255, 255), font=font)
        y = bottom + 6
    h, w = image.shape[:2]
    bar = max(3, h // 60)
    draw.rectangle((0, h - bar, w, h), fill=(40, 40, 40))
    draw.rectangle((0, h - bar, int(progress * w), h), fill=phase_color)
    if mark is not None:
        x = int(mark * w)
        draw.rectangle((x - 1, h - 3 * bar, x + 1, h), fill=MODEL_COLOR)
    return np.asarray(picture)


def render_frames(track: Track, robot: Robot, terrain: Terrain, config: VideoConfig = VideoConfig()) -> list[np.ndarray]:
    """One labelled frame per control step of `track` between `config.start` and `config.end`."""
    end = track.times[-1] if config.end is None or not len(track.times) else min(config.end, track.times[-1])
    keep = np.flatnonzero((track.times >= config.start - 1e-9) & (track.times <= end + 1e-9))
    if not keep.size:
        raise VideoError(f"no control step between {config.start:g} and {end:g} s (the trial ran "
                         f"{track.times[-1] if len(track.times) else 0:g} s)")
    total = max(float(track.times[-1]), 1e-9)
    mark = track.eval_start / total if 0 < track.eval_start < total else None
    scene = Scene(robot, terrain, config)
    frames = []
    try:
        for i in keep:
            t = float(track.times[i])
            scene.pose(track.base_pos[i], track.base_quat[i], track.joint_pos[i])
            model_acts = t > track.eval_start or track.eval_start == 0
            color = MODEL_COLOR if model_acts else SEED_COLOR
            lines = [(f"{track.acting if model_acts else track.seeding}   t = {t:4.1f} s", color)]
            if track.caption:
                lines.append((track.caption, CAPTION_COLOR))
            if track.fall_time is not None and t >= track.fall_time - 1e-9:
                lines.append((f"fell at {track.fall_time:.1f} s", FALL_COLOR))
            frames.append(_banner(scene.draw(), lines, t / total, mark, color))
    finally:
        scene.close()
    return frames


def write_clip(frames: list[np.ndarray], path: Path, fps: float = 10.0) -> Path:
    """Frames into a GIF (looping) or an MP4 (H.264), by the path's suffix."""
    path = Path(path)
    check_video_path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        _write_gif(frames, path, fps)
    else:
        _write_mp4(frames, path, fps)
    return path


GIF_COLORS = 128  # one palette for the whole clip, no dithering: a moving floor then compresses ~2x smaller


def _write_gif(frames: list[np.ndarray], path: Path, fps: float) -> None:
    """A looping GIF through Pillow, every frame on one palette taken from a sample of the frames."""
    from PIL import Image

    sample = np.concatenate(frames[:: max(1, len(frames) // 12)], axis=0)
    swatch = np.zeros((8, sample.shape[1], 3), dtype=np.uint8)  # the banner's colours, however rare in the clip
    for i, color in enumerate((SEED_COLOR, MODEL_COLOR, FALL_COLOR, CAPTION_COLOR, (255, 255, 255))):
        swatch[:, i * 8:(i + 1) * 8] = color
    sample = np.concatenate([sample] + [swatch] * 40, axis=0)
    palette = Image.fromarray(sample).quantize(colors=GIF_COLORS, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:], duration=round(1000.0 / fps), loop=0)


def _write_mp4(frames: list[np.ndarray], path: Path, fps: float) -> None:
    """H.264 in yuv420p (plays in browsers), through the ffmpeg binary that imageio-ffmpeg installs."""
    import imageio.v2 as imageio

    with imageio.get_writer(path, format="FFMPEG", mode="I", fps=fps, codec="libx264", quality=7,
                            pixelformat="yuv420p", macro_block_size=2) as writer:
        for frame in frames:
            writer.append_data(frame)


def render_clip(track: Track, robot: Robot, terrain: Terrain, path: Path, config: VideoConfig = VideoConfig()) -> Path:
    """Draw `track` and write it to `path` (.gif or .mp4) at real time (one frame per 0.1 s control step)."""
    frames = render_frames(track, robot, terrain, config)
    step = float(np.median(np.diff(track.times))) if len(track.times) > 1 else 0.1
    return write_clip(frames, path, fps=1.0 / step)
