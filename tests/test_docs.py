"""The documentation against the code and against itself, so that it cannot drift.

- ``docs/configuration.md``: every ``cell.toml`` key, its default and its range are those of
  :mod:`deploy.config` (the dataclasses, ``RANGES``, ``INT_RANGES``, ``CHOICES``);
- the README and every page under ``docs/``: every ``iem`` command and ``--option`` they
  name exists in that command's parser (built as ``iem COMMAND --help`` builds it, in this
  process), every repository path they name exists, and every link to a page and anchor
  resolves;
- the README stays at most 250 lines, and starts with ``make demo`` and ``make test``;
- measured figures are kept in ``docs/benchmarks.md`` alone, each with its command. A figure
  is marked there as ``<!-- figure: KEY -->TEXT<!-- /figure -->`` (an HTML comment: the page
  shows TEXT alone); another page that needs it quotes it with the same marks and KEY, and
  its TEXT must be benchmarks.md's (white space aside). A KEY is kept once, every quote names
  a kept KEY, and a kept figure's TEXT does not stand unmarked on another page;
- ``docs/commissioning.md``'s commands run, in order, on simulated traffic (slow): the
  recordings its ``iem record`` lines would make are written from the MuJoCo plant, every
  other ``iem`` line runs through :func:`deploy.cli.main`, and its rehearsal configuration
  runs the service over the tool's recording.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import re
import shlex
import shutil
import tomllib
from dataclasses import fields
from pathlib import Path

import pytest

from deploy.cli import COMMANDS
from deploy.config import CHOICES, DERIVED_GATE_KEYS, INT_RANGES, RANGES, SECTIONS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PAGES = [README, *sorted(DOCS.glob("*.md"))]
MAX_README_LINES = 250

FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
SPAN = re.compile(r"`([^`\n]+)`")


def text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def blocks(doc: str) -> list[tuple[str, str]]:
    """The fenced code blocks of ``doc``: ``(language, body)``, in order."""
    return [(m.group(1), m.group(2)) for m in FENCE.finditer(doc)]


def prose(doc: str) -> str:
    """``doc`` without its fenced code blocks."""
    return FENCE.sub("", doc)


def lines_of(body: str) -> list[str]:
    """A code block's lines, ``\\`` continuations joined."""
    return body.replace("\\\n", " ").splitlines()


def snippets(doc: str) -> list[str]:
    """Every piece of code in ``doc``: each line of its code blocks, each inline code span."""
    out = [line for _, body in blocks(doc) for line in lines_of(body)]
    return out + SPAN.findall(prose(doc))


# -- the commands' parsers ---------------------------------------------------------------------
def _parser(prog: str, module: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog)
    importlib.import_module(module).configure(parser)
    return parser


def parsers() -> dict[str, argparse.ArgumentParser]:
    """``"train"``, ``"bench paper"``, ...: the parser ``iem COMMAND --help`` shows."""
    out = {}
    for name, (target, _) in COMMANDS.items():
        if isinstance(target, dict):
            for sub, (module, _) in target.items():
                out[f"{name} {sub}"] = _parser(f"iem {name} {sub}", module)
        else:
            out[name] = _parser(f"iem {name}", target)
    return out


def options(parser: argparse.ArgumentParser) -> set[str]:
    return {o for action in parser._actions for o in action.option_strings}


def tokens(snippet: str) -> list[str]:
    try:
        return shlex.split(snippet, comments=True)
    except ValueError:  # an unbalanced quote in prose code: words are enough here
        return snippet.split()


def iem_invocations(snippet: str) -> list[tuple[str, list[str]]]:
    """``(command, arguments)`` of every ``iem`` invocation in ``snippet`` (``iem`` or a path
    ending in ``/iem``); the arguments end at a shell operator. ``("", [...])`` for a word
    after ``iem`` that is a placeholder (``COMMAND``, ``...``) or an option of ``iem``."""
    words = tokens(snippet)
    found = []
    for i, word in enumerate(words):
        if word != "iem" and not word.endswith("/iem"):
            continue
        rest = []
        for w in words[i + 1:]:
            if w in ("&&", "||", "|", ";", "&", ">", "2>&1"):
                break
            rest.append(w)
        if not rest or not re.fullmatch(r"[a-z][a-z0-9-]*", rest[0]):
            found.append(("", rest))
        elif rest[0] == "bench" and len(rest) > 1 and re.fullmatch(r"[a-z][a-z0-9-]*", rest[1]):
            found.append((f"bench {rest[1]}", rest[2:]))
        else:
            found.append((rest[0], rest[1:]))
    return found


