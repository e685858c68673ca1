"""The README and docs/ hold to the code: every config key with its default, every rejection reason and
Health counter, every sub-command and option with its default. Each failure names the stale or missing item.

No process is started: the docs are read as text, the code as dataclasses, argparse parsers and an ``ast``
walk of the services' sources.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import dataclasses
import functools
import io
import math
import re
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from fedtrack import cli
from fedtrack.cli import main
from fedtrack.deploy.security import ZenohSettings
from fedtrack.deploy.settings import MultitargetSettings
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.geodetic import FrameConfig
from fedtrack.local_filters.imm.config import IMMConfig
from fedtrack.local_filters.mtt.config import MTT_VDIE_WINDOW, MhtConfig, MttConfig
from fedtrack.local_filters.pda.config import ExistenceConfig, PDAParams
from fedtrack.local_filters.radar.filters import CONFIG_CLASSES
from fedtrack.local_filters.regions import GridConfig, PolygonConfig, RegionsConfig
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.estimation import VdieParams
from fedtrack.sensors.radar import RadarConfig
from fedtrack.sensors.sonar import ScenarioConfig, SonarConfig

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
SOURCES = ("fedtrack", "local_filters", "fusion_center", "sensors", "deploy")

# ------------------------------------------------------------------------------------------- markdown


def section(path: Path, heading: str) -> str:
    """The text under the heading ``heading`` of ``path`` (else the first that starts with it: ``## Foo``), up
    to the next heading of the same or a higher level."""
    lines = path.read_text().splitlines()
    fence = 0
    headings = []  # (line index, level) outside fenced blocks
    for i, line in enumerate(lines):
        fence ^= line.startswith("```")
        if not fence and line.startswith("#"):
            headings.append((i, len(line) - len(line.lstrip("#"))))
    level = len(heading) - len(heading.lstrip("#"))
    start = next((i for i, _ in headings if lines[i] == heading), None)  # "## Messages" before "## Messages in parts"
    start = next((i for i, _ in headings if lines[i].startswith(heading)), None) if start is None else start
    assert start is not None, f"{path.name}: no heading {heading!r}"
    end = next((i for i, depth in headings if i > start and depth <= level), len(lines))
    return "\n".join(lines[start + 1:end])


def cells(line: str) -> list[str]:
    """A markdown table row's cells (``\\|`` inside a cell is a literal bar)."""
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]


def table(text: str, header: str) -> list[list[str]]:
    """The rows of the first markdown table in ``text`` whose header row starts with ``header``."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith(header)), None)
    assert start is not None, f"no table with the header {header!r}"
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append(cells(line))
    return rows


def code_block(text: str, lang: str) -> str:
    """The first fenced ``lang`` block of ``text``."""
    match = re.search(rf"```{lang}\n(.*?)```", text, re.DOTALL)
    assert match, f"no {lang} block"
    return match.group(1)


def ticked(text: str) -> list[str]:
    """The backticked spans of ``text``."""
    return re.findall(r"`([^`]+)`", text)


# ------------------------------------------------------------------------------------------- config keys

# table -> (its dataclass, keys documented in another table of their own)
TABLES: dict[str, tuple[type, tuple[str, ...]]] = {
    "fusion": (FusionConfig, ("vdie",)), "fusion.vdie": (VdieParams, ()),
    "deployment": (DeploymentConfig, ()), "sensor": (SensorConfig, ()), "zenoh": (ZenohSettings, ()),
    "imm": (IMMConfig, ()), "mtt": (MttConfig, ()), "mtt.mht": (MhtConfig, ()),
    "multitarget": (MultitargetSettings, ()), "radar_filter (ekf-ie)": (CONFIG_CLASSES["ekf-ie"], ()),
}
# (table, doc, heading, complete: every key of the table is in it; False: a subset, each key known, its default right;
# None: a subset whose second column is not the default (geodetic.md's values simulate traffic derives))
KEY_TABLES = [
    ("fusion", README, "### `[fusion]`", True),
    ("fusion.vdie", README, "### `[fusion.vdie]`", True),
    ("deployment", README, "### `[deployment]`", True),
    ("deployment", DOCS / "deploy.md", "### `[deployment]`", False),
    ("sensor", README, "### `[[sensor]]`", True),
    ("sensor", DOCS / "deploy.md", "### `[[sensor]]`", True),
    ("zenoh", DOCS / "deploy.md", "## Authenticated transport", True),
    ("imm", DOCS / "imm.md", "## Configuration (the `[imm]` table", True),
    ("mtt", DOCS / "multitarget-formats.md", "## Configuration: `[mtt]`", True),
    ("mtt.mht", DOCS / "mht.md", "## Defaults and why (`[mtt.mht]`)", True),
    ("multitarget", DOCS / "multitarget.md", "## Live: the same algorithms", True),
    ("mtt", DOCS / "multitarget.md", "## Parameters chosen where nothing else says", False),
    ("radar_filter (ekf-ie)", DOCS / "radar.md", "## EKF with direct input estimation", True),
    ("mtt", DOCS / "geodetic.md", "## Recorded air traffic as truth", None),
]
NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def defaults(cls: type) -> dict[str, Any]:
    """Each field of dataclass ``cls`` and its default (``dataclasses.MISSING`` when required)."""
    return {f.name: (f.default if f.default_factory is dataclasses.MISSING else f.default_factory())
            for f in dataclasses.fields(cls)}


def literal(text: str) -> tuple[bool, Any]:
    """``(True, value)`` when ``text`` is a TOML value or starts with a number (``1000 m``), else ``(False, None)``."""
    with contextlib.suppress(tomllib.TOMLDecodeError):
        return True, tomllib.loads(f"v = {text.strip()}")["v"]
    match = NUMBER.match(text.strip())
    return (True, float(match.group(0))) if match else (False, None)


def same(doc: Any, code: Any) -> bool:
    """A documented value equals the code's (numbers to 1e-9, sequences item by item)."""
    if isinstance(code, bool) or isinstance(doc, bool):
        return doc is code
    if isinstance(code, (int, float)) and isinstance(doc, (int, float)):
        return math.isclose(doc, code, rel_tol=1e-9, abs_tol=1e-12)
    if isinstance(code, (tuple, list)) and isinstance(doc, (tuple, list)):
        return len(doc) == len(code) and all(same(d, c) for d, c in zip(doc, code))
    return doc == code


