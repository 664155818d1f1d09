"""The command line's vocabulary (issue 31): every flag of every command says what it is, its
unit and its default; `galileo` alone shows the commands; `galileo --version`; old flag spellings
still work and say they are deprecated."""
import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

import galileo
from galileo import cli, registry

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
# float-valued flags carry a unit: a suffix of their name or a unit named in their help
FLOAT_TYPES = {cli.finite_float, cli.positive_float, cli.nonneg_float, cli.fps_float, cli.rhat_float}
UNIT_SUFFIXES = ("-m", "-s", "-deg", "-kg", "-px", "-mps", "-seconds")
UNIT_WORDS = ("m/s", "px", "seconds", "degrees", "frames per second", "unit", "R-hat", "effective sample size")


def run_cli(*args):
    p = subprocess.run([sys.executable, "-m", "galileo", *map(str, args)], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=ROOT, check=False)
    return p.returncode, p.stdout, p.stderr


def commands(parser: argparse.ArgumentParser, path=()):
    """(command path, parser) of the parser and every (sub)command under it."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from commands(sub, (*path, name))


def shown(value) -> str:
    """A default as the help writes it (400.0 as 400)."""
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() else f"{value:g}"
    return str(value)


def flat(text: str) -> str:
    return " ".join(text.split())


def problems(parser: argparse.ArgumentParser) -> list[str]:
    """What the vocabulary rules find wrong with `parser`'s flags, each as 'galileo CMD --flag: why'."""
    questions = {q.name for q in cli.all_questions()}
    out = []
    for path, p in commands(parser):
        page = flat(p.format_help())
        for a in p._actions:
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            where = " ".join(["galileo", *path, a.option_strings[0] if a.option_strings else a.dest])
            if a.help == argparse.SUPPRESS:
                if not isinstance(a, cli.DeprecatedFlag):
                    out.append(f"{where}: hidden, and not a deprecated spelling")
                continue
            text = flat((a.help or "") % {"default": a.default, "prog": p.prog})
            if not text:
                out.append(f"{where}: no help")
                continue
            if not a.option_strings or isinstance(a, argparse._VersionAction):
                continue
            if a.default not in (None, False, argparse.SUPPRESS):
                want = f"default: {shown(a.default)}"
                if want not in text or want not in page:
                    out.append(f"{where}: its help does not show its default ({want!r})")
            elif a.nargs != 0 and not a.required and a.dest not in questions and not any(
                    w in text for w in ("default", "not given", "(needed)")):
                out.append(f"{where}: its help does not say what happens when it is not given")
            if a.type in FLOAT_TYPES and not a.option_strings[0].endswith(UNIT_SUFFIXES) \
                    and not any(w in text for w in UNIT_WORDS):
                out.append(f"{where}: a number without a unit in its name or help")
    return out


def test_every_flag_of_every_command_has_help_and_shows_its_default():
    parser = cli.build_parser(lazy=False)     # with predict's questions and scene's numbers
    paths = {path for path, _ in commands(parser)}
    assert {("infer",), ("recognize", "train"), ("recognize", "eval"), ("predict",), ("scene",)} <= paths
    assert problems(parser) == []


def test_the_rules_catch_a_flag_without_help_or_default():
    """The check above can fail: a new flag without help, one whose help hides its default, a
    number without a unit."""
    parser = cli.build_parser(lazy=False)
    infer = next(p for path, p in commands(parser) if path == ("infer",))
    infer.add_argument("--new-thing", type=cli.positive_int)
    infer.add_argument("--level", type=cli.positive_float, default=3.0, help="how much (default: 2)")
    infer.add_argument("--pause", type=cli.positive_float, help="a pause (default: none)")
    found = problems(parser)
    assert any(f.startswith("galileo infer --new-thing: no help") for f in found)
    assert any(f.startswith("galileo infer --level: its help does not show its default") for f in found)
    assert any(f.startswith("galileo infer --pause: a number without a unit") for f in found)


def test_sigma_says_each_scenarios_unit_and_default():
    """--sigma is m/s for the ramp and px for the splash (and the others'): its help says each."""
    sigma = next(a for a in next(p for path, p in commands(cli.build_parser()) if path == ("infer",))._actions
                 if "--sigma" in a.option_strings)
    for name in registry.names():
        noise = registry.get(name).noise
        assert f"{name}: {noise.unit}, default: {noise.default:g}" in sigma.help, name


def test_calibrate_says_why_its_defaults_are_not_infers():
    code, out, err = run_cli("calibrate", "--help")
    assert code == 0 and err == ""
    page = flat(out)
    assert "4 chains x 200 sweeps" in page and "16 x 75" in page and "SBC needs many" in page


def test_galileo_alone_shows_the_commands():
    code, out, err = run_cli()
    assert code == 0, err
    assert err == ""
    assert out.startswith("usage: galileo COMMAND")
    for name in ("simulate", "dataset", "track", "infer", "predict", "experiment", "report", "scene", "calibrate",
                 "recognize", "scenarios"):
        assert f"\n  {name} " in out, name
    assert "`galileo COMMAND --help`" in out and "`galileo --version`" in out
    code, out, err = run_cli("recognize")
    assert code == 0 and err == ""
    assert all(f"\n  {step} " in out for step in ("label", "train", "eval", "predict"))
    assert "`galileo recognize STEP --help`" in out


def test_galileo_version():
    code, out, err = run_cli("--version")
    assert (code, out, err) == (0, f"galileo {galileo.__version__}\n", "")
    assert galileo.__version__ == "0.1.0"


def test_a_misspelt_command_is_still_one_line_exit_2():
    code, out, err = run_cli("infre")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("galileo: error: ")


@pytest.fixture(scope="module")
def result_file(tmp_path_factory):
    """A small ramp result (2 chains x 2 sweeps on the frozen demo tracks)."""
    from galileo.datatypes import Tracks
    from galileo.runner import RunConfig, infer

    path = tmp_path_factory.mktemp("vocab") / "result.json"
    infer(registry.load_scene(DATA / "scene.json"), Tracks.load(DATA / "tracks.json"),
          RunConfig(chains=2, sweeps=2, seed=0, workers=1), progress=False).save(path)
    return path


def test_predict_target_outcome_and_its_deprecated_spelling(result_file, capsys):
    """predict's yes/no question reads --target-outcome (scene's --target takes a kind of box);
    --target still asks it, and says once, after the answers, that it is deprecated."""
    assert cli.main(["predict", "--result", str(result_file), "--target-outcome"]) == 0
    new_out, new_err = capsys.readouterr()
    assert "deprecated" not in new_err and '"target"' in new_out
    assert cli.main(["predict", "--result", str(result_file), "--target"]) == 0
    old_out, old_err = capsys.readouterr()
    assert old_out == new_out
    assert old_err.count("galileo: warning: --target is deprecated: use --target-outcome\n") == 1
    page = flat(next(p for path, p in commands(cli.build_parser(lazy=False)) if path == ("predict",)).format_help())
    assert "--target-outcome" in page and "--target " not in page and "--target]" not in page


def test_a_refused_command_with_a_deprecated_flag_is_still_one_line(result_file, tmp_path, capsys):
    assert cli.main(["predict", "--result", str(tmp_path / "none.json"), "--target"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "deprecated" not in err
    assert cli.main(["predict", "--result", str(result_file)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nothing to predict" in err and "--target-outcome" in err
