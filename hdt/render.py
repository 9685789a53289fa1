"""Videos of policy rollouts: MuJoCo's offscreen renderer, headless, to MP4 or GIF.

A clip replays rollouts of hdt's own environments: an HL over its LL through
:func:`hdt.transfer.evaluate.trajectory` (which records every LL step's qpos), a flat policy (an LL on
reach, a Full policy) through a scan of its env's ``step``. Each frame sets one LL step's qpos on an
MjData, runs ``mj_forward`` and renders it with ``mujoco.Renderer``; the HL's sub-goal (an LL's goal
on reach) is drawn as a yellow sphere and the task's target (waypoint, maze goal cell) as a red disc,
both visual-only geoms added to the scene. Manipulation is seen from above; navigation and legged
robots by a camera tracking the robot's root body.

OpenGL without a display: ``MUJOCO_GL`` when set, else EGL, else OSMesa, each tried in a subprocess
first (PyOpenGL fixes its platform when it loads, so a failed attempt cannot be retried in-process).
MP4 goes through imageio-ffmpeg's bundled ffmpeg (H.264); GIF through Pillow, also the fallback when
no MP4 encoder works.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import importlib
import os
import subprocess
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from hdt import atomic
from hdt.transfer import rundir

SUBGOAL_RGBA = (1.0, 0.85, 0.0, 1.0)  # yellow: no scene or robot of hdt's is (tests look for it)
TARGET_RGBA = (0.9, 0.1, 0.1, 0.45)
GRID_RGBA = (0.3, 0.35, 0.45, 0.35)
MANIP_MARKER_Z = 0.05  # m: the sub-goal above the block (0.04 m) and the arm, seen from above
FORMATS = (".mp4", ".gif")


class RenderError(RuntimeError):
  """Rendering cannot work here (no headless OpenGL, no encoder); the message says why in one line."""


@dataclasses.dataclass(frozen=True)
class Camera:
  track: bool  # follow the robot's root body (a tracking camera), else a fixed one at ``lookat``
  distance: float  # m
  elevation: float  # degrees; -90 looks straight down
  azimuth: float = 90.0  # degrees; 90: +y points up in the image
  lookat: tuple[float, float, float] = (0.0, 0.0, 0.0)


# Per family: the arms' whole workspace from above (walls at +-0.3 m); a nav robot with its sub-goal box
# (+-4 m) around it; a legged robot closer and lower, so its gait shows.
CAMERAS = {"manip": Camera(False, 0.6, -90.0), "nav": Camera(True, 11.0, -55.0),
           "legged": Camera(True, 7.0, -40.0)}


@dataclasses.dataclass(frozen=True)
class RenderConfig:
  width: int = 480
  height: int = 360
  fps: float | None = None  # None: real time, one frame per LL step
  max_steps: int = 300  # LL steps (frames) per rollout at most
  episodes: int = 1  # rollouts, one after the other, each from its own key
  key: int = 0  # random key of the first rollout (rollout i uses key + i)
  seed_index: int = 0  # which trained seed of the policy acts
  shadows: bool = False  # software OpenGL (llvmpipe) renders shadows ~5x slower
  backend: str = "auto"  # physics backend of the rollouts

  def check(self) -> "RenderConfig":
    """This config, or a ValueError naming the first bad field."""
    for name in ("width", "height"):
      v = getattr(self, name)
      if isinstance(v, bool) or not isinstance(v, int) or not 16 <= v <= 4096 or v % 2:
        raise ValueError(f"{name}={v!r}: give an even number of pixels in 16..4096 (MP4's colour format "
                         f"halves both sizes)")
    for name in ("max_steps", "episodes"):
      v = getattr(self, name)
      if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
        raise ValueError(f"{name}={v!r}: give a positive integer")
    if self.fps is not None and not 0 < self.fps <= 240:
      raise ValueError(f"fps={self.fps!r}: give frames per second in (0, 240], or None for real time")
    return self


@dataclasses.dataclass(frozen=True, eq=False)
class Clip:
  """What a video shows, one row per LL step."""
  model: Any  # mujoco.MjModel of the scene the rollouts ran in
  qpos: np.ndarray  # (T, nq)
  subgoal: np.ndarray | None  # (T, 2): the HL's sub-goal, or an LL's goal on reach
  target: np.ndarray | None  # (T, 2): the task's waypoint or goal cell
  family: str  # a key of CAMERAS
  dt: float  # seconds per LL step
  subgoal_radius: float
  target_radius: float = 0.0

  def __len__(self) -> int:
    return len(self.qpos)

  @property
  def fps(self) -> float:
    """Real time."""
    return 1.0 / self.dt


# -- OpenGL ---------------------------------------------------------------------------------------

_PROBE = """
import mujoco
m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><light pos="0 0 2"/><geom size=".1"/></worldbody></mujoco>')
d = mujoco.MjData(m)
mujoco.mj_forward(m, d)
r = mujoco.Renderer(m, 32, 32)
r.update_scene(d)
assert r.render().max() > 0, "it rendered a black frame"
r.close()
"""


@contextmanager
def _exec_child():
  """Quiets JAX's warning about os.fork in a threaded process: the child execs at once (the probe,
  ffmpeg), which is safe."""
  with warnings.catch_warnings():
    warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
    yield


def _probe(gl: str) -> str | None:
  """None if MUJOCO_GL=``gl`` renders in a fresh process, else the last line of its error."""
  env = dict(os.environ, MUJOCO_GL=gl)
  env.pop("PYOPENGL_PLATFORM", None)  # mujoco's egl / osmesa modules set the one they need
  try:
    with _exec_child():
      p = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120)
  except subprocess.TimeoutExpired:
    return "timed out"
  if p.returncode == 0:
    return None
  lines = [ln.strip() for ln in p.stderr.splitlines() if ln.strip()]
  return lines[-1] if lines else f"exit status {p.returncode}"


@functools.cache
def gl_backend() -> str:
  """The headless OpenGL used here ("egl", "osmesa", or MUJOCO_GL when set), installed as
  ``mujoco.Renderer``'s context; a RenderError says why none works."""
  import mujoco
  asked = os.environ.get("MUJOCO_GL", "").strip().lower()
  errors = []
  for gl in (asked,) if asked else ("egl", "osmesa"):
    why = _probe(gl)
    if why is None:
      _install(mujoco, gl)
      return gl
    errors.append(f"MUJOCO_GL={gl}: {why}")
  raise RenderError("no OpenGL renders here without a display (" + "; ".join(errors) + "); install EGL "
                    "(apt libegl1 libgl1-mesa-dri) or OSMesa (apt libosmesa6), or set MUJOCO_GL")