def scalar(value: Any) -> bool:
    """A default a doc must state as a value (not "all roles", "first group", "none")."""
    return isinstance(value, (bool, int, float)) or isinstance(value, str) and value != ""


def check_default(where: str, key: str, doc_text: str, code: Any) -> list[str]:
    """Problems with ``doc_text`` as the documented default of ``key`` (code default ``code``)."""
    if code is dataclasses.MISSING:
        return [] if "required" in doc_text else [f"{where}: {key} is required, the doc says default {doc_text!r}"]
    ok, value = literal(doc_text)
    if not ok:
        return [f"{where}: {key}: the doc's default {doc_text!r} is not a value; the code's is {code!r}"] \
            if scalar(code) else []
    return [] if same(value, code) else [f"{where}: {key}: the doc says default {doc_text!r}, the code {code!r}"]


def assignments(text: str) -> dict[str, str]:
    """``key = value`` spans (backticked) in ``text``, e.g. ``window = "auto"``."""
    return dict(m.groups() for span in ticked(text) if (m := re.fullmatch(r"(\w+) = (.+)", span)))


def row_items(row: list[str]) -> Iterator[tuple[str, str, str | None]]:
    """``(key, default text, sub-table)`` of a key table's row: ```a`, `b`` | ``1``, ``2`` gives two;
    ```[mtt.mht]`` | ``k = 3``, ...`` gives each ``k = v`` of that sub-table; ```[[imm.models]]` `name``` the key
    ``models``."""
    keys, default = row[0], row[1]
    sub = re.fullmatch(r"`\[{1,2}([\w.]+)(\.<id>)?\]{1,2}`.*", keys)  # [mtt.mht], [[imm.models]], [mtt.sensor.<id>]
    if sub:
        name = sub.group(1).split(".")[-1]
        pairs = assignments(default)
        yield name, default if keys.startswith("`[[") or not pairs else "", None
        for key, value in pairs.items():
            yield key, value, name
        return
    names = ticked(keys)
    values = ticked(default) or [default]
    if len(names) > 1 and len(values) != len(names):
        values = [v.strip() for v in re.split(r",\s*|\s+/\s+|\s+of\s+", default)]  # "15 s / 60 s", "3 of 4"
    if len(values) != len(names):  # one default for every key of the row ("one-point init")
        values = values[:1] * len(names)
    yield from ((name, value, None) for name, value in zip(names, values))


