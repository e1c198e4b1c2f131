"""Every option described once (wfjax/options.py, params field metadata): the case keys, the
flags, their checks and docs/case_files.md all come from the descriptions.

No simulation runs here: every bad value must stop the command before any work.
"""

import dataclasses
import re
import shlex
from pathlib import Path

import pytest

import wfjax as wf
from wfjax import case as C
from wfjax import optdocs
from wfjax import options as O
from wfjax.cli import build_parser, main
from wfjax.contact import registry

ROOT = Path(__file__).resolve().parents[1]


def _bad_values(option: O.Option) -> list:
    """Values ``option`` must refuse, in its SI unit (or a wrong type)."""
    if option.kind == "bool":
        return ["yes"]
    if option.choice_list is not None:
        return [["nonsense"]] if option.kind == "strs" else ["nonsense"]
    if option.kind in ("str", "path"):
        return [5]
    out = ["abc"]
    if option.high is not None:
        out.append(option.high * 10 + 1)
    elif option.low is not None:
        out.append(option.low - 1)
    return out


def _as_int_if(option, value):
    return int(value) if option.kind == "int" and isinstance(value, float) else value


def _flag_text(option, value) -> str:
    if isinstance(value, (int, float)):
        return str(_as_int_if(option, value / option.factor))
    return value[0] if isinstance(value, list) else str(value)


CASE_CASES = [(path, v) for path, opt in O.KEYS.items() for v in _bad_values(opt)]


@pytest.mark.parametrize("path, value", CASE_CASES, ids=[f"{p}={v!r}" for p, v in CASE_CASES])
def test_every_case_key_refuses_a_bad_value_in_one_line(tmp_path, path, value):
    option = O.KEYS[path]
    value = _as_int_if(option, value)
    file = tmp_path / "case.toml"
    file.write_text(f"[{option.section}]\n{option.name} = {C._toml_value(value)}\n")
    with pytest.raises(C.CaseError) as err:
        C.resolve(option.commands[0], str(file), environ={})
    message = str(err.value)
    assert "\n" not in message
    assert f"{path} = " in message and "allowed: " in message, message
    shown = value[0] if isinstance(value, list) else value
    assert str(shown).replace("e+", "e") in message.replace("e+", "e"), message


FLAG_CASES = [(command, opt.flag, _flag_text(opt, v))
              for command in (*O.COMMANDS, "config") for opt in O.flags_of(command)
              if opt.action is None and opt.kind not in ("str", "path")
              or opt.choice_list is not None
              for v in _bad_values(opt)]


@pytest.mark.parametrize("command, flag, text", FLAG_CASES,
                         ids=[f"{c} {f} {t}" for c, f, t in FLAG_CASES])
def test_every_flag_refuses_a_bad_value_with_exit_2_and_nothing_written(
        tmp_path, capsys, monkeypatch, command, flag, text):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    argv = [command, flag, text] + (["--out", str(out)] if command != "config" else [])
    try:
        status = main(argv)
    except SystemExit as exc:  # argparse: an invalid choice
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert flag in err[0] and text in err[0], err[0]
    assert "allowed: " in err[0] or "invalid choice" in err[0], err[0]
    assert not out.exists() and not list(tmp_path.iterdir())