@pytest.fixture(scope="module")
def iem_parsers():
    return parsers()


def test_the_readme_is_short_and_starts_with_make_demo_and_make_test():
    lines = text(README).splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines"
    first = [line.split("#")[0].strip() for line in lines_of(blocks(text(README))[0][1])]
    assert first[:2] == ["make demo", "make test"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_iem_command_and_option_named_exists(page, iem_parsers):
    every = set().union(*(options(p) for p in iem_parsers.values()))
    problems = []
    for snippet in snippets(text(page)):
        for command, args in iem_invocations(snippet):
            if not command:
                continue
            if command not in iem_parsers:
                problems.append(f"{snippet!r}: no command 'iem {command}'")
                continue
            known = options(iem_parsers[command])
            problems += [f"{snippet!r}: 'iem {command}' has no option {a.split('=')[0]}"
                         for a in args if a.startswith("--")
                         and a.split("=")[0] not in known]
        words = tokens(snippet)
        if words and re.fullmatch(r"--[a-z][a-z0-9-]*", words[0]) and words[0] not in every:
            problems.append(f"{snippet!r}: no iem command has the option {words[0]}")
    assert not problems, "\n".join(problems)


REPO_PATH = re.compile(r"(?:sim|iem|deploy|firmware_bridge|tests|docs)/[\w./-]*[\w/]")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_repository_path_named_exists(page):
    missing = sorted({m for span in SPAN.findall(prose(text(page)))
                      for m in REPO_PATH.findall(span)
                      if span.startswith(m.split("/")[0]) and not (ROOT / m).exists()})
    assert not missing, f"{page.name} names paths that do not exist: {missing}"


def anchors(doc: str) -> set[str]:
    """GitHub's heading ids of ``doc`` (lower case, punctuation dropped, spaces to hyphens)
    and its explicit ``<a id="...">`` anchors."""
    ids = set(re.findall(r'<a id="([^"]+)"', doc))
    for title in re.findall(r"^#+ (.+)$", prose(doc), re.M):
        ids.add(re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-"))
    return ids


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_link_to_a_page_and_an_anchor_resolves(page):
    problems = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text(page)):
        if re.match(r"[a-z]+:", target):
            continue
        file, _, anchor = target.partition("#")
        linked = (page.parent / file).resolve() if file else page
        if not linked.exists():
            problems.append(f"{target}: no such file")
        elif anchor and anchor not in anchors(text(linked)):
            problems.append(f"{target}: no such anchor in {linked.name}")
    assert not problems, "\n".join(problems)


# -- figures: kept in docs/benchmarks.md, quoted elsewhere --------------------------------
BENCHMARKS = DOCS / "benchmarks.md"
FIGURE = re.compile(r"<!-- figure: ([a-z0-9-]+) -->(.*?)<!-- /figure -->", re.S)
FIGURE_OPEN = re.compile(r"<!-- /?figure\b")


def marked(doc: str) -> list[tuple[str, str]]:
    """``(key, text)`` of every marked figure in ``doc``, in order, white space collapsed."""
    return [(key, " ".join(body.split())) for key, body in FIGURE.findall(doc)]


def kept() -> dict[str, str]:
    return dict(marked(text(BENCHMARKS)))


def quote_problems(doc: str, kept_figures: dict[str, str]) -> list[str]:
    """What is wrong with ``doc``'s quotes of ``kept_figures``: a mark that does not parse,
    a key not kept, a text not the kept one, or a kept text standing unmarked."""
    problems = []
    if len(FIGURE_OPEN.findall(doc)) != 2 * len(FIGURE.findall(doc)):
        problems.append("a figure mark without its pair: <!-- figure: KEY -->TEXT<!-- /figure -->")
    for key, quoted in marked(doc):
        if key not in kept_figures:
            problems.append(f"{key}: quoted, but benchmarks.md keeps no figure of that key")
        elif quoted != kept_figures[key]:
            problems.append(f"{key}: quoted as {quoted!r}, benchmarks.md keeps "
                            f"{kept_figures[key]!r}")
    unmarked = " ".join(FIGURE.sub(" ", doc).split())
    problems += [f"{key}: {value!r} stands unmarked; quote it as benchmarks.md marks it"
                 for key, value in kept_figures.items()
                 if len(value) >= 6 and re.search(rf"(?<![\w.]){re.escape(value)}(?![\w])",
                                                  unmarked)]
    return problems


def test_benchmarks_keeps_each_figure_once():
    keys = [key for key, _ in marked(text(BENCHMARKS))]
    assert keys, "benchmarks.md marks no figure"
    assert len(keys) == len(set(keys)), sorted(k for k in keys if keys.count(k) > 1)
    assert len(FIGURE_OPEN.findall(text(BENCHMARKS))) == 2 * len(keys), "a mark without its pair"


@pytest.mark.parametrize("page", [p for p in PAGES if p != BENCHMARKS], ids=lambda p: p.name)
def test_every_quoted_figure_is_benchmarks(page):
    problems = quote_problems(text(page), kept())
    assert not problems, f"{page.name}:\n" + "\n".join(problems)


def test_a_quote_that_differs_from_benchmarks_is_found():
    figures = {"mass": "0.0121 / 0.0148 / 0.0411"}
    assert not quote_problems("mass <!-- figure: mass -->0.0121 / 0.0148\n / 0.0411"
                              "<!-- /figure --> kg", figures)
    for doc in ("mass <!-- figure: mass -->0.013-0.039<!-- /figure --> kg",
                "mass <!-- figure: masses -->0.0121 / 0.0148 / 0.0411<!-- /figure -->",
                "mass <!-- figure: mass -->0.0121 / 0.0148 / 0.0411 kg",
                "mass 0.0121 / 0.0148 / 0.0411 kg"):
        assert quote_problems(doc, figures), doc


# -- docs/configuration.md against deploy/config/sections.py ---------------------------------
def reference_tables() -> dict[str, dict[str, tuple[str, str]]]:
    """``{section: {key: (default cell, range cell)}}`` of the configuration reference."""
    out: dict[str, dict[str, tuple[str, str]]] = {}
    section = None
    for line in text(DOCS / "configuration.md").splitlines():
        if m := re.fullmatch(r"## \[(\w+)\]", line):
            section = out.setdefault(m.group(1), {})
        elif section is not None and (m := re.match(r"\| `(\w+)` \| `([^`]*)` \| ([^|]*) \|",
                                                     line)):
            assert m.group(1) not in section, f"[{line}] twice"
            section[m.group(1)] = (m.group(2), m.group(3).strip())
    return out


def number(literal: str) -> int | float:
    return float(literal) if "." in literal else int(literal)


def toml_value(literal: str):
    return tomllib.loads(f"v = {literal}")["v"]


def test_every_cell_toml_key_and_default_is_the_codes():
    tables = reference_tables()
    assert set(tables) == set(SECTIONS)
    for section, cls in SECTIONS.items():
        defaults = cls()
        keys = {f.name for f in fields(cls)} - (set(DERIVED_GATE_KEYS) if section == "gate"
                                                 else set())
        assert set(tables[section]) == keys, section
        for key, (default, _) in tables[section].items():
            want = getattr(defaults, key)
            got = toml_value(default)
            assert got == (list(want) if isinstance(want, tuple) else want), (section, key)
            assert type(got) is (list if isinstance(want, tuple) else type(want)), (section, key)


def test_every_range_and_choice_is_the_codes():
    for section, keys in reference_tables().items():
        for key, (default, stated) in keys.items():
            where = f"[{section}] {key}: {stated!r}"
            if (section, key) in RANGES or (section, key) in INT_RANGES:
                lo, hi = RANGES.get((section, key)) or INT_RANGES[(section, key)]
                m = re.fullmatch(r"(-?[\d.]+) to (-?[\d.]+)", stated)
                assert m, where
                assert (number(m.group(1)), number(m.group(2))) == (lo, hi), where
            elif (section, key) in CHOICES:
                named = re.findall(r'`"([^"`]*)"`', stated)
                assert set(CHOICES[(section, key)]) == set(named), where
            elif isinstance(toml_value(default), bool):
                assert stated == "`true`, `false`", where


# -- docs/commissioning.md, run --------------------------------------------------------------
RECORDED_EXT = {".blf", ".log", ".asc", ".trc", ".csv", ".toml", ".json", ".msgpack", ".mcap",
                ".db3"}


def is_path(word: str) -> bool:
    return "/" in word or Path(word).suffix in RECORDED_EXT


def procedure() -> tuple[list[list[str]], dict[str, str]]:
    """The commissioning page's shell lines (as words, in order) and its TOML blocks by the
    file name their first line names (``# /etc/iem/rehearsal.toml``)."""
    doc = text(DOCS / "commissioning.md")
    lines, tomls = [], {}
    for lang, body in blocks(doc):
        if lang == "sh":
            lines += [w for w in map(tokens, lines_of(body)) if w]
        elif lang == "toml" and (m := re.match(r"# (\S+)\n", body)):
            tomls[Path(m.group(1)).name] = body
    return lines, tomls


def test_the_commissioning_page_names_every_step():
    lines, tomls = procedure()
    commands = [c for words in lines for c, _ in iem_invocations(shlex.join(words))]
    for step in ("calibrate", "record", "train", "identify", "replay", "run"):
        assert step in commands, step
    run = next(a for words in lines for c, a in iem_invocations(shlex.join(words))
               if c == "run")
    assert Path(run[run.index("--config") + 1]).name in tomls


@pytest.mark.slow
def test_the_commissioning_procedure_runs_on_simulated_traffic(tmp_path, capsys):
    """Steps 2-8 of ``docs/commissioning.md`` on the modelled-only plant (gap seed 3: an arm
    whose departure from its model an arm file describes), the recordings written as the
    controller would have sent them (``tests/deploy/commands/test_identify.py``'s ``write_log``)."""
    from deploy.cli import main
    from sim.family import default_test_payload
    from sim.paths import calibration_path
    from sim.payload import load_payload
    from sim.plant import ArmPlant, RealityGap
    from tests.deploy.commands.test_identify import write_log

    gap = RealityGap(seed=3).modelled_only()
    truth = default_test_payload()
    recordings = {"bare-arm.blf": ArmPlant(gap=gap, seed=21),
                  "tool-loaded.blf": ArmPlant(gap=gap, seed=24, payload=truth)}
    for name, plant in recordings.items():
        write_log(plant.follow(calibration_path()), tmp_path / name)

    def here(value):
        """A path of the page, in this test's folder (by its file name)."""
        if isinstance(value, str) and is_path(value):
            return str(tmp_path / Path(value).name)
        if isinstance(value, dict):
            return {k: here(v) for k, v in value.items()}
        return value

    lines, tomls = procedure()
    transcript, run_log = [], ""
    for words in lines:
        if words[0] == "cp":
            shutil.copy(here(words[1]), here(words[2]))
            transcript.append(f"$ cp {Path(words[1]).name} {Path(words[2]).name}")
            continue
        for command, args in iem_invocations(shlex.join(words)):
            if not command:  # the unit or user named iem (systemctl, sudo -u iem)
                continue
            if command == "record":  # the plant's recording stands in for the bus
                assert Path(args[args.index("--out") + 1]).name in recordings
                continue
            if command == "set-load":  # no controller here: tests/deploy/commands/test_set_load.py
                continue
            args = [here(a) for a in args]
            if command == "run":
                config = tmp_path / Path(args[args.index("--config") + 1]).name
                doc = tomllib.loads(tomls[config.name])
                config.write_text("".join(
                    f"[{section}]\n" + "".join(f"{k} = {json.dumps(v)}\n"
                                               for k, v in here(table).items())
                    for section, table in doc.items()), encoding="utf-8")
            status = main([*command.split(), *args])
            out = capsys.readouterr()
            transcript.append(f"$ iem {command} {shlex.join(args)}\n{out.out}{out.err}"
                              .rstrip().replace(f"{tmp_path}/", ""))
            assert status == 0, transcript[-1]
            if command == "run":
                run_log = out.err
    with capsys.disabled():
        print("\n" + "\n".join(transcript))

    tool = load_payload(tmp_path / "tool.toml")
    assert abs(tool.mass - truth.mass) < 0.005
    replayed = json.loads((tmp_path / "replay.json").read_text())
    assert replayed["writes"]["would_send"] >= 1
    events = [json.loads(line) for line in run_log.splitlines() if line.startswith("{")]
    assert "initial_payload" in [e.get("event") for e in events]
    reasons = [e["reason"] for e in events if e.get("event") == "gate"]
    assert reasons[0] == "unverified", reasons  # held until live data tested the file
    assert "load_sent" in [e.get("event") for e in events], reasons


# -- the first live run: the recipe of deploying.md runs as written --------------------------
def first_run_recipe() -> str:
    """The shell block of deploying.md's section on the first live run."""
    doc = text(DOCS / "deploying.md")
    section = doc.split("## A first live run, against the simulated controller", 1)[1]
    section = section.split("\n## ", 1)[0]
    return next(body for lang, body in blocks(section) if lang == "sh")


def test_the_first_live_run_recipe_is_short_and_complete():
    recipe = first_run_recipe()
    assert len(recipe.splitlines()) <= 20  # a screenful: 8 lines of commands, a cell.toml
    for part in ("iem sim-controller --interface slcan-pty", "iem run --config cell.toml",
                 "kill $CONTROLLER"):
        assert part in recipe, part


def test_the_first_live_run_recipe_runs_as_written(tmp_path):
    """The recipe, run by bash in an empty folder with this checkout's ``iem`` on the PATH:
    the controller starts, ``iem run`` trains a model, writes the load and the controller
    acknowledges it, as the page says to look for."""
    import os
    import signal
    import subprocess
    import sys

    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}"
           f"{os.environ.get('PATH', '')}", "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen(["bash", "-e", "-c", first_run_recipe()], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        _, err = proc.communicate(timeout=180)
    finally:  # whatever happened, the controller the recipe started is gone
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, err[-3000:]
    assert "saved the new model to model.msgpack" in err, err[-3000:]
    assert "controller acknowledged load command 1" in err, err[-3000:]
    assert (tmp_path / "model.msgpack").is_file()