def key_table_problems(table_name: str, doc: Path, heading: str, complete: bool | None) -> list[str]:
    """What the first key table under ``heading`` of ``doc`` gets wrong about ``table_name`` (KEY_TABLES)."""
    cls, elsewhere = TABLES[table_name]
    code = defaults(cls)
    if table_name == "mtt":
        code["vdie"] = VdieParams(window=MTT_VDIE_WINDOW)
    where = f"{doc.name} [{table_name}]"
    problems, seen = [], set()
    for row in table(section(doc, heading), "| key |"):
        if "not a key" in row[0]:  # a constant documented beside the keys
            continue
        for key, text, sub in row_items(row):
            if sub is not None:
                seen.add(sub)
                sub_code = defaults(type(code[sub])) if sub in code else {}
                value = getattr(code[sub], key, dataclasses.MISSING) if sub in code else dataclasses.MISSING
                if key not in sub_code:
                    problems.append(f"{where}: documents {sub}.{key}, which the code does not accept")
                elif complete is not None:
                    problems += check_default(where, f"{sub}.{key}", text, value)
                continue
            seen.add(key)
            if key not in code:
                problems.append(f"{where}: documents {key}, which the code does not accept")
            elif complete is not None and not dataclasses.is_dataclass(code[key]):
                problems += check_default(where, key, text, code[key])
    if complete:
        problems += [f"{where}: {key} (default {code[key]!r}) is not documented"
                     for key in code if key not in seen and key not in elsewhere]
    return problems


@pytest.mark.parametrize("table_name, doc, heading, complete", KEY_TABLES,
                         ids=[f"{d.name}:{t}" for t, d, _, _ in KEY_TABLES])
def test_every_config_key_is_in_its_doc_table_with_its_default(table_name: str, doc: Path, heading: str,
                                                              complete: bool | None) -> None:
    problems = key_table_problems(table_name, doc, heading, complete)
    assert not problems, "\n".join(problems)


def test_the_readme_lists_every_table_of_the_config_file() -> None:
    """The README's table of tables names each top-level table the config file may hold (fedtrack.config.TABLES)
    and no other."""
    from fedtrack.config import TABLES as FILE_TABLES

    rows = table(section(README, "## Configuration (TOML)"), "| table |")
    named = {re.sub(r"[\[\]]", "", t).split(".")[0] for row in rows for t in ticked(row[0])}
    assert named == set(FILE_TABLES), (f"README's tables: missing {sorted(set(FILE_TABLES) - named)}, "
                                       f"unknown {sorted(named - set(FILE_TABLES))}")


def test_the_toml_blocks_and_key_lists_name_every_key_with_its_default() -> None:
    """The tables documented as a TOML block (``[pda]``: its defaults; ``[frame]``, ``[regions]``: an example
    naming every key) or as a list of ``key = value`` / ``key value`` (``[sonar]``, ``[radar]``,
    ``[radar_filter]``)."""
    problems: list[str] = []
    hpda = (DOCS / "hpda.md").read_text()
    block = tomllib.loads(code_block(hpda[hpda.index("Config: the `[pda]` table"):], "toml"))["pda"]
    for name, cls in (("tracker", PDAParams), ("existence", ExistenceConfig)):
        code = defaults(cls)
        problems += [f"hpda.md [pda.{name}]: {k} is not documented" for k in code if k not in block[name]]
        for key, value in block[name].items():
            if key not in code:
                problems.append(f"hpda.md [pda.{name}]: documents {key}, which the code does not accept")
            elif not same(value, code[key]):
                problems.append(f"hpda.md [pda.{name}]: {key} = {value!r}, the code's default is {code[key]!r}")
    for doc, heading, classes in ((DOCS / "geodetic.md", "## Frames", (FrameConfig,)),
                                  (DOCS / "multitarget.md", "## Regions", (RegionsConfig, GridConfig, PolygonConfig))):
        text = code_block(section(doc, heading), "toml")
        names = {k for cls in classes for k in defaults(cls)}
        written = set(re.findall(r"(\w+)\s*=", text)) - {"r1"}  # r1: a sensor id of [frame.sites]
        headers = re.findall(r"^(?:# )?\[+([\w.]+)\]+", text, re.MULTILINE)  # [frame.sites], # [[regions.polygon]]
        written |= {name.split(".")[-1] for name in headers} - {"frame", "regions"}
        problems += [f"{doc.name}: the TOML example lacks the key {k}" for k in sorted(names - written)]
        problems += [f"{doc.name}: the TOML example names {k}, which the code does not accept"
                     for k in sorted(written - names)]
    sonar = section(DOCS / "hpda.md", "### Simulated sonar")
    own, _, scenario = sonar.partition("`[scenario]`")
    radar = (DOCS / "radar.md").read_text()
    radar_keys = radar[radar.index("`RadarConfig` keys (defaults)"):].split("\n\n")[0]
    spans = dict(re.findall(r"`(\w+)` (\[[^\]]*\]|\"[^\"]*\"|[-\d.e]+)", radar_keys))
    lists = [("hpda.md [sonar]", SonarConfig, assignments(own), ("scenario",)),
             ("hpda.md [sonar.scenario]", ScenarioConfig, assignments(scenario.split("\n\n")[0]), ()),
             ("radar.md [radar]", RadarConfig, spans, ())]
    for row in table(section(DOCS / "radar.md", "## Config keys"), "| algorithm |"):
        algorithm = ticked(row[0])[0]
        pairs = dict(re.findall(r"`(\w+)` = ([^,(]+)", row[1]))
        lists.append((f"radar.md [radar_filter] {algorithm}", CONFIG_CLASSES[algorithm], pairs, ()))
    for where, cls, documented, elsewhere in lists:
        code = defaults(cls)
        problems += [f"{where}: {k} (default {code[k]!r}) is not documented"
                     for k in code if k not in documented and k not in elsewhere]
        for key, text in documented.items():
            if key not in code:
                problems.append(f"{where}: documents {key}, which the code does not accept")
            else:
                problems += check_default(where, key, text, code[key])
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------------------------------- reasons and counters