def _install(mujoco, gl: str) -> None:
  """Makes ``mujoco.Renderer`` create ``gl`` contexts: mujoco picks its context class from MUJOCO_GL
  when it is imported, which in hdt happens before anything renders."""
  os.environ["MUJOCO_GL"] = gl  # for child processes
  renderer_module = sys.modules[mujoco.Renderer.__module__]
  if gl in ("egl", "osmesa", "glfw"):
    renderer_module.gl_context.GLContext = importlib.import_module(f"mujoco.{gl}").GLContext


# -- rollouts -------------------------------------------------------------------------------------

def _target_radius(task) -> float:
  """Radius of the disc drawn at the task's target: the waypoint's reach distance, half a maze cell;
  0 where the scene draws the target itself (BlockPush's destination, PegInsert's slot)."""
  from hdt.envs.tasks import Maze, Waypoint
  if isinstance(task, Waypoint):
    return float(task.reach_dist)
  if isinstance(task, Maze):  # and Steps: the goal cell, obs_hi[2:4]
    return float(task.cell) / 2
  return 0.0


def _agent(policy):
  from hdt.envs import agent_spec
  card = policy.low_card or policy.card
  return agent_spec(card.agent).replace(**card.morphology)


def _hl_episode(policy, task: str, config: RenderConfig, key: int):
  """(model, qpos, sub-goal, target) of one HL episode (at most ``max_steps`` LL steps)."""
  from hdt.envs.tasks import get_task
  from hdt.transfer.evaluate import trajectory
  overrides = dict(policy.card.task_overrides or {}) if task == policy.card.task else {}
  # Every HL step takes one LL step or more: no more HL steps than frames are needed.
  overrides["hl_horizon"] = min(overrides.get("hl_horizon", get_task(task).hl_horizon), config.max_steps)
  tr = trajectory(policy, task, seed_index=config.seed_index, key=key, backend=config.backend, **overrides)
  n = config.max_steps
  return tr["model"], tr["qpos"][:n], tr["step_goals"][:n], tr["block"][:n]