# -- the defaults the pages give are the code's ------------------------------------------------
def test_the_block_frames_default_the_pages_give_is_the_codes():
    """A sentence of prose that gives ``block_frames`` a default gives the code's (0: the
    link's rate over 100); commissioning.md said 10. (configuration.md's table is held to the
    code by test_every_cell_toml_key_and_default_is_the_codes.)"""
    from deploy.config import EstimateConfig

    default = EstimateConfig().block_frames
    said = 0
    for page in PAGES:
        flat = " ".join(text(page).split())
        for sentence in re.split(r"(?<=[.;])\s", flat):
            if "block_frames" in sentence and "default" in sentence and "|" not in sentence:
                m = re.search(r"default(?:s to| is|,|:)?\s*`?(\d+)", sentence)
                assert m and int(m.group(1)) == default, (page.name, sentence)
                said += 1
    assert said >= 2  # commissioning.md and outputs.md give it


def test_the_model_kind_comment_says_what_the_code_does(tmp_path):
    """``deploy/cell.toml`` said a model file of another kind "is used as it is, with a
    warning"; it is refused (ConfigError, exit 78), as the comment now says."""
    from deploy.config import ConfigError, config_from_dict
    from deploy.model.setup import load_or_train_model
    from iem.model_kinds import new_model
    from iem.persistence import save_model

    cell = text(ROOT / "deploy" / "cell.toml")
    model_section = cell.split("\n[model]\n", 1)[1].split("\n[", 1)[0]
    comment = model_section.split("# kind:", 1)[1].split("\nkind =", 1)[0]
    assert "used as it is" not in comment
    assert "another kind" in comment and "is refused (exit 78)" in comment
    path = tmp_path / "model.msgpack"
    save_model(new_model("IEM"), path)
    config = config_from_dict({"model": {"path": str(path), "kind": "IEM+phys"}})
    with pytest.raises(ConfigError, match="holds a model of kind 'IEM'"):
        load_or_train_model(config)