WIRE = DOCS / "wire.md"


def _sources() -> Iterator[tuple[Path, ast.AST]]:
    for root in SOURCES:
        for path in sorted((ROOT / root).rglob("*.py")):
            yield path, ast.parse(path.read_text())


def _string(node: ast.AST | None) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


@functools.cache
def emitted() -> tuple[set[str], set[str], set[str]]:
    """``(reasons, counters, patterns)`` the services' code can emit: the reasons of ``Rejected(...)`` (and
    of its subclasses and ``reason_of``), the counter names given to ``self.count`` / ``self.counters[...]``, the
    keys of the engines' ``counters()`` dicts and the reassembly's ``_drop``; ``patterns`` the f-strings among
    them, whose names :func:`expand` gives."""
    reasons, counters, patterns = set(), set(), set()
    for _, tree in _sources():
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                func = node.func
                name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
                first = node.args[0] if node.args else None
                if name == "Rejected" or name == "__init__" and isinstance(func, ast.Attribute) \
                        and isinstance(func.value, ast.Call) and getattr(func.value.func, "id", "") == "super":
                    reasons |= {r for r in [_string(first)] if r}
                elif name in ("count", "_count_part") and isinstance(func, ast.Attribute) \
                        and getattr(func.value, "id", "") == "self" and first is not None:
                    if _string(first):
                        counters.add(_string(first))  # type: ignore[arg-type]
                    elif isinstance(first, ast.JoinedStr):
                        patterns.add(ast.unparse(first))
                elif name == "_drop" and len(node.args) > 1 and _string(node.args[1]):
                    counters.add(_string(node.args[1]))  # type: ignore[arg-type]
            elif isinstance(node, ast.Subscript) and getattr(node.value, "attr", "") == "counters":
                if _string(node.slice):
                    counters.add(_string(node.slice))  # type: ignore[arg-type]
                elif isinstance(node.slice, ast.JoinedStr):
                    patterns.add(ast.unparse(node.slice))
            elif isinstance(node, ast.FunctionDef) and node.name in ("counters", "health_counters", "reason_of"):
                for sub in ast.walk(node):
                    if node.name == "reason_of" and isinstance(sub, ast.Return):
                        reasons |= {c.value for c in ast.walk(sub) if _string(c)}  # type: ignore[attr-defined]
                    if isinstance(sub, ast.Dict):
                        counters |= {k for k in map(_string, sub.keys) if k}
                    if isinstance(sub, ast.DictComp) and isinstance(sub.key, ast.JoinedStr):
                        patterns.add(ast.unparse(sub.key))
    return reasons, counters, patterns


