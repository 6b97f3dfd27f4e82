"""Sweep file (``orange-plan sweep SWEEP.toml``, docs/formats.md): parse, validate, expand.

A sweep is scenarios x the Cartesian product of a parameter grid x seeds; each combination is
one run (plan, simulate, score). Every run gets a deterministic id, the hash of all it depends
on, so a rerun of the same sweep can skip what is already stored.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import itertools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from orange_plan.errors import InputError, close_match_hint
from orange_plan.files import file_problem
from orange_plan.scenario import read_toml, scenario_from_dict
from orange_plan.sim.truth import truth_from_dict

TOP_KEYS = ("name", "scenarios", "seeds", "truth", "vertices", "sample_rate_Hz", "grid")
TRUTH_KINDS = ("calibration", "model")
"""``calibration``: each seed draws a truth within the model's calibration uncertainty
(``sim.perturb.calibration_truths``); ``model``: the scenario's own model is the truth.
Anything else is the path of a TRUTH.toml (``simulate --truth``)."""

MIN_VERTICES = 50


@dataclass(frozen=True)
class RunSpec:
    """One run: everything ``sweep.task.run_one`` needs (picklable, file-free but the map).

    Attributes
    ----------
    index : position in the sweep (scenarios, then grid points, then seeds)
    run_id : 16 hex digits of the hash of the inputs below (and the map's bytes)
    scenario : the scenario's name
    scenario_file : its path as written in the sweep file
    scenario_data : the parsed scenario TOML with the grid point applied, ``map`` absolute
    params : the grid point, ``(dotted key, value)`` pairs in grid order
    seed : truth draw, simulator noise and roadmap seed
    truth : "calibration", "model", or a TRUTH.toml's parsed content
    n_vertices : roadmap size of the planner
    sample_rate_Hz : simulator rate [Hz]
    """

    index: int
    run_id: str
    scenario: str
    scenario_file: str
    scenario_data: dict = field(compare=False)
    params: tuple[tuple[str, Any], ...]
    seed: int
    truth: str | dict = field(compare=False)
    n_vertices: int
    sample_rate_Hz: float


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file and its runs."""

    name: str
    path: Path
    grid_keys: tuple[str, ...]
    runs: tuple[RunSpec, ...]


def load_sweep(path: str | Path) -> Sweep:
    """Read, validate and expand a sweep file.

    Raises
    ------
    InputError
        One line naming the sweep file and the problem: bad TOML, unknown key (with a close
        match), a missing scenario or truth file, a bad seed list, a grid key the scenarios do
        not have or a grid value they refuse, bad run settings.
    """

    path = Path(path)
    data = read_toml(path, "sweep", InputError)
    where = str(path)
    for key in data:
        if key not in TOP_KEYS:
            raise InputError(f"{where}: unknown key '{key}'" + close_match_hint(key, TOP_KEYS))
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise InputError(f"{where}: name must be a non-empty string, got {name!r}")
    scenarios = _scenario_files(data.get("scenarios"), path)
    seeds = _seeds(data.get("seeds", 1), where)
    truth = _truth(data.get("truth", "calibration"), path)
    n_vertices = _integer(data.get("vertices", 1000), "vertices", MIN_VERTICES, where)
    rate = data.get("sample_rate_Hz", 5.0)
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (
            math.isfinite(rate) and rate > 0):
        raise InputError(f"{where}: sample_rate_Hz = {rate!r} must be a number > 0")
    grid = _grid(data.get("grid", {}), where)
    points = [tuple(zip(grid, values)) for values in itertools.product(*grid.values())]
    runs = []
    for label, scenario_path, scenario in scenarios:
        digest = _file_digest(scenario_path, scenario)
        for point in points:
            applied = _apply(scenario, point, scenario_path, where)
            for seed in seeds:
                key = {"scenario": digest, "params": point, "seed": seed, "vertices": n_vertices,
                       "sample_rate_Hz": float(rate), "truth": truth}
                runs.append(RunSpec(len(runs), run_id(key), applied["name"], label, applied,
                                    point, seed, truth, n_vertices, float(rate)))
    return Sweep(name, path, tuple(grid), tuple(runs))


def run_id(inputs: Mapping) -> str:
    """16 hex digits of the SHA-256 of ``inputs`` as canonical JSON."""
    text = json.dumps(inputs, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _scenario_files(value, path: Path) -> list[tuple[str, Path, dict]]:
    """(as written, resolved path, parsed TOML with ``map`` absolute) per scenario."""

    where = str(path)
    if (not isinstance(value, list) or not value
            or not all(isinstance(v, str) and v for v in value)):
        raise InputError(f"{where}: scenarios must be a non-empty list of scenario TOML paths "
                         f"(relative to the sweep file), got {value!r}")
    if len(set(value)) != len(value):
        raise InputError(f"{where}: scenarios lists a file twice")
    out = []
    for label in value:
        file = (path.parent / label).resolve()
        problem = file_problem(file, label, "scenario TOML")
        if problem:
            raise InputError(f"{where}: scenario file {problem}")
        with _named(where, "scenarios"):
            data = read_toml(file, "scenario")
        if isinstance(data.get("map"), str):  # the runs carry the data, not the file's folder
            data["map"] = str((file.parent / data["map"]).resolve())
        data.setdefault("name", file.stem)
        out.append((label, file, data))
    return out


def _file_digest(scenario_path: Path, data: dict) -> str:
    """Hash of the scenario file's text and its map's bytes (a changed input is a new run)."""
    h = hashlib.sha256(scenario_path.read_bytes())
    map_path = Path(data.get("map", ""))
    if map_path.is_file():
        h.update(map_path.read_bytes())
    return h.hexdigest()


def _seeds(value, where: str) -> list[int]:
    if isinstance(value, int) and not isinstance(value, bool):
        if value < 1:
            raise InputError(f"{where}: seeds = {value} must be >= 1 (a count) or a list of "
                             "integers")
        return list(range(value))
    if (isinstance(value, list) and value
            and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
        if len(set(value)) != len(value):
            raise InputError(f"{where}: seeds lists a seed twice")
        return list(value)
    raise InputError(f"{where}: seeds must be a count >= 1 or a non-empty list of integers, "
                     f"got {value!r}")


def _truth(value, path: Path) -> str | dict:
    where = str(path)
    if not isinstance(value, str) or not value:
        raise InputError(f"{where}: truth must be one of {', '.join(TRUTH_KINDS)} or the path "
                         f"of a TRUTH.toml, got {value!r}")
    if value in TRUTH_KINDS:
        return value
    if not value.endswith(".toml"):
        raise InputError(f"{where}: truth = {value!r} must be one of {', '.join(TRUTH_KINDS)} "
                         "or the path of a TRUTH.toml" + close_match_hint(value, TRUTH_KINDS))
    with _named(where, "truth"):
        data = read_toml(path.parent / value, "truth", InputError)
        truth_from_dict(data, value)  # refuse a bad truth now, not on every worker
    return data


@contextlib.contextmanager
def _named(where: str, what: str):
    """An error in a file the sweep names, prefixed with the sweep file and the key."""
    try:
        yield
    except InputError as exc:
        raise InputError(f"{where}: {what}: {exc}") from None


def _integer(value, key: str, low: int, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise InputError(f"{where}: {key} = {value!r} must be an integer >= {low}")
    return value


def _grid(value, where: str) -> dict[str, list]:
    if not isinstance(value, Mapping):
        raise InputError(f"{where}: [grid] must be a table of dotted scenario keys, got "
                         f"{value!r}")
    grid = {}
    for key, values in value.items():
        if isinstance(values, Mapping):  # [grid.battery] rated_energy_Wh = [...]
            raise InputError(f"{where}: grid key '{key}' must be quoted whole, e.g. "
                             f"\"{key}.{next(iter(values), 'key')}\" = [...]")
        if key.count(".") != 1 or not all(key.split(".")):
            raise InputError(f"{where}: grid key '{key}' must be 'table.key' of the scenario "
                             "(e.g. \"battery.rated_energy_Wh\")")
        if not isinstance(values, list) or not values:
            raise InputError(f"{where}: grid '{key}' must be a non-empty list of values, got "
                             f"{values!r}")
        if any(isinstance(v, list) for v in values):
            raise InputError(f"{where}: grid '{key}' values must be numbers, strings, "
                             f"booleans or inline tables, got {values!r}")
        if len({json.dumps(v, sort_keys=True) for v in values}) != len(values):
            raise InputError(f"{where}: grid '{key}' lists a value twice")
        grid[key] = values
    return grid


def _apply(scenario: dict, point, scenario_path: Path, where: str) -> dict:
    """The scenario with the grid point set, validated like a scenario file."""

    data = copy.deepcopy(scenario)
    for dotted, value in point:
        table, key = dotted.split(".")
        if not isinstance(data.setdefault(table, {}), dict):
            raise InputError(f"{where}: grid '{dotted}': '{table}' is not a table of "
                             f"{scenario_path.name}")
        data[table][key] = value
    try:
        scenario_from_dict(data, scenario_path)
    except InputError as exc:
        shown = ", ".join(f"{k} = {v!r}" for k, v in point) or "no grid"
        raise InputError(f"{where}: grid point {shown}: {exc}") from None
    return data
