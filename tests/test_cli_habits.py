"""Command-line habits (issue 22, item 6): did-you-mean, ignored options refused, negative numbers as values."""

from __future__ import annotations

import pytest

from covviz import cli
from covviz.cli.habits import given_options


def error_of(argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    return capsys.readouterr().err


def test_mistyped_option_suggests_the_option_with_the_subcommands_usage(capsys):
    err = error_of(["track", "--trakers", "ipca"], capsys)
    assert "did you mean --trackers" in err
    assert err.startswith("usage: covviz track")  # the subcommand's usage, not the top level's


def test_mistyped_subcommand_suggests_the_subcommand(capsys):
    assert "did you mean 'track'?" in error_of(["trak"], capsys)


@pytest.mark.parametrize("command", ["track", "bench ROOT"])
def test_mistyped_tracker_suggests_the_tracker(capsys, tmp_path, command):
    argv = [*command.replace("ROOT", str(tmp_path)).split(), "--trackers", "manifold,ipac", "--no-progress"]
    if command == "track":
        err = error_of(argv, capsys)
    else:
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
    assert "did you mean 'ipca'?" in err


def test_mistyped_choice_suggests_the_choice(capsys):
    assert "did you mean 'smacof'?" in error_of(["mds", "--method", "smacfo"], capsys)


@pytest.mark.parametrize("argv", [["track", "--box", "-5,10,40,60"], ["mds", "--box", "-5.5,-10,40,60"]])
def test_negative_numbers_after_box(argv):
    args = cli.build_parser().parse_args(cli._glue_negative_values(argv))
    assert args.box[0] < 0 and list(args.box[2:]) == [40, 60]


def test_box_before_another_option_still_says_the_value_is_missing(capsys):
    assert "expected one argument" in error_of(["track", "--box", "--no-save"], capsys)


IGNORED = [
    (["snapshot", "x.rrd", "--offsets", "-5,0,5"], "--event"),
    (["track", "--no-save", "--mds-every", "3"], "--mds-every"),
    (["track", "--no-save", "--likelihood-every", "3"], "--likelihood-every"),
    (["track", "--trackers", "csrt", "--particles", "5"], "--particles"),
    (["bench", "ROOT", "--cluster", "local:2", "--jobs", "2"], "--jobs"),
    (["tune", "ROOT", "--trials", "1", "--cluster", "local:2", "--jobs", "2"], "--jobs"),
    (["mds", "--no-png", "--png-dir", "somewhere"], "--png-dir"),
    (["mds", "--no-png", "--format", "svg"], "--format"),
]


@pytest.mark.parametrize(("argv", "option"), IGNORED, ids=lambda v: " ".join(v) if isinstance(v, list) else v)
def test_an_option_that_would_be_ignored_is_an_error(argv, option, tmp_path, capsys):
    argv = [str(tmp_path) if a == "ROOT" else a for a in argv]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0], err


def test_the_same_options_are_fine_where_they_act(tmp_path):
    given = given_options(cli.build_parser, ["snapshot", "x.rrd", "--event", "2", "--off=-5,0"])
    assert {"event", "offsets"} <= given  # abbreviations count as given, as argparse reads them
    assert "timeout" not in given and "size" not in given


def test_mistyped_event_kind_suggests_the_kind(capsys):
    assert "did you mean 'diagnosis'?" in error_of(["events", "x.rrd", "--kind", "diagnosys"], capsys)


def test_events_of_a_mistyped_tracker_suggest_the_tracker(tmp_path, capsys):
    import covviz

    rrd = tmp_path / "occ.rrd"
    covviz.track("synthetic:occlusion", trackers="identity", max_frames=90, save=rrd)
    assert cli.main(["events", str(rrd), "--tracker", "identiti"]) == 2
    err = capsys.readouterr().err
    assert "did you mean 'identity'?" in err and "events of: identity" in err
    assert cli.main(["events", str(rrd), "--tracker", "identity"]) == 0