def expand(pattern: str, reasons: set[str]) -> set[str]:
    """The counter names an f-string counter of the code stands for (a new f-string fails here, by name)."""
    from fedtrack.fusion_center.mtt.centre import Counters
    from fedtrack.local_filters.vdie.estimation import EVENT_NAMES
    from fedtrack.recording import CONFLICT, DUPLICATE, TABLES

    known = {
        "f'rejected_{reason}'": {f"rejected_{r}" for r in reasons},
        # the recorder counts a row recorded in its table, else the outcome (self.count(outcome))
        "f'{table.name}_recorded'": {f"{t.name}_recorded" for t in TABLES} | {DUPLICATE, CONFLICT},
        "f\"events_{EVENT_NAMES[kind].replace('-', '_')}\"": {f"events_{n.replace('-', '_')}"
                                                             for n in EVENT_NAMES.values()},
        "f'centre_{k}'": {f"centre_{k}" for k in vars(Counters())},
    }
    assert pattern in known, f"a counter named by the f-string {pattern}: add its names to expand()"
    return known[pattern]


def documented_reasons() -> set[str]:
    rows = table(section(WIRE, "## Rejections"), "| reason |")
    return {r for row in rows for r in ticked(row[0])}


def documented_counters() -> set[str]:
    rows = table(section(WIRE, "### Health counters"), "| counter |")
    return {c for row in rows for c in ticked(row[0])}


def test_every_rejection_reason_is_in_the_wire_doc() -> None:
    reasons, _, _ = emitted()
    doc = documented_reasons()
    missing, stale = sorted(reasons - doc), sorted(doc - reasons)
    assert not missing and not stale, (f"docs/wire.md Rejections: reasons the code emits but the table lacks: "
                                       f"{missing}; reasons the table lists that the code no longer emits: {stale}")


def test_every_health_counter_is_in_the_wire_doc() -> None:
    reasons, counters, patterns = emitted()
    for pattern in patterns:
        counters |= expand(pattern, reasons)
    counters = {c for c in counters if not c.startswith("rejected_") or c == "rejected_parts"}
    doc = documented_counters() - {"rejected_<reason>"}
    missing, stale = sorted(counters - doc), sorted(doc - counters)
    assert not missing and not stale, (f"docs/wire.md Health counters: counters the code emits but the table "
                                       f"lacks: {missing}; counters the table lists that the code never emits: {stale}")
# ------------------------------------------------------------------------------------------- commands and options

def _parsers(argv: list[str], entry: Any = main) -> list[argparse.ArgumentParser]:
    """The parsers that print ``fedtrack ARGV --help`` (or ``entry``'s, a module's ``main``)."""
    seen: list[argparse.ArgumentParser] = []
    original = argparse.ArgumentParser.print_help
    argparse.ArgumentParser.print_help = lambda self, file=None: seen.append(self)  # type: ignore[method-assign]
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
            entry([*argv, "--help"])
    finally:
        argparse.ArgumentParser.print_help = original  # type: ignore[method-assign]
    return seen


BENCH_SUITES = ("pipeline", "kernels", "montecarlo", "multitarget", "scale", "soak", "hpda-soak", "all")
COMMANDS = [["reproduce"], ["replay"], *(["simulate", s] for s in cli.SIMULATORS), ["evaluate"], ["export"], ["demo"],
            ["launch"], *(["train", t] for t in cli.TRAINERS), *(["bench", s] for s in BENCH_SUITES)]
HELP_CASES = COMMANDS + [["serve", role] for role in cli.SERVICES]


def _options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))
            and a.dest != "help" and a.help != argparse.SUPPRESS]


@pytest.mark.parametrize("argv", HELP_CASES, ids=" ".join)
def test_every_option_has_its_meaning_and_default_in_help(argv: list[str]) -> None:
    parsers = _parsers(argv)
    assert parsers
    for parser in parsers:
        formatter = parser._get_formatter()
        for action in _options(parser):
            text = formatter._expand_help(action) if action.help else ""
            name = "/".join(action.option_strings) or action.dest
            assert re.sub(r"\(?default[^)]*\)?", "", text).strip(" ;,.()"), f"{parser.prog} {name}: no meaning"
            if action.default not in (None, False, argparse.SUPPRESS):
                assert "default" in text and mentions_default(text, "default", action.default), \
                    f"{parser.prog} {name}: default {action.default!r} not in {text!r}"
            elif action.option_strings and action.nargs != 0 and not action.required:
                assert "default" in text, f"{parser.prog} {name}: the help says nothing of its default: {text!r}"


