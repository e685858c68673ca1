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
import io
import math
import re
import tomllib
from pathlib import Path
from typing import Any, Iterator

import pytest

from fedtrack import cli
from fedtrack.cli import main

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
SOURCES = ("fedtrack", "local_filters", "fusion_center", "sensors", "deploy")

# ------------------------------------------------------------------------------------------- markdown


def section(path: Path, heading: str) -> str:
    """The text under the first heading of ``path`` that starts with ``heading`` (``## Foo``), up to the
    next heading of the same or a higher level."""
    lines = path.read_text().splitlines()
    fence = 0
    headings = []  # (line index, level) outside fenced blocks
    for i, line in enumerate(lines):
        fence ^= line.startswith("```")
        if not fence and line.startswith("#"):
            headings.append((i, len(line) - len(line.lstrip("#"))))
    level = len(heading) - len(heading.lstrip("#"))
    start = next((i for i, _ in headings if lines[i].startswith(heading)), None)
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
    match = re.search(rf"```{lang}\n(.*?)```", text, re.S)
    assert match, f"no {lang} block"
    return match.group(1)


def ticked(text: str) -> list[str]:
    """The backticked spans of ``text``."""
    return re.findall(r"`([^`]+)`", text)


# ------------------------------------------------------------------------------------------- config keys

# (config table, the dataclass of its keys, the doc and heading documenting it, the doc's layout)
from fedtrack.deploy.security import ZenohSettings  # noqa: E402
from fedtrack.deploy.settings import MultitargetSettings  # noqa: E402
from fedtrack.deployment import DeploymentConfig, SensorConfig  # noqa: E402
from fedtrack.geodetic import FrameConfig  # noqa: E402
from fedtrack.local_filters.imm.config import IMMConfig  # noqa: E402
from fedtrack.local_filters.mtt.config import MTT_VDIE_WINDOW, MhtConfig, MttConfig  # noqa: E402
from fedtrack.local_filters.pda.config import ExistenceConfig, PDAParams  # noqa: E402
from fedtrack.local_filters.radar.filters import CONFIG_CLASSES  # noqa: E402
from fedtrack.local_filters.regions import GridConfig, PolygonConfig, RegionsConfig  # noqa: E402
from fedtrack.local_filters.vdie.config import FusionConfig  # noqa: E402
from fedtrack.local_filters.vdie.estimation import VdieParams  # noqa: E402
from fedtrack.sensors.radar import RadarConfig  # noqa: E402
from fedtrack.sensors.sonar import ScenarioConfig, SonarConfig  # noqa: E402

# table -> (its dataclass, keys documented in another table of their own)
TABLES: dict[str, tuple[type, tuple[str, ...]]] = {
    "fusion": (FusionConfig, ("vdie",)), "fusion.vdie": (VdieParams, ()),
    "deployment": (DeploymentConfig, ()), "sensor": (SensorConfig, ()), "zenoh": (ZenohSettings, ()),
    "imm": (IMMConfig, ()), "mtt": (MttConfig, ()), "mtt.mht": (MhtConfig, ()),
    "multitarget": (MultitargetSettings, ()),
}
# (table, doc, heading, complete: every key of the table is in it; False: a subset, each key known and its default right)
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
        values = [v.strip() for v in re.split(r",\s*|\s+/\s+", default)]
    if len(values) != len(names):  # one default for every key of the row ("one-point init")
        values = values[:1] * len(names)
    yield from ((name, value, None) for name, value in zip(names, values))


def key_table_problems(table_name: str, doc: Path, heading: str, complete: bool) -> list[str]:
    cls, elsewhere = TABLES[table_name]
    code = defaults(cls)
    if table_name == "mtt":
        code["vdie"] = VdieParams(window=MTT_VDIE_WINDOW)
    where = f"{doc.name} [{table_name}]"
    problems, seen = [], set()
    for row in table(section(doc, heading), "| key |"):
        for key, text, sub in row_items(row):
            if sub is not None:
                seen.add(sub)
                sub_code = defaults(type(code[sub])) if sub in code else {}
                value = getattr(code[sub], key, dataclasses.MISSING) if sub in code else dataclasses.MISSING
                if key not in sub_code:
                    problems.append(f"{where}: documents {sub}.{key}, which the code does not accept")
                else:
                    problems += check_default(where, f"{sub}.{key}", text, value)
                continue
            seen.add(key)
            if key not in code:
                problems.append(f"{where}: documents {key}, which the code does not accept")
            elif not dataclasses.is_dataclass(code[key]):
                problems += check_default(where, key, text, code[key])
    if complete:
        problems += [f"{where}: {key} (default {code[key]!r}) is not documented"
                     for key in code if key not in seen and key not in elsewhere]
    return problems


@pytest.mark.parametrize("table_name, doc, heading, complete", KEY_TABLES,
                         ids=[f"{d.name}:{t}" for t, d, _, _ in KEY_TABLES])
def test_every_config_key_is_in_its_doc_table_with_its_default(table_name: str, doc: Path, heading: str,
                                                              complete: bool) -> None:
    problems = key_table_problems(table_name, doc, heading, complete)
    assert not problems, "\n".join(problems)


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
        written |= {name.split(".")[-1] for name in re.findall(r"^\[+([\w.]+)\]+", text, re.M)} - {"frame", "regions"}
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
