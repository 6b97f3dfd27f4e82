"""Scenarios for the service: by name from ``scenarios/`` or inline TOML, confined.

A client never names a file on the server: a scenario is either a bare name looked up in the
configured scenarios folder (``rusti_v1_box`` -> ``scenarios/rusti_v1_box.toml``) or TOML
text whose ``map`` must name a map in the configured maps folder (``lab_box``,
``lab_box.geojson`` or ``../maps/lab_box.geojson``, resolved as if the text were a file in
``scenarios/``). Anything that would resolve outside those folders is refused.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from orange_plan.context import context_of
from orange_plan.errors import InputError, ScenarioError, close_match_hint
from orange_plan.examples import find_dir
from orange_plan.scenario import scenario_from_dict

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")
"""A scenario or map name: letters, digits, ``_ . -``; no path separators."""

MAP_SUFFIXES = (".geojson", ".json")


@dataclass(frozen=True)
class ScenarioSource:
    """Where a mission's scenario came from: its name and its TOML text (what is stored)."""

    name: str
    toml_text: str
    inline: bool


def default_folder(kind: str) -> Path:
    """``scenarios/`` or ``maps/`` by the examples' look-up rule (the working folder, then the
    installed examples); the working folder's when there is none (a library with no names)."""

    return find_dir(kind) or Path.cwd() / kind


class ScenarioLibrary:
    """Resolves scenario names and inline scenarios inside two folders.

    Parameters
    ----------
    scenarios_dir : folder of ``NAME.toml`` scenarios
    maps_dir : folder of ``NAME.geojson`` maps (and their rasters)
    """

    def __init__(self, scenarios_dir: str | Path | None = None,
                 maps_dir: str | Path | None = None):
        self.scenarios_dir = Path(scenarios_dir or default_folder("scenarios")).resolve()
        self.maps_dir = Path(maps_dir or default_folder("maps")).resolve()

    def names(self) -> list[str]:
        """The scenario names a client may ask for."""
        if not self.scenarios_dir.is_dir():
            return []
        return sorted(p.stem for p in self.scenarios_dir.glob("*.toml") if NAME_RE.match(p.stem))

    def source(self, name: str | None = None, toml_text: str | None = None) -> ScenarioSource:
        """The stored form of a request: exactly one of a name or TOML text.

        Raises
        ------
        InputError
            Unknown or ill-formed name (with a close match), both or neither given.
        """
        if (name is None) == (toml_text is None):
            raise InputError("give exactly one of 'scenario' (a name from scenarios/) and "
                             "'scenario_toml' (the scenario's TOML text)")
        if name is not None:
            name = name.removesuffix(".toml")
            if not NAME_RE.match(name) or ".." in name:
                raise InputError(f"scenario {name!r} is not a scenario name (letters, digits, "
                                 "'_', '.', '-'; no folders)")
            path = self.scenarios_dir / f"{name}.toml"
            if not path.is_file():
                raise InputError(f"no scenario named {name!r} in scenarios/"
                                 + close_match_hint(name, self.names()))
            return ScenarioSource(name, path.read_text(encoding="utf-8"), inline=False)
        data = parse_toml(toml_text, "scenario_toml")
        label = data.get("name") if isinstance(data.get("name"), str) else "inline"
        return ScenarioSource(label, toml_text, inline=True)

    def context(self, source: ScenarioSource):
        """Load a stored scenario into a Context (scenario, world, energy model).

        Raises
        ------
        InputError
            Bad TOML, a map outside maps/, or anything ``load_context`` refuses.
        """

        where = "scenario_toml" if source.inline else f"scenarios/{source.name}.toml"
        data = parse_toml(source.toml_text, where)
        data["map"] = str(self.map_path(data.get("map"), where))
        try:
            return context_of(scenario_from_dict(data, Path(where)))
        except InputError as exc:
            raise type(exc)(self._relative(str(exc))) from None

    def map_path(self, value, where: str) -> Path:
        """The map file a scenario's ``map`` value names, confined to maps/."""
        if not isinstance(value, str) or not value:
            raise ScenarioError(f"{where}: 'map' must name a map in maps/ (e.g. 'lab_box')")
        name = value
        for prefix in ("../maps/", "maps/"):
            name = name.removeprefix(prefix)
        if not name.endswith(MAP_SUFFIXES):
            name += ".geojson"
        if "/" in name or "\\" in name or not NAME_RE.match(name) or ".." in name:
            raise ScenarioError(f"{where}: map {value!r} must name a map in maps/ "
                                "(e.g. 'lab_box' or '../maps/lab_box.geojson'); other paths "
                                "are not served")
        path = (self.maps_dir / name).resolve()
        if path.parent != self.maps_dir or not path.is_file():
            known = [p.stem for p in self.maps_dir.glob("*.geojson")]
            raise ScenarioError(f"{where}: no map {value!r} in maps/"
                                + close_match_hint(Path(name).stem, known))
        return path

    def _relative(self, message: str) -> str:
        """Error text without the server's folders."""
        for folder, label in ((self.maps_dir, "maps"), (self.scenarios_dir, "scenarios")):
            message = message.replace(str(folder), label)
        return message


def parse_toml(text: str, where: str) -> dict:
    """Parse TOML text; a syntax error is one InputError line."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{where}: not valid TOML ({exc})") from None
    return data