def _readme_row(argv: list[str]) -> str:
    command = "bench" if argv[0] == "bench" else " ".join(argv)
    rows = [line for line in README.read_text().splitlines() if line.startswith(f"| `fedtrack {command}")]
    assert len(rows) == 1, command
    return rows[0]


@pytest.mark.parametrize("argv", COMMANDS, ids=" ".join)
def test_the_readme_lists_every_option(argv: list[str]) -> None:
    row = _readme_row(argv)
    for parser in _parsers(argv):
        for action in _options(parser):
            for option in action.option_strings:
                assert re.search(rf"{re.escape(option)}(?![\w-])", row), f"README: {' '.join(argv)} lacks {option}"

def shown(value: Any) -> set[str]:
    """The ways a default may be written: ``1.0`` as ``1.0`` or ``1``; a list item by item; a path as text."""
    if isinstance(value, (list, tuple)):
        return {",".join(map(str, value)), ", ".join(map(str, value)), " ".join(map(str, value))}
    forms = {str(value)}
    if isinstance(value, float):
        forms |= {f"{value:g}", f"{value:,g}"}
    return forms


def mentions_default(text: str, option: str, value: Any) -> bool:
    """Whether ``text`` gives ``value`` as ``option``'s default: a number as the first number after a mention
    of the option (``--runs` defaults to 500``, ``[--c 100]``), any other value anywhere in ``text``."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        for match in re.finditer(rf"{re.escape(option)}(?![\w-])", text):
            first = re.search(r"(?<![\w.])[-+]?(\d[\d,]*\.?\d*|\.\d+)([eE][-+]?\d+)?(?![\w])", text[match.end():])
            if first and math.isclose(float(first.group(0).replace(",", "")), value, rel_tol=1e-9):
                return True
        return False
    return any(form in text for form in shown(value if not isinstance(value, Path) else str(value)))


def has_default(action: argparse.Action) -> bool:
    return action.default not in (None, False, argparse.SUPPRESS) and not action.required


@pytest.mark.parametrize("argv", COMMANDS, ids=" ".join)
def test_the_readme_gives_every_default(argv: list[str]) -> None:
    row = _readme_row(argv)
    missing = [f"{option} {action.default!r}" for parser in _parsers(argv) for action in _options(parser)
               if has_default(action) for option in action.option_strings[-1:]
               if not mentions_default(row, option, action.default)]
    assert not missing, f"README: fedtrack {' '.join(argv)}: defaults not given beside their option: {missing}"


@pytest.mark.parametrize("module", ["security", "wait_ready", "verify_run"])
def test_the_readme_gives_every_option_of_the_deployment_helpers(module: str) -> None:
    """``python -m fedtrack.deploy.MODULE``: each option, and its default, in the README's row of helpers."""
    import importlib

    entry = importlib.import_module(f"fedtrack.deploy.{module}").main
    row = next(line for line in README.read_text().splitlines() if line.startswith("| `python -m fedtrack.deploy"))
    assert f"python -m fedtrack.deploy.{module}" in row
    problems = [f"{option} (default {action.default!r})" for parser in _parsers([], entry)
                for action in _options(parser) for option in action.option_strings[-1:]
                if not re.search(rf"{re.escape(option)}(?![\w-])", row)
                or has_default(action) and not mentions_default(row, option, action.default)]
    assert not problems, f"README: python -m fedtrack.deploy.{module}: not given: {problems}"


def test_every_command_role_and_scenario_is_in_the_readme() -> None:
    text = README.read_text()
    commands = section(README, "## Commands")
    sub = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    missing = [name for name in sub.choices if f"| `fedtrack {name}" not in commands]
    missing += [f"serve {role}" for role in cli.SERVICES if f"`{role}`" not in _readme_row(["serve"])]
    missing += [f"reproduce {name}" for name in cli.REPRODUCERS if f"`{name}`" not in _readme_row(["reproduce"])]
    missing += [f"replay --algorithm {name}" for name in cli.REPLAY_ALGORITHMS
                if not re.search(rf"`{name}[` ]", _readme_row(["replay"]))]
    missing += [f"bench {suite}" for suite in BENCH_SUITES if suite not in _readme_row(["bench"])]
    missing += [f"{kind} {name}" for kind, names in (("simulate", cli.SIMULATORS), ("train", cli.TRAINERS))
                for name in names if f"| `fedtrack {kind} {name}" not in text]
    assert not missing, f"README's command table lacks: {missing}"