def test_an_alias_is_named_as_typed(capsys, tmp_path):
    assert main(["sweep", "--depths-mm", "9", "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.startswith('wfjax sweep: error: --depths-mm "9": out of '
                                              "range; allowed: (0, 5] mm")


def test_add_argument_is_called_in_one_generator_only():
    """No command writes its flags by hand: they come from the option descriptions."""
    calls = []
    for path in sorted((ROOT / "wfjax").rglob("*.py")):
        for i, line in enumerate(path.read_text().splitlines()):
            if "add_argument(" in line:
                calls.append((path.relative_to(ROOT).as_posix(), i))
    assert [p for p, _ in calls] == ["wfjax/cli.py"], calls
    source = (ROOT / "wfjax" / "cli.py").read_text()
    generator = source[source.index("def add_options("):source.index("def build_parser(")]
    assert generator.count("add_argument(") == 1 and source.count("add_argument(") == 1


def test_model_keys_come_from_the_dataclass_metadata():
    """One description: the case key's unit, range and doc are the field's metadata."""
    for section, cls in O.MODEL_SECTIONS.items():
        for f in dataclasses.fields(cls):
            key = O.KEYS[f"{section}.{f.name}"]
            assert (key.unit, key.low, key.high, key.doc) == (
                f.metadata["unit"], f.metadata["low"], f.metadata["high"], f.metadata["doc"])
    depth = {f.name: f for f in dataclasses.fields(wf.Flat)}["depth"].metadata
    assert O.KEYS["flat.depth"].high == depth["high"] == wf.params.MAX_FLAT_DEPTH
    assert "_positive" not in vars(wf.Wheel) and "_positive" not in vars(wf.Track)


def test_contact_choices_are_the_registry(monkeypatch):
    names = registry.names()
    assert O.KEYS["run.contact"].choice_list == names == O.KEYS["compare.models"].choice_list
    assert C.default_layer("compare")["compare.models"] == list(names)
    monkeypatch.setitem(registry._MODELS, "my-law",
                        registry.ContactModel("my-law", "a test law", lambda *a, **k: None))
    assert "my-law" in O.KEYS["run.contact"].choice_list
    args = build_parser().parse_args(["simulate", "--contact", "my-law"])
    assert args.contact == "my-law"
    for name in ("case.py", "commands/compare.py", "commands/sweep.py"):
        text = (ROOT / "wfjax" / name).read_text()
        assert "CONTACT_MODELS" not in text and '"hertz-profile")' not in text, name


def test_docs_page_is_generated():
    """docs/case_files.md == python -m wfjax.optdocs's output (rerun it after a change)."""
    template = (ROOT / "docs" / "case_files.template.md").read_text()
    assert (ROOT / "docs" / "case_files.md").read_text() == optdocs.render(template)


def _readme_commands() -> list[list[str]]:
    text = (ROOT / "README.md").read_text()
    block = text[text.index("## Using it"):]
    block = block[block.index("```bash") + 7:block.index("```", block.index("```bash") + 7)]
    block = block.replace("\\\n", " ")
    return [shlex.split(line.split("#")[0].split(" > ")[0])[1:] for line in block.splitlines()
            if line.startswith("wfjax ")]


@pytest.mark.parametrize("argv", _readme_commands(), ids=lambda a: " ".join(a[:3]))
def test_readme_commands_parse_and_their_flags_resolve(argv, monkeypatch, tmp_path):
    """Every command of the README's "Using it" block parses unchanged, and its flags pass
    their checks (files it names are not needed: paths are not opened here)."""
    from wfjax.commands._common import flag_layer

    monkeypatch.chdir(ROOT)
    args = build_parser().parse_args(argv)
    layer = flag_layer(args, args.command)
    for path in layer:
        assert path in O.KEYS
    if "--speeds-kmh" in argv and args.command != "figures":
        assert layer["run.speeds_kmh"] == argv[argv.index("--speeds-kmh") + 1]


def test_help_shows_units_and_the_subcommands_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    text = re.sub(r"\s+", " ", capsys.readouterr().out)
    assert "--depth-mm" in text and "[mm] (default: 1.2)" in text
    assert "(default: hertz-trajectory)" in text and "--impact-positions" in text


@pytest.mark.parametrize("argv, words", [
    (["detector", "--gauge-offset-m", "0.4"],
     ["detector.gauge_offset = 0.4 m", "(0, 0.325) m", "track.sleeper_spacing"]),
    (["simulate", "--vehicle", "single", "--flat-wheel", "1"], ["[vehicle]", "flat_wheel"]),
    (["sweep", "--wheel-positions-m", "0,0.5"], ["[vehicle]", "0.5 m apart"]),
])
def test_errors_between_options_name_the_keys_not_python_objects(tmp_path, capsys, argv,
                                                                  words):
    out = tmp_path / "o"
    assert main([*argv, "--out", str(out)]) == 2
    line = capsys.readouterr().err.strip()
    assert "\n" not in line and "(" + "n_bays=" not in line and not out.exists()
    for w in words:
        assert w in line, (w, line)
