"""What a new user's first commands are told: one reader of image sizes wherever one is typed, refusals that name
the value and the file as given, a method's setting for a method not run refused, and `compare` naming only the
methods a run has.

Refusals are `PROG: error: ...` on one line, exit status 2, nothing written. Nothing here trains.
"""

import json
import pathlib
import re

import pytest

from ape_jax.pipeline import hints
from ape_jax.pipeline.presets import SettingsError, parse_set
from experiments import collect, compare, keyframes, pose_probe

from _refusal import assert_sweep_refuses
from test_cli_guards import refused

ROOT = pathlib.Path(__file__).resolve().parents[1]
TOYTOWN = ROOT / "results" / "toytown-image-nocrash-default-seeds0.json"
FORMS = "an image size is N, HxW or H,W (positive integers)"
TINY = ["--env", "toycar", "--obs", "full", "--iterations", "4", "--eval-episodes", "2", "--seeds", "1", "--quiet"]


# -- image sizes: one reader ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("text,size", [("32", (32, 32)), ("32x32", (32, 32)), ("32,32", (32, 32)),
                                       ("48X64", (48, 64)), (" 16 , 8 ", (16, 8))])
def test_an_image_size_reads_the_same_from_set_and_from_the_reader_every_flag_uses(text, size):
    assert hints.image_size(text) == size
    assert parse_set(f"protocol.image_size={text}") == ("protocol", "image_size", size)


@pytest.mark.parametrize("text", ["abc", "0", "-3", "32x", "1.5", "32x32x32", "", "３２"])
def test_a_bad_image_size_says_what_is_accepted(text):
    with pytest.raises(ValueError, match=re.escape(FORMS)):
        hints.image_size(text)
    with pytest.raises(SettingsError, match=re.escape(f"--set 'protocol.image_size={text}': {FORMS}")):
        parse_set(f"protocol.image_size={text}")


def test_none_still_means_the_task_s_own_image_size():
    assert parse_set("protocol.image_size=none")[2] is None


@pytest.mark.parametrize("main,argv", [
    (collect.main, ["--env", "toycar", "--obs", "image"]),
    (keyframes.main, ["--env", "toycar"]),
    (pose_probe.main, ["--out", "probe.json"]),
])
def test_every_image_size_flag_refuses_a_bad_value_naming_it_and_the_forms(main, argv, capsys, tmp_path,
                                                                          monkeypatch):
    monkeypatch.chdir(tmp_path)
    err = refused(capsys, lambda: main([*argv, "--image-size", "abc"]))
    assert err.endswith(f": error: --image-size 'abc': {FORMS}\n"), err
    assert list(tmp_path.iterdir()) == []


def test_collect_takes_a_single_side_as_the_sweep_does(tmp_path):
    args = collect.parse(["--env", "toycar", "--obs", "image", "--image-size", "24", "--data-dir", str(tmp_path)])
    assert tuple(args.overrides["image_size"]) == (24, 24)


def test_keyframes_takes_hxw_and_refuses_a_side_over_its_limit(capsys):
    err = refused(capsys, lambda: keyframes.main(["--env", "toycar", "--image-size", "2000x16"]))
    assert "--image-size must be at most 1024 pixels a side, got 2000x16" in err


# -- whole numbers -----------------------------------------------------------------------------------------------------

def test_a_non_integer_for_an_int_field_says_whole_number_and_echoes_it():
    with pytest.raises(SettingsError) as e:
        parse_set("protocol.history_stride=1.5")
    assert str(e.value) == ("--set 'protocol.history_stride=1.5': protocol.history_stride takes int: '1.5' is not a "
                            "whole number")
    assert "invalid literal" not in str(e.value)
    with pytest.raises(SettingsError, match="'fast' is not a number"):
        parse_set("recipe.lr=fast")


# -- the dataset as given ------------------------------------------------------------------------------------------

def test_a_dataset_named_by_its_json_is_refused_naming_the_path_given(tmp_path, capsys):
    given = tmp_path / "x.json"
    assert_sweep_refuses(tmp_path, capsys, [*TINY, "--methods", "bc-oh", "--dataset", str(given)],
                         f"error: {given}: no such dataset file (a dataset is NAME.npz with its NAME.json beside "
                         "it, and x.npz is not there)")


# -- a method's setting for a method not run ---------------------------------------------------------------------------

def test_a_setting_for_a_method_not_among_methods_is_refused_naming_it(tmp_path, capsys):
    assert_sweep_refuses(tmp_path, capsys, [*TINY, "--methods", "bc-so,bc-oh", "--set", "fca.alphas=0.5"],
                         "error: --set fca.alphas=0.5: fca is not among --methods (bc-so, bc-oh), so nothing would "
                         "read its setting: add fca to --methods, or leave the --set out")


def test_the_grids_the_shortcuts_set_for_every_weighting_are_not_the_user_s_and_pass():
    from experiments import sweep

    args = sweep.parse([*TINY, "--methods", "bc-oh", "--step-grid", "0.1:5", "--softmax-grid", "0.2"], writes=False)
    assert args.methods == ("bc-oh",) and args.settings.knob("ours-step").grid == ((0.1, 5.0),)
    args = sweep.parse([*TINY, "--methods", "bc-oh,fca", "--set", "fca.alphas=0.5"], writes=False)
    assert args.settings.knob("fca").alphas == (0.5,)


# -- compare names the run's own methods -------------------------------------------------------------------------------

def test_compare_of_a_run_of_references_only_lists_the_run_s_methods(tmp_path, capsys):
    r = json.loads(TOYTOWN.read_text())
    r["runs"] = [x for x in r["runs"] if x["method"] in ("bc-so", "bc-oh")]
    r["summary"] = [x for x in r["summary"] if x["method"] in ("bc-so", "bc-oh")]
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "results.json").write_text(json.dumps(r))
    err = refused(capsys, lambda: compare.main([str(tmp_path / "run")]))
    assert "holds only reference methods (bc-so, bc-oh): nothing of yours to compare" in err
    assert "fca" not in err and "ours-step" not in err
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["results.json"]
