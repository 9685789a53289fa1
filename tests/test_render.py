"""hdt.render: frames of two agents are not blank and show the sub-goal marker; videos decode to their
frames; an existing file is kept unless overwrite."""

import dataclasses

import jax
import numpy as np
import pytest
from PIL import Image

from hdt import render
from hdt.agents import networks as nets
from hdt.agents.sac import SACConfig
from hdt.envs import make
from hdt.transfer.card import PolicyCard
from hdt.transfer.evaluate import Policy

CFG = render.RenderConfig(width=160, height=120, max_steps=5)


@pytest.fixture(scope="module", autouse=True)
def gl():
  try:
    return render.gl_backend()
  except render.RenderError as e:
    pytest.skip(f"no headless OpenGL here: {e}")


def random_policy(agent: str) -> Policy:
  """An untrained LL of ``agent`` on reach, built as training builds one (its card and parameters)."""
  env = make(agent, "reach")
  card = PolicyCard.from_env(env, "low", SACConfig(hidden_sizes=(16, 16)))
  net = nets.make_sac_networks(env.observation_size, env.action_size, (16, 16))
  return Policy(jax.tree.map(lambda x: x[None], net.policy_init(jax.random.PRNGKey(0))), card)


@pytest.fixture(scope="module")
def arm_clip():
  """The PM's HL over the 3-link arm's LL on BlockPush (zoo policies): a composed rollout."""
  policy = render.load(high="zoo:arm_point/push1", low="zoo:arm3/low_paper")
  return render.rollout(policy, "push1", CFG)


@pytest.fixture(scope="module")
def point_clip():
  return render.rollout(random_policy("point"), None, CFG)


def marker_pixels(frame: np.ndarray) -> int:
  """Pixels of the sub-goal's yellow (drawn with emission 1: the same colour under any light)."""
  r, g, b = (frame[..., i].astype(int) for i in range(3))
  return int(np.sum((r > 200) & (g > 170) & (b < 80)))


@pytest.mark.parametrize("name", ["arm_clip", "point_clip"])
def test_frames_show_the_robot_and_the_sub_goal(name, request):
  clip = request.getfixturevalue(name)
  assert len(clip) == CFG.max_steps and clip.subgoal is not None
  assert clip.family == {"arm_clip": "manip", "point_clip": "nav"}[name]
  assert np.ptp(clip.qpos, axis=0).max() > 1e-4  # the robot moves between frames
  frames = list(render.frames(clip, CFG))
  assert len(frames) == CFG.max_steps
  for f in frames:
    assert f.shape == (CFG.height, CFG.width, 3) and f.dtype == np.uint8
    assert f.std() > 10, "a blank frame"
    assert marker_pixels(f) >= 4, "no sub-goal marker"
  # The yellow is the marker's alone: without it no pixel has that colour.
  bare = next(render.frames(dataclasses.replace(clip, subgoal=None), CFG))
  assert marker_pixels(bare) == 0


def test_videos_decode_to_their_frames(arm_clip, tmp_path):
  import imageio_ffmpeg
  frames = list(render.frames(arm_clip, CFG))
  mp4 = render.write(frames, tmp_path / "arm.mp4", fps=10)
  reader = imageio_ffmpeg.read_frames(str(mp4))
  meta = next(reader)
  assert tuple(meta["size"]) == (CFG.width, CFG.height) and sum(1 for _ in reader) == len(frames)
  # GIF: distinct frames (Pillow merges identical neighbours into one longer frame)
  colours = [np.full((CFG.height, CFG.width, 3), 40 * i, np.uint8) for i in range(4)]
  gif = render.write(colours, tmp_path / "c.gif", fps=10)
  assert Image.open(gif).n_frames == 4
  # No MP4 encoder: a GIF beside the asked-for path.
  with pytest.MonkeyPatch.context() as mp:
    mp.setattr(render, "mp4_encoder", lambda: (_ for _ in ()).throw(render.RenderError("none here")))
    assert render.write(colours, tmp_path / "d.mp4", fps=10) == tmp_path / "d.gif"
  # An existing file is kept unless overwrite; no temporary is left behind.
  with pytest.raises(ValueError, match="exists"):
    render.write(colours, mp4, fps=10)
  assert render.write(colours, mp4, fps=10, overwrite=True) == mp4
  assert sorted(p.name for p in tmp_path.iterdir()) == ["arm.mp4", "c.gif", "d.gif"]


def test_bad_sizes_are_refused():
  with pytest.raises(ValueError, match="even number"):
    render.RenderConfig(width=161).check()
  with pytest.raises(ValueError, match=r"\.mp4 or \.gif"):
    render.check_out("clip.avi")


def test_a_video_is_never_written_into_the_zoo(tmp_path, monkeypatch):
  from hdt.transfer import names
  monkeypatch.setattr(names, "ZOO_DIR", tmp_path / "zoo")
  (tmp_path / "zoo" / "ant").mkdir(parents=True)
  with pytest.raises(ValueError, match="lies in the model zoo"):
    render.check_out(tmp_path / "zoo" / "ant" / "clip.mp4")
  assert render.check_out(tmp_path / "clip.mp4") == tmp_path / "clip.mp4"


def test_a_failed_write_leaves_nothing_under_the_name(tmp_path):
  def broken():
    yield np.zeros((16, 16, 3), np.uint8)
    raise RuntimeError("renderer died")
  with pytest.raises(RuntimeError, match="renderer died"):
    render.write(broken(), tmp_path / "c.gif", fps=10)
  assert list(tmp_path.iterdir()) == []
