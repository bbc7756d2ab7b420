"""The keyframe picture: frame picking, the figure from plain arrays, the CLI's refusals (no simulator needed)."""

import numpy as np
import pytest
from PIL import Image

from ape_jax.pipeline import keyframes
from experiments.report import figures
from experiments import keyframes as cli

CHANGES = (60, 130, 215, 300, 370)  # where the synthetic expert switches its action


def synthetic_episode(steps=400, seed=0):
    """Piecewise-constant actions switching at `CHANGES`; APE spikes at each switch and the step after."""
    rng = np.random.default_rng(seed)
    levels = rng.uniform(-1, 1, size=(len(CHANGES) + 1, 3))
    actions = levels[np.searchsorted(CHANGES, np.arange(steps), side="right")]
    jump = np.r_[0.0, np.sum(np.diff(actions, axis=0) ** 2, axis=1)]
    ape = 0.02 + 0.01 * rng.random(steps) + jump + 0.6 * np.r_[0.0, jump[:-1]]  # ψ needs a step to catch up
    return actions.astype(np.float32), (ape / ape.mean()).astype(np.float32)


def test_keyframe_mask_is_the_step_weightings_top_fraction():
    ape = np.r_[np.arange(30, dtype=np.float32), 27.0]  # a tie at the cut: the lower index wins
    mask, threshold = keyframes.keyframe_mask(ape, 0.1)
    assert mask.sum() == 3 and list(np.flatnonzero(mask)) == [27, 28, 29]
    assert threshold == 27.0
    assert keyframes.keyframe_mask(np.ones(5, np.float32), 0.1)[1] == float("inf")  # ⌊0.5⌋ = 0 keyframes


def test_pick_frames_finds_the_planted_changes_spread_apart():
    _, ape = synthetic_episode()
    mask, _ = keyframes.keyframe_mask(ape, 0.05)
    steps, is_key = keyframes.pick_frames(ape, mask, count=4, min_gap=20, ordinary=1)
    key_steps = steps[is_key]
    assert len(key_steps) == 4 and len(steps) == 5
    assert set(key_steps) <= set(CHANGES)  # the switch itself, never the runner-up step right after it
    assert np.all(np.diff(steps) >= 20) and list(steps) == sorted(steps)
    calm = steps[~is_key][0]
    assert calm >= 9 and not mask[calm] and min(abs(calm - c) for c in CHANGES) > 1
    # a gap wider than the switches' spacing leaves fewer keyframes, never crowded ones
    wide, wide_key = keyframes.pick_frames(ape, mask, count=4, min_gap=150, ordinary=0)
    assert wide_key.all() and 1 <= len(wide) < 4 and np.all(np.diff(wide) >= 150)


def test_zoom_window_stays_inside_the_episode():
    assert keyframes.zoom_window(1000, 309, 150) == (234, 384)
    assert keyframes.zoom_window(1000, 10, 150) == (0, 150)
    assert keyframes.zoom_window(1000, 995, 150) == (850, 1000)
    assert keyframes.zoom_window(100, 50, 150) == (0, 100)


@pytest.mark.parametrize("window", [None, (150, 290)])
def test_the_picture_is_a_png_a_person_can_open(tmp_path, window):
    actions, ape = synthetic_episode()
    mask, threshold = keyframes.keyframe_mask(ape, 0.05)
    steps, is_key = keyframes.pick_frames(ape, mask, count=4, min_gap=20)
    frames = np.zeros((len(steps), 32, 32, 3), np.uint8)
    frames[:, 8:24, 8:24] = np.array([200, 60, 40], np.uint8)
    fig = figures.keyframes(ape, actions, threshold, frames, steps, keyframe=mask, title="synthetic, episode 0",
                            note="a note", action_names=["x", "y", "z"], frame_is_key=is_key, window=window)
    assert len(fig.axes) == len(steps) + (3 if window else 2)  # a close-up adds the zoomed APE row
    out = tmp_path / "sub" / "kf.png"
    size = figures.save_png(fig, out)
    assert size == out.stat().st_size and 10_000 < size < 400_000
    assert [p.name for p in out.parent.iterdir()] == ["kf.png"]  # no temporary file left behind
    with Image.open(out) as im:
        assert im.format == "PNG" and 1000 < im.width < 2000 and 700 < im.height < 1400
        pixels = np.asarray(im.convert("RGB"))
    assert (np.abs(pixels.astype(int) - [214, 39, 40]).sum(-1) < 30).any()  # the keyframe red is drawn
    with pytest.raises(ValueError, match="frames must be"):
        figures.keyframes(ape, actions, threshold, frames[..., 0], steps)


def test_select_spaces_the_frames_and_zooms_on_the_highest_ape_keyframe():
    _, ape = synthetic_episode()
    mask, _ = keyframes.keyframe_mask(ape, 0.05)
    pick = keyframes.select(ape, mask, count=4, ordinary=1, zoom=100)
    steps, is_key = keyframes.pick_frames(ape, mask, 4, 400 // (2 * 5), 1)  # the default gap: T / (2 × frames)
    assert list(pick.steps) == list(steps) and list(pick.is_key) == list(is_key)
    top = pick.steps[pick.is_key][np.argmax(ape[pick.steps[pick.is_key]])]
    assert pick.window == keyframes.zoom_window(400, int(top), 100) and pick.window[0] <= top < pick.window[1]
    assert keyframes.select(ape, mask, count=4, zoom=201).window is None  # episode shorter than twice the zoom
    assert keyframes.select(ape, mask, count=4, zoom=0).window is None


@pytest.mark.parametrize(
    "argv,message",
    [
        (["--env", "hoper"], "unknown env 'hoper'"),
        (["--env", "hopper", "--episode", "25"], "--episode must be in [0, 24]"),
        (["--env", "toycar", "--episode", "-1"], "--episode must be in [0, 9]"),
        (["--frames", "0"], "--frames must be >= 1"),
        (["--image-size", "-3"], "--image-size '-3': an image size is N, HxW or H,W (positive integers)"),
        (["--ape-steps", "0"], "--ape-steps must be >= 1"),
        (["--min-gap", "0"], "--min-gap must be >= 1"),
        (["--thr", "1.5"], "--thr must be in (0, 1)"),
        (["--out", "picture.jpg"], "must name a .png"),
        (["--frames", "two"], "invalid int value"),
        (["--zoom", "-1"], "--zoom must be >= 0"),
        (["--frames", "12"], "must be <= 12"),
    ],
)
def test_bad_input_is_refused_on_one_line_with_exit_code_2(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


def test_an_unwritable_out_is_refused_before_any_work(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(SystemExit) as exc:
        cli.main(["--out", str(blocker / "kf.png")])
    assert exc.value.code == 2
    assert "cannot write there" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["--out", str(tmp_path)])  # a directory, not a file
