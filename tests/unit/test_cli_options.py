"""Every numeric option of the ``shapeviewer`` command is checked before the command runs: a bad value
stops it with a one-line message naming the option, and nothing is written."""

from __future__ import annotations

import pytest

from shapeviewer.cli.parser import build_parser

BAD = [
    (["evaluate", "--out", "o", "--grasp-budget", "-5"], "--grasp-budget"),
    (["evaluate", "--out", "o", "--grasp-budget", "nan"], "--grasp-budget"),
    (["evaluate", "--out", "o", "--views-per-set", "0"], "--views-per-set"),
    (["evaluate", "--out", "o", "--views-per-set", "-1"], "--views-per-set"),
    (["evaluate", "--out", "o", "--workers", "0"], "--workers"),
    (["evaluate", "--out", "o", "--workers", "-3"], "--workers"),
    (["evaluate", "--out", "o", "--n-grasps", "0"], "--n-grasps"),
    (["evaluate", "--out", "o", "--widen-below", "1.5"], "--widen-below"),
    (["evaluate", "--out", "o", "--seed", "-1"], "--seed"),
    (["grasp", "m.ply", "--out", "g.json", "--n", "0"], "--n"),
    (["grasp", "m.ply", "--out", "g.json", "--n", "-1"], "--n"),
    (["grasp", "m.ply", "--out", "g.json", "--budget", "0"], "--budget"),
    (["serve", "--port", "-1"], "--port"),
    (["serve", "--port", "99999"], "--port"),
    (["serve", "--fx", "-525"], "--fx"),
    (["generate", "--out", "o", "--views", "0"], "--views"),
    (["train", "--data", "d", "--run", "r", "--steps", "0"], "--steps"),
    (["train", "--data", "d", "--run", "r", "--lr", "0"], "--lr"),
    (["complete", "x.pcd", "--out", "o", "--seed", "abc"], "--seed"),
]


@pytest.mark.parametrize(("argv", "option"), BAD, ids=[" ".join(a) for a, _ in BAD])
def test_a_bad_numeric_option_is_refused_with_its_name(argv, option, capsys):
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}" in err and "Traceback" not in err


def test_good_values_parse():
    argv = ["evaluate", "--out", "o", "--views-per-set", "3", "--workers", "2", "--grasp-budget", "30"]
    args = build_parser().parse_args([*argv, "--widen-below", "0"])
    assert (args.views_per_set, args.workers, args.grasp_budget, args.widen_below) == (3, 2, 30.0, 0.0)
    assert build_parser().parse_args(["serve", "--port", "8081"]).port == 8081