def serve_options() -> dict[str, tuple[set[str], Any]]:
    """Each option of ``fedtrack serve ROLE`` -> (the roles that take it, its default per role: ``"(required)"``
    where the role requires it)."""
    options: dict[str, tuple[set[str], Any]] = {}
    for role in cli.SERVICES:
        for parser in _parsers(["serve", role]):
            for action in _options(parser):
                option = action.option_strings[-1]
                roles, default = options.setdefault(option, (set(), {}))
                roles.add(role)
                default[role] = "(required)" if action.required else action.default
    return options


def test_the_readme_lists_every_serve_option_with_its_roles_and_default() -> None:
    rows = {ticked(row[0])[0]: row for row in table(section(README, "### `fedtrack serve` options"), "| option |")}
    options = serve_options()
    problems = [f"{option} is not in the table" for option in options if option not in rows]
    problems += [f"{option} is listed but no role takes it" for option in rows if option not in options]
    for option, (roles, default) in options.items():
        if option not in rows:
            continue
        listed, text = rows[option][1], rows[option][2]
        if listed != "every role":
            named = set(ticked(listed))
            problems += [f"{option}: {sorted(named ^ roles)} listed wrongly" for _ in [0] if named != roles]
        elif roles != set(cli.SERVICES):
            problems.append(f"{option}: 'every role', the code's roles are {sorted(roles)}")
        for role, value in default.items():
            if value == role and "the role's name" in text:
                continue
            if value == "(required)":
                if not re.search(rf"`{role}`: required|^\(required\)", text):
                    problems.append(f"{option}: required by {role}, the table does not say so: {text!r}")
                continue
            if value not in (None, False) and not any(form in text for form in shown(value)):
                problems.append(f"{option}: {role}'s default {value!r} is not in {text!r}")
    assert not problems, "README `fedtrack serve` options:\n" + "\n".join(problems)


def test_simulate_sensor_ids_are_documented(capsys: pytest.CaptureFixture[str]) -> None:
    with contextlib.suppress(SystemExit):
        main(["simulate", "multitarget", "--help"])
    assert "s<k> for a position sensor and r<k> for a radar" in " ".join(capsys.readouterr().out.split())
    assert "`r<k>`" in _readme_row(["simulate", "multitarget"])


# ------------------------------------------------------------------------------------------- keys


def test_the_wire_doc_lists_every_key_with_its_keys_method() -> None:
    """docs/wire.md's key table: each ``Keys`` method once, with the key expression it builds."""
    from fedtrack.keys import DEFAULT_DEPLOYMENT, Keys

    section_text = section(WIRE, "## Key expressions")
    keys = Keys(DEFAULT_DEPLOYMENT)
    methods = {name for name in vars(Keys) if not name.startswith("_") and callable(getattr(Keys, name))}
    methods -= {"sender", "region_of"}  # parsers of keys, not builders
    problems = [] if re.search(rf"default\s+`{DEFAULT_DEPLOYMENT}`", section_text) else \
        [f"the default deployment is {DEFAULT_DEPLOYMENT!r}, not the one the section names"]
    listed = set()
    for row in table(section_text, "| key under"):
        key, call = ticked(row[0])[0], ticked(row[3])[0]
        name, args = re.fullmatch(r"(\w+)\((.*)\)", call).groups()  # type: ignore[union-attr]
        listed.add(name)
        if name not in methods:
            problems.append(f"{call}: no such Keys method")
            continue
        params = [a.strip() for a in args.split(",") if a.strip()]
        built = getattr(keys, name)(*(f"<{p}>" for p in params)) if params else getattr(keys, name)()
        if built != f"fedtrack/{DEFAULT_DEPLOYMENT}/{key}":
            problems.append(f"{call} builds {built}, the table says fedtrack/<dep>/{key}")
    problems += [f"Keys.{m} is not in the table" for m in sorted(methods - listed)]
    assert not problems, "docs/wire.md key table:\n" + "\n".join(problems)


