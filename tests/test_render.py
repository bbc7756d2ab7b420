"""The MJX ray-cast renderer: inside jit and vmap, informative pixels."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import envs
from envs import render, video


@pytest.fixture(scope="module")
def hopper_frames():
    env = envs.make("hopper", obs="image", image_size=(48, 64))
    policy = envs.stateless(lambda p, s, k: jax.random.uniform(k, (3,), minval=-1, maxval=1))

    @jax.jit
    def run(key):
        traj = envs.rollout(env, policy, None, key, num_episodes=2, num_steps=25,
                            record=lambda s: (env.segmentation(s), env.render(s)))
        return traj

    return env, run(jax.random.PRNGKey(0))


@pytest.mark.integration
def test_frames_are_uint8_images_rendered_in_a_vmapped_scan(hopper_frames):
    env, traj = hopper_frames
    assert traj.obs.shape == (2, 25, 48, 64, 3) and traj.obs.dtype == jnp.uint8
    # the observation is the rendered frame of the same state
    np.testing.assert_array_equal(np.asarray(traj.obs), np.asarray(traj.extra[1]))
    frame = np.asarray(traj.obs[0, 0])
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 5, "frame is (nearly) constant"


@pytest.mark.integration
def test_frames_change_when_the_body_moves(hopper_frames):
    _, traj = hopper_frames
    first, later = np.asarray(traj.obs[0, 0]), np.asarray(traj.obs[0, -1])
    changed = np.any(first != later, axis=-1).mean()
    assert changed > 0.02, f"only {changed:.1%} of pixels changed after 24 steps"


@pytest.mark.integration
def test_floor_and_torso_have_different_colours(hopper_frames):
    env, traj = hopper_frames
    seg, rgb = np.asarray(traj.extra[0][0, 0]), np.asarray(traj.obs[0, 0])
    geom_body = np.asarray(env.brax_env.sys.geom_bodyid)
    floor = np.isin(seg, np.flatnonzero(geom_body == 0))
    torso = np.isin(seg, np.flatnonzero(geom_body == 1))
    assert floor.sum() > 10 and torso.sum() > 2, "camera does not frame floor and torso"
    floor_colours = {tuple(c) for c in rgb[floor]}
    torso_colours = {tuple(c) for c in rgb[torso]}
    assert not floor_colours & torso_colours


def test_image_size_is_configurable():
    env = envs.make("walker2d", obs="image", image_size=(8, 12))
    assert env.observation_shape == (8, 12, 3)
    s = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    assert s.obs.shape == (8, 12, 3) and s.obs.dtype == jnp.uint8


def test_camera_rejects_bad_settings():
    with pytest.raises(ValueError, match="fov"):
        render.Camera(fov_deg=0)
    with pytest.raises(ValueError, match="positive"):
        render.Camera(height=0)


def test_save_frames_writes_a_gif_and_pngs(tmp_path):
    env = envs.make("toycar", image_size=32)
    policy = envs.from_observation(env.expert, expert=True, env=env)
    frames = video.render_rollout(env, policy, None, jax.random.PRNGKey(0), num_steps=20)
    assert frames.shape == (20, 32, 32, 3)
    gif = video.save_frames(frames, str(tmp_path / "car.gif"), scale=2)[0]
    with Image.open(gif) as im:
        assert im.n_frames >= 5 and im.size == (64, 64)
    pngs = video.save_frames(frames, str(tmp_path / "pngs"))
    assert len(pngs) == 20
    np.testing.assert_array_equal(np.asarray(Image.open(pngs[3]).convert("RGB")), frames[3])
    with pytest.raises(ValueError, match="uint8"):
        video.save_frames(frames.astype(np.float32), str(tmp_path / "x.gif"))