def _flat_episode(policy, task: str, config: RenderConfig, key: int):
  """(model, qpos, goal, target) of a flat policy: ``max_steps`` steps of an LL on reach (its short
  episodes go on from where the robot is, with new goals), else one episode of its task."""
  import jax
  import jax.numpy as jnp
  env = policy.card.make_env(task, config.backend)
  policy.card.check_env(env, task)
  at = lambda tree: jax.tree.map(lambda x: x[config.seed_index], tree)
  apply = policy.card.policy_fn(at(policy.obs_norm))
  reach = env.task.low_level

  def run(params, k):
    def f(s, _):
      n = env.step(s, apply(params, s.obs))
      goal = n.task["t"]["goal"] if reach else jnp.zeros(2)
      target = n.obs_hi[2:4] if n.obs_hi.shape[-1] >= 4 else jnp.zeros(2)
      return n, (n.physics.qpos, goal, target, n.done)
    return jax.lax.scan(f, env.reset(k), None, length=config.max_steps if reach else min(config.max_steps, env.horizon))[1]

  qpos, goal, target, done = jax.device_get(jax.jit(run)(at(policy.params), jax.random.PRNGKey(key)))
  end = len(done) if reach or not np.any(done > 0) else int(np.argmax(done > 0)) + 1
  return env.mj_model, qpos[:end], goal[:end], target[:end]


def rollout(policy, task: str | None = None, config: RenderConfig = RenderConfig()) -> Clip:
  """The clip of ``config.episodes`` deterministic rollouts of ``policy``
  (:class:`hdt.transfer.evaluate.Policy`: an HL over an LL, or a flat policy) on ``task`` (default:
  its own)."""
  from hdt.envs.tasks import get_task
  config.check()
  if not 0 <= config.seed_index < policy.num_seeds:
    raise ValueError(f"seed_index={config.seed_index}: the policy has seeds 0..{policy.num_seeds - 1}")
  task = task or policy.card.task
  task_obj = get_task(task)
  episode = _hl_episode if policy.low_card is not None else _flat_episode
  parts = [episode(policy, task, config, config.key + i) for i in range(config.episodes)]
  spec = _agent(policy)
  cat = lambda i: np.concatenate([np.asarray(p[i], np.float64) for p in parts])
  has_subgoal = policy.low_card is not None or task_obj.low_level
  radius = _target_radius(task_obj)
  model = parts[0][0]
  return Clip(model=model, qpos=cat(1), subgoal=cat(2) if has_subgoal else None,
              target=cat(3) if radius > 0 else None, family="legged" if spec.legged else spec.family,
              dt=float(model.opt.timestep * spec.frame_skip), subgoal_radius=max(spec.reach_eps, 0.01),
              target_radius=radius)


# -- frames ---------------------------------------------------------------------------------------

def camera(model, family: str):
  """The ``mujoco.MjvCamera`` of a family (CAMERAS)."""
  import mujoco
  from hdt.envs.model import AGENT_PREFIX
  c = CAMERAS[family]
  cam = mujoco.MjvCamera()
  if c.track:
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, AGENT_PREFIX + "root")
  else:
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = c.lookat
  cam.distance, cam.elevation, cam.azimuth = c.distance, c.elevation, c.azimuth
  return cam


