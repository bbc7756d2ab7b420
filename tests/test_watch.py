"""Videos a person watches (`ape_jax.pipeline.watch`): real-time frame rates, captions with the task's words
(`Env.caption`), the outcome at the end, clips side by side. ToyTown on a short route, its expert driving."""

import numpy as np
import pytest
from PIL import Image

import envs
from ape_jax.pipeline import watch
from envs import experts

SHORT = dict(route_length=180.0, intersections=2, episode_length=700)   # tests/test_toytown.py's: ~300 steps


@pytest.mark.parametrize("dt, length, max_frames, expected", [
    (0.1, 2000, 600, (4, 10.0, 4.0)),    # ToyTown: 10 per second, every 4th step of a 2,000-step limit
    (0.1, 300, 600, (1, 10.0, 1.0)),     # ToyCar: every step, real time
    (0.008, 1000, 600, (3, 50.0, 1.2)),  # MuJoCo's 8 ms: capped at 50 per second, so every 3rd step
    (0.037, 100, 600, (1, 1 / 0.03, 0.037 / 0.03)),   # whole centiseconds rounded down: never slower
])
def test_frame_timing_plays_in_real_time_or_faster_at_what_gif_players_honour(dt, length, max_frames, expected):
    stride, fps, speedup = watch.frame_timing(dt, length, max_frames)
    assert (stride, fps, speedup) == pytest.approx(expected)
    assert speedup >= 1.0 and fps <= 50.0


@pytest.fixture(scope="module")
def clips():
    """The expert's first evaluation episode on a short empty route, rendered at 64×64."""
    env = envs.make("toytown", obs="full", traffic="empty", **SHORT)
    viewer = envs.make("toytown", obs="image", traffic="empty", image_size=64, **SHORT)
    policy = envs.from_observation(experts.executed(env.expert, env.action_bounds), expert=True, env=env)
    clip = watch.record_clip(env, viewer, policy, None, episodes=1, episode=0, title="expert, episode 0",
                             metric="success", max_frames=200, log=lambda m: None)
    return clip


def test_a_toytown_clip_plays_at_ten_frames_per_second_with_speed_light_and_outcome_in_its_caption(clips, tmp_path):
    clip = clips
    assert clip.fps == 10.0 and clip.stride == 4 and clip.frame_ms == 100   # 700 steps / 200 frames: every 4th
    assert len(clip.words) == len(clip.frames) and set(clip.words[0]) == {"speed", "light"}
    assert {w["light"] for w in clip.words} <= {"red", "amber", "green", "none"}
    assert len({w["light"] for w in clip.words}) > 1   # the lights ahead come and go
    assert clip.outcome == clip.words[-1]["outcome"] == "success"   # the expert on an empty route
    gif = watch.write_gif(clip, tmp_path / "expert.gif")
    with Image.open(gif) as im:
        assert im.n_frames == len(clip.frames) and im.size == (256, 256 + 3 * watch.LINE + 2)
        assert im.info["duration"] == 100   # 10 per second: the 0.1 s step in real time
        frames = []
        for i in range(im.n_frames):
            im.seek(i)
            frames.append((np.asarray(im.convert("RGB")), im.info["duration"]))
    assert frames[-1][1] == round(watch.HOLD_LAST_S * 1000)   # the outcome stays readable
    speeds = [w["speed"] for w in clip.words]
    i, j = 0, next(k for k, s in enumerate(speeds) if s != speeds[0])
    band = slice(256 + watch.LINE, 256 + 2 * watch.LINE)   # the caption's second line: step, speed, light
    assert (frames[i][0][band] < 100).any() and not np.array_equal(frames[i][0][band], frames[j][0][band])


def test_clips_side_by_side_share_the_frame_rate_and_the_one_that_ended_holds_its_last_frame(clips, tmp_path):
    short = watch.Clip(**{**clips.__dict__, "frames": clips.frames[:5], "steps": clips.steps[:5],
                          "words": clips.words[:5]})
    gif = watch.write_gif([clips, short], tmp_path / "both.gif")
    with Image.open(gif) as im:
        assert im.size == (2 * 256 + 4, 256 + 3 * watch.LINE + 2) and im.n_frames == len(clips.frames)
        im.seek(im.n_frames - 2)
        right = np.asarray(im.convert("RGB"))[:256, 260:]
    assert np.array_equal(right, np.asarray(Image.fromarray(clips.frames[4]).resize((256, 256), Image.NEAREST)))


def test_bad_video_choices_are_refused_in_one_line():
    assert watch.parse_choices("ours-step:0,expert") == [("ours-step", 0), ("expert", None)]
    for text, message in (("bc-oh,bc-oh", "each policy once"), ("expert:1", "the expert has no seed"),
                          ("bc-oh,", "name a method"), ("bc-oh:x", "must be an integer")):
        with pytest.raises(watch.WatchError, match=message):
            watch.parse_choices(text)
