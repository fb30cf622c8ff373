"""The answer the project ships: the calibrated model of each measured column on the default config,
frozen from a default DAG's calibrated.json into data/answer/<name>.json, and checked against the
DEM of the code at hand (tests/test_shipped_answer.py).

  python -m pipeline.shipped freeze results/calibrated/quartz/calibrated.json data/answer/quartz.json
  python -m pipeline.shipped readme README.md data/answer/*.json   # the README's answer table

A ShippedAnswer holds what an engineer takes away (model, route, parameters, validated MSE with its
jackknife SE on so many packings) and what it takes to check it: the measured file, the runout
method, the size_scale, the engine version, and the runout curve of every packing it was scored on.

The answer is the one carried to the target resolution (calibration.target_size_scale) where the
DAG did so. The check (`rerun`) runs the answer on its first validation packings again. With the same engine
version the builtin DEM repeats its bits on every x86-64 processor, so the curves must come back as
stored; under other kernels a collapse is another draw of its chaos, and the score must lie within
what the packing scatter of the stored curves allows (`scatter_bound`).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.calibrated import Validation, validate
from calibration.calibrated_result import CalibratedResult
from calibration.design_runs import SimulationSettings
from calibration.measured import load_column
from calibration.model import Model, model_named
from calibration.objective import runout_mse
from dem.atomic import StrPath, write_json, write_text
from dem.integrate import ENGINE_VERSION
from dem.runout import RunoutMethod
from pipeline.calibrated_section import answer_score


@dataclass
class ShippedAnswer:
    """The shipped answer of one measured column.

    parameters: {name: value} in the model's order; mse: runout MSE (L*^2) of the mean curve over
    the packings `seeds`, mse_se its jackknife SE (None under 3 packings); curves [R][K]: L* of each
    packing at the measured t/t* (None where a run failed); channel_width (m): the side-wall
    candidate's channel; engine_version: dem.integrate.ENGINE_VERSION of the runs (that of the tree
    which freezes them: freeze on the tree that ran the DAG)."""

    name: str
    measured: str
    model: str
    route: str
    parameters: dict[str, float]
    mse: float
    mse_se: float | None
    seeds: list[int]
    curves: list[list[float] | None]
    size_scale: float
    runout: dict
    channel_width: float
    engine: str
    engine_version: str
    dem_runs: int  # what the route spent to find the parameters

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> ShippedAnswer:
        return cls(**data)

    def model_of(self) -> Model:
        """The Model the answer calibrates (its parameters in this answer's order)."""
        model = model_named(self.model, self.channel_width)
        if list(model.parameter_names) != list(self.parameters):
            raise ValueError(f"{self.name}: parameters {list(self.parameters)} are not model {self.model}'s")
        return model


def freeze(calibrated: CalibratedResult, channel_width: float = 0.01) -> ShippedAnswer:
    """The ShippedAnswer of a calibrated.json (as CalibratedResult.from_json reads it): the answer at
    the resolution it must hold at where the DAG carried it there (calibration.target_size_scale:
    its validation at the target), else the answer's route, scored on the runoff's packings where it
    ran one, else on the validation's (pipeline.calibrated_section.answer_score)."""
    score = answer_score(calibrated.to_dict())
    answer = score["route"]
    route, dem_runs, size_scale = answer["route"], int(answer["dem_runs"]), float(calibrated.size_scale)
    parameters = answer["parameters"]
    target = calibrated.target
    if target:  # the coarse answer's slopes and the target's steps are the carrying's cost
        score = target["validation"]
        parameters = score["parameters"]
        route += f", carried to size_scale {target['size_scale']:g}"
        dem_runs += int(target["coarse_runs"]) + int(target["target_runs"])
        size_scale = float(target["size_scale"])
    return ShippedAnswer(
        name=calibrated.name,
        measured=calibrated.measured,
        model=calibrated.model,
        route=route,
        parameters={k: float(v) for k, v in parameters.items()},
        mse=float(score["mse"]),
        mse_se=score["mse_se"],
        seeds=[int(s) for s in score["seeds"]],
        curves=score["curves"],
        size_scale=size_scale,
        runout=calibrated.runout,
        channel_width=channel_width,
        engine=calibrated.engine,
        engine_version=ENGINE_VERSION,
        dem_runs=dem_runs,
    )


def read_answer(path: StrPath) -> ShippedAnswer:
    return ShippedAnswer.from_dict(json.loads(Path(path).read_text()))


def rerun(answer: ShippedAnswer, n_packings: int = 2, root: StrPath = ".") -> Validation:
    """The answer run again by the DEM on its first n_packings packings (the measured file read from
    under `root`)."""
    column = load_column(Path(root) / answer.measured)
    runout = column.runout_reading(RunoutMethod.from_config(answer.runout))
    settings = SimulationSettings(size_scale=answer.size_scale)
    theta = list(answer.parameters.values())
    first = answer.seeds[0]
    dem = {"engine": answer.engine}
    return validate(answer.route, answer.model_of(), column, theta, settings, runout, dem, n_packings, seed0=first)


def scatter_bound(answer: ShippedAnswer, measured: np.ndarray, n_packings: int = 2) -> tuple[float, float]:
    """(lowest, highest) MSE of the mean curve of any n_packings of the stored packings: the range
    another draw of as many packings of the same parameters falls in, by the stored scatter."""
    curves = [np.asarray(c, float) for c in answer.curves if c is not None]
    scores = [runout_mse(np.mean(group, axis=0), measured) for group in itertools.combinations(curves, n_packings)]
    return float(min(scores)), float(max(scores))


TABLE_START, TABLE_END = "<!-- answer-table -->", "<!-- /answer-table -->"


def answer_table(answers: list[ShippedAnswer]) -> str:
    """The README's answer table (Markdown) of the shipped answers."""
    lines = [
        "| column | model | route | size_scale | parameters | validated runout MSE +- SE | packings | DEM runs |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for a in answers:
        parameters = ", ".join(f"{k} {v:.3g}" for k, v in a.parameters.items())
        se = "n/a" if a.mse_se is None else f"{a.mse_se:.2g}"
        score = f"{a.mse:.3g} +- {se}"
        row = f"| {a.name} | {a.model} | {a.route} | {a.size_scale:g} | {parameters} | {score} | {len(a.seeds)} |"
        lines.append(f"{row} {a.dem_runs} |")
    return "\n".join(lines)


def with_answer_table(readme: str, answers: list[ShippedAnswer]) -> str:
    """`readme` with the text between its answer-table markers replaced by answer_table(answers)."""
    head, start, rest = readme.partition(TABLE_START)
    _, end, tail = rest.partition(TABLE_END)
    if not start or not end:
        raise ValueError(f"the README has no {TABLE_START} ... {TABLE_END} block")
    return f"{head}{TABLE_START}\n{answer_table(answers)}\n{TABLE_END}{tail}"


def main(argv: list[str]) -> None:
    """freeze <calibrated.json> <answer.json> | readme <README.md> <answer.json>..."""
    if argv[1] == "freeze":
        write_json(argv[3], freeze(CalibratedResult.from_json(argv[2])).to_dict())
    elif argv[1] == "readme":
        readme = Path(argv[2])
        write_text(readme, with_answer_table(readme.read_text(), [read_answer(p) for p in argv[3:]]))
    else:
        raise SystemExit(main.__doc__)


if __name__ == "__main__":
    main(sys.argv)