def _add_geom(scene, kind, size, pos, rgba, emission: float = 0.0) -> None:
  """A visual-only geom in a scene already filled by ``update_scene`` (none if the scene is full)."""
  import mujoco
  if scene.ngeom >= scene.maxgeom:
    return
  g = scene.geoms[scene.ngeom]
  mujoco.mjv_initGeom(g, kind, np.asarray(size, np.float64), np.asarray(pos, np.float64),
                      np.eye(3).ravel(), np.asarray(rgba, np.float32))
  g.emission = emission
  scene.ngeom += 1


def _add_grid(scene, center, half: int = 25, step: float = 1.0) -> None:
  """Floor lines every ``step`` m within ``half`` steps of ``center``, aligned to the world grid."""
  import mujoco
  cx, cy = np.round(np.asarray(center) / step) * step
  for i in range(-half, half + 1):
    for a, b in (((cx + i * step, cy - half * step), (cx + i * step, cy + half * step)),
                 ((cx - half * step, cy + i * step), (cx + half * step, cy + i * step))):
      if scene.ngeom >= scene.maxgeom:
        return
      g = scene.geoms[scene.ngeom]
      mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(),
                          np.asarray(GRID_RGBA, np.float32))
      mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, 1.5, np.array([*a, 0.01]), np.array([*b, 0.01]))
      scene.ngeom += 1


def frames(clip: Clip, config: RenderConfig = RenderConfig()) -> Iterator[np.ndarray]:
  """The clip's frames, (height, width, 3) uint8 each, rendered one at a time."""
  import mujoco
  from hdt.envs.model import AGENT_PREFIX
  config.check()
  gl_backend()
  model = copy.copy(clip.model)  # the offscreen buffer must hold the frame
  model.vis.global_.offwidth = max(model.vis.global_.offwidth, config.width)
  model.vis.global_.offheight = max(model.vis.global_.offheight, config.height)
  data = mujoco.MjData(model)
  point = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, AGENT_PREFIX + "goal_point")
  root = max(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, AGENT_PREFIX + "root"), 0)
  cam = camera(model, clip.family)
  renderer = mujoco.Renderer(model, config.height, config.width)
  try:
    for t in range(len(clip)):
      data.qpos[:] = clip.qpos[t]
      mujoco.mj_forward(model, data)
      renderer.update_scene(data, cam)
      scene = renderer.scene
      scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = config.shadows
      scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
      if clip.target is not None:
        r = clip.target_radius
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER, (r, r, 0.01), (*clip.target[t], 0.01), TARGET_RGBA)
      if clip.family != "manip":  # a tracked robot moves over a plain floor: lines show it moving
        _add_grid(scene, data.xpos[root][:2])
      if clip.subgoal is not None:
        # Above the block and the arm (seen from above); at the torso of a nav robot.
        z = MANIP_MARKER_Z if clip.family == "manip" else data.site_xpos[point][2] if point >= 0 else 0.0
        # emission 1: the same flat colour under any light, so a viewer (and a test) finds it
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, (clip.subgoal_radius,) * 3, (*clip.subgoal[t], z),
                  SUBGOAL_RGBA, emission=1.0)
      yield renderer.render().copy()
  finally:
    renderer.close()


# -- files ----------------------------------------------------------------------------------------

def mp4_encoder() -> str:
  """The ffmpeg binary that writes MP4 here, or a RenderError saying why there is none."""
  try:
    import imageio_ffmpeg
    return imageio_ffmpeg.get_ffmpeg_exe()
  except (ImportError, RuntimeError) as e:
    raise RenderError(f"no MP4 encoder ({' '.join(str(e).split())}): `pip install imageio-ffmpeg`, or write a "
                      f".gif") from None


