"""The result file of a GNS inverse design (calibration.inverse): InverseResult and inverse.json.
Apart from the design so that the stages that read a result (the answer, the comparison) load no
torch.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from dem.atomic import write_json


@dataclass
class InverseResult:
    """Everything an inverse design produced (JSON via to_dict)."""

    measured: str
    names: list
    bounds: list
    gradient: str
    starts: list  # [StartResult]
    best_params: list
    best_value: float
    best_runout: list  # GNS L* at the measured t/t* at the optimum
    start_runout: list  # GNS L* at the first start
    posterior: dict
    geometry: dict
    seconds: dict  # optimisation, posterior, total (online), landscape
    n_batches: int
    landscape: dict | None = None  # {"axes": [[...], [...]], "values": [[...]]} GNS objective grid
    model_error_std: list | None = None  # GNS runout error of L* [K] joined to the noise model
    roughness: dict | None = None  # objective near the optimum (see posterior_at)
    start_packing_std: list | None = None  # packing scatter of L* [K] joined to the noise model
    runout: dict | None = None  # the runout method (dem.runout.RunoutMethod.to_config) every L* was read by
    # points whose rollout failed or was not finite: [{params, reason, seconds, start, iteration}]
    failed_points: list = field(default_factory=list)
    optimiser: str = "lbfgsb"  # OPTIMISERS
    # the GNS's response of the last L* to each design parameter against its dataset's DEM runs:
    # {"parameters": [ParameterResponse.to_dict()], "why": "" or why not checked (too few runs),
    # "dem" and "gns": {"points" [n][P], "last" [n]}}; None without those runs (calibration.sensitivity)
    sensitivity: dict | None = None
    # every point the GNS rolled out (the search's, the posterior's, the checks'): {"points" [n][P],
    # "runouts" [n][K] its L* at the measured t/t*}: its response, for a DEM correction of its optimum
    evaluated: dict | None = None

    def to_dict(self) -> dict:
        data = {
            k: getattr(self, k)
            for k in (
                "measured",
                "names",
                "bounds",
                "gradient",
                "best_params",
                "best_value",
                "best_runout",
                "start_runout",
                "posterior",
                "geometry",
                "seconds",
                "n_batches",
                "landscape",
                "model_error_std",
                "roughness",
                "start_packing_std",
                "runout",
                "failed_points",
                "optimiser",
                "sensitivity",
                "evaluated",
            )
        }
        data["starts"] = [s.to_dict() for s in self.starts]
        return data


def write_result(result: InverseResult, path: str | os.PathLike) -> None:
    """inverse.json (atomically)."""
    write_json(path, result.to_dict())


def read_result(path: str | os.PathLike) -> dict:
    """The inverse.json at path, as written by write_result."""
    return json.loads(Path(path).read_text())