def test_the_wire_doc_names_every_message_field() -> None:
    """Every field of every wire message is named in docs/wire.md's Messages (as ``name``, ``Msg.name`` or
    ``"name"``; ``part`` / ``parts`` in Messages in parts), and a message's field table lists only its fields."""
    from fedtrack import wire

    messages = section(WIRE, "## Messages") + section(WIRE, "## Messages in parts")
    problems = []
    records = [(name, cls) for name, cls in sorted(vars(wire).items())
               if isinstance(cls, type) and dataclasses.is_dataclass(cls)
               and cls.__module__.startswith("fedtrack.wire")]
    assert {"Measurement", "TrackPicture", "HandOver", "Health"} <= {name for name, _ in records}, records
    for name, cls in records:
        for field in defaults(cls):
            if not re.search(rf"`({name}\.)?{field}`|\"{field}\"", messages):
                problems.append(f"{name}.{field} is not named")
        heading = f"### `{name}` on"
        if heading in messages:
            rows = table(section(WIRE, heading), "| field |")
            problems += [f"{name}: the table lists {f}, not a field" for row in rows for f in ticked(row[0])
                         if f not in defaults(cls)]
    assert not problems, "docs/wire.md messages:\n" + "\n".join(problems)


# ------------------------------------------------------------------------------------------- links


@functools.cache
def slugs(path: Path) -> set[str]:
    """The anchors of ``path``'s headings as GitHub makes them (lower case, punctuation dropped, spaces to
    hyphens, a repeated one suffixed ``-1``, ``-2`` ...)."""
    anchors: set[str] = set()
    counts: dict[str, int] = {}
    fence = False
    for line in path.read_text().splitlines():
        fence ^= line.startswith("```")
        if fence or not line.startswith("#"):
            continue
        slug = re.sub(r"[^\w\- ]", "", line.lstrip("#").strip().lower()).replace(" ", "-")
        n = counts.get(slug, 0)
        counts[slug] = n + 1
        anchors.add(slug if n == 0 else f"{slug}-{n}")
    return anchors


def test_every_local_link_of_the_docs_reaches_its_file_and_heading() -> None:
    problems = []
    for doc in [README, *sorted(DOCS.glob("*.md"))]:
        text = doc.read_text()
        for match in re.finditer(r"\]\(([^)\s]+)\)", text):
            target = match.group(1)
            if re.match(r"\w+:", target):  # http:, mailto:
                continue
            path, _, anchor = target.partition("#")
            linked = (doc.parent / path).resolve() if path else doc
            line = text.count("\n", 0, match.start()) + 1
            if not linked.exists():
                problems.append(f"{doc.name}:{line}: {target}: no such file")
            elif anchor and linked.suffix == ".md" and anchor not in slugs(linked):
                problems.append(f"{doc.name}:{line}: {target}: no such heading")
    assert not problems, "\n".join(problems)


TOP_FOLDERS = ("benchmarks/", "deploy/", "docs/", "examples/", "experiments/", "fedtrack/", "fusion_center/",
               "local_filters/", "sensors/", "tests/")


def test_every_file_path_the_docs_name_exists() -> None:
    """A path in backticks under one of the checkout's folders (``fusion_center/snapshot.py``) names a file
    that is there; a pattern (``<id>``, ``{a,b}``, ``*``, ``...``) is not a path."""
    problems = []
    for doc in [README, *sorted(DOCS.glob("*.md"))]:
        for number, line in enumerate(doc.read_text().splitlines(), 1):
            for path in re.findall(r"`([^`\s]+\.(?:py|toml|sh|md|gz|csv|json))`", line):
                if path.startswith(TOP_FOLDERS) and not re.search(r"[<>{}*|]|\.\.\.", path) \
                        and not (ROOT / path).is_file():
                    problems.append(f"{doc.name}:{number}: {path}: no such file")
    assert not problems, "\n".join(problems)


def test_the_readmes_hpda_table_2_counts_are_docs_hpdas() -> None:
    """The README's summary of paper 001's Table 2 quotes docs/hpda.md's table: the first five bins of each
    tracker under the paper's rule, and the mean confirmation times of both rules."""
    rows = {row[0]: row[1:] for row in table(section(DOCS / "hpda.md", "## Results"), "| bin (s) |")}
    bins = [rows[b] for b in ("0-150", "150-300", "300-350", "350-375", "375-425")]
    counts = {column: "/".join(row[column] for row in bins) for column in range(4)}
    means = [m.removesuffix(" s") for m in rows["mean time"]]
    summary = " ".join(README.read_text().split("**Paper 001, HPDA**")[1].split("- **Papers 002")[0].split())
    assert f"IPDA-AI {counts[0]}, HPDA {counts[2]} (paper {counts[1]} and {counts[3]})" in summary, summary
    assert f"(mean {means[4]} / {means[5]} s against {means[0]} / {means[2]} s)" in summary, summary