def check_out(out: str | Path, overwrite: bool = False) -> Path:
  """``out`` if a video may be written there: an .mp4 or .gif path, not an existing file unless
  ``overwrite``."""
  out = Path(out)
  if out.suffix.lower() not in FORMATS:
    raise ValueError(f"{out}: name the video .mp4 or .gif")
  if out.is_dir():
    raise ValueError(f"{out} is a directory: give a file name ending in .mp4 or .gif")
  rundir.refuse_zoo(out, "--out", "a file outside it")
  if out.exists() and not overwrite:
    raise ValueError(f"{out} exists: pass --overwrite (overwrite=True) to replace it, or give another file name")
  return out


def write(images: Iterable[np.ndarray], out: str | Path, fps: float, overwrite: bool = False) -> Path:
  """Writes the frames to ``out`` (.mp4, or .gif) through a hidden temporary renamed into place and
  returns the path written: a .gif beside ``out`` when MP4 was asked for and no encoder works here."""
  out = check_out(out, overwrite)
  if out.suffix.lower() == ".mp4":
    try:
      mp4_encoder()
    except RenderError as e:
      gif = out.with_suffix(".gif")
      print(f"hdt render: {e}; writing {gif} instead", file=sys.stderr)
      return write(images, check_out(gif, overwrite), fps, overwrite)
  out.parent.mkdir(parents=True, exist_ok=True)
  with atomic.temp_path(out) as tmp:  # a killed render leaves no half-written video under the name
    n = _write_mp4(images, tmp, fps) if out.suffix.lower() == ".mp4" else _write_gif(images, tmp, fps)
    if n == 0:
      raise ValueError("no frames to write: the rollout took no steps")
  return out


def _write_mp4(images, path: str, fps: float) -> int:
  import imageio_ffmpeg
  n, writer = 0, None
  try:
    for img in images:
      if writer is None:
        h, w = img.shape[:2]
        # H.264 in yuv420p plays everywhere (browsers, QuickTime); -f: the temporary has no .mp4 suffix
        writer = imageio_ffmpeg.write_frames(path, (w, h), fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                                             macro_block_size=2, quality=7, ffmpeg_log_level="error",
                                             output_params=["-f", "mp4"])
        with _exec_child():
          writer.send(None)  # starts ffmpeg
      writer.send(np.ascontiguousarray(img))
      n += 1
  finally:
    if writer is not None:
      writer.close()
  return n


def _write_gif(images, path: str, fps: float) -> int:
  from PIL import Image
  pics = [Image.fromarray(img).quantize(colors=255, method=Image.Quantize.MEDIANCUT) for img in images]
  if pics:
    pics[0].save(path, format="GIF", save_all=True, append_images=pics[1:], loop=0,
                 duration=max(20, round(1000 / fps)), disposal=1)
  return len(pics)


def render(policy, out: str | Path, task: str | None = None, config: RenderConfig = RenderConfig(),
           overwrite: bool = False) -> Path:
  """Renders ``policy``'s rollouts on ``task`` to ``out`` (.mp4 or .gif) and returns the path written."""
  check_out(out, overwrite)
  config.check()
  gl_backend()  # before the rollout: say at once when nothing can render
  clip = rollout(policy, task, config)
  return write(frames(clip, config), out, config.fps or clip.fps, overwrite)


def load(policy: str | Path | None = None, high: str | Path | None = None, low: str | Path | None = None,
         box: str = "refuse"):
  """The Policy to render: a flat ``policy`` run (an LL, or Full), or the HL ``high`` over the LL ``low``
  (run directories or zoo:NAME)."""
  from hdt.transfer.evaluate import compose, load_policy
  if policy is not None and (high is not None or low is not None):
    raise ValueError("render either a flat policy, or an HL over an LL (high and low), not both")
  if policy is not None:
    return load_policy(policy)
  if high is None or low is None:
    raise ValueError("render needs a policy run, or both an HL run (high) and an LL run (low)")
  return compose(high, low, box=box)
